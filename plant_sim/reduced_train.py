"""Seed 000's reduced train model (Picasso, Caporale, Colaneri), eqs. (1)-(4): pure numerics.

n braking cars at fixed spacings Δ_i = x_1 − x_i behind car 1 (Δ_1 = 0) on a rigid train of common
speed v, each car's closed-loop slip a first-order lag of its reference Σ_i°:

    ẋ_1 = v
    v̇   = −g/n · Σ_i μ(θ(x_1 − Δ_i), σ_i, v)                     eq. (3)
    σ̇_i = −α σ_i + α Σ_i°                                         eq. (4)

with μ(θ, σ, v) = μ̄(θ, k2(v) σ)/k1(v) of eq. (1) (plant_sim.adhesion.mu_scalar).  The theoretical limit
S° of §3 ("ideal") replaces μ by its peak μ°(x_i, v) = μ̄°(x_i)/k1(v) of eq. (2).

Two users: the PLANT node of the paper-mode loop (hil.studies.preview_slip.nodes) steps `ReducedTrain` with
the
references received over CAN held constant over a step (zero-order hold, as an actuator holds its
last command), and `simulate` integrates the same equations with references computed from the true
state at every Runge-Kutta stage, without CAN: the comparison of the two isolates what the CAN path
(quantisation, cycle times, latency) changes.  The reference law is a callable given by the caller
(plant_sim does not know the controllers).  Units: SI, time [s], positions [m], speeds [m/s].
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from plant_sim.adhesion import mu_bar_scalar, mu_scalar
from plant_sim.errors import PlantConfigError
from plant_sim.params import G_MPS2, AdhesionParams
from plant_sim.track import Track


@dataclass(frozen=True)
class ReducedTrainParams:
    """The reduced model's constants."""

    spacing_m: tuple[float, ...] = (0.0, 50.0)   # Δ_i [m], Δ_1 = 0, increasing (seed 000 Fig. 1)
    alpha_per_s: float = 1.5                     # α [1/s], inverse time constant of eq. (4) (seed 000 §3.1)
    sigma0: float = 0.001                        # σ_i(0) [-], seed 000 §3
    ideal: bool = False                          # μ = μ° (the theoretical limit S°, seed 000 §3)
    g_mps2: float = G_MPS2
    adhesion: AdhesionParams = field(default_factory=AdhesionParams)   # k_i(v) = 1 + v/40, seed 000 §3

    def __post_init__(self) -> None:
        d = self.spacing_m
        if not d or d[0] != 0.0 or any(b <= a for a, b in zip(d, d[1:], strict=False)):
            raise PlantConfigError(f"ReducedTrainParams: spacing_m must start at 0 (car 1) and increase, "
                                   f"got {d}")
        if not (self.alpha_per_s > 0.0 and math.isfinite(self.alpha_per_s)):
            raise PlantConfigError(f"ReducedTrainParams: alpha_per_s must be > 0, got {self.alpha_per_s}")
        if not 0.0 <= self.sigma0 < 1.0:
            raise PlantConfigError(f"ReducedTrainParams: sigma0 must be in [0, 1), got {self.sigma0}")

    @property
    def n(self) -> int:
        return len(self.spacing_m)


def sigma_opt_bar_scalar(theta: tuple[float, float, float]) -> float:
    """σ̄° = (−θ2 + √(θ2² + 12 θ1 θ3)) / (6 θ3) [-], the maximiser of μ̄(θ, ·), seed 000 §2.1."""
    t1, t2, t3 = theta
    return (-t2 + math.sqrt(t2 * t2 + 12.0 * t1 * t3)) / (6.0 * t3)   # seed 000 §2.1


class Rail:
    """θ(x), σ̄°(x) and μ̄°(x) of a Track as scalar look-ups (one bisect, then affine in x)."""

    def __init__(self, track: Track) -> None:
        self.track = track
        self._knots = [float(k) for k in track.knots_m]
        reps = ([self._knots[0] - 1.0] if self._knots else [0.0]) + \
            [k for k in self._knots]                                   # one x inside every interval
        s = track.sample(np.array(reps, dtype=float))
        self._anchor = [float(a) if math.isfinite(a) else 0.0 for a in s.anchor_m]
        self._theta0 = [tuple(float(c) for c in row) for row in s.theta_anchor]
        self._dtheta = [tuple(float(c) for c in row) for row in s.dtheta_per_m]

    def theta(self, x: float) -> tuple[float, float, float]:
        """θ(x) (seed 000 §2.1)."""
        i = bisect.bisect_right(self._knots, x)
        a, (t1, t2, t3), (d1, d2, d3) = x - self._anchor[i], self._theta0[i], self._dtheta[i]
        return (t1 + d1 * a, t2 + d2 * a, t3 + d3 * a)

    def sigma_opt_bar(self, x: float) -> float:
        """σ̄°(x) [-]: the optimal slip at v = 0 of the rail at x, seed 000 §2.1."""
        return sigma_opt_bar_scalar(self.theta(x))

    def mu_opt_bar(self, x: float) -> float:
        """μ̄°(x) = μ̄(θ(x), σ̄°(x)) [-], seed 000 §2.1."""
        th = self.theta(x)
        return mu_bar_scalar(th, sigma_opt_bar_scalar(th))


