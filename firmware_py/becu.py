"""Brake ECU of one car (BECU), v1.

Chain: train deceleration demand (BCU_DEMAND.TargetDecel) -> brake-cylinder pressure set-point
(inverse of the brake model: force -> torque -> pressure on the squeeze line of seed 001 eq. (6))
-> PI pressure control of the EP valve (the shared PI primitive), with a basic wheel-slide protection
(WSP) that vents above a slip threshold and refills with hysteresis.  With the EP valve's flow this
loop behaves as seed 001's first-order cylinder (eq. 4).

Inputs (DBC signal names, bound by hil): AxleSpeed, CylPressure, AccelLong (the car's sensors),
TargetDecel and Mode (BCU_DEMAND), EmergencyActive (BCU_EMERGENCY).
Outputs: the pressure command frame (CylPressureSet, ValveCmd, WspValve), the status frame and the
diagnostics frame (governor; SpeedSensorFault, AccelSensorFault, AccelBiasEst).

With BecuParams.control = "decel" the set-point comes from seed 001's deceleration PI (eq. 16) instead,
optionally behind the reference governor (eq. 9, firmware_py.governor), which sets GovernorActive.

Deceleration feedback (seed 004 §5, firmware_py.decel_feedback): in "pressure" control the BCU's
pressure correction φ (BCU_STATUS.FrictionPhi, eq. (34)) divides the force part of the set-point,
P_c = preload + (P_c0 − preload)/φ, gated to `phi_limits`; not received, not finite, emergency or loss of
command: φ = 1 (`apply_phi`).

Sensor plausibility (issue #9): the wheel-speed sensor is declared failed (SpeedSensorFault, latched)
when its reading says the wheel stands while the accelerometer says the car moves for longer than a
real slide lasts, or when its reading is frozen while the accelerometer says the speed changed; the
speed estimate then runs on the accelerometer alone and WSP is inhibited (the brake stays applied).
The accelerometer's bias (accelerometer − the axle's acceleration, filtered) is AccelBiasEst; above a
limit for a time it is AccelSensorFault (latched) and the axle's acceleration replaces it.  A vent-time
watchdog refills a cylinder that WSP has kept vented too long.  See `speed_sensor_check`,
`accel_bias_check` and `vent_watchdog`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple

from firmware_py.cycle import CycleTimer
from firmware_py.governor import GovernorDecision, GovernorParams, GovernorState, govern, play
from firmware_py.limits import clip, finite_or
from firmware_py.pi import PI, PIParams


class Wsp(IntEnum):
    """WSP dump-valve state; values are the DBC choices of BECUn_PRESS_CMD.WspValve."""

    FILL = 0   # normal: the EP valve controls the cylinder
    HOLD = 1   # cylinder isolated, pressure held
    VENT = 2   # cylinder vented to atmosphere


@dataclass(frozen=True)
class WspParams:
    vent_slip_mps: float = 0.30          # slip speed that starts venting at standstill (chosen)
    vent_slip_per_speed: float = 0.03    # + this fraction of the speed: 1.05 m/s at 25 m/s (chosen;
    #                                      above the slip of peak adhesion of seed 000 at that speed)
    hold_fraction: float = 0.5           # VENT -> HOLD below this fraction of the vent threshold
    refill_fraction: float = 0.25        # HOLD -> FILL below this fraction of the vent threshold
    min_speed_mps: float = 1.0           # WSP inhibited below this speed (lets the train stop)
    # vent-time watchdog: a cylinder kept out of FILL (vent or hold) longer than this is refilled and WSP
    # stays off until the wheel has recovered. 5 s is the "standard five (5) second" WSP safety timer of
    # Canadian patent CA 2025196 (axle health discriminatory safety timer); UIC 541-05 limits continuous
    # venting too, but its figure was not found in the sources at hand
    max_vent_s: float = 5.0


def wsp_transition(state: Wsp, slip_mps: float, speed_mps: float, p: WspParams) -> Wsp:
    """Pure mode transition of the basic wheel-slide protection (vent / hold / refill with hysteresis).

    With refill_fraction ≥ hold_fraction there is no hold phase: VENT returns to FILL as soon as the slip
    is below the refill threshold, as seed 001 §II-C's WSP does (vent, u = 0, while s > s̄; track again
    once s is back in the adhesion region).
    """
    if speed_mps < p.min_speed_mps:
        return Wsp.FILL
    vent_at = p.vent_slip_mps + p.vent_slip_per_speed * speed_mps
    if slip_mps > vent_at:
        return Wsp.VENT
    if state == Wsp.VENT and p.refill_fraction >= p.hold_fraction:
        return Wsp.FILL if slip_mps < p.refill_fraction * vent_at else Wsp.VENT
    if state == Wsp.VENT:
        return Wsp.HOLD if slip_mps < p.hold_fraction * vent_at else Wsp.VENT
    if state == Wsp.HOLD:
        return Wsp.FILL if slip_mps < p.refill_fraction * vent_at else Wsp.HOLD
    return Wsp.FILL


def vent_watchdog(vent_s: float, tripped: bool, venting: bool, recovered: bool, dt_s: float,
                  max_vent_s: float) -> tuple[float, bool]:
    """Pure vent-time watchdog: (time vented continuously [s], tripped).

    `venting`: WSP wants the cylinder out of FILL this cycle; `recovered`: the wheel's slip is back
    below the refill threshold.  Trips when venting lasts longer than `max_vent_s`; while tripped the
    caller keeps the cylinder in FILL; it re-arms once the wheel has recovered."""
    if tripped:
        return 0.0, not recovered
    vent_s = vent_s + dt_s if venting else 0.0
    return (0.0, True) if vent_s > max_vent_s else (vent_s, False)


# Steepest gradient a scenario may declare: hil.scenario's GradientPoint.permille is bounded to ±60 ‰.
# On it the accelerometer legitimately reads g·sin(atan(0.060)) = 0.588 m/s² more than the axle's
# acceleration, so the bias limit must lie above that.
STEEPEST_GRADIENT_MPS2 = 9.81 * 0.060 / math.sqrt(1.0 + 0.060 ** 2)


@dataclass(frozen=True)
class SensorCheckParams:
    """Plausibility limits of the car's wheel-speed sensor and accelerometer (issue #9)."""

    # wheel-speed sensor, "stands": a reading below stand_mps while the speed estimate (accelerometer)
    # is above moving_mps for longer than lock_s.  A real slide ends within lock_s: WSP vents above a
    # few tenths of a m/s of slip and the wheel spins up within tenths of a second; the longest slide
    # to a standing wheel in the rg_* scenarios and the wet section of default is 0 s (chosen)
    stand_mps: float = 0.3                 # wheel reading that says the wheel stands [m/s] (chosen, ~1 km/h)
    moving_mps: float = 3.0                # ... while the car moves faster than this [m/s] (chosen)
    lock_s: float = 1.0                    # ... for longer than this [s] (chosen, see above)
    # wheel-speed sensor, "frozen": the same reading on every fresh frame while the accelerometer
    # (corrected by its bias estimate, which holds the gradient term) integrates to a speed change of
    # more than frozen_dv_mps.  With the sensor noise of the plant (0.002–0.02 rad/s std against a
    # 0.005 rad/s resolution) a live reading does not repeat for long at speed (chosen)
    frozen_dv_mps: float = 0.5             # [m/s]
    frozen_min_mps: float = 1.0            # only readings above this [m/s]: a standing wheel reads 0 forever
    # accelerometer bias: first-order filter (time constant bias_tau_s) of accelerometer − d(r·ω)/dt,
    # updated on fresh wheel frames while the wheel is not sliding (below); above bias_limit_mps2 for
    # longer than bias_hold_s it is a fault.  The limit must lie above STEEPEST_GRADIENT_MPS2
    # (0.588 m/s²), which the accelerometer legitimately reads on the steepest gradient a scenario
    # allows.  What a slide leaves in the filter (the slip that built up before the gate below closed,
    # Δslip/τ) was at most 0.29 m/s² in the wet section of default (seeds 1–3) and 0.04 m/s² in the
    # rg_* runs: on a gradient near 60 ‰ combined with such slides the limit can be reached (chosen;
    # a longer τ lowers that transient but slows detection: a 0.8 m/s² bias needs τ·ln 8 + hold)
    bias_tau_s: float = 1.5                # [s]
    bias_limit_mps2: float = 0.7           # [m/s²]
    bias_hold_s: float = 0.5               # [s]
    # "not sliding": estimated slip below slide_gate_mps, WSP in FILL and the axle's acceleration within
    # what the car can do (car_accel_max_mps2, below); a slide is bridged (one update over the whole
    # span once the wheel is back, so the slip's rise and fall cancel), but a span is closed after
    # span_max_s whatever the slip (a biased accelerometer inflates the estimated slip)
    slide_gate_mps: float = 0.1            # [m/s] (chosen: a third of the WSP's lowest vent threshold)
    span_max_s: float = 1.0                # [s] (chosen)
    # the axle-derived acceleration that replaces a failed accelerometer: d(r·ω)/dt through a first-order
    # filter, bounded to what the car itself can do (a sliding wheel decelerates far faster), so that a
    # slide still shows as slip against the reference speed (chosen: 0.25 g, seed 001's r⁰)
    axle_accel_tau_s: float = 0.1          # [s]
    car_accel_max_mps2: float = 2.5        # [m/s²]

    def __post_init__(self) -> None:
        if not self.bias_limit_mps2 > STEEPEST_GRADIENT_MPS2:
            raise ValueError(f"SensorCheckParams: bias_limit_mps2 {self.bias_limit_mps2} must be above "
                             f"{STEEPEST_GRADIENT_MPS2:.3f} m/s², the steepest gradient's g·sin θ")


