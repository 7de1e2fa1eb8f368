"""The PLANT node: binds plant_sim to the DBC (actuator frames in, sensor frames out) and records
the plant's ground truth, from which the KPIs are computed."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np
from cantools.database.can import Database, Message
from mypy_extensions import mypyc_attr

from firmware_py.rx import RxTable
from hil.errors import BindingError
from hil.runtime.truth import STANDSTILL_MPS
from plant_sim.brake import WSP_FILL, WSP_HOLD
from plant_sim.params import PlantParams
from plant_sim.sensors import Sensors, quantise

TRUTH_PERIOD_US = 10_000         # ground truth is sampled every 10 ms
SENSOR_FIELDS = (("AxleSpeed", "axle_speed_rad_s"), ("CylPressure", "cyl_pressure_Pa"),
                 ("AccelLong", "accel_mps2"))


@dataclass
class SensorFault:
    """A failed sensor of one car (hil.safety.injection `sensor`), applied to the reading the plant reports.

    mode "stuck": in [start_us, end_us) the reading is `value`, or, when `value` is None, the last
    reading before start_us.  mode "bias": `value` (the sensor's SI unit: rad/s, Pa, m/s²) is added
    to the reading, which is then quantised to the sensor's resolution again and kept ≥ 0 where the
    sensor cannot read negative (wheel speed, pressure).  The plant's physics is untouched."""

    car: int                       # 0-based
    signal: str                    # PLANT_CARn_SENSORS signal: AxleSpeed, CylPressure or AccelLong
    mode: str                      # "stuck" | "bias"
    value: float | None
    start_us: int
    end_us: int
    on_apply: Callable[[int], None] | None = None   # called with the plant time [µs] per reading altered
    last: float | None = None      # the reading before start_us


class PlantState(Protocol):
    """A plant's state now, per car (plant_sim's TruthSnapshot, an FMU plant's FmuSnapshot)."""

    @property
    def x(self) -> list[float]: ...        # position [m]

    @property
    def v(self) -> list[float]: ...        # speed [m/s]


class TruthSample(Protocol):
    """One sample of a plant's truth as the truth log keeps it (plant_sim's TruthSnapshot of numpy rows,
    an FMU plant's FmuRecord): the node reads its cars' speeds."""

    @property
    def v(self) -> list[float] | np.ndarray: ...


class SteppedPlant(Protocol):
    """The plant a PlantController steps and reads: plant_sim.plant.Plant, or an FMU
    (hil.fmi.plant.FmuPlant)."""

    @property
    def params(self) -> PlantParams: ...

    @property
    def t_us(self) -> int: ...

    @property
    def lead_position_m(self) -> float: ...

    @property
    def max_slip_mps(self) -> np.ndarray: ...

    def step(self, valve_cmd: np.ndarray, wsp_valve: np.ndarray,
             pressure_set: np.ndarray | None = None) -> None: ...

    def sense(self) -> Sensors: ...

    def snapshot(self) -> PlantState: ...

    def truth_record(self) -> TruthSample: ...

    def truth_series(self, snaps: Sequence[Any]) -> dict[str, np.ndarray]: ...   # its own samples


#: resolution of each sensor in plant_sim.params.SensorParams, and whether it reads ≥ 0 only
SENSOR_QUANTUM = {"AxleSpeed": ("axle_speed_quantum_rad_s", True),
                  "CylPressure": ("pressure_quantum_Pa", True),
                  "AccelLong": ("accel_quantum_mps2", False)}


def faulty_reading(reading: float, fault: SensorFault, quantum: float, non_negative: bool) -> float:
    """What a failed sensor reports instead of `reading` while its fault is active (pure): stuck, its value,
    else the last reading before the fault (this one when there was none); biased, the reading plus its
    bias, quantised again."""
    if fault.mode == "stuck":
        if fault.value is not None:
            return fault.value
        return reading if fault.last is None else fault.last
    bias = 0.0 if fault.value is None else fault.value      # a bias fault has its value (FaultSpec checks)
    out = float(quantise(np.asarray(reading + bias), quantum))
    return max(out, 0.0) if non_negative else out


class TruthLog:
    """Ground truth sampled at a fixed period: cheap raw snapshots during the run, derived quantities
    (adhesion, optimal slip, forces) computed once when the columns are asked for."""

    plant: SteppedPlant | None          # None in a copy from another process (its series are kept)
    t_us: list[int]
    snaps: list[TruthSample]
    max_slip_mps: np.ndarray | None
    rt_lag_us: list[int] | None
    _series: dict[str, np.ndarray]

    def __init__(self, plant: SteppedPlant | None) -> None:
        self.plant = plant
        self.t_us = []
        self.snaps = []
        # largest slip speed over EVERY plant step, per car [m/s]; kept for "lag" plants (seed 001 runs,
        # whose acceptance is s ≤ s̄ at every step), None otherwise (the 10 ms samples are all there is);
        # the plant's own running max, copied when the log crosses a process boundary
        self.max_slip_mps = None
        # real time: how far the plant's outputs of each sample's step were behind their schedule [µs]
        # (its wake's lateness + its clock's slip, hil.runtime.host); None in lockstep
        self.rt_lag_us = None
        self._series = {}

    def record(self, t_us: int, snap: TruthSample) -> None:
        self.t_us.append(t_us)
        self.snaps.append(snap)

    def __reduce__(self) -> tuple[Callable[..., TruthLog], tuple[Any, ...]]:
        """Crosses process boundaries as its series, without the plant or the raw snapshots (pickling those
        lists of floats took a real-time plant host ~0.4 CPU s at the end of a 30 s run)."""
        return _truth_copy, (self.t_us, self.series(), self.max_slip_mps, self.rt_lag_us)

    def series(self) -> dict[str, np.ndarray]:
        if self.plant is None:
            return self._series
        if not self.snaps:
            return {}
        return self.plant.truth_series(self.snaps)

    def columns(self) -> dict[str, np.ndarray]:
        """Flat columns: t_s, then `<quantity>_<k>` per car (or coupler) k starting at 1."""
        cols = {"t_s": np.asarray(self.t_us, dtype=np.int64) / 1e6}
        for key, arr in self.series().items():
            for k in range(arr.shape[1]):
                cols[f"{key}_{k + 1}"] = arr[:, k]
        if self.rt_lag_us is not None and len(self.rt_lag_us) == len(self.t_us):
            cols["rt_lag_s"] = np.asarray(self.rt_lag_us, dtype=np.int64) / 1e6
        return cols


def _truth_copy(t_us: list[int], series: dict[str, np.ndarray], max_slip_mps: np.ndarray | None,
                rt_lag_us: list[int] | None) -> TruthLog:
    """A TruthLog from another process (TruthLog.__reduce__): its samples' times and series, no plant."""
    log = TruthLog(None)
    log.t_us, log._series, log.max_slip_mps, log.rt_lag_us = t_us, series, max_slip_mps, rt_lag_us
    return log


def _message(db: Database, name: str, dbc_name: str) -> Message:
    """The DBC message the plant needs, or a BindingError naming it (a DBC of another bus)."""
    try:
        return db.get_message_by_name(name)
    except KeyError:
        raise BindingError(f"node PLANT: {dbc_name} has no message {name!r}; the plant needs the train "
                           f"brake frames of dbc/train_brake.dbc") from None


FAILSAFE_CYCLES = 3        # pressure-command cycles without a usable frame before the fail-safe applies
# how long the actuators hold a car's cylinder where its last command left it before they fill it [s]: the
# WSP safety timer's five seconds (firmware_py.wsp.WspParams.max_vent_s, patent CA 2025196), the longest an
# electronic fault may keep a cylinder below the demand before the brake applies regardless.  Scenario key
# [plant] failsafe_hold_s; 0 fills at once
FAILSAFE_HOLD_S = 5.0
NEVER_STALE_US = 1 << 62   # µs: no command can go stale before it (no car commanded yet)


class BaliseReader:
    """Car 1's balise transmission module: watches the train's front pass fixed balises (track positions
    [m], increasing) and reports the last one passed with the time since (PLANT_BTM).  The passage time
    is interpolated inside the plant step in which the front crossed the balise; balises behind the start
    position are not reported."""

    OUTPUTS: ClassVar[tuple[str, ...]] = ("PLANT_BTM.BalisePos", "PLANT_BTM.PassageAge",
                                          "PLANT_BTM.BaliseCount", "PLANT_BTM.BaliseValid")

    passed_us: float | None                                    # plant time of the last passage [µs]

    def __init__(self, positions: tuple[float, ...], x0_m: float) -> None:
        self.positions = positions
        self.next = sum(1 for b in positions if b <= x0_m)     # index of the next balise ahead
        self.count = 0
        self.passed_us = None
        self.x_prev = x0_m

    def after_step(self, t0_us: int, dt_us: int, x_m: float, out: dict[str, float]) -> None:
        """The plant stepped from t0_us by dt_us and its front is now at x_m: record passages, then set the
        frame's values in `out`."""
        while self.next < len(self.positions) and x_m >= self.positions[self.next]:
            b = self.positions[self.next]
            frac = (b - self.x_prev) / (x_m - self.x_prev) if x_m > self.x_prev else 1.0
            self.passed_us = t0_us + frac * dt_us
            self.count += 1
            self.next += 1
        self.x_prev = x_m
        if self.passed_us is not None:
            out["PLANT_BTM.BalisePos"] = self.positions[self.next - 1]
            out["PLANT_BTM.PassageAge"] = min((t0_us + dt_us - self.passed_us) * 1e-6, 6.5535)
            out["PLANT_BTM.BaliseCount"] = self.count % 256
            out["PLANT_BTM.BaliseValid"] = 1


@mypyc_attr(allow_interpreted_subclasses=True)   # a study's plant extends it (hil/studies/*/nodes.py)
class PlantController:
    """step(now_us, rx): sense (when the sensor frames are due), record truth, then integrate one step.

    The brake actuators of each car follow its BECU's last usable pressure command (frames the E2E
    or SecOC check rejects never arrive here).  Loss of command is braking, as on a railway, within a
    bound: when a car that has been commanded gets no usable command for FAILSAFE_CYCLES command cycles,
    its actuators first hold the cylinder where the last command left it (EP valve closed, dump valve in
    HOLD) for `failsafe_hold_s`, then apply the brake on their own — EP valve fully open to the
    reservoir, dump valve closed, set-point p̄ — until commands come back.  The hold keeps a car whose
    commands are lost for a moment (a blocked bus, a corrupted stream) off a locked wheel on low adhesion,
    where a fill without WSP locks it within 1.5 s; a BECU that stays silent still brakes after the hold
    (`failsafe_us`: time in the fail-safe per car, `failsafe_fill_us`: of which filling)."""

    plant: SteppedPlant
    n: int
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    truth: TruthLog
    standstill: bool             # every car below STANDSTILL_MPS at the last truth sample
    sensor_faults: list[SensorFault]
    btm: BaliseReader | None

    def __init__(self, plant: SteppedPlant, n_cars: int, db: Database, dbc_name: str = "the DBC",
                 balises: Sequence[float] = (), failsafe_hold_s: float = FAILSAFE_HOLD_S) -> None:
        self.plant = plant
        self.n = n_cars
        self.valve_keys = [f"BECU{i}_PRESS_CMD.ValveCmd" for i in range(1, n_cars + 1)]
        self.wsp_keys = [f"BECU{i}_PRESS_CMD.WspValve" for i in range(1, n_cars + 1)]
        self.lag = plant.params.brake.pressure_model == "lag"     # cylinders follow CylPressureSet
        self.set_keys = ([f"BECU{i}_PRESS_CMD.CylPressureSet" for i in range(1, n_cars + 1)] if self.lag
                         else [])
        self.inputs = tuple(self.valve_keys + self.wsp_keys + self.set_keys)
        self._pset = np.zeros(n_cars)
        self.outputs = tuple(f"PLANT_CAR{i}_SENSORS.{sig}" for i in range(1, n_cars + 1)
                             for sig, _ in SENSOR_FIELDS + (("SensorCounter", ""),))
        cycle_ms = _message(db, "PLANT_CAR1_SENSORS", dbc_name).cycle_time
        if not cycle_ms:
            raise BindingError(f"node PLANT: message PLANT_CAR1_SENSORS of {dbc_name} has no cycle time "
                               "(GenMsgCycleTime); the plant sends its sensor frames at that period")
        self.sensor_period_us = int(cycle_ms) * 1000
        command_ms = _message(db, "BECU1_PRESS_CMD", dbc_name).cycle_time or 10
        self.failsafe_after_us = FAILSAFE_CYCLES * int(command_ms) * 1000
        self.fill_after_us = self.failsafe_after_us + round(failsafe_hold_s * 1e6)   # held until then
        self.failsafe_us = np.zeros(n_cars, dtype=np.int64)        # time in the fail-safe, per car [µs]
        self.failsafe_fill_us = np.zeros(n_cars, dtype=np.int64)   # ... of which filling [µs]
        self._p_max = plant.params.brake.p_max_Pa
        self._last_us: int | None = None         # the time of the last step [µs]
        self.next_sense_us = 0
        self.next_truth_us = 0
        self.sense_count = 0
        self.truth = TruthLog(plant)
        if self.lag:
            self.truth.max_slip_mps = plant.max_slip_mps     # the plant's running max (a live view)
        self._rx_version = -1                    # the table's version the actuators last followed
        # _failsafe: until _quiet_until_us [µs] no command can be stale, while rx is the same table and has
        # not changed since (version _quiet_version).  Once every car has been commanded (_quiet_version
        # None) a change cannot make it wrong: a command received only makes its car's command fresher
        self._quiet_until_us = -1
        self._quiet_rx: RxTable | None = None
        self._quiet_version: int | None = -1
        self._valve = np.zeros(n_cars)
        self._wsp = np.zeros(n_cars, dtype=np.int64)
        self.standstill = False
        self.sensor_faults = []
        self._sensor_keys = [tuple(f"PLANT_CAR{i}_SENSORS.{sig}" for sig, _ in SENSOR_FIELDS)
                             for i in range(1, n_cars + 1)]
        self._counter_keys = [f"PLANT_CAR{i}_SENSORS.SensorCounter" for i in range(1, n_cars + 1)]
        self.btm = BaliseReader(tuple(balises), plant.lead_position_m) if balises else None
        if self.btm is not None:
            self.outputs += BaliseReader.OUTPUTS

    def add_sensor_fault(self, fault: SensorFault) -> None:
        """A failed sensor (hil.safety.injection `sensor`): applied to the readings this node sends."""
        self.sensor_faults.append(fault)

    def _apply_sensor_faults(self, now_us: int, out: dict[str, float]) -> None:
        sp = self.plant.params.sensors
        for f in self.sensor_faults:
            key = f"PLANT_CAR{f.car + 1}_SENSORS.{f.signal}"
            if now_us < f.start_us:
                f.last = out[key]
            elif now_us < f.end_us:
                if f.last is None:
                    f.last = out[key]
                attr, non_negative = SENSOR_QUANTUM[f.signal]
                out[key] = faulty_reading(out[key], f, getattr(sp, attr), non_negative)
                if f.on_apply is not None:
                    f.on_apply(now_us)

    def glance(self) -> dict[str, np.ndarray]:
        """Speeds and positions now, for progress displays."""
        snap = self.plant.snapshot()
        return {"v_mps": np.array(snap.v), "x_m": np.array(snap.x)}

    def _actuators(self, rx: RxTable) -> None:
        """Each car's valve, dump valve (and set-point) as its last command in `rx` has them; a command not
        received yet (NaN) or not finite leaves the valve closed, the dump valve in FILL, the set-point 0."""
        if rx.version == self._rx_version:
            return
        self._rx_version = rx.version
        latest = rx.latest
        self._valve[:] = [_finite_or(latest[key], 0.0) for key in self.valve_keys]
        self._wsp[:] = [int(_finite_or(latest[key], 0.0)) for key in self.wsp_keys]   # a 2-bit state's float
        if self.lag:
            self._pset[:] = [_finite_or(latest[key], 0.0) for key in self.set_keys]

    def _failsafe(self, now_us: int, rx: RxTable) -> None:
        """Cars whose command went stale hold their cylinder, then apply the brake (class docstring)."""
        dt = 0 if self._last_us is None else now_us - self._last_us
        self._last_us = now_us
        if self._quiet(now_us, rx):
            return                            # none can be stale yet
        quiet_until_us = NEVER_STALE_US
        commanded = 0
        for k, key in enumerate(self.valve_keys):
            age = rx.age_us(key, now_us)
            if age is None:                   # never commanded: nothing to hold
                continue
            quiet_until_us = min(quiet_until_us, now_us - age + self.failsafe_after_us)   # stale after it
            commanded += 1
            if age > self.failsafe_after_us:
                if age > self.fill_after_us:     # held as long as allowed: the brake applies
                    self._valve[k] = 1.0
                    self._wsp[k] = WSP_FILL
                    if self.lag:
                        self._pset[k] = self._p_max
                    self.failsafe_fill_us[k] += dt
                else:                            # held where the last command left it
                    self._valve[k] = 0.0
                    self._wsp[k] = WSP_HOLD
                self.failsafe_us[k] += dt
                self._rx_version = -1          # recompute from rx as soon as commands return
        self._quiet_until_us, self._quiet_rx = quiet_until_us, rx
        self._quiet_version = None if commanded == self.n else rx.version

    def _quiet(self, now_us: int, rx: RxTable) -> bool:
        """No command can be stale at `now_us` (the quick case of `_failsafe`)."""
        return now_us <= self._quiet_until_us and rx is self._quiet_rx and (
            self._quiet_version is None or rx.version == self._quiet_version)

    def step(self, now_us: int, rx: RxTable) -> dict[str, float]:
        out: dict[str, float] = {}
        if now_us >= self.next_sense_us:
            s = self.plant.sense()
            counter = self.sense_count % 256
            speeds, pressures, accels = (s.axle_speed_rad_s.tolist(), s.cyl_pressure_Pa.tolist(),
                                         s.accel_mps2.tolist())
            for k, (speed_key, pressure_key, accel_key) in enumerate(self._sensor_keys):
                out[speed_key] = speeds[k]
                out[pressure_key] = pressures[k]
                out[accel_key] = accels[k]
                out[self._counter_keys[k]] = counter
            if self.sensor_faults:
                self._apply_sensor_faults(now_us, out)
            self.sense_count += 1
            self.next_sense_us += self.sensor_period_us
        if now_us >= self.next_truth_us:
            snap = self.plant.truth_record()
            self.truth.record(now_us, snap)
            self.standstill = float(np.max(snap.v)) < STANDSTILL_MPS
            self.next_truth_us += TRUTH_PERIOD_US
        self._actuators(rx)
        self._failsafe(now_us, rx)
        if self.lag:
            self.plant.step(self._valve, self._wsp, self._pset)
        else:
            self.plant.step(self._valve, self._wsp)
        if self.btm is not None:
            self.btm.after_step(now_us, self.plant.t_us - now_us, self.plant.lead_position_m, out)
        return out


def _finite_or(value: float, default: float) -> float:
    """`value` if it is finite, else `default` (a command not received yet reads NaN)."""
    return value if math.isfinite(value) else default