def k_factor(pi_s_per_m: float, v_mps: float) -> float:
    """k_i(v) = 1 + π_i v [-], seed 000 eq. (1)."""
    return 1.0 + pi_s_per_m * v_mps


def adhesion_used(rail: Rail, p: ReducedTrainParams, x1: float, v: float,
                  sig: Sequence[float]) -> list[float]:
    """μ_i the wheels of each car use [-]: μ(θ(x_1 − Δ_i), σ_i, v) of eq. (1), or μ°(x_i, v) of eq. (2)
    in the ideal case."""
    ad = p.adhesion
    if p.ideal:
        k1 = k_factor(ad.pi1_s_per_m, v)
        return [rail.mu_opt_bar(x1 - d) / k1 for d in p.spacing_m]                 # eq. (2)
    return [mu_scalar(rail.theta(x1 - d), s if s > 0.0 else 0.0, v, ad)           # eq. (1)
            for d, s in zip(p.spacing_m, sig, strict=True)]


def train_accel(rail: Rail, p: ReducedTrainParams, x1: float, v: float, sig: Sequence[float]) -> float:
    """v̇ = −g/n Σ μ_i [m/s²], eq. (3) seed 000."""
    return -p.g_mps2 * sum(adhesion_used(rail, p, x1, v, sig)) / p.n           # eq. (3)


#: a reference law: (x_1 [m], v [m/s], v̇ [m/s²]) -> Σ_i° per car
RefLaw = Callable[[float, float, float], Sequence[float]]


class ReducedTrain:
    """The state (x_1, v, σ_1..σ_n) of eqs. (3)-(4) and a fixed-step RK4 integrator around it.

    The train stops when v reaches 0 inside a step: the step ends there (v = 0, x_1 at the stop,
    found with v linear over the step) and the state stays frozen."""

    def __init__(self, rail: Rail, p: ReducedTrainParams, v0_mps: float, x0_m: float = 0.0) -> None:
        if not (v0_mps >= 0.0 and math.isfinite(v0_mps)):
            raise PlantConfigError(f"ReducedTrain: initial speed must be >= 0 m/s, got {v0_mps}")
        self.rail, self.p = rail, p
        self.x1, self.v = float(x0_m), float(v0_mps)
        self.sig = [p.sigma0] * p.n
        self.stopped = self.v <= 0.0

    def accel(self) -> float:
        return train_accel(self.rail, self.p, self.x1, self.v, self.sig) if not self.stopped else 0.0

    def _deriv(self, x1: float, v: float, sig: list[float], law: RefLaw) -> tuple[float, float, list[float]]:
        a = train_accel(self.rail, self.p, x1, v, sig)                            # eq. (3)
        ref = law(x1, v, a)
        al = self.p.alpha_per_s
        return v, a, [al * (r - s) for r, s in zip(ref, sig, strict=True)]                     # eq. (4)

    def step(self, dt_s: float, law: RefLaw) -> None:
        """Advance by dt_s [s] (classic RK4); `law` gives Σ_i° at each stage's state."""
        if self.stopped:
            return
        x, v, s = self.x1, self.v, self.sig
        h = dt_s
        k1x, k1v, k1s = self._deriv(x, v, s, law)
        k2x, k2v, k2s = self._deriv(x + 0.5 * h * k1x, v + 0.5 * h * k1v,
                                    [a + 0.5 * h * b for a, b in zip(s, k1s, strict=True)], law)
        k3x, k3v, k3s = self._deriv(x + 0.5 * h * k2x, v + 0.5 * h * k2v,
                                    [a + 0.5 * h * b for a, b in zip(s, k2s, strict=True)], law)
        k4x, k4v, k4s = self._deriv(x + h * k3x, v + h * k3v,
                                    [a + h * b for a, b in zip(s, k3s, strict=True)], law)
        v_new = v + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        sig_new = [a + h / 6.0 * (b + 2.0 * c + 2.0 * d + e)
                   for a, b, c, d, e in zip(s, k1s, k2s, k3s, k4s, strict=True)]
        if v_new <= 0.0:                                      # stops inside this step: v linear over it
            frac = v / (v - v_new) if v > v_new else 0.0
            self.x1 = x + 0.5 * v * frac * h
            self.v = 0.0
            self.sig = [a + frac * (b - a) for a, b in zip(s, sig_new, strict=True)]
            self.stopped = True
            return
        self.x1 = x + h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
        self.v = v_new
        self.sig = sig_new


