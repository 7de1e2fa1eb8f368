"""Precise stopping at a target point (seed 002 §III, §VI–§VIII): the BCU's braking command along a
theoretical braking curve (S, V, a), three ways.

* ``adaptive`` — the paper's PLC program: the *adaptive search with united attempt and work steps* (§III,
  Fig. 2) setting the driver's brake valve (§VII: II release, IV lap with feeding, V service brake).  The
  PLC scans every 100 ms (the S7-200 of §VI); every work period (a multiple of the scan) it evaluates the
  quality function Q and takes one work step, which is also the next attempt: the valve in V (brake
  harder) or II (release) for a few scans, then IV.  If Q did not deteriorate by more than the threshold δ
  (δ > 0) the previous work step is repeated, otherwise the opposite step is taken (`search_step`); inside
  the insensitivity zone (Q below `dead_zone_m`) the valve stays in IV (lap).  Q is the path deviation from
  the theoretical curve, |S − S_th(t)| [m].
* ``adaptive_diff`` — the same search with the *differentiation unit* (Fig. 3), which "follows a change of
  the controllable parameters in time": it takes the time derivatives of the path deviation e = S − S_th,
  ė = V − V_th and ë = a_th − a (the measured speed and deceleration are the derivatives of the path), and
  Q is the deviation they predict `diff_horizon_s` = T_d ahead, |e + T_d·ė + T_d²/2·ë| — evaluated as the
  train's path extrapolated with V and a (up to its standstill) minus the curve's path at t + T_d.  A work
  step changes ë at once (after the brake's lag), so Q shows the step within one work period; on S alone
  it shows only after the lag and a double integration, under the drift of the deviation itself.
* ``pi`` — a modern baseline (not in the paper): curve tracking on distance to go.  The curve is
  V_th(s) = √(2 a_c s) (s: distance to go); the command is the feed-forward v²/(2s) (the deceleration
  that stops the train exactly at the point from here) plus the shared PI (`firmware_py.pi`) on the
  speed error v − V_th(s).  It commands the deceleration directly, without the valve.

The searches' decisions are the pure `AdaptiveSearch` (one PLC scan: time, S, V, a and the curve in, a
valve position out), so a PLC program can run the same search; the valve positions become the braking
command through `firmware_py.brake_valve.BrakeValve`, as the BCU integrates a PLC's positions.

Theoretical curve (§VI: "a road driven S, a current motion speed V and a current braking acceleration
a"): the curve starts at time t_0, position x_0 and speed v_0 and ends at the target, d_0 = target − x_0
ahead, with a_c = max(a_p, v_0²/(2 d_0)):  S_th(τ) = v_0 τ − a_c τ²/2, V_th(τ) = v_0 − a_c τ, a_th = a_c,
for 0 ≤ τ = t − t_0 ≤ T = v_0/a_c; afterwards S_th = d_0, V_th = 0; before t_0 the train coasts
(S_th = v_0 τ).  It starts when the train reaches the point from which a stop at the planned
deceleration a_p ends at the target (at once, and harder, when it is nearer).  With the valve the brake
needs a_c / service rate to apply: the valve goes to V half that time before t_0, so the application ramp
is centred on the curve's start (`apply_lead_s`).

Position: the BCU knows the train's position only from CAN.  Its odometer (`Odometer`) starts from a
known reference point passed at a known time (a balise: the scenario's start position at t = 0) and
integrates the train speed estimate over the samples' reception times (trapezoidal), extrapolating from
the last sample and compensating the speed chain's latency (wheel sensor → BECU estimate → CAN).

Mode logic is the pure `stop_state_transition`; `StoppingController.step` is one BCU cycle.  Units: SI,
decelerations positive when braking; time an integer count of microseconds.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field
from enum import IntEnum
from typing import ClassVar, NamedTuple

from firmware_py.bcu import BcuMode, Demand, Train
from firmware_py.brake_valve import BrakeValve, BrakeValveParams, ValvePosition
from firmware_py.limits import clip, finite_or
from firmware_py.pi import PI, PIParams
from firmware_py.rx import RxTable

METHODS = ("adaptive", "adaptive_diff", "pi")


class StopState(IntEnum):
    """State of the precise-stopping function (proposed DBC choices of BCU_STATUS.StopState)."""

    OFF = 0          # not fitted, no valid target, emergency, or standing without a stop in progress
    ARMED = 1        # a target ahead: coasting until the braking curve begins
    FOLLOWING = 2    # braking along the theoretical curve
    STOPPED = 3      # standstill after following the curve: holding brake applied


def stop_state_transition(state: StopState, *, target_valid: bool, new_target: bool, emergency: bool,
                          standstill: bool, curve_reached: bool) -> StopState:
    """Pure mode logic of precise stopping.

    target_valid: DESK_TARGET.TargetStopValid; new_target: the target position changed this cycle;
    curve_reached: the distance to go is at or below the braking distance at the planned deceleration."""
    if emergency or not target_valid:
        return StopState.OFF                            # emergency braking has priority; no target, no stop
    if new_target and not standstill:
        return StopState.FOLLOWING if curve_reached else StopState.ARMED
    if state == StopState.OFF:
        if standstill:
            return StopState.OFF                        # a brake-only function cannot start a standing train
        return StopState.FOLLOWING if curve_reached else StopState.ARMED
    if state == StopState.ARMED:
        return StopState.FOLLOWING if curve_reached else StopState.ARMED
    if state == StopState.FOLLOWING:
        return StopState.STOPPED if standstill else StopState.FOLLOWING
    return StopState.STOPPED


def search_step(direction: int, q_now: float, q_before: float, threshold: float,
                dead_zone: float) -> tuple[int, bool]:
    """One decision of the adaptive search with united attempt and work steps (seed 002 Fig. 2), pure.

    direction: +1 (brake harder) or −1 (release) of the previous work step.  Returns (direction, move):
    the previous direction repeated when ΔQ = Q_N − Q_(N−1) ≤ δ, reversed when ΔQ > δ (deteriorated);
    move is False (lap: the valve stays in IV) while Q is inside the insensitivity zone."""
    if q_now - q_before > threshold:
        direction = -direction
    return direction, q_now >= dead_zone


def step_position(direction: int, move: bool, scan_in_period: int, step_scans: int) -> ValvePosition:
    """The valve position of one scan of a work period, pure: a work step holds the valve in V (direction
    +1) or II (−1) for the period's first `step_scans` scans, then in IV; no step (insensitivity zone): IV."""
    if not move or scan_in_period >= step_scans:
        return ValvePosition.LAP
    return ValvePosition.SERVICE if direction > 0 else ValvePosition.RELEASE


