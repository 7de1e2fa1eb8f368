"""Train brake control unit (BCU): a small pipeline.

    DESK brake step (0..7), or the driver's brake valve a PLC on the desk sets -> a target deceleration
    demand sources (`DemandSource`: a function that asks for service or emergency braking)
    -> the mode (released / service / emergency, latched until standstill) and the target deceleration
       sent to every car (the largest asked for; jerk-limited in service; the emergency deceleration)
    -> followers (`Follower`: a function that watches the demand and adds its own signals).

An emergency request (the desk's, or a source's) brakes at the emergency deceleration until the train
stands and the request is released; BCU_EMERGENCY.Source says who asked (1 the desk, a source's own code,
3 the BCU's fail-safe).  A stage brings its own parameters, state, inputs and output signals; the pipeline
knows only the stage interfaces (a study binds its stages: hil/studies/<name>/nodes.py).

Train speed: the highest speed estimate (BECUn_STATUS.SpeedEst) of the cars that are heard from and
plausible.  A car is implausible (issues #9, #19: excluded, latched, flagged in CarsImplausible, Degraded)
only on evidence a real slide cannot produce (`_vote`): its estimate more than 2 m/s ABOVE the median of
the train for longer than 3 of its status cycles (a braked wheel is never faster than its car, seed 001
eq. (2): s ≥ 0), or more than 2 m/s BELOW it for longer than a slide can last (6 s: the BECU's WSP
vent watchdog refills within 5 s and its locked-wheel check takes over within 1 s).  A low estimate
cannot lower the train speed (the maximum), so the longer allowance costs no safety.
A car that reports a failed sensor (BECUn_DIAG.SpeedSensorFault / AccelSensorFault / CylSensorFault) also
makes the train Degraded (its estimate stays in: its BECU already excluded the failed sensor).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import ClassVar, NamedTuple, Protocol

from firmware_py.brake_valve import BrakeValve, BrakeValveParams, ValvePosition
from firmware_py.cycle import CycleTimer
from firmware_py.limits import finite_or, rate_limit
from firmware_py.rx import RxTable


class BcuMode(IntEnum):
    """Values are the DBC choices of BCU_DEMAND.Mode."""

    RELEASED = 0
    SERVICE = 1
    EMERGENCY = 2


def bcu_mode_transition(mode: BcuMode, brake_step: int, emergency_req: bool, standstill: bool,
                        service_demand: bool = False) -> BcuMode:
    """Pure mode logic: emergency latches until the train stands and the request is gone; service while
    a brake step is demanded or a demand source asks for service braking (`service_demand`, e.g. holding
    the train at a stop)."""
    if emergency_req:
        return BcuMode.EMERGENCY
    if mode == BcuMode.EMERGENCY and not standstill:
        return BcuMode.EMERGENCY
    return BcuMode.SERVICE if brake_step > 0 or service_demand else BcuMode.RELEASED


def disagreement(speeds: Sequence[float], trusted: Sequence[bool], limit_mps: float,
                 min_voters: int = 3) -> list[int]:
    """Per car, +1 if its speed estimate [m/s] is more than `limit_mps` above the median of the trusted
    cars that are heard from, −1 if more than that below it, else 0 (pure).  NaN = not heard from: never
    disagreeing.  Needs `min_voters` such cars: with two, nobody can tell which one is wrong.  The median
    includes the car itself: with three cars the median of the other two is their mean, which one stuck
    car drags along."""
    voters = [v for v, ok in zip(speeds, trusted, strict=True) if ok and not math.isnan(v)]
    if len(voters) < min_voters:
        return [0] * len(speeds)
    median = statistics.median(voters)
    return [0 if math.isnan(v) or not abs(v - median) > limit_mps else 1 if v > median else -1
            for v in speeds]


def disagreeing_cars(speeds: Sequence[float], trusted: Sequence[bool], limit_mps: float,
                     min_voters: int = 3) -> list[bool]:
    """Cars whose speed estimate disagrees with the train's median either way (`disagreement`)."""
    return [d != 0 for d in disagreement(speeds, trusted, limit_mps, min_voters)]