class ReducedTrainTruth:
    """The reduced model's ground truth at a fixed period, in the columns hil.report.kpis reads
    (`x_m_k, v_mps_k, a_mps2_k, slip_speed_mps_k, slip_ratio_k, wsp_valve_k, p_Pa_k`, `coupler_dl_m_k`,
    zeros where the reduced model has no such quantity) plus `sigma_ref_k` (Σ_k° applied), `sigma_opt_k`
    (true σ°(x_k, v)) and `mu_k` (adhesion used).  Plain lists: it pickles."""

    def __init__(self, spacing_m: Sequence[float]) -> None:
        self.spacing_m = tuple(spacing_m)
        self.rows: list[tuple] = []        # (t_s, x1, v, a, sig tuple, ref tuple, sigma_opt tuple, mu tuple)

    def record(self, t_s: float, x1: float, v: float, a: float, sig, ref, sopt, mu) -> None:
        self.rows.append((t_s, x1, v, a, tuple(sig), tuple(ref), tuple(sopt), tuple(mu)))

    def columns(self) -> dict[str, np.ndarray]:
        n = len(self.spacing_m)
        if not self.rows:
            return {"t_s": np.zeros(0)}
        t, x1, v, a, sig, ref, sopt, mu = (np.array(c, dtype=float) for c in zip(*self.rows, strict=True))
        cols = {"t_s": t}
        zero = np.zeros_like(t)
        for k in range(n):
            cols[f"x_m_{k + 1}"] = x1 - self.spacing_m[k]
            cols[f"v_mps_{k + 1}"] = v
            cols[f"a_mps2_{k + 1}"] = a
            cols[f"slip_speed_mps_{k + 1}"] = sig[:, k] * v
            cols[f"slip_ratio_{k + 1}"] = sig[:, k]
            cols[f"wsp_valve_{k + 1}"] = zero
            cols[f"p_Pa_{k + 1}"] = zero
            cols[f"sigma_ref_{k + 1}"] = ref[:, k]
            cols[f"sigma_opt_{k + 1}"] = sopt[:, k]
            cols[f"mu_{k + 1}"] = mu[:, k]
        for k in range(1, n):
            cols[f"coupler_dl_m_{k}"] = zero                                     # rigid train, seed 000
        return cols


def sigma_opt_true(rail: Rail, p: ReducedTrainParams, x1: float, v: float) -> list[float]:
    """σ°(x_i, v) = σ̄°(x_i)/k2(v) per car [-], eq. (2)."""
    k2 = k_factor(p.adhesion.pi2_s_per_m, v)
    return [rail.sigma_opt_bar(x1 - d) / k2 for d in p.spacing_m]


@dataclass
class DirectResult:
    stopping_m: float             # S: x_1 at the stop minus x_1(0) [m]
    time_s: float                 # time to stop [s]
    truth: ReducedTrainTruth


def simulate(rail: Rail, p: ReducedTrainParams, v0_mps: float, law: RefLaw, dt_s: float = 0.002,
             record_every: int = 5, max_time_s: float = 600.0) -> DirectResult:
    """Integrate eqs. (1)-(4) to standstill without CAN: Σ_i° = law(x_1, v, v̇) at every RK4 stage."""
    train = ReducedTrain(rail, p, v0_mps)
    truth = ReducedTrainTruth(p.spacing_m)
    steps = 0
    while not train.stopped and steps * dt_s < max_time_s:
        if steps % record_every == 0:
            a = train.accel()
            truth.record(steps * dt_s, train.x1, train.v, a, train.sig, law(train.x1, train.v, a),
                         sigma_opt_true(rail, p, train.x1, train.v),
                         adhesion_used(rail, p, train.x1, train.v, train.sig))
        train.step(dt_s, law)
        steps += 1
    return DirectResult(train.x1, steps * dt_s, truth)
