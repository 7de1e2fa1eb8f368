"""Precise stopping at a target point (seed 002 §III, §VI–§VIII): the BCU's braking command along a
theoretical braking curve (S, V, a), three ways.

* ``adaptive`` — the paper's *adaptive search with united attempt and work steps* (§III, Fig. 2): every
  work period the command u (a target deceleration) takes one work step ±Δu, which is also the next
  attempt.  The quality function Q is evaluated after each step: if Q did not deteriorate by more than
  the threshold δ (δ > 0) the previous work step is repeated, otherwise the opposite step is taken.  Inside
  the insensitivity zone (Q below `dead_zone_m`) the command is held: the driver's brake valve's lap
  position (§VII, position IV), between release (II) and service brake (V).  Q is the path deviation from
  the theoretical curve, |S − S_th(t)| [m] (the PLC of §VI computes S, V and a along the curve, Fig. 4).
* ``adaptive_diff`` — the same search with the *differentiation unit* (Fig. 3), which "follows a change
  of the controllable parameters in time": it differentiates the speed (the odometer's deceleration
  estimate a, `Odometer.decel`), and Q is evaluated on the path deviation predicted a horizon T_d ahead,
  |e + T_d·ė + T_d²/2·ë| with e = S − S_th, ė = V − V_th and ë = a_th − a (the time derivatives of e),
  so the search sees where the deviation is heading before the brake's lag and the double integration
  from deceleration to path show it in S; and it judges each work step against the trend it follows,
  ΔQ = Q_N − |2ê_(N−1) − ê_(N−2)| (the deviation extrapolated one work period as if no step had been
  taken), so that a drifting deviation is not mistaken for the step's failure.
* ``pi`` — a modern baseline (not in the paper): curve tracking on distance to go.  The curve is
  V_th(s) = √(2 a_c s) (s: distance to go); the command is the feed-forward v²/(2s) (the deceleration
  that stops the train exactly at the point from here) plus the shared PI (`firmware_py.pi`) on the
  speed error v − V_th(s).

Theoretical curve (§VI: "a road driven S, a current motion speed V and a current braking acceleration
a"): when the train reaches the point from which a stop at the planned deceleration a_p ends at the target
(or at once, when the target is nearer than that), the curve starts at time t_0, position x_0 and speed
v_0 with a_c = max(a_p, v_0²/(2 d_0)), d_0 = target − x_0:  S_th(τ) = v_0 τ − a_c τ²/2, V_th(τ) = v_0 − a_c τ,
a_th = a_c, for τ = t − t_0 ≤ T = v_0/a_c; afterwards S_th = d_0, V_th = 0.

Position: the BCU knows the train's position only from CAN.  Its odometer (`Odometer`) starts from a
known reference point passed at a known time (a balise: the scenario's start position at t = 0) and
integrates the train speed estimate over the samples' reception times (trapezoidal), extrapolating from
the last sample and compensating the speed chain's latency (wheel sensor → BECU estimate → CAN).

Mode logic is the pure `stop_state_transition`; `StoppingController.step` is one BCU cycle.  Units: SI,
decelerations positive when braking.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

from firmware_py.limits import clip
from firmware_py.pi import PI, PIParams

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
    move is False (lap: the command is held) while Q is inside the insensitivity zone."""
    if q_now - q_before > threshold:
        direction = -direction
    return direction, q_now >= dead_zone


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
    # --- adaptive search (Fig. 2): work period, step size a, threshold δ, insensitivity zone
    # (the search's four constants were chosen together by a sweep on an ideal train with a 0.3 s brake
    #  lag, ±15 % brake gain, 400–1000 m at 20–25 m/s: the best worst case of adaptive_diff; the plain
    #  search gets the same constants so that the two differ by the differentiation unit only)
    work_period_s: float = 0.5               # one work step every 0.5 s: the brake's response limits how
    #                                          often the command may usefully change (§III-A)
    search_step_mps2: float = 0.05           # Δu: one brake-valve notch of the command [m/s²]
    threshold_m: float = 0.1                 # δ on ΔQ [m]
    dead_zone_m: float = 2.0                 # insensitivity zone on Q [m]: lap position inside it
    diff_horizon_s: float = 5.0              # T_d of the differentiation unit (Fig. 3) [s]
    diff_tau_s: float = 0.5                  # low-pass of the differentiated speed (deceleration) [s]
    # --- PI baseline: speed error [m/s] → deceleration [m/s²]
    pi: PIParams = field(default_factory=lambda: PIParams(kp=0.4, ki=0.1, out_min=0.0, out_max=1.0))
    final_distance_m: float = 0.3            # below this distance to go the feed-forward is held (1/s → ∞)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"StoppingParams.method must be one of {METHODS}, got {self.method!r}")