@dataclass(frozen=True)
class StoppingParams:
    """Seed 002 gives the algorithm, not its constants: every number here is "chosen" unless marked."""

    method: str = "pi"                       # "adaptive" | "adaptive_diff" | "pi"
    planned_decel_mps2: float = 0.6          # a_p: the curve's deceleration set in the PLC (§VII) (chosen:
    #                                          a metro/EMU ATO's comfortable service deceleration)
    max_decel_mps2: float = 1.0              # command ceiling: full service (BcuParams step 7)
    hold_decel_mps2: float = 1.0             # holding brake at standstill (STOPPED)
    start_position_m: float = 0.0            # odometer: the reference point passed at start_time_us ...
    start_time_us: int = 0                   # ... (the scenario's start: a balise at t = 0)
    balises: bool = False                    # re-anchor the odometer on PLANT_BTM balise passages
    speed_latency_s: float = 0.005           # speed chain latency, wheel → BECU SpeedEst → CAN: the plant's
    #                                          sensor frame, the BECU's estimate and its 50 ms status frame
    #                                          (chosen, measured on the lockstep bench: see README)
    # --- the PLC (§VI) and the driver's brake valve it sets (§VII), for the adaptive methods
    scan_us: int = 100_000                   # the PLC's scan cycle [µs] (chosen: a SIMATIC S7-200, §VI,
    #                                          scans a program of this size in a few ms; 100 ms is its
    #                                          usual cyclic-interrupt period for a slow loop)
    valve_service_rate_mps3: float = BrakeValveParams().service_rate_mps3   # V: the valve's application
    valve_release_rate_mps3: float = BrakeValveParams().release_rate_mps3   # ... and II: its release rate
    #                                          [m/s³] (firmware_py/brake_valve.py: 0.3, chosen)
    # --- adaptive search (Fig. 2), the same for both variants: work period, work step, δ, insensitivity
    # (the paper gives none of these numbers; chosen together from its text and the bench's brake, and
    #  checked by a sweep on a point-mass train with the bench's brake hysteresis, lag and speed noise, the
    #  campaign's mass/pad/gradient spread, 1500 m: docs/studies/precise-stop.md)
    work_scans: int = 15                     # work period = 15 scans = 1.5 s (chosen: §III-A, the brake
    #                                          system limits how often the control signal may change: a step's
    #                                          effect (lag ~0.2 s, a estimate 0.25 s) has settled before Q is
    #                                          evaluated again)
    step_scans: int = 5                      # a work step holds V or II for 5 scans (0.5 s): Δu = 0.15 m/s²
    #                                          (chosen: above the brake's hysteresis, ~0.09 m/s², so that a
    #                                          reversed step still moves the deceleration)
    threshold_m: float = 0.3                 # δ on ΔQ [m] (chosen: a small part of the insensitivity zone;
    #                                          a smaller deterioration is taken as the noise of Q)
    dead_zone_m: float = 2.0                 # insensitivity zone on Q [m]: the valve stays in IV (lap) inside
    #                                          it (chosen: the paper's best stop, ±2–7 m, at its low end)
    # --- the differentiation unit (Fig. 3)
    diff_horizon_s: float = 12.0             # T_d: horizon of the predicted deviation [s] (chosen: on the
    #                                          surface Q = 0 the deviation settles in ~2 T_d, about half of a
    #                                          40 s stop; a step then moves Q by T_d²/2·Δu ≈ 10 m, well
    #                                          above the drift left after the unit's extrapolation)
    diff_tau_s: float = 0.25                 # low-pass of the differentiated speed, the deceleration a [s]
    #                                          (chosen: settles within a work period's lap; on the bench the
    #                                          estimate is within ~0.01 m/s² rms of the truth)
    # --- PI baseline: speed error [m/s] → deceleration [m/s²]
    pi: PIParams = field(default_factory=lambda: PIParams(kp=0.4, ki=0.1, out_min=0.0, out_max=1.0))
    final_distance_m: float = 0.3            # below this distance to go the feed-forward is held (1/s → ∞)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"StoppingParams.method must be one of {METHODS}, got {self.method!r}")
        if self.scan_us <= 0 or self.work_scans < 1 or not 0 <= self.step_scans <= self.work_scans:
            raise ValueError(f"StoppingParams: scan_us {self.scan_us} must be > 0 and 0 <= step_scans "
                             f"{self.step_scans} <= work_scans {self.work_scans} (>= 1)")

    @property
    def valve(self) -> BrakeValveParams:
        """The driver's brake valve the adaptive methods set (the demand's ceiling: full service)."""
        return BrakeValveParams(self.valve_service_rate_mps3, self.valve_release_rate_mps3,
                                self.max_decel_mps2)

    def apply_lead_s(self, decel_mps2: float) -> float:
        """How long before the curve's start the valve goes to V: half the time it takes to apply
        `decel_mps2` at the service rate (the application ramp is centred on the curve's start); 0 for pi."""
        if self.method == "pi":
            return 0.0
        return 0.5 * min(decel_mps2, self.max_decel_mps2) / self.valve_service_rate_mps3