@dataclass(frozen=True)
class BcuParams:
    cycle_us: int = 10_000                   # BCU cycle, DESIGN.md node table
    # seven service brake steps, each a target deceleration (seed 004 §2: "seven levels"); linear up to
    # 1.0 m/s^2 at step 7, a typical full-service deceleration of a metro/EMU (chosen)
    step_decel_mps2: tuple[float, ...] = (0.0, 1 / 7, 2 / 7, 3 / 7, 4 / 7, 5 / 7, 6 / 7, 1.0)
    emergency_decel_mps2: float = 1.3        # emergency brake deceleration (chosen)
    jerk_limit_mps3: float = 1.0             # comfort limit on service demand changes (chosen)
    standstill_mps: float = 0.1              # train speed estimate below which the train stands
    # a car whose BECUn_STATUS (50 ms, DBC) is older than 3 of its cycles is silent: degraded mode
    status_timeout_us: int = 150_000
    # issues #9, #19: a car whose SpeedEst is more than implausible_mps above the train's median for longer
    # than 3 of its BECUn_STATUS cycles (50 ms, DBC) is implausible: no slide makes an estimate high.  2 m/s
    # (7 km/h) is far above what cars coupled in one train differ by (coupler play; a BECU's estimate
    # rides on its accelerometer during slides: ≤ 0.2 m/s from the truth in 25 default runs) (chosen)
    implausible_mps: float = 2.0
    implausible_after_us: int = 150_000
    # ... and one more than implausible_mps BELOW the median only after this: a slide lowers a wheel, and a
    # BECU whose estimate followed it would read low while it lasts; WSP's vent watchdog refills a vented
    # cylinder within 5 s (BecuParams.wsp.max_vent_s) and the locked-wheel check (SensorCheckParams.lock_s,
    # 1 s) switches a wheel that stays down to the accelerometer, so a slide is over by then (chosen)
    slide_allow_us: int = 6_000_000
    # the driver's brake valve a PLC on the desk sets (DESK_CMD.BrakeValve, seed 002 §VII), integrated into a
    # demand at its service / release rate; its ceiling is full service (step 7)
    brake_valve: BrakeValveParams = field(default_factory=BrakeValveParams)
    desk_timeout_us: int = 300_000           # a valve position (DESK_CMD, 100 ms) older than 3 cycles: the
    #                                          PLC is silent and the valve goes to V (service brake), as a
    #                                          brake pipe vents when its control is lost (chosen)


VALVE_POSITIONS = frozenset(int(p) for p in ValvePosition)


class Train(NamedTuple):
    """What a stage sees of the train in one BCU cycle."""

    speed_mps: float            # the train speed: the highest plausible estimate heard from; NaN: none
    known_mps: list[float]      # the plausible estimates heard from
    status_rx_us: int | None    # when the newest BECUn_STATUS arrived; None: none yet
    standstill: bool
    desk_emergency: bool        # the desk asks for the emergency brake
    brake_step: int             # the desk's brake step (0..7) and its deceleration [m/s²]
    step_decel_mps2: float
    mode: BcuMode               # a demand source sees last cycle's mode and target, a follower this cycle's
    target_mps2: float
    dt_s: float


class Demand(NamedTuple):
    """What a demand source asks of the BCU this cycle."""

    decel_mps2: float = 0.0     # a service deceleration [m/s²]
    service: bool = False       # service braking, even at 0 m/s² (holding the train where it stands)
    emergency_source: int = 0   # the emergency brake, with this BCU_EMERGENCY.Source; 0: not asked
    degraded: bool = False      # the function is not healthy: the train is Degraded


class DemandSource(Protocol):
    """A function that asks for braking."""

    # read-only: a stage has them as class constants or sets them per instance
    @property
    def INPUTS(self) -> tuple[str, ...]: ...      # its input signals (rx keys), bound beside the BCU's own

    @property
    def OUTPUTS(self) -> tuple[str, ...]: ...     # the output signals it writes into `out` every cycle

    def demand(self, now_us: int, rx: RxTable, train: Train, out: dict[str, float]) -> Demand: ...


class Follower(Protocol):
    """A function that follows the demand the BCU decided and sends its own signals."""

    @property
    def INPUTS(self) -> tuple[str, ...]: ...

    @property
    def OUTPUTS(self) -> tuple[str, ...]: ...

    def follow(self, now_us: int, rx: RxTable, train: Train, out: dict[str, float]) -> None: ...


