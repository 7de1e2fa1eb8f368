"""The EBC-7's control law on its own signals: what its firmware (ebc7.py) runs every 10 ms, and what
railhil runs as the EBC-7's model in lockstep (acme_becu.toml: model = "ebc7_control:Ebc7Control").

`Ebc7Control.step(now_us, rx) -> signals` reads the EBC-7's inputs by their names in acme_becu.dbc
(km/h, bar, m/s²) from `rx` — any mapping of "MESSAGE.Signal" to the latest value that also answers
`rx.age_us(name, now_us)`, the time since that value was received (None: never) — and returns its outputs
by the same names.  The law itself is railhil's BECU in its pressure control, as
examples/external_becu/brake_control.py writes it without railhil (demand → set-point through the inverse
brake model, reference speed, sensor checks, wheel-slide protection, PI on the EP valve), in SI units: this
module converts at its edges, as a supplier's interface layer would.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

# the control law of examples/external_becu, beside this example
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "external_becu"))
from brake_control import BrakeControl, CarParams, Inputs  # noqa: E402

KMH_PER_MPS = 3.6
PA_PER_BAR = 1e5
KG_PER_T = 1000.0
APPLIED = 1                  # VCU_BRAKE_DEMAND.EmergencyBrake "APPLIED" (acme_becu.dbc)
SLIP_KMH_MAX = 327.67        # EBC7_STATUS.SlipSpeed's range [km/h]
BIAS_MPS2 = (-4.096, 4.094)  # EBC7_STATUS.AccelBias's range [m/s²]

DEMAND, MODE, EMERGENCY, LOAD = ("VCU_BRAKE_DEMAND.DecelDemand", "VCU_BRAKE_DEMAND.BrakeMode",
                                 "VCU_BRAKE_DEMAND.EmergencyBrake", "VCU_BRAKE_DEMAND.CarLoad")
WHEEL, CYLINDER, ACCEL = "VCU_WHEEL_DATA.WheelSpeed", "VCU_WHEEL_DATA.CylPressure", "VCU_WHEEL_DATA.LongAccel"


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


class Ebc7Control:
    """The EBC-7 of one car (module docstring)."""

    inputs = (DEMAND, MODE, EMERGENCY, LOAD, WHEEL, CYLINDER, ACCEL)
    outputs = ("EBC7_VALVE_CMD.PressureSetpoint", "EBC7_VALVE_CMD.ValveOpening", "EBC7_VALVE_CMD.DumpValve",
               "EBC7_STATUS.SpeedEstimate", "EBC7_STATUS.SlipSpeed", "EBC7_STATUS.WspActive",
               "EBC7_STATUS.InputMissing", "EBC7_STATUS.IntegratorSat", "EBC7_STATUS.SpeedSensorFail",
               "EBC7_STATUS.AccelSensorFail", "EBC7_STATUS.CylSensorFail", "EBC7_STATUS.AccelBias")

    def __init__(self, params: CarParams | None = None) -> None:
        self.control = BrakeControl(params or CarParams())

    def _load(self, load_t: float) -> None:
        """The load-weighed mass of the car (VCU_BRAKE_DEMAND.CarLoad) sets the brake model's mass."""
        if math.isfinite(load_t) and load_t > 0.0 and load_t * KG_PER_T != self.control.p.car_mass_kg:
            self.control.p = dataclasses.replace(self.control.p, car_mass_kg=load_t * KG_PER_T)

    def step(self, now_us: int, rx) -> dict[str, float]:
        self._load(rx[LOAD])
        r = self.control.p.wheel_radius_m
        emergency = rx[EMERGENCY]
        out = self.control.step(now_us, Inputs(
            axle_speed_rad_s=rx[WHEEL] / KMH_PER_MPS / r,
            cyl_pressure_Pa=rx[CYLINDER] * PA_PER_BAR,
            accel_mps2=rx[ACCEL],
            target_decel_mps2=rx[DEMAND],
            emergency=emergency if emergency != emergency else float(emergency == APPLIED),
            demand_age_us=rx.age_us(DEMAND, now_us),
            sensors_age_us=rx.age_us(WHEEL, now_us)))
        return self._signals(out)

    def _signals(self, out: dict[str, float]) -> dict[str, float]:
        """The law's SI outputs as the EBC-7's signals (its DumpValve values are the law's Wsp numbers)."""
        return {
            "EBC7_VALVE_CMD.PressureSetpoint": out["CylPressureSet"] / PA_PER_BAR,
            "EBC7_VALVE_CMD.ValveOpening": out["ValveCmd"] * 100.0,
            "EBC7_VALVE_CMD.DumpValve": out["WspValve"],
            "EBC7_STATUS.SpeedEstimate": out["SpeedEst"] * KMH_PER_MPS,
            "EBC7_STATUS.SlipSpeed": _clip(out["SlipSpeedEst"] * KMH_PER_MPS, -SLIP_KMH_MAX, SLIP_KMH_MAX),
            "EBC7_STATUS.WspActive": out["WspActive"],
            "EBC7_STATUS.InputMissing": out["InputMissing"],
            "EBC7_STATUS.IntegratorSat": out["IntegratorSat"],
            "EBC7_STATUS.SpeedSensorFail": out["SpeedSensorFault"],
            "EBC7_STATUS.AccelSensorFail": out["AccelSensorFault"],
            "EBC7_STATUS.CylSensorFail": out["CylSensorFault"],
            "EBC7_STATUS.AccelBias": _clip(out["AccelBiasEst"], *BIAS_MPS2),
        }

    def safe_outputs(self) -> dict[str, float]:
        """What the EBC-7 sends when its step fails: it fills the cylinder (a brake ECU that fails brakes)."""
        return self._signals({**dict.fromkeys(("SpeedEst", "SlipSpeedEst", "AccelBiasEst", "WspActive",
                                               "IntegratorSat", "SpeedSensorFault", "AccelSensorFault",
                                               "CylSensorFault"), 0), **self.control.safe_outputs()})