class Odometer:
    """Train position [m] from the speed estimate [m/s] received over CAN.

    `sample(t_rx_us, v)` with each fresh speed estimate (its reception time); `position(now_us)` the
    estimated position now.  Anchored at `x0_m` passed at `t0_us`; before the first sample the train is
    assumed to keep the first sample's speed (it coasts onto the reference point)."""

    def __init__(self, x0_m: float, t0_us: int, latency_s: float, decel_tau_s: float = 0.5) -> None:
        self.x0, self.t0, self.latency_s, self.decel_tau_s = x0_m, t0_us, latency_s, decel_tau_s
        self.decel = 0.0                      # −dv/dt of the samples, low-passed with decel_tau_s [m/s²]
        self.t_us: int | None = None          # the last sample's reception time; None: no sample yet
        self.x = x0_m                         # position at the last sample's reference time [m]
        self.v = 0.0                          # the last sample [m/s]

    def sample(self, t_rx_us: int, v_mps: float) -> None:
        if not math.isfinite(v_mps):
            return
        t_last = self.t_us
        if t_last is None:
            # the sample describes the train latency_s before it arrived: anchor on the reference point
            self.x = self.x0 + v_mps * ((t_rx_us - self.t0) * 1e-6 - self.latency_s)
        elif t_rx_us > t_last:
            dt = (t_rx_us - t_last) * 1e-6
            self.x += 0.5 * (self.v + v_mps) * dt                                     # trapezoid
            self.decel += (1.0 - math.exp(-dt / self.decel_tau_s)) * ((self.v - v_mps) / dt - self.decel)
        else:
            return
        self.t_us, self.v = t_rx_us, v_mps

    def position(self, now_us: int) -> float:
        if self.t_us is None:
            return self.x0
        return self.x + self.v * ((now_us - self.t_us) * 1e-6 + self.latency_s)

    def anchor(self, x_m: float, t_us: float) -> float:
        """A fixed reference point (a balise) was passed at `x_m` at time `t_us`: shift the odometer so that
        it reads x_m then.  Returns the correction [m] (+: the odometer was behind)."""
        if not (math.isfinite(x_m) and math.isfinite(t_us)):
            return 0.0
        if self.t_us is None:               # no speed sample yet: the balise is the new reference point
            self.x0, self.t0 = x_m, round(t_us)
            return 0.0
        shift = x_m - (self.x + self.v * ((t_us - self.t_us) * 1e-6 + self.latency_s))
        self.x += shift
        return shift


