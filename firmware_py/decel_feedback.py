"""BCU deceleration feedback (seed 004 §5): the brake-cylinder pressure correction φ of eq. (34).

The BCU distributes a target deceleration; each BECU turns it into a cylinder pressure P_c0 with its
inverse brake model (eq. (32): P_c0 ∝ m a_0 / (brake gain at the mean pad friction μ_d0), which is
`firmware_py.becu.Becu.pressure_for_decel`).  The real pad friction μ_d(v, t) differs from μ_d0
(eqs. (24)–(25)), so the actual deceleration differs from the target.  This module decides when to
correct and by how much:

* the actual deceleration and the slope come from the EKF of `firmware_py.ekf` (front and rear
  accelerometers, train speed);
* the deceleration the target should give by now is the target through the cylinder's first-order
  lag T_q (eq. (33)); ratio = actual / that;
* mode logic (`feedback_transition`, pure): the loop engages when, once the demand is steady (at its
  brake step's value, past the jerk-limited ramp and T_q), the ratio stays outside 90–110 % for more
  than 0.5 s (§5.2); it is disabled for emergency braking and while any
  car's WSP acts, and when it cannot bring the ratio back into the band (§5.3); once it has engaged and is
  released, the corrected pressure is kept (HELD, §5.2) until the service brake is released;
* φ (eq. (34), φ = μ_d(v, t − T_q)/μ_d0): the friction-coefficient set μ(v, t)/μ_d0 (`FrictionSet`,
  built from brake-disc test data, `plant_sim.padbench`) read at the stop's initial speed class and the
  time since brake application plus T_q (so that the pressure leads the friction by the cylinder's lag),
  times a trim from the shared PI on the ratio error (the set predicts the shape, the feedback its level;
  the trim starts at engagement from φ measured as actual/target, eq. (34)).
  Each BECU applies P_c = P_c0 / φ to the force part of its pressure (above the return-spring preload).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

from firmware_py.ekf import DecelEstimator, DecelEstimatorParams
from firmware_py.limits import clip
from firmware_py.pi import PI, PIParams


class FbState(IntEnum):
    """Values are the DBC choices of FbState (BCU_STATUS, BCU_BRAKE_CORR)."""

    OFF = 0        # no service braking, emergency braking, or the function is not fitted: φ = 1
    MONITOR = 1    # service braking: actual/target deceleration watched, no correction
    ENGAGED = 2    # the loop corrects the cylinder pressure through φ
    HELD = 3       # the loop was released (WSP, or it could not meet the band): the last φ is kept


def feedback_transition(state: FbState, *, enabled: bool, service: bool, emergency: bool, wsp_active: bool,
                        out_of_band_s: float, failing_s: float, engage_after_s: float,
                        give_up_after_s: float) -> FbState:
    """Pure mode logic of the deceleration feedback (seed 004 §5.2–5.3).

    enabled: the closed loop may act (False: monitor only, the open-loop BCU); service: service braking
    is demanded; out_of_band_s: how long the ratio has been outside the band while the demand is steady;
    failing_s: how long the ratio has been outside the band while engaged."""
    if emergency or not service:
        return FbState.OFF                          # emergency has priority; a released brake ends the stop
    if state == FbState.OFF:
        return FbState.MONITOR
    if state == FbState.MONITOR:
        if enabled and not wsp_active and out_of_band_s > engage_after_s:
            return FbState.ENGAGED
        return FbState.MONITOR
    if state == FbState.ENGAGED:
        if wsp_active or failing_s > give_up_after_s:
            return FbState.HELD                     # released: the corrected pressure is kept (§5.2)
        return FbState.ENGAGED
    return FbState.HELD


def band_timer(timer_s: float, ratio: float, judged: bool, dt_s: float, band: tuple[float, float]) -> float:
    """Time [s] the ratio has been outside `band` without a break, counting only `judged` cycles (pure)."""
    if not judged:
        return 0.0
    lo, hi = band
    return timer_s + dt_s if not (lo <= ratio <= hi) else 0.0


@dataclass(frozen=True)
class FrictionSet:
    """μ(v, t)/μ_d0 on a grid (seed 004 §4.2, Fig. 15): rows by the stop's initial speed [km/h] (increasing),
    columns every dt_s [s] from brake application."""

    speeds_kmh: tuple[float, ...]
    dt_s: float
    values: tuple[tuple[float, ...], ...]

    def __post_init__(self) -> None:
        if (not self.speeds_kmh or len(self.values) != len(self.speeds_kmh) or not self.dt_s > 0.0
                or any(len(row) != len(self.values[0]) or not row for row in self.values)
                or any(b <= a for a, b in zip(self.speeds_kmh, self.speeds_kmh[1:], strict=False))):
            raise ValueError("FrictionSet: one non-empty row of equal length per increasing speed class")

    def at(self, v0_kmh: float, t_s: float) -> float:
        """Bilinear look-up, clamped to the grid."""
        sp, row_len = self.speeds_kmh, len(self.values[0])
        x = clip(t_s / self.dt_s, 0.0, row_len - 1.0)
        j = min(int(x), row_len - 2) if row_len > 1 else 0
        fx = x - j if row_len > 1 else 0.0

        def row_at(i: int) -> float:
            r = self.values[i]
            return r[j] if row_len == 1 else r[j] + fx * (r[j + 1] - r[j])

        if v0_kmh <= sp[0]:
            return row_at(0)
        if v0_kmh >= sp[-1]:
            return row_at(len(sp) - 1)
        i = next(k for k in range(len(sp) - 1) if sp[k + 1] >= v0_kmh)
        f = (v0_kmh - sp[i]) / (sp[i + 1] - sp[i])
        return row_at(i) + f * (row_at(i + 1) - row_at(i))


@dataclass(frozen=True)
class FeedbackParams:
    """Seed 004 §5 constants; "chosen" where the paper gives none."""

    enabled: bool = True                     # False: monitor only (the open-loop BCU, for comparison)
    band: tuple[float, float] = (0.9, 1.1)   # actual/target deceleration band, §5.2
    engage_after_s: float = 0.5              # outside the band for longer than this: engage, §5.2
    give_up_after_s: float = 5.0             # engaged and still outside the band this long: release (chosen)
    tq_s: float = 0.1                        # T_q, eq. (33): the cylinder's lag seen from the BCU (chosen:
    #                                          the BECU's 50 ms pressure loop plus the CAN chain)
    min_target_mps2: float = 0.2             # the ratio is judged above this target [m/s²] (chosen) ...
    steady_tol: float = 0.02                 # ... once the demand is steady: at its brake step's value, and
    #                                          its lagged value (eq. (33)) within 2 % of it; during the
    #                                          jerk-limited ramp the brake's lag is not T_q exactly (chosen)
    min_speed_mps: float = 1.0               # ... and above this train speed [m/s]: near standstill the
    #                                          deceleration collapses as the train stops (chosen)
    ratio_tau_s: float = 0.2                 # the judged ratio is low-pass filtered with this τ [s] (chosen)
    # trim of the set's level: PI on (ratio − 1), output multiplies φ; bounds are the correction authority
    trim_pi: PIParams = field(default_factory=lambda: PIParams(kp=0.1, ki=0.6, out_min=0.7, out_max=1.4))
    phi_limits: tuple[float, float] = (0.6, 1.6)   # φ sent on CAN (the BECUs gate it again)
    friction_set: FrictionSet | None = None  # None: φ = trim only (no coefficient set)
    estimator: DecelEstimatorParams = field(default_factory=DecelEstimatorParams)


@dataclass
class FeedbackOutput:
    state: FbState
    phi: float              # φ of eq. (34) [-]: each BECU applies P_c = P_c0 / φ
    decel_mps2: float       # the EKF's actual train deceleration [m/s², + braking]
    slope: float            # the EKF's mean slope tan θ [-]
    ratio: float            # actual / lagged target deceleration [-] (NaN when not judged)


class DecelFeedback:
    """One BCU cycle of the function: step(...) -> FeedbackOutput (time passed in as dt)."""

    def __init__(self, p: FeedbackParams | None = None) -> None:
        self.p = p or FeedbackParams()
        self.estimator = DecelEstimator(self.p.estimator)
        self.trim = PI(self.p.trim_pi)
        self.state = FbState.OFF
        self.phi = 1.0
        self.expected = 0.0          # target through the first-order lag T_q, eq. (33) [m/s²]
        self.ratio = math.nan        # actual / expected deceleration, filtered; NaN when not judged
        self.out_of_band_s = 0.0
        self.failing_s = 0.0
        self.brake_t_s = 0.0         # time since service brake application [s]
        self.v0_kmh = 0.0            # train speed at brake application [km/h]: the speed class
        self.engaged_at_s: float | None = None   # brake_t_s when the loop engaged (diagnostic)

    def step(self, dt_s: float, target_mps2: float, target_final: bool, service: bool, emergency: bool,
             wsp_active: bool, accel_front: float, accel_rear: float, speed_mps: float | None,
             train_speed_mps: float) -> FeedbackOutput:
        """target_mps2: the target deceleration sent this cycle; target_final: it has reached the brake
        step's value (no jerk-limited ramp going on); speed_mps: a fresh train speed for the EKF, or None;
        train_speed_mps: the BCU's train speed estimate."""
        p = self.p
        decel, slope = self.estimator.step(dt_s, accel_front, accel_rear, speed_mps)
        self.expected += (1.0 - math.exp(-dt_s / p.tq_s)) * (target_mps2 - self.expected)   # eq. (33)
        # judged: service braking at a steady demand worth comparing with, a train that is not stopping
        steady = (service and target_final and target_mps2 >= p.min_target_mps2
                  and abs(self.expected - target_mps2) <= p.steady_tol * target_mps2
                  and train_speed_mps >= p.min_speed_mps)
        if steady:
            raw = decel / self.expected
            self.ratio = raw if self.ratio != self.ratio else (
                self.ratio + (1.0 - math.exp(-dt_s / p.ratio_tau_s)) * (raw - self.ratio))
        else:
            self.ratio = math.nan
        ratio = self.ratio
        if self.state == FbState.OFF and service and not emergency:
            self.brake_t_s, self.v0_kmh = 0.0, train_speed_mps * 3.6          # a new stop begins
        else:
            self.brake_t_s += dt_s
        self.out_of_band_s = band_timer(self.out_of_band_s, ratio, steady and not wsp_active, dt_s, p.band)
        self.failing_s = band_timer(self.failing_s, ratio, steady and self.state == FbState.ENGAGED, dt_s,
                                    p.band)
        before = self.state
        self.state = feedback_transition(before, enabled=p.enabled, service=service, emergency=emergency,
                                         wsp_active=wsp_active, out_of_band_s=self.out_of_band_s,
                                         failing_s=self.failing_s, engage_after_s=p.engage_after_s,
                                         give_up_after_s=p.give_up_after_s)
        if self.state == FbState.OFF:
            self.phi, self.engaged_at_s, self.failing_s = 1.0, None, 0.0
            self.trim.reset(0.0)
        elif self.state == FbState.ENGAGED:
            judged = steady
            if before != FbState.ENGAGED:
                # eq. (34) measured at engagement: with φ = 1 so far, μ_d/μ_d0 = actual/target now; the
                # trim starts where it makes φ equal to that, and the set carries it on from there
                self.engaged_at_s = self.brake_t_s
                start = ratio / self.set_phi() if ratio == ratio else 1.0
                self.trim.handover(clip(start, p.trim_pi.out_min, p.trim_pi.out_max),
                                   error=(ratio - 1.0) if judged else 0.0)
            error = (ratio - 1.0) if judged else 0.0                       # > 0: braking too hard
            trim = self.trim.update(error, dt_s, freeze=not judged)
            lo, hi = p.phi_limits
            self.phi = clip(self.set_phi() * trim, lo, hi)                 # eq. (34)
        # MONITOR: φ stays 1; HELD: φ stays where the loop left it (§5.2)
        return FeedbackOutput(self.state, self.phi, decel, slope, ratio)

    def set_phi(self) -> float:
        """μ(v0, t + T_q)/μ_d0 from the coefficient set (1 without one)."""
        fs = self.p.friction_set
        return 1.0 if fs is None else fs.at(self.v0_kmh, self.brake_t_s + self.p.tq_s)
