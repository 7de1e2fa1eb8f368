"""The brake control of one car, as an external BECU: pure, no bus, no clock (time is passed in).

Chain, each cycle (10 ms):

1. target deceleration: BCU_DEMAND.TargetDecel; at least the emergency deceleration while
   BCU_EMERGENCY.EmergencyActive = 1, and also when the demand is lost (no usable BCU_DEMAND for more
   than 3 cycles: a corrupt, forged, stale and missing demand all age it);
2. cylinder-pressure set-point from the inverse brake model: force F = m·a, torque τ = F·r, pressure
   p = τ/ᾱ + preload on the squeeze line, clipped to 0..p̄; the BCU's friction correction φ
   (BCU_STATUS.FrictionPhi) divides the force part, except in emergency and on loss of command;
3. reference speed: the accelerometer integrated, pulled to the axle's r·ω while the wheel does not slip;
4. wheel-slide protection: slip speed = reference − r·ω; VENT above 0.30 m/s + 3 % of the speed, HOLD
   below half of that, FILL below a quarter; off below 1 m/s; a cylinder kept out of FILL for 5 s is
   refilled until the wheel recovers;
5. PI control of the EP valve opening (ValveCmd, −1..+1) on the pressure error, with conditional
   anti-windup; frozen, and the valve closed, while WSP holds or vents.

The numbers are those of the brake ECU and the plant of the train this BECU joins (railhil's defaults for
the default scenario: a 40 t car); each constant says where it comes from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum


class Wsp(IntEnum):
    """WSP dump-valve state: the DBC choices of BECUn_PRESS_CMD.WspValve."""

    FILL = 0
    HOLD = 1
    VENT = 2


@dataclass(frozen=True)
class CarParams:
    """The car and its brake, and the gains of this ECU."""

    cycle_us: int = 10_000                # BECUn_PRESS_CMD's GenMsgCycleTime (DBC), 10 ms
    car_mass_kg: float = 40_000.0         # [train] mass_kg of scenarios/default.toml (load-weighed)
    wheel_radius_m: float = 0.46          # r, the plant's TrainParams.wheel_radius_m (Ø 920 mm wheel)
    brake_gain_Nm_per_Pa: float = 0.08    # ᾱ, slope of the plant's squeeze line (BrakeParams, seed 001 eq. 6)
    brake_preload_Pa: float = 30e3        # −β̄/ᾱ, the return spring: no torque below it (BrakeParams)
    p_max_Pa: float = 450e3               # p̄, the reservoir pressure (BrakeParams.p_max_Pa)
    # EP valve PI: opening per Pa of pressure error; with the valve's 1 MPa/s at full opening kp gives a
    # 50 ms closed-loop time constant (railhil's BecuParams.pressure_pi)
    kp_per_Pa: float = 2.0e-5
    ki_per_Pa_s: float = 4.0e-5
    # wheel-slide protection (railhil's WspParams)
    vent_slip_mps: float = 0.30           # vent threshold at standstill [m/s]
    vent_slip_per_speed: float = 0.03     # + this fraction of the reference speed
    hold_fraction: float = 0.5            # VENT -> HOLD below this fraction of the vent threshold
    refill_fraction: float = 0.25         # HOLD -> FILL below this fraction
    wsp_min_speed_mps: float = 1.0        # WSP off below this speed: lets the train stop
    max_vent_s: float = 5.0               # vent-time watchdog (a 5 s WSP safety timer)
    # reference speed: below this apparent slip the axle is trusted, with this gain per cycle
    wheel_trust_slip_mps: float = 0.2
    wheel_trust_gain: float = 0.2
    emergency_decel_mps2: float = 1.3     # the BCU's emergency deceleration (BcuParams.emergency_decel_mps2)
    failsafe_cycles: int = 3              # cycles without a usable demand before loss of command
    phi_limits: tuple[float, float] = (0.6, 1.6)   # the authority of the BCU's φ over this car


@dataclass(frozen=True)
class Inputs:
    """The latest usable values of the received signals (NaN: never received) and the demand's age."""

    axle_speed_rad_s: float = math.nan    # PLANT_CARn_SENSORS.AxleSpeed
    cyl_pressure_Pa: float = math.nan     # PLANT_CARn_SENSORS.CylPressure
    accel_mps2: float = math.nan          # PLANT_CARn_SENSORS.AccelLong
    target_decel_mps2: float = math.nan   # BCU_DEMAND.TargetDecel
    emergency: float = math.nan           # BCU_EMERGENCY.EmergencyActive
    friction_phi: float = math.nan        # BCU_STATUS.FrictionPhi
    demand_age_us: int | None = None      # time since the last usable BCU_DEMAND; None: none yet