class CurvePoint(NamedTuple):
    """The theoretical braking curve at one time (§VI)."""

    s_m: float            # S_th: path from the curve's start [m]
    v_mps: float          # V_th: speed [m/s]
    a_mps2: float         # a_th: deceleration [m/s²]


@dataclass(frozen=True)
class Curve:
    """The theoretical braking curve (S, V, a) of §VI, started at t0_us from x0_m at v0_mps."""

    t0_us: int
    x0_m: float
    v0_mps: float
    d0_m: float           # distance to go at the start
    a_mps2: float         # a_c

    @property
    def end_us(self) -> float:
        """The curve's end (V_th = 0) [µs]."""
        return self.t0_us + (self.v0_mps / self.a_mps2 * 1e6 if self.a_mps2 > 0.0 else math.inf)

    def state(self, now_us: float) -> CurvePoint:
        """(S_th, V_th, a_th): path [m] from the curve's start, speed [m/s] and deceleration [m/s²] at now_us;
        before the start the train coasts at v0, after the end it stands at d0."""
        tau = (now_us - self.t0_us) * 1e-6
        if tau < 0.0:
            return CurvePoint(self.v0_mps * tau, self.v0_mps, 0.0)
        if now_us >= self.end_us:
            return CurvePoint(self.d0_m, 0.0, 0.0)
        return CurvePoint(self.v0_mps * tau - 0.5 * self.a_mps2 * tau * tau, self.v0_mps - self.a_mps2 * tau,
                          self.a_mps2)

    def at(self, now_us: float) -> tuple[float, float]:
        """(S_th, V_th) at now_us (not before the curve's start)."""
        s_th, v_th, _ = self.state(max(now_us, self.t0_us))
        return s_th, v_th


