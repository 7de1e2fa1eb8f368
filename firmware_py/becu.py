"""Brake ECU of one car (BECU), v1.

Chain: train deceleration demand (BCU_DEMAND.TargetDecel) -> brake-cylinder pressure set-point
(inverse of the brake model: force -> torque -> pressure on the squeeze line of seed 001 eq. (6))
-> PI pressure control of the EP valve (the shared PI primitive), with a basic wheel-slide protection
(WSP) that vents above a slip threshold and refills with hysteresis.  With the EP valve's flow this
loop behaves as seed 001's first-order cylinder (eq. 4).

Inputs (DBC signal names, bound by hil): AxleSpeed, CylPressure, AccelLong (the car's sensors),
TargetDecel and Mode (BCU_DEMAND), EmergencyActive (BCU_EMERGENCY).
Outputs: the pressure command frame (CylPressureSet, ValveCmd, WspValve) and the status frame.

With BecuParams.control = "decel" the set-point comes from seed 001's deceleration PI (eq. 16) instead,
optionally behind the reference governor (eq. 9, firmware_py.governor), which sets GovernorActive.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntEnum

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

    INPUTS = ("AxleSpeed", "CylPressure", "AccelLong", "TargetDecel", "Mode", "EmergencyActive")
    OUTPUTS = ("CylPressureSet", "ValveCmd", "WspValve", "SpeedEst", "SlipSpeedEst", "WspActive",
               "GovernorActive", "IntegratorSat", "InputMissing", "OptSlipEst", "OptSlipPos",
               "GovernedDecel", "GovernorMargin", "GovernorFeasible")

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

    def pressure_for_decel(self, decel_mps2: float) -> float:
        """Set-point that gives `decel` on the squeeze line: F = m a, tau = F r, p = tau/alpha + preload."""
        if decel_mps2 <= 0.0:
            return 0.0
        torque = self.p.car_mass_kg * decel_mps2 * self.p.wheel_radius_m
        return clip(torque / self.p.brake_gain_Nm_per_Pa + self.p.brake_preload_Pa, 0.0, self.p.p_max_Pa)

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
        E2E or SecOC check rejects never update the demand (hil.node), so a corrupt, forged, stale or
        missing demand all age it.  Needs the reception times of the node runtime's RxTable; a plain
        mapping (unit tests) never loses its command; neither does a BECU that never had one."""
        age_us = getattr(rx, "age_us", None)
        age = age_us("TargetDecel", now_us) if age_us is not None else None
        return age is not None and age > self.p.failsafe_cycles * self.p.cycle_us

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
        self.v_ref = self.estimate_speed(wheel_v, accel, dt_s)
        slip = self.v_ref - wheel_v                                   # eq. (2), seed 001
        self.wsp = wsp_transition(self.wsp, slip, self.v_ref, p.wsp)

        overridden = self.wsp != Wsp.FILL
        governed = False
        if p.control == "decel":
            p_set, governed = self.decel_control(decel, -accel, pressure, dt_s, overridden)
        else:
            p_set = self.pressure_for_decel(decel)
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
        }