class Odometer:
    """Train position [m] from the speed estimate [m/s] received over CAN.

    `sample(t_rx_us, v)` with each fresh speed estimate (its reception time); `position(now_us)` the
    estimated position now.  Anchored at `x0_m` passed at `t0_us`; before the first sample the train is
    assumed to keep the first sample's speed (it coasts onto the reference point)."""

    def __init__(self, x0_m: float, t0_us: int, latency_s: float, decel_tau_s: float = 0.5) -> None:
        self.x0, self.t0, self.latency_s, self.decel_tau_s = x0_m, t0_us, latency_s, decel_tau_s
        self.decel = 0.0                      # −dv/dt of the samples, low-passed with decel_tau_s [m/s²]
        self.x: float | None = None           # position at the last sample's reference time
        self.t_us: int | None = None          # the last sample's reception time
        self.v = 0.0

    def sample(self, t_rx_us: int, v_mps: float) -> None:
        if not math.isfinite(v_mps):
            return
        if self.x is None:
            # the sample describes the train latency_s before it arrived: anchor on the reference point
            self.x = self.x0 + v_mps * ((t_rx_us - self.t0) * 1e-6 - self.latency_s)
        elif t_rx_us > self.t_us:
            dt = (t_rx_us - self.t_us) * 1e-6
            self.x += 0.5 * (self.v + v_mps) * dt                                     # trapezoid
            self.decel += (1.0 - math.exp(-dt / self.decel_tau_s)) * ((self.v - v_mps) / dt - self.decel)
        else:
            return
        self.t_us, self.v = t_rx_us, v_mps

    def position(self, now_us: int) -> float:
        if self.x is None:
            return self.x0
        return self.x + self.v * ((now_us - self.t_us) * 1e-6 + self.latency_s)

    def anchor(self, x_m: float, t_us: float) -> float:
        """A fixed reference point (a balise) was passed at `x_m` at time `t_us`: shift the odometer so that
        it reads x_m then.  Returns the correction [m] (+: the odometer was behind)."""
        if not (math.isfinite(x_m) and math.isfinite(t_us)):
            return 0.0
        if self.x is None:                  # no speed sample yet: the balise is the new reference point
            self.x0, self.t0 = x_m, round(t_us)
            return 0.0
        shift = x_m - (self.x + self.v * ((t_us - self.t_us) * 1e-6 + self.latency_s))
        self.x += shift
        return shift


@dataclass(frozen=True)
class Curve:
    """The theoretical braking curve (S, V, a) of §VI, started at t0_us from x0_m at v0_mps."""

    t0_us: int
    x0_m: float
    v0_mps: float
    d0_m: float           # distance to go at the start
    a_mps2: float         # a_c

    def at(self, now_us: int) -> tuple[float, float]:
        """(S_th, V_th): path [m] from the curve's start and speed [m/s] at now_us."""
        tau = max((now_us - self.t0_us) * 1e-6, 0.0)
        t_end = self.v0_mps / self.a_mps2 if self.a_mps2 > 0.0 else math.inf
        if tau >= t_end:
            return self.d0_m, 0.0
        return self.v0_mps * tau - 0.5 * self.a_mps2 * tau * tau, self.v0_mps - self.a_mps2 * tau


@dataclass
class StopOutput:
    state: StopState
    command_mps2: float      # the braking command (target deceleration) [m/s²]; 0 when OFF or ARMED
    distance_to_go_m: float  # target − odometer position [m] (NaN without target)
    ref_speed_mps: float     # the curve's speed at this point [m/s] (NaN when not following)
    quality: float           # the search's last Q [m] (NaN for pi or when not following)