class SpeedCheck(NamedTuple):
    """State of the wheel-speed sensor check (`speed_sensor_check`)."""

    fault: bool = False
    cause: str = ""              # "stands" | "frozen" once latched
    stand_s: float = 0.0         # time the reading has said "stands" while the car moves [s]
    frozen_s: float = 0.0        # time the reading has been frozen (≥ frozen_min_mps) [s]
    frozen_dv_mps: float = 0.0   # bias-corrected accelerometer integrated over the frozen span [m/s]


def speed_sensor_check(s: SpeedCheck, wheel_mps: float, prev_wheel_mps: float, v_ref_mps: float,
                       accel_mps2: float, span_s: float, p: SensorCheckParams) -> SpeedCheck:
    """The wheel-speed sensor check on one fresh reading (pure; latched once it fails).  Call it per
    new sensor frame only: a stale frame (none arrived this cycle) is not a frozen sensor.

    wheel_mps: r·ω of the reading; prev_wheel_mps: the previous reading; v_ref_mps: the car's speed
    estimate (from the accelerometer while the wheel disagrees); accel_mps2: accelerometer minus its
    bias estimate, over the span; span_s: time since the previous reading [s]."""
    if s.fault:
        return s
    stand_s = s.stand_s + span_s if (wheel_mps < p.stand_mps and v_ref_mps > p.moving_mps) else 0.0
    if wheel_mps == prev_wheel_mps and wheel_mps >= p.frozen_min_mps:
        frozen_s, dv = s.frozen_s + span_s, s.frozen_dv_mps + accel_mps2 * span_s
    else:
        frozen_s, dv = 0.0, 0.0
    if stand_s > p.lock_s:
        return SpeedCheck(True, "stands", stand_s, frozen_s, dv)
    if abs(dv) > p.frozen_dv_mps:
        return SpeedCheck(True, "frozen", stand_s, frozen_s, dv)
    return SpeedCheck(False, "", stand_s, frozen_s, dv)