def finite_or(x: float, safe: float) -> tuple[float, bool]:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return safe, False
    return (x, True) if math.isfinite(x) else (safe, False)


def clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def wsp_transition(state: Wsp, slip_mps: float, speed_mps: float, p: CarParams) -> Wsp:
    """Vent / hold / refill with hysteresis on the slip speed (pure)."""
    if speed_mps < p.wsp_min_speed_mps:
        return Wsp.FILL
    vent_at = p.vent_slip_mps + p.vent_slip_per_speed * speed_mps
    if slip_mps > vent_at:
        return Wsp.VENT
    if state == Wsp.VENT:
        return Wsp.HOLD if slip_mps < p.hold_fraction * vent_at else Wsp.VENT
    if state == Wsp.HOLD:
        return Wsp.FILL if slip_mps < p.refill_fraction * vent_at else Wsp.HOLD
    return Wsp.FILL


def pressure_for_decel(decel_mps2: float, p: CarParams) -> float:
    """The set-point that gives `decel` on the squeeze line: F = m a, τ = F r, p = τ/ᾱ + preload."""
    if decel_mps2 <= 0.0:
        return 0.0
    torque = p.car_mass_kg * decel_mps2 * p.wheel_radius_m
    return clip(torque / p.brake_gain_Nm_per_Pa + p.brake_preload_Pa, 0.0, p.p_max_Pa)


def apply_phi(p_set_Pa: float, phi: float, p: CarParams) -> float:
    """The BCU's correction φ on the force part of the set-point, φ gated to `phi_limits`."""
    pre = p.brake_preload_Pa
    if phi == 1.0 or p_set_Pa <= pre:
        return p_set_Pa
    return clip(pre + (p_set_Pa - pre) / clip(phi, *p.phi_limits), 0.0, p.p_max_Pa)