class Bcu:
    """step(now_us, rx) -> BCU_DEMAND / BCU_EMERGENCY / BCU_STATUS signals and the stages'."""

    OUTPUTS: ClassVar[tuple[str, ...]] = ("Mode", "BrakeStep", "TargetDecel", "EmergencyActive", "Source",
                                          "CarsSilent", "Degraded", "TrainSpeedEst", "CarsImplausible")

    def __init__(self, n_cars: int, params: BcuParams | None = None, sources: Sequence[DemandSource] = (),
                 followers: Sequence[Follower] = ()) -> None:
        self.p = params or BcuParams()
        self.n_cars = n_cars
        self.sources, self.followers = tuple(sources), tuple(followers)
        self.mode = BcuMode.RELEASED
        self.target = 0.0
        self.source = 0                              # BCU_EMERGENCY.Source: 0 none, 1 DESK, a source's code
        self.timer = CycleTimer(self.p.cycle_us)
        self.speed_keys = tuple(f"BECU{i}_STATUS.SpeedEst" for i in range(1, n_cars + 1))
        self.fault_keys = tuple(f"BECU{i}_DIAG.{sig}" for i in range(1, n_cars + 1)
                                for sig in ("SpeedSensorFault", "AccelSensorFault", "CylSensorFault"))
        stages = self.sources + self.followers
        self.inputs = (("BrakeStep", "EmergencyReq", "BrakeValve") + self.speed_keys + self.fault_keys
                       + tuple(k for s in stages for k in s.INPUTS))
        self.outputs = self.OUTPUTS + tuple(k for s in stages for k in s.OUTPUTS)
        self.valve = BrakeValve(self.p.brake_valve)
        self.implausible = [False] * n_cars           # latched per car
        self._disagree_since: list[int | None] = [None] * n_cars
        self._disagree_sign = [0] * n_cars            # +1 above the median, −1 below, since _disagree_since

    def step(self, now_us: int, rx: RxTable) -> dict[str, float]:
        p = self.p
        dt_s = self.timer.dt_s(now_us)
        step_raw, _ = finite_or(rx["BrakeStep"], 0.0)
        emergency_req, _ = finite_or(rx["EmergencyReq"], 0.0)
        brake_step = int(min(max(step_raw, 0), 7))
        speeds = [finite_or(rx[name], float("nan"))[0] for name in self.speed_keys]
        ages = [rx.age_us(name, now_us) for name in self.speed_keys]
        # a car heard from, but not lately, is silent too
        speeds = [float("nan") if a is not None and a > p.status_timeout_us else v
                  for a, v in zip(ages, speeds, strict=True)]
        heard = [a for a in ages if a is not None]
        self._vote(now_us, speeds)
        known = [v for v, bad in zip(speeds, self.implausible, strict=True) if not (math.isnan(v) or bad)]
        train_speed = max(known) if known else float("nan")
        silent = sum(1 << i for i, v in enumerate(speeds) if math.isnan(v))
        implausible = sum(1 << i for i, bad in enumerate(self.implausible) if bad)
        sensor_fault = any(finite_or(rx.get(key, 0.0), 0.0)[0] >= 0.5 for key in self.fault_keys)
        standstill = bool(known) and train_speed < p.standstill_mps
        desk_emergency = emergency_req >= 0.5
        step_decel = p.step_decel_mps2[brake_step]

        out: dict[str, float] = {}
        train = Train(train_speed, known, now_us - min(heard) if heard else None, standstill, desk_emergency,
                      brake_step, step_decel, self.mode,
                      self.target, dt_s)
        demands = [source.demand(now_us, rx, train, out) for source in self.sources]
        valve_cmd = self._valve_step(now_us, rx, dt_s)
        asked = next((d.emergency_source for d in demands if d.emergency_source), 0)
        self.mode = bcu_mode_transition(self.mode, brake_step, desk_emergency or asked != 0, standstill,
                                        valve_cmd > 0.0 or any(d.service for d in demands))
        emergency = self.mode == BcuMode.EMERGENCY
        if emergency:
            self.target = p.emergency_decel_mps2                      # no jerk limit on emergency
            if desk_emergency:                                        # BCU_EMERGENCY.Source: who
                self.source = 1                                       # demanded it, DESK (kept while
            elif asked or self.source == 0:                           # latched), else the source
                self.source = asked or 1
        else:
            self.source = 0
            wanted = max(step_decel, valve_cmd, *[d.decel_mps2 for d in demands])
            jerk = p.jerk_limit_mps3 * dt_s
            self.target = rate_limit(wanted, self.target, jerk, jerk)
        if self.followers:
            train = train._replace(mode=self.mode, target_mps2=self.target)
            for follower in self.followers:
                follower.follow(now_us, rx, train, out)
        degraded = silent != 0 or implausible != 0 or sensor_fault or any(d.degraded for d in demands)
        out.update(Mode=int(self.mode), BrakeStep=brake_step, TargetDecel=self.target,
                   EmergencyActive=int(emergency), Source=self.source, CarsSilent=silent,
                   Degraded=int(degraded), TrainSpeedEst=train_speed if known else 0.0,
                   CarsImplausible=implausible)
        return out

    def _valve_step(self, now_us: int, rx: RxTable, dt_s: float) -> float:
        """The demand of the driver's brake valve a PLC on the desk sets (DESK_CMD.BrakeValve): 0 while it
        is not used (NONE, or never received); its position integrated (firmware_py.brake_valve); a
        position gone stale, or a value that is no position, brakes (V)."""
        raw = rx.get("BrakeValve", math.nan)      # not bound in a controller test: not used
        if math.isnan(raw) or raw == 0:
            self.valve.demand = 0.0                  # not used: the brake step alone
            return 0.0
        position = int(raw) if raw in VALVE_POSITIONS else ValvePosition.SERVICE
        age = rx.age_us("BrakeValve", now_us)
        if age is not None and age > self.p.desk_timeout_us:
            position = ValvePosition.SERVICE
        return self.valve.step(dt_s, position)

    def _vote(self, now_us: int, speeds: list[float]) -> None:
        """Latch the cars whose estimate disagrees with the train's median on evidence a slide cannot
        produce: above it for longer than implausible_after_us, below it for longer than slide_allow_us.
        A disagreement that changes side starts its timer again."""
        p = self.p
        trusted = [not bad for bad in self.implausible]
        for k, sign in enumerate(disagreement(speeds, trusted, p.implausible_mps)):
            if sign == 0 or self.implausible[k]:
                self._disagree_since[k], self._disagree_sign[k] = None, 0
                continue
            since = self._disagree_since[k]
            if since is None or sign != self._disagree_sign[k]:
                self._disagree_since[k], self._disagree_sign[k] = now_us, sign
            elif now_us - since > (p.implausible_after_us if sign > 0 else p.slide_allow_us):
                self.implausible[k] = True
