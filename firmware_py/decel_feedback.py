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
from typing import ClassVar

from firmware_py.bcu import BcuMode, Train
from firmware_py.becu import Loop
from firmware_py.ekf import DecelEstimator, DecelEstimatorParams
from firmware_py.limits import clip, finite_or
from firmware_py.pi import PI, PIParams
from firmware_py.rx import RxTable


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
            self.ratio = raw if math.isnan(self.ratio) else (
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
                start = 1.0 if math.isnan(ratio) else ratio / self.set_phi()
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


class TrainFeedback:
    """The function in the BCU, as a follower of its demand (firmware_py.bcu.Follower): it reads the front
    and rear cars' accelerometers (PLANT_CAR1/n_SENSORS.AccelLong, §6.1) and every car's WspActive, and
    sends its state and the slope estimate in BCU_STATUS (FbState, SlopeEst) and the pressure correction φ
    with its state in the authenticated BCU_BRAKE_CORR (FbState, FrictionPhi); the BECUs apply φ while
    FbState is ENGAGED or HELD (`PhiCorrection`)."""

    OUTPUTS: ClassVar[tuple[str, ...]] = ("FbState", "FrictionPhi", "SlopeEst")

    def __init__(self, params: FeedbackParams, n_cars: int) -> None:
        self.feedback = DecelFeedback(params)
        self.accel_keys = ("PLANT_CAR1_SENSORS.AccelLong", f"PLANT_CAR{n_cars}_SENSORS.AccelLong")
        self.wsp_keys = tuple(f"BECU{i}_STATUS.WspActive" for i in range(1, n_cars + 1))
        self.speed_key = "BECU1_STATUS.SpeedEst"
        self.INPUTS = self.accel_keys + self.wsp_keys
        self.out: FeedbackOutput | None = None      # last FeedbackOutput (diagnostic)
        self._speed_rx_us: int | None = None

    def follow(self, now_us: int, rx: RxTable, train: Train, out: dict[str, float]) -> None:
        front, rear = [finite_or(rx[key], math.nan)[0] for key in self.accel_keys]
        if math.isnan(front):                          # an accelerometer not heard from: use the other
            front = 0.0 if math.isnan(rear) else rear
        if math.isnan(rear):
            rear = front
        wsp = any(finite_or(rx[key], 0.0)[0] >= 0.5 for key in self.wsp_keys)
        # a fresh speed estimate for the EKF: when a new BECU1_STATUS arrived
        train_speed = train.speed_mps if train.known_mps else 0.0
        speed: float | None = train_speed if train_speed > 0.0 else None
        if speed is not None:
            age = rx.age_us(self.speed_key, now_us)
            t_rx = None if age is None else now_us - age
            if t_rx == self._speed_rx_us:
                speed = None
            self._speed_rx_us = t_rx
        wanted = train.step_decel_mps2
        service = train.mode == BcuMode.SERVICE and wanted > 0.0
        target = train.target_mps2
        fb = self.out = self.feedback.step(train.dt_s, target, target == wanted, service,
                                           train.mode == BcuMode.EMERGENCY, wsp, front, rear, speed,
                                           train_speed)
        out.update(FbState=int(fb.state), FrictionPhi=fb.phi,
                   SlopeEst=clip(fb.slope, -0.064, 0.06375))          # the DBC signal's range


# the BCU's feedback states in which its φ is a correction to apply (HELD keeps the engaged one)
PHI_STATES = (float(FbState.ENGAGED), float(FbState.HELD))


@dataclass(frozen=True)
class PhiParams:
    """A BECU's side of the deceleration feedback (`PhiCorrection`)."""

    # output gate on the BCU's pressure correction φ (eq. (34)): the authority the BCU has over this car's
    # service-brake pressure, -38 %/+67 % (chosen; the BCU's own limits are the same)
    limits: tuple[float, float] = (0.6, 1.6)
    # φ older than this is not applied: 3 cycles of BCU_BRAKE_CORR (100 ms, DBC), as the BCU judges a
    # silent car after 3 of its status cycles; a lost or deleted correction falls back to φ = 1
    timeout_us: int = 300_000


class PhiCorrection:
    """The pressure correction φ as a set-point stage of a BECU's pipeline (firmware_py.becu.SetpointStage):
    eq. (34), P_c = preload + (P_c0 − preload)/φ on the force part of the set-point (above the return-spring
    preload, where the torque is proportional to the pressure, eq. (24)), φ gated to `PhiParams.limits`.
    φ = 1 unless BCU_BRAKE_CORR's FbState says the feedback is ENGAGED or HELD (HELD keeps the engaged
    correction, §5), and when φ is not received, older than `timeout_us`, not finite, in emergency or on
    loss of command (§5: not for emergency braking).  `preload_Pa`, `p_max_Pa`: the BECU's brake data."""

    INPUTS: ClassVar[tuple[str, ...]] = ("FrictionPhi", "FbState")        # BCU_BRAKE_CORR
    OUTPUTS: ClassVar[tuple[str, ...]] = ()

    def __init__(self, params: PhiParams, preload_Pa: float, p_max_Pa: float) -> None:
        self.p, self.preload_Pa, self.p_max_Pa = params, preload_Pa, p_max_Pa

    def setpoint(self, now_us: int, rx: RxTable, p_set_Pa: float, loop: Loop, out: dict[str, float]) -> float:
        phi, phi_ok = finite_or(rx.get("FrictionPhi", 1.0), 1.0)
        engaged = finite_or(rx.get("FbState", 0.0), 0.0)[0] in PHI_STATES and not self.stale(now_us, rx)
        if phi_ok and engaged and not (loop.emergency or loop.lost):
            return self.apply(p_set_Pa, phi)
        return p_set_Pa

    def apply(self, p_set_Pa: float, phi: float) -> float:
        """Eq. (34) on the force part of the set-point, φ gated to `limits`."""
        pre = self.preload_Pa
        if phi == 1.0 or p_set_Pa <= pre:
            return p_set_Pa
        lo, hi = self.p.limits
        return clip(pre + (p_set_Pa - pre) / clip(phi, lo, hi), 0.0, self.p_max_Pa)

    def stale(self, now_us: int, rx: RxTable) -> bool:
        """φ was received more than `timeout_us` ago."""
        age = rx.age_us("FrictionPhi", now_us)
        return age is not None and age > self.p.timeout_us
