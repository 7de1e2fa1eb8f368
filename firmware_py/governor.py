"""Reference governor for wheel-slip prevention (seed 001, eq. 9): pure, no I/O, no clock.

Each BECU cycle `govern(state, r0, params, r_prev)` returns the constant deceleration reference r closest
to the request r⁰ (eq. 9a) such that the closed loop -- deceleration PI (eq. 16), cylinder lag (eq. 4),
bounds (eq. 5), brake hysteresis (eq. 10a) and the uncertain slip dynamics (eqs. 3, 10b) -- keeps the
slip speed s ≤ s̄ (eq. 8) for all future time with r held constant (eq. 9b, 14).

Model (the one the BECU runs; one control step Δ, index k; decelerations positive when braking):
    e_k   = r − (F_k + R) / M                             error of eq. (16), F = friction force [N],
                                                          R = running resistance, held (0 in seed 001)
    u_k   = PI(e_k)  (firmware_py.pi.pi_step, clip to [0, p̄])            eq. (16), (5b)
    p_k+1 = u_k + (p_k − u_k) φ,  φ = exp(−Δ/Tp)                          eq. (4) with Tp, §IV; (5a)
    τ_k+1 = play(τ_k, p_k+1)                                              eq. (10a)
    F_k+1 = a_k F_k + (1 − a_k) κ τ_k+1,   a_k ∈ [a̲, ā]  (any sequence)   slip dynamics, see below

Why this form of the slip inclusion. Eq. (3) is ṡ = −k f(s) + (r_w/J) τ with k = 1/M + r_w²/J. Along a
trajectory the friction force F = f(s) obeys Ḟ = f'(s) ṡ = k f'(s) (κ τ − F) with κ = r_w / (J k): F is a
first-order lag of κ τ whose rate γ = k f'(s) is unknown and time-varying. For every adhesion curve in the
family considered (monotone on [0, s̄] with slope f' ∈ [f'_lo, f'_hi]) γ ∈ [γ̲, γ̄], so over one step of
constant torque F_k+1 = a F_k + (1 − a) κ τ with a = exp(−γΔ) ∈ [a̲, ā]: a polytopic inclusion with one
scheduling parameter ξ ∈ [0, 1], a = ξ a̲ + (1 − ξ) ā, switching arbitrarily (seed 001's eq. (10b) bounds
s instead of F; in F the inclusion needs no jumps of F at constant s, which no fixed curve can make).

Safety argument (what is proved):
  (1) Torque ceiling. Let F̄ = f(s̄) (for an uncertain curve, its lower bound over the family, the lower edge
      of the cone of seed 001 Fig. 5 at s̄) and τ̄ = F̄ / κ. F_k+1 is a convex combination of F_k and κ τ_k+1
      for every a ∈ [0, 1], so F_k ≤ F̄ and τ ≤ τ̄ at all future steps give F ≤ F̄ forever, whatever the
      sequence a_k. Since f is increasing on [0, s̄], F ≤ F̄ ⇔ s ≤ s̄ (eq. 8). The continuous-time version
      holds too (Ḟ ≤ 0 whenever F = F̄ ≥ κ τ), so s ≤ s̄ also between samples.
  (2) The torque only rises on the squeeze line (play operator, eq. 10a), so τ ≤ τ̄ is a condition on the
      pressure trajectory, which is what the prediction below checks, with no reference to s at all.
  (3) 0 ≤ u, p ≤ p̄ (eq. 5) hold by construction (the PI's output clip and the lag's convex combination).
  (4) The only uncertain input of the prediction is F in the error e. For a FIXED torque history the
      recursion F_k+1 = a F_k + (1 − a) κ τ_k+1 is increasing in F_k, so the pointwise-lowest friction force
      over all admissible sequences is obtained greedily: a_k = ā when F_k < κ τ_k+1 (rising torque: the
      slowest lag) and a_k = a̲ otherwise. The lowest F gives the largest error e = r − F/M, hence the
      largest PI output at that step. The governor predicts the closed loop with this decel-minimising
      adversary -- a sequence of the inclusion's vertices, chosen per step -- (optionally cross-checked
      with a held at either vertex, GovernorParams.vertices) and accepts r only if the predicted
      trajectory keeps τ ≤ τ̄ (1 − margin) over the horizon and ends settled at a steady state that is
      itself admissible (M r − R ≤ κ τ̄ (1 − margin), the steady-state torque of a constant r being
      (M r − R) / κ whatever the curve; R the running resistance, GovernorState.resistance_N). That this
      pointwise worst case is also the closed-loop worst case is NOT
      proved (the feedback through τ and F is negative, so the loop is not a monotone system and a
      pointwise bound is not a trajectory bound); it is tested by tests/firmware/test_governor.py over sampled
      states and adversarial sequences switching a every step (random, alternating, blocks, interior
      values), which also pass with margin 0. Likewise the tail after "settled" (|F − M r| and |u − p|
      within settle_frac) is covered by the settle tolerance on the steady state, not by a proof.
What is assumed: the adhesion curve lies in the family (F̄ and the slope bounds are right; for an
uncertain curve F̄ is the smallest f(s̄) of the family, then F ≤ F̄ still gives s ≤ s̄), the BECU's state
estimate is close to the truth (integrator: exact; pressure: an observer running eq. (4) on the sent
set-point, corrected by the measurement; torque: the play model on that pressure; F: M times the
measured deceleration), and no other force on the wheelset (grade, coupler push) raises the slip. The
margin (a fraction of τ̄) covers sensor noise, the CAN delay and the plant's 1 ms integrator against this
10 ms model; it is a tuning value, not a bound.

Search (`govern`): r⁰ is tried first; then the previous reference (admissible again if the model is
exact, the set being positively invariant), then the largest β ∈ [0, 1] with r_prev + β (r⁰ − r_prev)
admissible, by bisection -- the admissible references are taken to be an interval [0, r_max(x)] (a larger
constant reference only raises the PI's drive), an assumption the bisection relies on, not a theorem.
There is no offline set computation: R(x) of eq. (14) is evaluated online by prediction.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Any, ClassVar

from firmware_py.becu import Loop
from firmware_py.governor_kernel import play_scalar, predict_loop, warm_up
from firmware_py.limits import clip
from firmware_py.pi import PIParams
from firmware_py.rx import RxTable


@dataclass(frozen=True)
class GovernorParams:
    """The closed-loop model and the constraint, every constant in SI units (see the module docstring)."""

    dt_s: float                 # Δ, the BECU cycle [s]
    mass_kg: float              # M, the mass braked by this wheelset/brake [kg]
    kappa: float                # κ = r_w / (J k), steady friction force per brake torque [N / (N m)]
    friction_max_N: float       # F̄ = f(s̄), friction force at the slip limit s̄ (eq. 8) [N]
    a_lo: float                 # a̲ = exp(−γ̄ Δ): fastest friction lag over one step [-]
    a_hi: float                 # ā = exp(−γ̲ Δ): slowest friction lag over one step [-]
    phi: float                  # φ = exp(−Δ/Tp), cylinder lag over one step, eq. (4) [-]
    alpha_squeeze: float        # ᾱ [N m / Pa], squeeze line τ = ᾱ p + β̄, eq. (6)
    beta_squeeze: float         # β̄ [N m]
    alpha_release: float        # α̲ [N m / Pa], release line τ = α̲ p + β̲, eq. (6)
    beta_release: float         # β̲ [N m]
    pi: PIParams                # the deceleration PI of eq. (16): error [m/s²] -> set-point [Pa]
    margin_frac: float = 0.005  # torque kept below τ̄ as a fraction of τ̄ (model mismatch, noise) [-]
    horizon_steps: int = 600    # prediction horizon N (6 s at 10 ms) [steps]
    settle_frac: float = 0.002  # settled: |F − M r| and |u − p| below this fraction of F̄ and of p̄ [-]
    bisect_steps: int = 7       # bisection iterations: at most 1/128 of the interval searched ...
    resolution_mps2: float = 0.002  # ... and no finer than this (0.0002 g) [m/s²]
    # friction schedules predicted for each candidate (predict_peak_torque's `vertex`): the
    # decel-minimising adversary, optionally cross-checked with a held at either vertex
    vertices: tuple[str, ...] = ("adversary",)

    def __post_init__(self) -> None:
        for name in ("dt_s", "mass_kg", "kappa", "friction_max_N", "alpha_squeeze", "alpha_release"):
            val = getattr(self, name)
            if not (math.isfinite(val) and val > 0.0):
                raise ValueError(f"GovernorParams: {name} must be > 0, got {val!r}")
        if not (0.0 <= self.a_lo <= self.a_hi < 1.0):
            raise ValueError(f"GovernorParams: need 0 <= a_lo <= a_hi < 1, got {self.a_lo!r}, {self.a_hi!r}")
        if not (0.0 <= self.phi < 1.0) or not (0.0 <= self.margin_frac < 1.0):
            raise ValueError(f"GovernorParams: need 0 <= phi < 1 and 0 <= margin_frac < 1, got "
                             f"{self.phi!r}, {self.margin_frac!r}")

    @property
    def torque_max_Nm(self) -> float:
        """τ̄ = F̄ / κ: the torque ceiling of step (1) [N m]."""
        return self.friction_max_N / self.kappa

    @property
    def torque_limit_Nm(self) -> float:
        """τ̄ (1 − margin): the ceiling the prediction enforces [N m]."""
        return self.torque_max_Nm * (1.0 - self.margin_frac)

    @property
    def decel_max_mps2(self) -> float:
        """Largest constant reference admissible in steady state: κ τ̄ (1 − margin) / M [m/s²]."""
        return self.kappa * self.torque_limit_Nm / self.mass_kg


@dataclass(frozen=True)
class GovernorSchedule:
    """The governor's model scheduled on the car's speed (gain scheduling): where the adhesion curve moves
    with the speed (seed 000 eq. (1)-(2): the peak slip speed σ°(v)·v and the peak μ°(v) both change with v),
    one GovernorParams per speed band, each built for the whole band (its F̄ the smaller and its slope
    bounds the wider of the band's edges).  The proof of the module docstring holds within a band; the
    switch between bands is not covered by it (the bands are narrow, and F̄ changes little across one)."""

    speeds_mps: tuple[float, ...]           # lower edge of each band, increasing, the first 0 [m/s]
    params: tuple[GovernorParams, ...]      # the model of each band

    def __post_init__(self) -> None:
        if len(self.speeds_mps) != len(self.params) or not self.params:
            raise ValueError("GovernorSchedule: one GovernorParams per speed band, at least one")
        edges = self.speeds_mps
        if edges[0] != 0.0 or any(b <= a for a, b in zip(edges, edges[1:], strict=False)):
            raise ValueError(f"GovernorSchedule: band edges must start at 0 and increase, got "
                             f"{self.speeds_mps[:3]}...")

    def at(self, v_mps: float) -> GovernorParams:
        """The model of the band holding v (below 0 or not finite: the lowest band; above the last edge:
        the last band)."""
        if not v_mps > 0.0:
            return self.params[0]
        return self.params[bisect.bisect_right(self.speeds_mps, v_mps) - 1]


@dataclass(frozen=True)
class GovernorState:
    """The closed loop's state at the start of a cycle (x of eq. 11, in this module's coordinates)."""

    integrator_Pa: float        # the deceleration PI's integrator i [Pa]
    pressure_Pa: float          # cylinder pressure p [Pa]
    torque_Nm: float            # brake torque τ [N m] (the play model run on the measured pressure)
    friction_N: float           # friction force F = M · deceleration − R [N]
    # R: the car's running resistance at its speed (Davis, eq. (4) seed 003), held over the horizon [N]; seed
    # 001's eq. (1a) has none (0): M v̇ = −F − R, so the PI's error is r − (F + R)/M
    resistance_N: float = 0.0

    def reference_top_mps2(self, gp: GovernorParams) -> float:
        """Largest constant reference whose steady state is admissible with room for the settling tolerance:
        (κ τ̄ (1 − margin) / (1 + settle_frac) + R) / M [m/s²] (the friction it needs, M r − R, within the
        ceiling)."""
        return gp.decel_max_mps2 / (1.0 + gp.settle_frac) + self.resistance_N / gp.mass_kg


@dataclass(frozen=True)
class GovernorDecision:
    r_mps2: float               # the governed reference r (eq. 9) [m/s²]
    active: bool                # r < r⁰: the governor limits the demand
    margin_Nm: float            # τ̄ − (largest predicted torque under r) [N m]
    evaluations: int            # predictions run this cycle
    feasible: bool = True       # r ∈ R(x); False: not even r = 0 is admissible (x outside the set)


def play(tau_prev: float, p: float, gp: GovernorParams) -> float:
    """Brake torque after the pressure moved to p: eq. (10a) as a play operator (cf. plant_sim.brake,
    which the firmware cannot import: the ECU carries its own model of the brake), clipped at 0
    (firmware_py.governor_kernel.play_scalar, which the compiled prediction runs)."""
    return play_scalar(tau_prev, p, gp.alpha_squeeze, gp.beta_squeeze, gp.alpha_release, gp.beta_release)


#: predict_peak_torque's friction schedules, as the compiled loop takes them
VERTEX_CODES = {"adversary": 0, "slow": 1, "fast": 2}


def predict_peak_torque(x: GovernorState, r: float, gp: GovernorParams, vertex: str = "adversary",
                        stop_above: float = math.inf) -> tuple[float, bool]:
    """Simulate the model with r held constant; (largest torque over the horizon, settled at the end).

    vertex: "adversary" (a_k chosen each step to minimise F, step (4) of the module docstring), "slow"
    (a = ā throughout) or "fast" (a = a̲ throughout). The simulation stops early once the torque exceeds
    `stop_above` (the candidate is rejected anyway) or once the loop has settled.  The loop runs compiled
    (firmware_py.governor_kernel.predict_loop, numba; NUMBA_DISABLE_JIT=1 runs it as Python, to the same
    bits).
    """
    pi = gp.pi
    return predict_loop(x.integrator_Pa, x.pressure_Pa, x.torque_Nm, x.friction_N, x.resistance_N, r,
                        VERTEX_CODES[vertex], stop_above, pi.kp, pi.ki, pi.out_min, pi.out_max, gp.dt_s,
                        gp.mass_kg, gp.kappa, gp.phi, gp.a_lo, gp.a_hi, gp.alpha_squeeze, gp.beta_squeeze,
                        gp.alpha_release, gp.beta_release, gp.settle_frac * gp.friction_max_N,
                        gp.settle_frac * pi.out_max, gp.horizon_steps)


def admissible(x: GovernorState, r: float, gp: GovernorParams) -> tuple[bool, float]:
    """(r ∈ R(x), the smallest torque headroom τ̄(1 − margin) − peak over the predictions) (eq. 14).

    The steady state of a constant r (torque (M r − R) / κ, any curve) must itself be admissible with room
    for the settling tolerance; then the adversary and both constant vertices must keep τ ≤ τ̄ (1 − margin)
    and settle within the horizon.
    """
    limit = gp.torque_limit_Nm
    if r > x.reference_top_mps2(gp):
        return False, limit - (gp.mass_kg * r - x.resistance_N) / gp.kappa
    worst = math.inf
    for vertex in gp.vertices:
        peak, settled = predict_peak_torque(x, r, gp, vertex, stop_above=limit)
        worst = min(worst, limit - peak)
        if peak > limit or not settled:
            return False, worst
    return True, worst


def govern(x: GovernorState, r0: float, gp: GovernorParams, r_prev: float | None = None) -> GovernorDecision:
    """r = argmin |r − r⁰| s.t. r ∈ R(x) (eq. 9) over r ∈ [0, r⁰].

    r⁰ is tried first. Otherwise, as the scalar reference governor of Kolmanovsky et al. (seed 001 ref.
    [12]), r = r_b + β (min(r⁰, r_max) − r_b) with the largest β ∈ [0, 1] found by bisection, from a base
    r_b that is admissible: the previous cycle's reference when it still is (it is, if the model is exact:
    the admissible set is positively invariant), else found by bisection on [0, r_prev]. When not even
    r = 0 is admissible (the state is outside the set), r = 0 is returned with feasible = False.
    """
    back = gp.torque_max_Nm * gp.margin_frac        # headroom is reported against τ̄ itself
    if not (r0 > 0.0):                               # no braking asked (or NaN): r = 0, still checked
        ok, head = admissible(x, 0.0, gp)
        return GovernorDecision(0.0, False, head + back, 1, ok)
    ok, head = admissible(x, r0, gp)
    evals = 1
    if ok:
        return GovernorDecision(r0, False, head + back, evals)
    top = min(r0, x.reference_top_mps2(gp))
    if r_prev is not None and 0.0 <= r_prev < top:    # the previous reference, admissible again?
        base = r_prev
        ok_b, head_b = admissible(x, base, gp)
        evals += 1
    else:
        base, ok_b = top, False
    if not ok_b:                                     # a base by bisection on [0, r_prev] (or [0, top])
        lo, hi = 0.0, base
        ok_b, head_b = admissible(x, lo, gp)
        evals += 1
        if not ok_b:
            return GovernorDecision(0.0, True, head_b + back, evals, False)
        for _ in range(gp.bisect_steps):
            mid = 0.5 * (lo + hi)
            ok, head = admissible(x, mid, gp)
            evals += 1
            if ok:
                lo, head_b = mid, head
            else:
                hi = mid
        base = lo
    lo, hi = 0.0, 1.0                                # β
    if top - base <= gp.resolution_mps2:              # already at the top (steady governed operation)
        return GovernorDecision(base, True, head_b + back, evals)
    for _ in range(gp.bisect_steps):
        if (hi - lo) * (top - base) <= gp.resolution_mps2:
            break
        mid = 0.5 * (lo + hi)
        ok, head = admissible(x, base + mid * (top - base), gp)
        evals += 1
        if ok:
            lo, head_b = mid, head
        else:
            hi = mid
    return GovernorDecision(base + lo * (top - base), True, head_b + back, evals)


def governor_params(*, dt_s: float, mass_kg: float, wheel_radius_m: float, inertia_kgm2: float,
                    friction_max_N: float, slope_lo_N_per_mps: float, slope_hi_N_per_mps: float, tp_s: float,
                    alpha_squeeze: float, beta_squeeze: float, alpha_release: float, beta_release: float,
                    pi: PIParams, **options: Any) -> GovernorParams:
    """GovernorParams from the physical data: k = 1/M + r_w²/J and κ = r_w/(J k) (eq. 3), γ = k f'(s)
    with f' ∈ [slope_lo, slope_hi] over [0, s̄] (the friction-force slope of the curve family [N/(m/s)]),
    a = exp(−γΔ), φ = exp(−Δ/Tp) (eq. 4). `options` are the remaining GovernorParams fields."""
    k = 1.0 / mass_kg + wheel_radius_m * wheel_radius_m / inertia_kgm2          # eq. (3), seed 001
    kappa = wheel_radius_m / (inertia_kgm2 * k)
    if not (0.0 < slope_lo_N_per_mps <= slope_hi_N_per_mps):
        raise ValueError(f"governor_params: need 0 < slope_lo <= slope_hi, got {slope_lo_N_per_mps!r}, "
                         f"{slope_hi_N_per_mps!r}")
    return GovernorParams(
        dt_s=dt_s, mass_kg=mass_kg, kappa=kappa, friction_max_N=friction_max_N,
        a_lo=math.exp(-k * slope_hi_N_per_mps * dt_s), a_hi=math.exp(-k * slope_lo_N_per_mps * dt_s),
        phi=math.exp(-dt_s / tp_s), alpha_squeeze=alpha_squeeze, beta_squeeze=beta_squeeze,
        alpha_release=alpha_release, beta_release=beta_release, pi=pi, **options)


@dataclass(frozen=True)
class ReferenceGovernorParams:
    """The reference governor as a BECU's reference stage (`ReferenceGovernor`)."""

    model: GovernorParams | GovernorSchedule        # the car's model; a schedule picks one by SpeedEst
    # the car's running resistance as the governor knows it, Davis (c0 [N], c1 [N s/m], c2 [N s²/m²]), eq.
    # (4) seed 003: the measured deceleration's force less R(SpeedEst) is the friction; None: R = 0 (seed 001)
    running_resistance: tuple[float, float, float] | None = None
    observer_gain: float = 0.1                      # the cylinder observer's correction per cycle (chosen)