class AccelCheck(NamedTuple):
    """State of the accelerometer bias check (`accel_bias_check`)."""

    fault: bool = False
    bias_mps2: float = 0.0       # filtered accelerometer − d(r·ω)/dt [m/s²] (AccelBiasEst)
    above_s: float = 0.0         # time |bias| has been above the limit [s]


def accel_bias_check(s: AccelCheck, accel_mean_mps2: float, wheel_accel_mps2: float, span_s: float,
                     p: SensorCheckParams) -> AccelCheck:
    """One update of the accelerometer bias check over `span_s` seconds since the last update (pure;
    latched once it fails).

    accel_mean_mps2: the accelerometer's mean over the span; wheel_accel_mps2: the wheel's speed
    change over the span divided by it.  Their difference is the bias plus g·sin θ plus the slip's
    rate of change, which averages out over a slide."""
    if s.fault or span_s <= 0.0:
        return s
    gain = min(span_s / p.bias_tau_s, 1.0)
    bias = s.bias_mps2 + gain * (accel_mean_mps2 - wheel_accel_mps2 - s.bias_mps2)
    above_s = s.above_s + span_s if abs(bias) > p.bias_limit_mps2 else 0.0
    return AccelCheck(above_s > p.bias_hold_s, bias, above_s)


@dataclass(frozen=True)
class BecuParams:
    cycle_us: int = 10_000                   # BECU cycle, DESIGN.md node table
    car_mass_kg: float = 40_000.0            # nominal car mass (load-weighed in service), chosen
    wheel_radius_m: float = 0.46             # nominal wheel radius
    brake_gain_Nm_per_Pa: float = 0.08       # squeeze-line slope alpha-bar, seed 001 eq. (6), brake data
    brake_preload_Pa: float = 30e3           # squeeze line offset -beta-bar/alpha-bar (return spring)
    p_max_Pa: float = 450e3                  # p-bar, seed 001 eq. (5)
    # EP valve flow 1 MPa/s at full opening: kp = 1/(Tp*rate) gives seed 001's Tp = 50 ms (eq. 4, §IV)
    pressure_pi: PIParams = field(default_factory=lambda: PIParams(
        kp=2.0e-5, ki=4.0e-5, out_min=-1.0, out_max=1.0))
    wsp: WspParams = field(default_factory=WspParams)
    wheel_trust_slip_mps: float = 0.2        # speed estimator: below this apparent slip, trust the axle
    wheel_trust_gain: float = 0.2            # complementary-filter gain towards the axle speed
    emergency_decel_mps2: float = 1.3        # used when BCU_EMERGENCY is active and the demand lags
    # railway fail-safe, issue #9: a demand missing or unusable (E2E/SecOC) for this many cycles is
    # loss of command, and loss of command is braking at the emergency deceleration
    failsafe_cycles: int = 3
    # "pressure": feed-forward set-point from the demand (inverse brake model) + the pressure PI (v1).
    # "decel": seed 001's eq. (16), a PI on the deceleration error measured by the accelerometer whose
    # output is the cylinder pressure set-point u (CylPressureSet); the pressure PI still drives the EP
    # valve for plants without an integrated pressure controller.
    control: str = "pressure"
    # eq. (16) gains, issue #4's set: K_P = 5 bar/g, K_I = 40 bar/(g s), in Pa per m/s² (1 bar = 1e5 Pa,
    # g = 9.81 m/s²); output bounded to 0 ≤ u ≤ p̄, eq. (5b)
    decel_pi: PIParams = field(default_factory=lambda: PIParams(
        kp=5e5 / 9.81, ki=40e5 / 9.81, out_min=0.0, out_max=450e3))
    governor: GovernorParams | None = None   # reference governor of seed 001 eq. (9), decel mode only
    # decel mode, leaving WSP: "freeze" resumes the PI where WSP froze it (the project's convention);
    # "handover" restarts it bumplessly from the vented set-point u = 0
    wsp_resume: str = "freeze"
    pressure_observer_gain: float = 0.1     # governor's cylinder observer: correction per cycle (chosen)
    sensors: SensorCheckParams = field(default_factory=SensorCheckParams)   # plausibility, issue #9
    # output gate on the BCU's pressure correction φ (seed 004 eq. (34)): the authority the BCU has over
    # this car's service-brake pressure, -38 %/+67 % (chosen; the BCU's own limits are the same)
    phi_limits: tuple[float, float] = (0.6, 1.6)

    def __post_init__(self) -> None:
        if self.control not in ("pressure", "decel"):
            raise ValueError(f"BecuParams: control must be 'pressure' or 'decel', got {self.control!r}")
        if self.wsp_resume not in ("freeze", "handover"):
            raise ValueError(f"BecuParams: wsp_resume must be 'freeze' or 'handover', "
                             f"got {self.wsp_resume!r}")
        if self.governor is not None and self.control != "decel":
            raise ValueError("BecuParams: the reference governor needs control = 'decel'")