def braking_curve(now_us: int, x_m: float, v_mps: float, togo_m: float, p: StoppingParams) -> Curve:
    """The curve that starts now from x_m at v_mps, togo_m before the target (§VI), its start moved
    `apply_lead_s` ahead for the valve's application ramp."""
    lead = p.apply_lead_s(max(p.planned_decel_mps2, v_mps * v_mps / (2.0 * max(togo_m, 0.01))))
    d0 = max(togo_m - v_mps * lead, 0.01)
    a_c = max(p.planned_decel_mps2, v_mps * v_mps / (2.0 * d0))
    return Curve(now_us + round(lead * 1e6), x_m + v_mps * lead, v_mps, d0, a_c)


def braked_path(v_mps: float, a_mps2: float, h_s: float) -> float:
    """Path [m] a train at v_mps braking at a_mps2 covers in h_s, up to its standstill."""
    if a_mps2 > 0.0:
        h_s = min(h_s, v_mps / a_mps2)
    return v_mps * h_s - 0.5 * a_mps2 * h_s * h_s


class AdaptiveSearch:
    """The PLC program of seed 002 (§VI, Fig. 2; with `diff`, Fig. 3) for one braking curve: `scan(now_us,
    s_m, v_mps, a_mps2) -> ValvePosition`, one PLC scan (call it every `p.scan_us`).

    s_m: the path driven since the curve's start point x0 [m]; v_mps: the speed [m/s]; a_mps2: the
    deceleration [m/s²] (positive when braking).  It needs nothing else: a PLC program can run the same.

    First the brake is applied: V until the valve's demand (modelled with `BrakeValve`, from the positions
    sent) reaches the curve's deceleration a_c (§VII: "a desired braking acceleration a" is set in the PLC;
    a curve beyond full service keeps V).  Then the search: every `work_scans` scans Q is evaluated and
    `search_step` decides the work step, held `step_scans` scans (`step_position`).  A scan without a
    finite S, V or a holds the valve in IV and does not count."""

    def __init__(self, p: StoppingParams, curve: Curve, diff: bool) -> None:
        self.p, self.curve, self.diff = p, curve, diff
        self.model = BrakeValve(p.valve)         # the demand the positions sent so far make (the BCU's)
        self.applying = True                     # the initial application to a_c
        self.scans = 0                           # scans since the search began
        self.direction = 1                       # the last work step's direction (+1: V, brake harder)
        self.move = False
        self.q_expected: float | None = None     # Q expected at the next evaluation without a step
        self.quality = math.nan                  # the last Q [m]
        self.deviation = math.nan                # the last e (plain) or predicted e (diff) [m]; + = ahead

    def predicted_deviation(self, now_us: float, s_m: float, v_mps: float, a_mps2: float) -> float:
        """e = S − S_th now (plain search), or with the differentiation unit the deviation T_d ahead:
        the train's path extrapolated with V and a (to its standstill when that comes first) minus the
        curve's path at t + T_d, = e + T_d·ė + T_d²/2·ë while neither stops."""
        if not self.diff:
            return s_m - self.curve.state(now_us).s_m
        h = self.p.diff_horizon_s
        return s_m + braked_path(v_mps, a_mps2, h) - self.curve.state(now_us + h * 1e6).s_m

    def expected_quality(self, now_us: int, s_m: float, v_mps: float, a_mps2: float, q: float) -> float:
        """What Q will be at the next evaluation if the work step has no effect: the plain search expects
        the Q it has (Fig. 2: ΔQ = Q_N − Q_(N−1)); the differentiation unit follows the parameters' change
        in time and extrapolates them one work period with the V and a measured now."""
        if not self.diff:
            return q
        tw = self.p.work_scans * self.p.scan_us * 1e-6
        e = self.predicted_deviation(now_us + tw * 1e6, s_m + braked_path(v_mps, a_mps2, tw),
                                     max(v_mps - a_mps2 * tw, 0.0), a_mps2)
        return abs(e) if math.isfinite(e) else math.inf

    def scan(self, now_us: int, s_m: float, v_mps: float, a_mps2: float) -> ValvePosition:
        p = self.p
        if not (math.isfinite(s_m) and math.isfinite(v_mps) and math.isfinite(a_mps2)):
            return self._send(ValvePosition.LAP)             # no valid measurement: hold what is applied
        if self.applying:
            if self.model.demand + p.valve_service_rate_mps3 * p.scan_us * 1e-6 <= self.curve.a_mps2 + 1e-9:
                return self._send(ValvePosition.SERVICE)
            self.applying = False
        k = self.scans % p.work_scans
        if k == 0:                                           # one united attempt-and-work step
            e = self.predicted_deviation(now_us, s_m, v_mps, a_mps2)
            q = abs(e) if math.isfinite(e) else math.inf
            if self.q_expected is None:
                self.move = q >= p.dead_zone_m               # the first step: towards braking harder
            else:
                self.direction, self.move = search_step(self.direction, q, self.q_expected, p.threshold_m,
                                                        p.dead_zone_m)
            self.q_expected = self.expected_quality(now_us, s_m, v_mps, a_mps2, q)
            self.quality, self.deviation = q, e
        self.scans += 1
        return self._send(step_position(self.direction, self.move, k, p.step_scans))

    def _send(self, position: ValvePosition) -> ValvePosition:
        self.model.step(self.p.scan_us * 1e-6, position)
        return position