class StoppingController:
    """One BCU cycle of precise stopping: step(...) -> StopOutput."""

    def __init__(self, p: StoppingParams) -> None:
        self.p = p
        self.state = StopState.OFF
        self.odometer = Odometer(p.start_position_m, p.start_time_us, p.speed_latency_s, p.diff_tau_s)
        self.target_m: float | None = None
        self.curve: Curve | None = None
        self.command = 0.0
        self.pi = PI(p.pi)
        self._dir = 1                            # the search's last work-step direction (+1: brake harder)
        self._q_before: float | None = None
        self._e_before: float | None = None       # ê of the last two work steps (differentiation unit)
        self._e_before2: float | None = None
        self._next_work_us = 0
        self.quality = math.nan

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
        curve_reached = target_valid and togo <= v * v / (2.0 * p.planned_decel_mps2)
        before = self.state
        self.state = stop_state_transition(before, target_valid=target_valid, new_target=new_target,
                                           emergency=emergency, standstill=standstill,
                                           curve_reached=curve_reached)
        ref_speed = math.nan
        if self.state == StopState.FOLLOWING:
            if before != StopState.FOLLOWING or new_target:
                self._start_curve(now_us, x, v, togo)
            ref_speed = self._follow(now_us, dt_s, x, v, togo)
        elif self.state == StopState.STOPPED:
            self.command = p.hold_decel_mps2
        else:
            self.command, self.curve, self.quality = 0.0, None, math.nan
        return StopOutput(self.state, self.command, togo, ref_speed, self.quality)

    def _start_curve(self, now_us: int, x: float, v: float, togo: float) -> None:
        p = self.p
        d0 = max(togo, 0.01)
        a_c = max(p.planned_decel_mps2, v * v / (2.0 * d0))
        self.curve = Curve(now_us, x, v, d0, a_c)
        self.command = min(a_c, p.max_decel_mps2)       # the desired braking acceleration (§VII)
        self._dir, self._q_before, self._next_work_us = 1, None, now_us
        self._e_before = self._e_before2 = None
        # bumpless: the first PI output is the curve's deceleration, with the feed-forward v²/(2 d0) in it
        self.pi.handover(self.command, feedforward=min(v * v / (2.0 * d0), p.max_decel_mps2))

    def _follow(self, now_us: int, dt_s: float, x: float, v: float, togo: float) -> float:
        p, curve = self.p, self.curve
        if p.method == "pi":
            s = max(togo, 0.0)
            ref = math.sqrt(2.0 * curve.a_mps2 * s)
            if togo > p.final_distance_m:
                ff = v * v / (2.0 * togo)
            else:
                ff = p.max_decel_mps2 if togo <= 0.0 else v * v / (2.0 * p.final_distance_m)
            self.command = self.pi.update(v - ref, dt_s, feedforward=clip(ff, 0.0, p.max_decel_mps2))
            return ref
        s_th, v_th = curve.at(now_us)
        e = (x - curve.x0_m) - s_th                      # > 0: ahead of the curve: brake harder
        if p.method == "adaptive_diff":
            # differentiation unit, Fig. 3: ė = V − V_th, ë = a_th − a
            a_th = curve.a_mps2 if v_th > 0.0 else 0.0
            td = p.diff_horizon_s
            e += td * (v - v_th) + 0.5 * td * td * (a_th - self.odometer.decel)
        q = abs(e)
        if now_us >= self._next_work_us:                  # one united attempt-and-work step
            if self._q_before is not None:
                q_before = self._q_before
                if p.method == "adaptive_diff" and self._e_before2 is not None:
                    q_before = abs(2.0 * self._e_before - self._e_before2)      # the trend, extrapolated
                self._dir, move = search_step(self._dir, q, q_before, p.threshold_m, p.dead_zone_m)
                if move:
                    self.command = clip(self.command + self._dir * p.search_step_mps2, 0.0, p.max_decel_mps2)
            self._q_before, self._e_before2, self._e_before = q, self._e_before, e
            self._next_work_us = now_us + round(p.work_period_s * 1e6)
        self.quality = q
        return v_th