class Becu:
    """One car's brake ECU: step(now_us, rx) -> dict of output signals."""

    INPUTS = ("AxleSpeed", "CylPressure", "AccelLong", "TargetDecel", "BCU_DEMAND.Mode", "EmergencyActive",
              "FrictionPhi")
    OUTPUTS = ("CylPressureSet", "ValveCmd", "WspValve", "SpeedEst", "SlipSpeedEst", "WspActive",
               "GovernorActive", "IntegratorSat", "InputMissing", "OptSlipEst", "OptSlipPos",
               "GovernedDecel", "GovernorMargin", "GovernorFeasible", "SpeedSensorFault", "AccelSensorFault",
               "AccelBiasEst")

    def __init__(self, params: BecuParams | None = None) -> None:
        self.p = params or BecuParams()
        self.pressure_pi = PI(self.p.pressure_pi)
        self.decel_pi = PI(self.p.decel_pi)
        self._vented = False          # WSP overrode the decel PI last cycle
        self.u_sent = 0.0             # decel mode: the set-point sent last cycle [Pa]
        self.p_hat = 0.0              # decel mode: observed cylinder pressure [Pa]
        self.torque_est = 0.0         # brake torque: the governor's play model run on the measured pressure
        self.r_gov: float | None = None              # last governed reference [m/s²]
        self.decision: GovernorDecision | None = None   # last governor decision (diagnostic)
        self.wsp = Wsp.FILL
        self.v_ref = math.nan
        self.timer = CycleTimer(self.p.cycle_us)
        self.missing_inputs = 0       # cycles with a missing or non-finite input (diagnostic)
        self.failsafe_cycles = 0      # cycles braked by the fail-safe (diagnostic)
        # sensor plausibility (issue #9)
        self.speed_check = SpeedCheck()
        self.accel_check = AccelCheck()
        self.speed_fault_us: int | None = None     # when SpeedSensorFault latched (diagnostic)
        self.accel_fault_us: int | None = None     # when AccelSensorFault latched (diagnostic)
        self._wheel_prev = math.nan   # previous fresh wheel reading r·ω [m/s]
        self._rx_us: int | None = None   # reception time of the sensor frame used last cycle
        self._axle_accel = 0.0        # d(r·ω)/dt, filtered [m/s²]
        self._anchor_wheel = math.nan  # bias filter: wheel reading at its last update [m/s] ...
        self._accel_sum = 0.0         # ... the accelerometer integrated since [m/s] ...
        self._span_s = 0.0            # ... over this time [s]
        self.vent_s = 0.0             # WSP: time out of FILL without a break [s]
        self.wsp_tripped = False      # WSP: the vent-time watchdog holds the cylinder in FILL
        self.wsp_watchdog_trips = 0   # times the watchdog refilled a cylinder (diagnostic)

    def pressure_for_decel(self, decel_mps2: float) -> float:
        """Set-point that gives `decel` on the squeeze line: F = m a, tau = F r, p = tau/alpha + preload."""
        if decel_mps2 <= 0.0:
            return 0.0
        torque = self.p.car_mass_kg * decel_mps2 * self.p.wheel_radius_m
        return clip(torque / self.p.brake_gain_Nm_per_Pa + self.p.brake_preload_Pa, 0.0, self.p.p_max_Pa)

    def apply_phi(self, p_set_Pa: float, phi: float) -> float:
        """Seed 004 eq. (34): P_c = P_c0/φ on the force part of the set-point (above the return-spring
        preload, where the torque is proportional to the pressure, eq. (24)); φ gated to `phi_limits`."""
        pre = self.p.brake_preload_Pa
        if phi == 1.0 or p_set_Pa <= pre:
            return p_set_Pa
        lo, hi = self.p.phi_limits
        return clip(pre + (p_set_Pa - pre) / clip(phi, lo, hi), 0.0, self.p.p_max_Pa)

    def estimate_speed(self, wheel_v: float, accel: float, dt_s: float) -> float:
        """Reference speed: integrate the accelerometer, pulled to the axle while it is not slipping."""
        if not math.isfinite(self.v_ref):
            return wheel_v
        v_pred = self.v_ref + accel * dt_s
        if wheel_v >= v_pred:
            return wheel_v
        if v_pred - wheel_v < self.p.wheel_trust_slip_mps:
            return v_pred + self.p.wheel_trust_gain * (wheel_v - v_pred)
        return max(v_pred, 0.0)

    def decel_control(self, r0: float, decel: float, pressure: float, dt_s: float,
                      overridden: bool) -> tuple[float, bool]:
        """Seed 001's loop: governor (eq. 9) -> PI on the deceleration error (eq. 16) -> set-point u.

        r0: requested deceleration [m/s²]; decel: measured deceleration (−AccelLong) [m/s²]; pressure:
        measured cylinder pressure [Pa]. Returns (u [Pa], governor active). While WSP overrides
        (`overridden`), the PI is frozen and u = 0 (vent, seed 001 §II-C).
        """
        p = self.p
        r = r0
        governed = False
        gp = p.governor
        if gp is not None:
            # cylinder observer: the lag of eq. (4) run on the set-point this BECU sent, corrected towards
            # the measured pressure; the torque estimate is the play model (10a) on the observed pressure
            # (on the raw measurement, sensor noise would ratchet the estimated torque up)
            p_hat = self.u_sent + (self.p_hat - self.u_sent) * gp.phi
            self.p_hat = p_hat + p.pressure_observer_gain * (pressure - p_hat)
            self.torque_est = play(self.torque_est, self.p_hat, gp)
            x = GovernorState(self.decel_pi.i, self.p_hat, self.torque_est, gp.mass_kg * decel)
            self.decision = govern(x, r0, gp, self.r_gov)
            r = self.r_gov = self.decision.r_mps2
            governed = self.decision.active
        if self._vented and not overridden and p.wsp_resume == "handover":
            # back from WSP: bumpless hand-over from the applied u = 0 (simple-pid's set_auto_mode), so
            # tracking restarts from the vented cylinder as in seed 001 §IV-A rather than from the
            # pre-slide set-point that just made the wheel slide
            self.decel_pi.handover(0.0, error=r - decel)
        self._vented = overridden
        u = self.decel_pi.update(r - decel, dt_s, freeze=overridden)  # eq. (16), e = r − v̇
        self.u_sent = 0.0 if overridden else u
        return self.u_sent, governed

    def demand_lost(self, now_us: int, rx: Mapping[str, float]) -> bool:
        """Loss of command: no usable brake demand for more than `failsafe_cycles` cycles.  Frames the
        E2E or SecOC check rejects never update the demand (hil.runtime.node), so a corrupt, forged, stale or
        missing demand all age it.  Needs the reception times of the node runtime's RxTable; a plain
        mapping (unit tests) never loses its command; neither does a BECU that never had one."""
        age_us = getattr(rx, "age_us", None)
        age = age_us("TargetDecel", now_us) if age_us is not None else None
        return age is not None and age > self.p.failsafe_cycles * self.p.cycle_us

    def _fresh_sensor_frame(self, now_us: int, rx: Mapping[str, float], dt_s: float) -> tuple[bool, float]:
        """(a sensor frame arrived since the last cycle, time since the previous one [s]).  A plain
        mapping (unit tests) has no reception times: every cycle is a fresh frame, `dt_s` apart."""
        age_us = getattr(rx, "age_us", None)
        if age_us is None:
            return True, dt_s
        age = age_us("AxleSpeed", now_us)
        if age is None:
            return False, dt_s
        t_rx = now_us - age
        last, self._rx_us = self._rx_us, t_rx
        if last is None:
            return True, dt_s
        return t_rx != last, (t_rx - last) * 1e-6

    def _check_sensors(self, now_us: int, wheel_v: float, accel: float, span_s: float) -> None:
        """Plausibility of the wheel-speed sensor and the accelerometer on a fresh sensor frame (after the
        speed estimate of this cycle, before WSP)."""
        sc = self.p.sensors
        prev = self._wheel_prev
        self._wheel_prev = wheel_v
        if not math.isfinite(prev) or span_s <= 0.0:
            self._anchor_wheel = wheel_v
            return
        gain = min(span_s / sc.axle_accel_tau_s, 1.0)
        self._axle_accel += gain * ((wheel_v - prev) / span_s - self._axle_accel)
        ac = self.accel_check
        before = self.speed_check
        corrected = accel - ac.bias_mps2 if not ac.fault else clip(self._axle_accel, -sc.car_accel_max_mps2,
                                                                     sc.car_accel_max_mps2)
        check = speed_sensor_check(before, wheel_v, prev, self.v_ref, corrected, span_s, sc)
        self.speed_check = check
        if check.fault:
            if not before.fault:
                self.speed_fault_us = now_us
                if check.cause == "frozen":          # the speed the frozen reading would have reached
                    self.v_ref = max(wheel_v + check.frozen_dv_mps, 0.0)
                self.wsp = Wsp.FILL
            return                                   # no axle to compare the accelerometer with
        self._accel_sum += accel * span_s
        self._span_s += span_s
        if check.stand_s > 0.0 or check.frozen_s > 0.0:
            return                                   # the wheel is not trusted yet: wait for the span's end
        sliding = (self.v_ref - wheel_v > sc.slide_gate_mps or self.wsp != Wsp.FILL
                   or abs(self._axle_accel) > sc.car_accel_max_mps2)   # the wheel does what the car cannot
        if sliding and self._span_s < sc.span_max_s:
            return                                   # bridge the slide: update once the wheel is back
        span = self._span_s
        wheel_rate = (wheel_v - self._anchor_wheel) / span
        if not (sliding and abs(wheel_rate) > sc.car_accel_max_mps2):   # a slide still on: no evidence
            self.accel_check = accel_bias_check(ac, self._accel_sum / span, wheel_rate, span, sc)
        self._anchor_wheel, self._accel_sum, self._span_s = wheel_v, 0.0, 0.0
        if self.accel_check.fault and not ac.fault:
            self.accel_fault_us = now_us
            self.v_ref = wheel_v                     # drop what the biased accelerometer integrated

    def step(self, now_us: int, rx: Mapping[str, float]) -> dict[str, float]:
        p = self.p
        dt_s = self.timer.dt_s(now_us)
        omega, ok1 = finite_or(rx["AxleSpeed"], 0.0)
        pressure, ok2 = finite_or(rx["CylPressure"], 0.0)
        accel, ok3 = finite_or(rx["AccelLong"], 0.0)
        decel, ok4 = finite_or(rx["TargetDecel"], 0.0)
        emergency, ok5 = finite_or(rx["EmergencyActive"], 0.0)
        missing = not (ok1 and ok2 and ok3 and ok4 and ok5)
        self.missing_inputs += missing
        if emergency >= 0.5:
            decel = max(decel, p.emergency_decel_mps2)
        lost = self.demand_lost(now_us, rx)
        if lost:                                                      # fail-safe: loss of command brakes
            decel = max(decel, p.emergency_decel_mps2)
            self.failsafe_cycles += 1

        wheel_v = omega * p.wheel_radius_m
        sc = p.sensors
        # the car's acceleration: the accelerometer, or the axle's (bounded) once the accelerometer failed
        accel_used = accel if not self.accel_check.fault else clip(
            self._axle_accel, -sc.car_accel_max_mps2, sc.car_accel_max_mps2)
        if self.speed_check.fault:                   # no wheel: the accelerometer alone, bias-corrected
            self.v_ref = max(self.v_ref + (accel - self.accel_check.bias_mps2) * dt_s, 0.0)
        else:
            self.v_ref = self.estimate_speed(wheel_v, accel_used, dt_s)
        fresh, span_s = self._fresh_sensor_frame(now_us, rx, dt_s)
        if fresh and ok1 and ok3:
            self._check_sensors(now_us, wheel_v, accel, span_s)
        speed_fault = self.speed_check.fault
        slip = 0.0 if speed_fault else self.v_ref - wheel_v          # eq. (2), seed 001
        if speed_fault:
            self.wsp = Wsp.FILL                      # WSP inhibited: a failed sensor never vents the brake
        else:
            wanted = wsp_transition(self.wsp, slip, self.v_ref, p.wsp)
            self.vent_s, tripped = vent_watchdog(self.vent_s, self.wsp_tripped, wanted != Wsp.FILL,
                                                 wanted == Wsp.FILL, dt_s, p.wsp.max_vent_s)
            self.wsp_watchdog_trips += tripped and not self.wsp_tripped
            self.wsp_tripped = tripped
            self.wsp = Wsp.FILL if tripped else wanted

        overridden = self.wsp != Wsp.FILL
        governed = False
        if p.control == "decel":
            p_set, governed = self.decel_control(decel, -accel_used, pressure, dt_s, overridden)
        else:
            p_set = self.pressure_for_decel(decel)
            phi, phi_ok = finite_or(rx.get("FrictionPhi", 1.0), 1.0)
            if phi_ok and emergency < 0.5 and not lost:                  # seed 004 §5: not for emergency
                p_set = self.apply_phi(p_set, phi)
        valve = self.pressure_pi.update(p_set - pressure, dt_s, freeze=overridden)
        if overridden:
            valve = 0.0                                               # the dump valve acts, EP valve holds
        return {
            "CylPressureSet": p_set,
            "ValveCmd": valve,
            "WspValve": int(self.wsp),
            "SpeedEst": max(self.v_ref, 0.0),
            "SlipSpeedEst": slip,
            "WspActive": int(overridden),
            "GovernorActive": int(governed),
            "IntegratorSat": int(self.pressure_pi.saturated or self.pressure_pi.frozen or (
                p.control == "decel" and (self.decel_pi.saturated or self.decel_pi.frozen))),
            "InputMissing": int(missing or lost),
            "OptSlipEst": 0.0,
            "OptSlipPos": 0.0,
            "GovernedDecel": self.r_gov if (self.r_gov is not None and governed) else decel,
            "GovernorMargin": clip(self.decision.margin_Nm, -65536.0, 65534.0) if self.decision else 0.0,
            "GovernorFeasible": int(self.decision.feasible) if self.decision else 1,
            "SpeedSensorFault": int(speed_fault),
            "AccelSensorFault": int(self.accel_check.fault),
            "AccelBiasEst": clip(self.accel_check.bias_mps2, -4.096, 4.094),   # the DBC signal's range
        }