@dataclass
class StopOutput:
    state: StopState
    command_mps2: float      # the braking command (target deceleration) [m/s²]; 0 when OFF or ARMED
    distance_to_go_m: float  # target − odometer position [m] (NaN without target)
    ref_speed_mps: float     # the curve's speed at this point [m/s] (NaN when not following)
    quality: float           # the search's last Q [m] (NaN for pi or when not following)
    valve: ValvePosition | None = None   # the brake valve position of the adaptive methods (None: pi)


class StoppingController:
    """One BCU cycle of precise stopping: step(...) -> StopOutput.

    The adaptive methods run `AdaptiveSearch` every PLC scan (`p.scan_us`) and turn its valve position into
    the command with `BrakeValve` every cycle; `valve_position` is the position in force (RELEASE when
    not braking, SERVICE while holding the train at the stop; None for pi)."""

    def __init__(self, p: StoppingParams) -> None:
        self.p = p
        self.state = StopState.OFF
        self.odometer = Odometer(p.start_position_m, p.start_time_us, p.speed_latency_s, p.diff_tau_s)
        self.target_m: float | None = None
        self.curve: Curve | None = None            # the braking curve followed; None: not following
        self.command = 0.0
        self.pi = PI(p.pi)
        self.search: AdaptiveSearch | None = None  # the adaptive methods' search along the curve
        self.valve = BrakeValve(p.valve)
        self._valve_position = ValvePosition.RELEASE   # the adaptive methods' position in force
        self._next_scan_us = 0
        self.quality = math.nan

    @property
    def valve_position(self) -> ValvePosition | None:
        """The brake valve position in force (the adaptive methods; None for pi)."""
        return None if self.p.method == "pi" else self._valve_position

    def step(self, now_us: int, dt_s: float, *, target_valid: bool, target_m: float, emergency: bool,
             standstill: bool, train_speed_mps: float) -> StopOutput:
        p = self.p
        x = self.odometer.position(now_us)
        new_target = target_valid and self.target_m is not None and target_m != self.target_m
        if target_valid and self.target_m is None:
            new_target = True
        self.target_m = target_m if target_valid else None
        v = max(train_speed_mps, 0.0)
        togo = (target_m - x) if target_valid else math.nan
        curve_reached = target_valid and togo <= v * v / (2.0 * p.planned_decel_mps2) + v * p.apply_lead_s(
            p.planned_decel_mps2)
        before = self.state
        self.state = stop_state_transition(before, target_valid=target_valid, new_target=new_target,
                                           emergency=emergency, standstill=standstill,
                                           curve_reached=curve_reached)
        ref_speed = math.nan
        if self.state == StopState.FOLLOWING:
            curve, search = self.curve, self.search
            if curve is None or before != StopState.FOLLOWING or new_target:
                curve, search = self._start_curve(now_us, x, v, togo)
            if search is None:                                  # pi: the curve tracked on distance to go
                ref_speed = self._track(curve, dt_s, v, togo)
            else:
                ref_speed = self._scan(curve, search, now_us, dt_s, x, v)
        elif self.state == StopState.STOPPED:
            self.command = p.hold_decel_mps2
            if p.method != "pi":
                self._valve_position = ValvePosition.SERVICE
                self.valve.demand = self.command
        else:
            self.command, self.curve, self.search, self.quality = 0.0, None, None, math.nan
            if p.method != "pi":
                self._valve_position, self.valve.demand = ValvePosition.RELEASE, 0.0
        return StopOutput(self.state, self.command, togo, ref_speed, self.quality, self.valve_position)

    def _start_curve(self, now_us: int, x: float, v: float,
                     togo: float) -> tuple[Curve, AdaptiveSearch | None]:
        """A new braking curve from here, and for the adaptive methods a new search along it."""
        p = self.p
        curve = self.curve = braking_curve(now_us, x, v, togo, p)
        if p.method == "pi":
            d0 = max(togo, 0.01)
            self.command = min(curve.a_mps2, p.max_decel_mps2)          # the desired braking acceleration
            # bumpless: the first PI output is the curve's deceleration, with the feed-forward v²/(2 d0) in it
            self.pi.handover(self.command, feedforward=min(v * v / (2.0 * d0), p.max_decel_mps2))
            return curve, None
        search = self.search = AdaptiveSearch(p, curve, diff=p.method == "adaptive_diff")
        search.model.demand = self.valve.demand                         # a new target while braking
        self._next_scan_us = now_us
        return curve, search

    def _track(self, curve: Curve, dt_s: float, v: float, togo: float) -> float:
        """The pi method's cycle: the feed-forward v²/(2 s) plus the PI on the speed error to V_th(s)."""
        p = self.p
        s = max(togo, 0.0)
        ref = math.sqrt(2.0 * curve.a_mps2 * s)
        if togo > p.final_distance_m:
            ff = v * v / (2.0 * togo)
        else:
            ff = p.max_decel_mps2 if togo <= 0.0 else v * v / (2.0 * p.final_distance_m)
        self.command = self.pi.update(v - ref, dt_s, feedforward=clip(ff, 0.0, p.max_decel_mps2))
        return ref

    def _scan(self, curve: Curve, search: AdaptiveSearch, now_us: int, dt_s: float, x: float,
              v: float) -> float:
        """The adaptive methods' cycle: a PLC scan when one is due, the valve's position into the command."""
        p = self.p
        if now_us >= self._next_scan_us:                       # one PLC scan
            self._valve_position = search.scan(now_us, x - curve.x0_m, v, self.odometer.decel)
            self.quality = search.quality
            self._next_scan_us += p.scan_us * max(1, (now_us - self._next_scan_us) // p.scan_us + 1)
        self.command = self.valve.step(dt_s, self._valve_position)
        return curve.state(now_us).v_mps


# the BCU_STOP frame's signals and StopState in BCU_STATUS
STOP_OUTPUTS = ("StopState", "DistanceToGo", "RefSpeed", "StopCommand", "BalisesSeen", "SearchQ")
BTM_INPUTS = ("BalisePos", "PassageAge", "BaliseCount", "BaliseValid")   # car 1's balise reader, PLANT_BTM


class StoppingDemand:
    """Precise stopping as a demand source of the BCU (firmware_py.bcu.DemandSource): it reads DESK_TARGET
    (TargetStopValid, TargetStopPos), keeps an odometer on the train speed estimate (re-anchored on car 1's
    balise passages, PLANT_BTM, on a track with balises), and asks for the service brake along the
    theoretical braking curve; it sends where it believes the train is against its target and curve
    (BCU_STOP) and its state (BCU_STATUS.StopState)."""

    OUTPUTS: ClassVar[tuple[str, ...]] = STOP_OUTPUTS

    def __init__(self, p: StoppingParams) -> None:
        self.p = p
        self.controller = StoppingController(p)
        self.INPUTS = ("TargetStopValid", "TargetStopPos") + (BTM_INPUTS if p.balises else ())
        self.out: StopOutput | None = None     # last StopOutput (diagnostic)
        self.balises_seen = 0                  # balise passages the odometer re-anchored on
        self._balise_count: float | None = None
        self._odo_rx_us: int | None = None

    def demand(self, now_us: int, rx: RxTable, train: Train, out: dict[str, float]) -> Demand:
        """The cycle: a fresh speed sample to the odometer (its reception time: the newest BECUn_STATUS),
        the balise, then the controller.  The odometer integrates the median of the cars' estimates: the
        maximum (the train speed, safe against sliding wheels) is biased upwards by the estimates' noise,
        and that bias integrates."""
        t_rx = train.status_rx_us
        odo_speed = statistics.median(train.known_mps) if train.known_mps else math.nan
        if t_rx is not None and t_rx != self._odo_rx_us and not math.isnan(odo_speed):
            self.controller.odometer.sample(t_rx, odo_speed)
            self._odo_rx_us = t_rx
        if self.p.balises:
            self._balise(now_us, rx)
        valid, _ = finite_or(rx["TargetStopValid"], 0.0)
        target_m, ok = finite_or(rx["TargetStopPos"], 0.0)
        speed = train.speed_mps
        so = self.out = self.controller.step(
            now_us, train.dt_s, target_valid=valid >= 0.5 and ok, target_m=target_m,
            emergency=train.desk_emergency or train.mode == BcuMode.EMERGENCY, standstill=train.standstill,
            train_speed_mps=0.0 if math.isnan(speed) else speed)
        out.update(StopState=int(so.state),
                   DistanceToGo=0.0 if math.isnan(so.distance_to_go_m) else so.distance_to_go_m,
                   RefSpeed=0.0 if math.isnan(so.ref_speed_mps) else so.ref_speed_mps,
                   StopCommand=so.command_mps2, BalisesSeen=self.balises_seen % 16,
                   SearchQ=0.0 if math.isnan(so.quality) else min(so.quality, 127.5))
        braking = so.state in (StopState.FOLLOWING, StopState.STOPPED)    # or holding the train at the stop
        return Demand(so.command_mps2 if braking else 0.0, braking)

    def _balise(self, now_us: int, rx: RxTable) -> None:
        """A new balise passage in PLANT_BTM (its count changed) re-anchors the odometer: the passage time
        is the frame's reception time minus its PassageAge."""
        valid, _ = finite_or(rx["BaliseValid"], 0.0)
        count, ok = finite_or(rx["BaliseCount"], math.nan)
        if valid < 0.5 or not ok or count == self._balise_count:
            return
        self._balise_count = count
        pos, ok_pos = finite_or(rx["BalisePos"], math.nan)
        age_s, ok_age = finite_or(rx["PassageAge"], math.nan)
        if not (ok_pos and ok_age):
            return
        t_pass = now_us - (rx.age_us("BaliseCount", now_us) or 0) - age_s * 1e6
        self.controller.odometer.anchor(pos, t_pass)
        self.balises_seen += 1
