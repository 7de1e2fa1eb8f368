"""Train brake control unit (BCU), v1.

DESK brake step (0..7) -> target deceleration for every car; an emergency request (desk or ACD) ->
full braking, latched until standstill and released request.  Deceleration feedback (seed 004 §5,
`firmware_py.decel_feedback`) when `BcuParams.feedback` is given: it reads the front and rear cars'
accelerometers (PLANT_CAR1/n_SENSORS.AccelLong) and every car's WspActive, and sends its state and the
slope estimate in BCU_STATUS (FbState, SlopeEst) and the pressure correction φ with its state in the
authenticated BCU_BRAKE_CORR (FbState, FrictionPhi); the BECUs apply φ while FbState is ENGAGED or
HELD.  Precise stopping at a target point (seed 002 §III, §VI–§VIII, `firmware_py.stopping`) when
`BcuParams.stopping` is given: it reads DESK_TARGET (TargetStopValid, TargetStopPos), keeps an odometer on
the train speed estimate, and commands the service brake along the theoretical braking curve; the target
deceleration sent is the larger of the driver's brake step and the stopping command.  The anti-collision
device (seed 002 §V, `firmware_py.acd`) when `BcuParams.acd` is set: ACD_BRAKE_REQ.Request = EMERGENCY is
an emergency request; SERVICE asks for RequestedDecel, and the target deceleration is the largest of the
driver's step, the stopping command and the ACD's request; BCU_EMERGENCY.Source = 2 (ACD) when the ACD
demanded the emergency brake.  An ACD not heard from for `acd_timeout_us` makes the train Degraded; its
last request stays in force until the train stands (a lost or deleted request never releases a brake the
ACD asked for, issue #19), and an ACD silent while asking for nothing requests nothing.

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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum

from firmware_py.brake_valve import BrakeValve, BrakeValveParams, ValvePosition
from firmware_py.cycle import CycleTimer
from firmware_py.decel_feedback import DecelFeedback, FbState, FeedbackParams
from firmware_py.limits import clip, finite_or, rate_limit
from firmware_py.stopping import StoppingController, StoppingParams, StopState


class BcuMode(IntEnum):
    """Values are the DBC choices of BCU_DEMAND.Mode."""

    RELEASED = 0
    SERVICE = 1
    EMERGENCY = 2


def bcu_mode_transition(mode: BcuMode, brake_step: int, emergency_req: bool, standstill: bool,
                        stop_demand: bool = False) -> BcuMode:
    """Pure mode logic: emergency latches until the train stands and the request is gone; service while
    a brake step is demanded or precise stopping brakes (`stop_demand`: following its curve or holding
    the train at the stop point)."""
    if emergency_req:
        return BcuMode.EMERGENCY
    if mode == BcuMode.EMERGENCY and not standstill:
        return BcuMode.EMERGENCY
    return BcuMode.SERVICE if brake_step > 0 or stop_demand else BcuMode.RELEASED


def disagreement(speeds: Sequence[float], trusted: Sequence[bool], limit_mps: float,
                 min_voters: int = 3) -> list[int]:
    """Per car, +1 if its speed estimate [m/s] is more than `limit_mps` above the median of the trusted
    cars that are heard from, −1 if more than that below it, else 0 (pure).  NaN = not heard from: never
    disagreeing.  Needs `min_voters` such cars: with two, nobody can tell which one is wrong.  The median
    includes the car itself: with three cars the median of the other two is their mean, which one stuck
    car drags along."""
    voters = [v for v, ok in zip(speeds, trusted, strict=True) if ok and v == v]
    if len(voters) < min_voters:
        return [0] * len(speeds)
    median = statistics.median(voters)
    return [0 if not (v == v and abs(v - median) > limit_mps) else 1 if v > median else -1 for v in speeds]


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
    feedback: FeedbackParams | None = None   # deceleration feedback, seed 004 §5; None: not fitted
    stopping: StoppingParams | None = None   # precise stopping at a target point, seed 002; None: not fitted
    acd: bool = False                        # obey ACD_BRAKE_REQ (an anti-collision device is fitted)
    acd_timeout_us: int = 300_000            # the ACD's request (100 ms cycle) is stale after 3 cycles
    #                                          (chosen)
    # the driver's brake valve a PLC on the desk sets (DESK_CMD.BrakeValve, seed 002 §VII), integrated into a
    # demand at its service / release rate; its ceiling is full service (step 7)
    brake_valve: BrakeValveParams = field(default_factory=BrakeValveParams)
    desk_timeout_us: int = 300_000           # a valve position (DESK_CMD, 100 ms) older than 3 cycles: the
    #                                          PLC is silent and the valve goes to V (service brake), as a
    #                                          brake pipe vents when its control is lost (chosen)


VALVE_POSITIONS = frozenset(int(p) for p in ValvePosition)


class Bcu:
    """step(now_us, rx) -> BCU_DEMAND / BCU_EMERGENCY / BCU_STATUS signals."""

    OUTPUTS = ("Mode", "BrakeStep", "TargetDecel", "EmergencyActive", "Source", "CarsSilent", "Degraded",
               "TrainSpeedEst", "CarsImplausible", "FbState", "SlopeEst", "StopState")
    STOP_OUTPUTS = ("DistanceToGo", "RefSpeed", "StopCommand", "BalisesSeen", "SearchQ")    # BCU_STOP
    ACD_INPUTS = ("ACD_BRAKE_REQ.Request", "ACD_BRAKE_REQ.RequestedDecel")

    def __init__(self, n_cars: int, params: BcuParams | None = None) -> None:
        self.p = params or BcuParams()
        self.n_cars = n_cars
        self.mode = BcuMode.RELEASED
        self.target = 0.0
        self.source = 0                              # BCU_EMERGENCY.Source: 0 none, 1 DESK, 2 ACD, 3 BCU
        self.timer = CycleTimer(self.p.cycle_us)
        self.outputs = self.OUTPUTS                  # + STOP_OUTPUTS with precise stopping
        self.speed_keys = tuple(f"BECU{i}_STATUS.SpeedEst" for i in range(1, n_cars + 1))
        self.fault_keys = tuple(f"BECU{i}_DIAG.{sig}" for i in range(1, n_cars + 1)
                                for sig in ("SpeedSensorFault", "AccelSensorFault", "CylSensorFault"))
        self.inputs = ("BrakeStep", "EmergencyReq", "BrakeValve") + self.speed_keys + self.fault_keys
        self.valve = BrakeValve(self.p.brake_valve)
        self.feedback: DecelFeedback | None = None
        if self.p.feedback is not None:
            self.feedback = DecelFeedback(self.p.feedback)
            # the front and rear cars' accelerometers (seed 004 §6.1) and every car's WSP flag
            self.accel_keys = ("PLANT_CAR1_SENSORS.AccelLong", f"PLANT_CAR{n_cars}_SENSORS.AccelLong")
            self.wsp_keys = tuple(f"BECU{i}_STATUS.WspActive" for i in range(1, n_cars + 1))
            self.inputs += self.accel_keys + self.wsp_keys
            self.outputs += ("FrictionPhi",)       # BCU_BRAKE_CORR, with FbState
            self._speed_rx_us: int | None = None
            self.fb_out = None                     # last FeedbackOutput (diagnostic)
        self.stopping: StoppingController | None = None
        if self.p.stopping is not None:
            self.stopping = StoppingController(self.p.stopping)
            self.inputs += ("TargetStopValid", "TargetStopPos")
            self.outputs += self.STOP_OUTPUTS
            self._odo_rx_us: int | None = None
            self.stop_out = None                   # last StopOutput (diagnostic)
            self.balises_seen = 0                  # balise passages the odometer re-anchored on
            self._balise_count: float | None = None
            if self.p.stopping.balises:            # car 1's balise transmission module (PLANT_BTM)
                self.inputs += ("BalisePos", "PassageAge", "BaliseCount", "BaliseValid")
        if self.p.acd:
            self.inputs += self.ACD_INPUTS
        self.implausible = [False] * n_cars           # latched per car
        self._disagree_since: list[int | None] = [None] * n_cars
        self._acd_last = (False, 0.0)                 # the ACD's last usable request (emergency, decel)
        self._disagree_sign = [0] * n_cars            # +1 above the median, −1 below, since _disagree_since

    def step(self, now_us: int, rx: Mapping[str, float]) -> dict[str, float]:
        p = self.p
        dt_s = self.timer.dt_s(now_us)
        step_raw, _ = finite_or(rx["BrakeStep"], 0.0)
        emergency_req, _ = finite_or(rx["EmergencyReq"], 0.0)
        brake_step = int(min(max(step_raw, 0), 7))
        speeds = [finite_or(rx[name], float("nan"))[0] for name in self.speed_keys]
        age_us = getattr(rx, "age_us", None)         # reception times: the node runtime's RxTable
        if age_us is not None:                        # a car heard from, but not lately, is silent too
            speeds = [float("nan") if (a := age_us(name, now_us)) is not None and a > p.status_timeout_us
                      else v for name, v in zip(self.speed_keys, speeds, strict=True)]
        self._vote(now_us, speeds)
        known = [v for v, bad in zip(speeds, self.implausible, strict=True) if v == v and not bad]
        train_speed = max(known) if known else float("nan")
        silent = sum(1 << i for i, v in enumerate(speeds) if v != v)
        implausible = sum(1 << i for i, bad in enumerate(self.implausible) if bad)
        sensor_fault = any(finite_or(rx.get(key, 0.0), 0.0)[0] >= 0.5 for key in self.fault_keys)
        standstill = bool(known) and train_speed < p.standstill_mps

        stop_cmd, stop_demand = 0.0, False
        if self.stopping is not None:
            # the odometer integrates the median of the cars' estimates: the maximum (the train speed, safe
            # against sliding wheels) is biased upwards by the estimates' noise, and that bias integrates
            so = self.stop_out = self._stopping_step(now_us, rx, dt_s, emergency_req >= 0.5, standstill,
                                                     train_speed if known else float("nan"),
                                                     statistics.median(known) if known else float("nan"))
            stop_demand = so.state in (StopState.FOLLOWING, StopState.STOPPED)
            stop_cmd = so.command_mps2 if stop_demand else 0.0
        acd_emergency, acd_cmd, acd_silent = (self._acd_request(now_us, rx, standstill) if p.acd
                                              else (False, 0.0, False))
        valve_cmd = self._valve_step(now_us, rx, dt_s)
        desk_emergency = emergency_req >= 0.5
        self.mode = bcu_mode_transition(self.mode, brake_step, desk_emergency or acd_emergency, standstill,
                                        stop_demand or acd_cmd > 0.0 or valve_cmd > 0.0)
        emergency = self.mode == BcuMode.EMERGENCY
        if emergency:
            self.target = p.emergency_decel_mps2                      # no jerk limit on emergency
            if desk_emergency:                                        # BCU_EMERGENCY.Source: who
                self.source = 1                                       # demanded it, DESK (kept while
            elif acd_emergency or self.source == 0:                   # latched), else ACD
                self.source = 2 if acd_emergency else 1
        else:
            self.source = 0
            wanted = max(p.step_decel_mps2[brake_step], stop_cmd, acd_cmd, valve_cmd)
            jerk = p.jerk_limit_mps3 * dt_s
            self.target = rate_limit(wanted, self.target, jerk, jerk)
        fb_state, phi, slope = FbState.OFF, 1.0, 0.0
        if self.feedback is not None:
            fb = self.fb_out = self._feedback_step(now_us, rx, dt_s, brake_step, emergency,
                                                   train_speed if known else 0.0)
            fb_state, phi, slope = fb.state, fb.phi, fb.slope
        return {
            "Mode": int(self.mode),
            "BrakeStep": brake_step,
            "TargetDecel": self.target,
            "EmergencyActive": int(emergency),
            "Source": self.source,
            "CarsSilent": silent,
            "Degraded": int(silent != 0 or implausible != 0 or sensor_fault or acd_silent),
            "TrainSpeedEst": train_speed if known else 0.0,
            "CarsImplausible": implausible,
            "FbState": int(fb_state),
            "FrictionPhi": phi,
            "SlopeEst": clip(slope, -0.064, 0.06375),            # the DBC signal's range
            **(self._stop_signals() if self.stopping is not None else {"StopState": 0}),
        }

    def _valve_step(self, now_us: int, rx: Mapping[str, float], dt_s: float) -> float:
        """The demand of the driver's brake valve a PLC on the desk sets (DESK_CMD.BrakeValve): 0 while it
        is not used (NONE, or never received); its position integrated (firmware_py.brake_valve); a
        position gone stale, or a value that is no position, brakes (V)."""
        raw = rx.get("BrakeValve", math.nan)      # not bound in a controller test: not used
        if raw != raw or raw == 0:
            self.valve.demand = 0.0                  # not used: the brake step alone
            return 0.0
        position = int(raw) if raw in VALVE_POSITIONS else ValvePosition.SERVICE
        age_us = getattr(rx, "age_us", None)
        age = age_us("BrakeValve", now_us) if age_us is not None else None
        if age is not None and age > self.p.desk_timeout_us:
            position = ValvePosition.SERVICE
        return self.valve.step(dt_s, position)

    def _acd_request(self, now_us: int, rx: Mapping[str, float],
                     standstill: bool) -> tuple[bool, float, bool]:
        """(emergency requested, service deceleration requested [m/s²], silent) from ACD_BRAKE_REQ; a silent
        ACD's last request holds until standstill (module docstring)."""
        age_us = getattr(rx, "age_us", None)
        age = age_us(self.ACD_INPUTS[0], now_us) if age_us is not None else 0
        request, ok = finite_or(rx[self.ACD_INPUTS[0]], 0.0)
        if age is None or age > self.p.acd_timeout_us or not ok:
            if standstill:
                self._acd_last = (False, 0.0)
            return (*self._acd_last, age is not None)          # never heard from: not (yet) silent
        decel, ok_decel = finite_or(rx[self.ACD_INPUTS[1]], self.p.step_decel_mps2[-1])
        if round(request) == 2:
            self._acd_last = (True, 0.0)
        elif round(request) == 1:                            # a bad deceleration asks for full service
            self._acd_last = (False, clip(decel if ok_decel else self.p.step_decel_mps2[-1], 0.0,
                                          self.p.step_decel_mps2[-1]))
        else:
            self._acd_last = (False, 0.0)
        return (*self._acd_last, False)

    def _stop_signals(self) -> dict[str, float]:
        """StopState in BCU_STATUS and the BCU_STOP frame, from the last StopOutput."""
        so = self.stop_out
        return {"StopState": int(so.state),
                "DistanceToGo": so.distance_to_go_m if so.distance_to_go_m == so.distance_to_go_m else 0.0,
                "RefSpeed": so.ref_speed_mps if so.ref_speed_mps == so.ref_speed_mps else 0.0,
                "StopCommand": so.command_mps2, "BalisesSeen": self.balises_seen % 16,
                "SearchQ": min(so.quality, 127.5) if so.quality == so.quality else 0.0}

    def _stopping_step(self, now_us: int, rx: Mapping[str, float], dt_s: float, emergency_req: bool,
                       standstill: bool, train_speed: float, odo_speed: float):
        """Precise stopping's cycle: a fresh speed sample to the odometer (its reception time: the newest
        BECUn_STATUS; every cycle for a plain mapping), then the controller."""
        age_us = getattr(rx, "age_us", None)
        if age_us is None:
            t_rx: int | None = now_us
        else:
            ages = [a for a in (age_us(k, now_us) for k in self.speed_keys) if a is not None]
            t_rx = now_us - min(ages) if ages else None
        if t_rx is not None and t_rx != self._odo_rx_us and odo_speed == odo_speed:
            self.stopping.odometer.sample(t_rx, odo_speed)
            self._odo_rx_us = t_rx
        if self.p.stopping.balises:
            self._balise(now_us, rx)
        valid, _ = finite_or(rx["TargetStopValid"], 0.0)
        target_m, ok = finite_or(rx["TargetStopPos"], 0.0)
        return self.stopping.step(now_us, dt_s, target_valid=valid >= 0.5 and ok, target_m=target_m,
                                  emergency=emergency_req or self.mode == BcuMode.EMERGENCY,
                                  standstill=standstill,
                                  train_speed_mps=train_speed if train_speed == train_speed else 0.0)

    def _balise(self, now_us: int, rx: Mapping[str, float]) -> None:
        """A new balise passage in PLANT_BTM (its count changed) re-anchors the odometer: the passage time
        is the frame's reception time (every cycle for a plain mapping) minus its PassageAge."""
        valid, _ = finite_or(rx["BaliseValid"], 0.0)
        count, ok = finite_or(rx["BaliseCount"], math.nan)
        if valid < 0.5 or not ok or count == self._balise_count:
            return
        self._balise_count = count
        pos, ok_pos = finite_or(rx["BalisePos"], math.nan)
        age_s, ok_age = finite_or(rx["PassageAge"], math.nan)
        if not (ok_pos and ok_age):
            return
        age_us = getattr(rx, "age_us", None)
        rx_age = age_us("BaliseCount", now_us) if age_us is not None else 0
        t_pass = now_us - (rx_age or 0) - age_s * 1e6
        self.stopping.odometer.anchor(pos, t_pass)
        self.balises_seen += 1

    def _feedback_step(self, now_us: int, rx: Mapping[str, float], dt_s: float, brake_step: int,
                       emergency: bool, train_speed: float):
        """The deceleration feedback's cycle: inputs from rx, the demand this BCU just computed."""
        accel = [finite_or(rx[key], float("nan"))[0] for key in self.accel_keys]
        if not all(a == a for a in accel):             # an accelerometer not heard from: use the other
            good = [a for a in accel if a == a]
            accel = [good[0]] * 2 if good else [0.0, 0.0]
        wsp = any(finite_or(rx[key], 0.0)[0] >= 0.5 for key in self.wsp_keys)
        # a fresh speed estimate for the EKF: when a new BECU1_STATUS arrived (every cycle for a plain
        # mapping, which has no reception times)
        speed: float | None = train_speed if train_speed > 0.0 else None
        age_us = getattr(rx, "age_us", None)
        if age_us is not None and speed is not None:
            age = age_us(self.speed_keys[0], now_us)
            t_rx = None if age is None else now_us - age
            if t_rx == self._speed_rx_us:
                speed = None
            self._speed_rx_us = t_rx
        wanted = self.p.step_decel_mps2[brake_step]
        service = self.mode == BcuMode.SERVICE and wanted > 0.0
        return self.feedback.step(dt_s, self.target, self.target == wanted, service, emergency, wsp,
                                  accel[0], accel[1], speed, train_speed)

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