class BrakeControl:
    """One car's brake ECU: `step(now_us, inputs)` -> the DBC signals of BECUn_PRESS_CMD, _STATUS, _DIAG."""

    def __init__(self, params: CarParams | None = None) -> None:
        self.p = params or CarParams()
        self.v_ref = math.nan         # reference speed [m/s]
        self.wsp = Wsp.FILL
        self.vent_s = 0.0             # time out of FILL without a break [s]
        self.wsp_tripped = False      # the vent-time watchdog holds the cylinder in FILL
        self.integrator = 0.0         # EP valve PI
        self.last_us: int | None = None
        self.lost_cycles = 0          # cycles braked by loss of command (diagnostic)

    def _dt_s(self, now_us: int) -> float:
        dt = self.p.cycle_us * 1e-6 if self.last_us is None else (now_us - self.last_us) * 1e-6
        self.last_us = now_us
        return dt

    def _reference_speed(self, wheel_v: float, accel: float, dt_s: float) -> float:
        if not math.isfinite(self.v_ref):
            return wheel_v
        v_pred = self.v_ref + accel * dt_s
        if wheel_v >= v_pred:
            return wheel_v
        if v_pred - wheel_v < self.p.wheel_trust_slip_mps:
            return v_pred + self.p.wheel_trust_gain * (wheel_v - v_pred)
        return max(v_pred, 0.0)

    def _valve(self, error_Pa: float, dt_s: float, freeze: bool) -> tuple[float, bool]:
        """PI with conditional anti-windup: (opening −1..+1, saturated)."""
        p = self.p
        i_next = self.integrator if freeze else self.integrator + p.ki_per_Pa_s * error_Pa * dt_s
        unclipped = p.kp_per_Pa * error_Pa + i_next
        out = clip(unclipped, -1.0, 1.0)
        winding_up = (unclipped > 1.0 and error_Pa > 0.0) or (unclipped < -1.0 and error_Pa < 0.0)
        if not winding_up:
            self.integrator = i_next
        return out, unclipped != out

    def step(self, now_us: int, rx: Inputs) -> dict[str, float]:
        p = self.p
        dt_s = self._dt_s(now_us)
        omega, ok1 = finite_or(rx.axle_speed_rad_s, 0.0)
        pressure, ok2 = finite_or(rx.cyl_pressure_Pa, 0.0)
        accel, ok3 = finite_or(rx.accel_mps2, 0.0)
        decel, ok4 = finite_or(rx.target_decel_mps2, 0.0)
        emergency, ok5 = finite_or(rx.emergency, 0.0)
        missing = not (ok1 and ok2 and ok3 and ok4 and ok5)
        if emergency >= 0.5:
            decel = max(decel, p.emergency_decel_mps2)
        lost = rx.demand_age_us is not None and rx.demand_age_us > p.failsafe_cycles * p.cycle_us
        if lost:                                          # loss of command brakes
            decel = max(decel, p.emergency_decel_mps2)
            self.lost_cycles += 1

        wheel_v = omega * p.wheel_radius_m
        self.v_ref = self._reference_speed(wheel_v, accel, dt_s)
        slip = self.v_ref - wheel_v
        wanted = wsp_transition(self.wsp, slip, self.v_ref, p)
        if self.wsp_tripped:                              # watchdog: re-armed once the wheel recovered
            self.vent_s, self.wsp_tripped = 0.0, wanted != Wsp.FILL
        else:
            self.vent_s = self.vent_s + dt_s if wanted != Wsp.FILL else 0.0
            if self.vent_s > p.max_vent_s:
                self.vent_s, self.wsp_tripped = 0.0, True
        self.wsp = Wsp.FILL if self.wsp_tripped else wanted
        overridden = self.wsp != Wsp.FILL

        p_set = pressure_for_decel(decel, p)
        phi, phi_ok = finite_or(rx.friction_phi, 1.0)
        if phi_ok and emergency < 0.5 and not lost:
            p_set = apply_phi(p_set, phi, p)
        valve, saturated = self._valve(p_set - pressure, dt_s, freeze=overridden)
        if overridden:
            valve = 0.0                                   # the dump valve acts, the EP valve holds
        return {
            "CylPressureSet": p_set,
            "ValveCmd": valve,
            "WspValve": int(self.wsp),
            "SpeedEst": max(self.v_ref, 0.0),
            "SlipSpeedEst": slip,
            "WspActive": int(overridden),
            "GovernorActive": 0,
            "IntegratorSat": int(saturated or overridden),
            "InputMissing": int(missing or lost),
            "OptSlipEst": 0.0,
            "OptSlipPos": 0.0,
            "GovernedDecel": decel,
            "GovernorMargin": 0.0,
            "GovernorFeasible": 1,
            "SpeedSensorFault": 0,
            "AccelSensorFault": 0,
            "AccelBiasEst": 0.0,
        }

    def safe_outputs(self) -> dict[str, float]:
        """What the ECU sends when its step fails: fill the cylinder (a brake ECU that fails brakes)."""
        return {"CylPressureSet": self.p.p_max_Pa, "ValveCmd": 1.0, "WspValve": int(Wsp.FILL),
                "InputMissing": 1, "GovernorFeasible": 1}