# the signals of the governor in the BECU's frames (BECUn_STATUS, BECUn_DIAG)
GOVERNOR_OUTPUTS = ("GovernorActive", "GovernedDecel", "GovernorMargin", "GovernorFeasible")


class ReferenceGovernor:
    """Seed 001's reference governor (eq. 9) as a reference stage of a BECU's pipeline
    (firmware_py.becu.ReferenceStage), before the deceleration PI (eq. 16): it limits the demand to the
    largest reference the closed loop keeps the slip below s̄ with.  Its state estimate: a cylinder observer
    (the lag of eq. (4) run on the set-point the BECU sent, corrected towards the measured pressure) and the
    play model (10a) on the observed pressure (on the raw measurement, sensor noise would ratchet the
    estimated torque up)."""

    INPUTS: ClassVar[tuple[str, ...]] = ()
    OUTPUTS: ClassVar[tuple[str, ...]] = GOVERNOR_OUTPUTS

    def __init__(self, params: ReferenceGovernorParams) -> None:
        self.p = params
        self.p_hat = 0.0              # observed cylinder pressure [Pa]
        self.torque_est = 0.0         # brake torque: the play model run on the observed pressure [N m]
        self.r_gov: float | None = None              # last governed reference [m/s²]
        self.decision: GovernorDecision | None = None   # last decision (diagnostic)
        warm_up()                     # the compiled prediction ready before the first cycle

    def reference(self, now_us: int, rx: RxTable, r_mps2: float, loop: Loop, out: dict[str, float]) -> float:
        """The largest admissible reference towards `r_mps2`, the request r⁰ of eq. (9a)."""
        p = self.p
        gp = p.model.at(loop.v_ref_mps) if isinstance(p.model, GovernorSchedule) else p.model
        p_hat = loop.setpoint_sent_Pa + (self.p_hat - loop.setpoint_sent_Pa) * gp.phi
        self.p_hat = p_hat + p.observer_gain * (loop.pressure_Pa - p_hat)
        self.torque_est = play(self.torque_est, self.p_hat, gp)
        c = p.running_resistance
        v = max(loop.v_ref_mps, 0.0) if math.isfinite(loop.v_ref_mps) else 0.0
        res = c[0] + v * (c[1] + c[2] * v) if c is not None else 0.0        # eq. (4), seed 003
        friction = gp.mass_kg * loop.decel_mps2 - res
        x = GovernorState(loop.integrator, self.p_hat, self.torque_est, friction, res)
        decision = self.decision = govern(x, r_mps2, gp, self.r_gov)
        r = self.r_gov = decision.r_mps2
        out["GovernorActive"] = int(decision.active)
        out["GovernedDecel"] = r if decision.active else r_mps2
        out["GovernorMargin"] = clip(decision.margin_Nm, -65536.0, 65534.0)
        out["GovernorFeasible"] = int(decision.feasible)
        return r


class Ungoverned:
    """The reference stage of a BECU without the governor: the reference passes; the governor's signals in
    the BECU's frames say what the DBC gives them for that case (GovernedDecel = the demand it passed,
    GovernorActive 0, GovernorMargin 0, GovernorFeasible 1)."""

    INPUTS: ClassVar[tuple[str, ...]] = ()
    OUTPUTS: ClassVar[tuple[str, ...]] = GOVERNOR_OUTPUTS

    def reference(self, now_us: int, rx: RxTable, r_mps2: float, loop: Loop, out: dict[str, float]) -> float:
        out["GovernorActive"] = 0
        out["GovernedDecel"] = r_mps2
        out["GovernorMargin"] = 0.0
        out["GovernorFeasible"] = 1
        return r_mps2
