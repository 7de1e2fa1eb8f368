"""Wheel-rail adhesion μ(θ(x), σ, v), seed 000 §2.1: pure functions.

The `*_scalar` functions are the implementation: one car, Python floats, θ = (θ1, θ2, θ3) a tuple; the
plant calls them per car in its step (why scalar: `plant_sim.plant`). `slip_ratio`, `mu_bar` and `mu` are
their array wrappers (`plant_sim.elementwise`): θ arrays shaped (n, 3) (one row per car), σ and v shaped
(n,), broadcast against each other. The closed-form peak (`sigma_opt_bar` ... `mu_opt`) is numpy: it is
not on the step's path (set-up, tests and the 10 ms truth only). σ is the slip RATIO (v − rω)/v ∈ [0, 1]
of a braking wheel.
"""

from __future__ import annotations

import math

import numpy as np
from numba.extending import register_jitable

from plant_sim.elementwise import elementwise
from plant_sim.params import AdhesionParams

# Slip-ratio regularisation (representative value, chosen): σ = s / max(v, V_EPS_MPS). Below 0.5 m/s the
# slip ratio of seed 000 (which divides by v) becomes s / 0.5, i.e. adhesion turns into a function of the
# slip speed s, as in seed 001's slip-speed model; this keeps the wheel dynamics bounded as v → 0
# (the slope dμ/ds = μ'(σ)/v would otherwise grow without bound) and σ finite at standstill.
V_EPS_MPS = 0.5
# With AdhesionParams.constant_mu the curve is flat at μ_c for σ ≥ 0.001 and rises linearly from 0 below
# (chosen): a free-rolling wheel (σ = 0) transmits no force, a slipping or locked one transmits μ_c.
CONST_MU_RAMP_SIGMA = 1e-3
_INV_RAMP = 1.0 / CONST_MU_RAMP_SIGMA
_CURVE = AdhesionParams()   # the adhesion curve (no constant_mu), for μ̄ = μ at v = 0

Theta = tuple[float, float, float]


# ------------------------------------------------------------------------------------ scalar: one car
# In the functions on the step's path, max(a, b) is written `b if b > a else a` and min(a, b) `b if b < a
# else a` (the same value, NaN and ±0 included): the builtins cost ~0.1–0.25 µs a call, ~20 times a step.
@register_jitable
def slip_ratio_unclipped_scalar(s_mps: float, v_mps: float) -> float:
    """σ = s / max(v, V_EPS_MPS) [-] (seed 000 §2.1; s = v − rω, eq. (2) seed 001), not clipped: the plant
    keeps 0 ≤ s ≤ v, hence σ ∈ [0, 1] already."""
    return s_mps / (V_EPS_MPS if V_EPS_MPS > v_mps else v_mps)  # σ = s / max(v, V_EPS), seed 000 §2.1


def slip_ratio_scalar(s_mps: float, v_mps: float) -> float:
    """σ = s / max(v, V_EPS_MPS) clipped to [0, 1] [-]."""
    return min(max(slip_ratio_unclipped_scalar(s_mps, v_mps), 0.0), 1.0)


@register_jitable
def mu_slip_speed_scalar(s_mps: float, mu_peak: float, s_peak_mps: float, mu_slide: float = 0.0) -> float:
    """μ(s) = 2 μ̂ x / (1 + x²), x = s/ŝ [-]: seed 001's adhesion as a function of the slip speed s ≥ 0
    (§II-A, eq. (3) f(s) = μ(s) N). Peak μ̂ at s = ŝ; μ(0) = 0; increasing below ŝ and decreasing above
    (the unstable-slip region); concave on [0, √3 ŝ], so the chord slope μ(s)/s falls with s there and
    the cone of seed 001 Fig. 5 over [0, s̄] is bounded by the slopes μ'(0) = 2 μ̂/ŝ and μ(s̄)/s̄.
    Beyond the peak (x > 1) μ never falls below `mu_slide`, the friction of a sliding wheel (0: the curve
    as seed 001 has it, μ → 0 as the wheel locks)."""
    x = s_mps / s_peak_mps
    mu = 2.0 * mu_peak * x / (1.0 + x * x)
    return mu_slide if x > 1.0 and mu < mu_slide else mu


def mu_slip_speed_slope_scalar(s_mps: float, mu_peak: float, s_peak_mps: float) -> float:
    """dμ/ds [1/(m/s)] of `mu_slip_speed_scalar`: (2 μ̂/ŝ) (1 − x²) / (1 + x²)², x = s/ŝ."""
    x = s_mps / s_peak_mps
    return 2.0 * mu_peak / s_peak_mps * (1.0 - x * x) / ((1.0 + x * x) ** 2)


def mu_scalar(theta: Theta, sigma: float, v_mps: float, p: AdhesionParams) -> float:
    """μ(θ, σ, v) [-] of the curve `p` chooses, σ ≥ 0: seed 000's (`mu_theta_scalar`), or with
    p.slip_speed_peak = (μ̂, ŝ) seed 001's μ(s) (`mu_slip_speed_scalar`) at the slip speed
    s = σ · max(v, V_EPS_MPS) (the inverse of `slip_ratio_unclipped_scalar`; θ unused), or with
    p.constant_mu a flat curve (`mu_constant_scalar`). The compiled step makes the same choice
    (`plant_sim.kernel`).
    """
    if p.constant_mu is not None:
        return mu_constant_scalar(sigma, p.constant_mu)   # flat μ (test hook)
    if p.slip_speed_peak is not None:
        mu_pk, s_pk = p.slip_speed_peak
        return mu_slip_speed_scalar(sigma * (V_EPS_MPS if V_EPS_MPS > v_mps else v_mps), mu_pk, s_pk,
                                    p.slip_speed_slide_ratio * mu_pk)
    return mu_theta_scalar(theta, sigma, v_mps, p)


@register_jitable
def mu_theta_scalar(theta: Theta, sigma: float, v_mps: float, p: AdhesionParams) -> float:
    """μ(θ, σ, v) = μ̄(θ, k2(v) σ) / k1(v) [-], eq. (1) seed 000, with k_i(v) = 1 + π_i v (v in m/s) and
    μ̄(θ, σ) = √σ / (θ1 + θ2 σ + θ3 σ²), seed 000 §2.1; σ ≥ 0. Reads p.pi1_s_per_m and p.pi2_s_per_m."""
    t1, t2, t3 = theta
    k1 = p.pi1_s_per_m * v_mps + 1.0                        # k1(v) = 1 + π1 v, seed 000 §2.1
    ks = (p.pi2_s_per_m * v_mps + 1.0) * sigma              # k2(v) σ, k2(v) = 1 + π2 v
    return math.sqrt(ks) / (t1 + ks * (t2 + t3 * ks)) / k1  # μ̄(θ, k2 σ) / k1(v), eq. (1) seed 000


@register_jitable
def mu_constant_scalar(sigma: float, mu_c: float) -> float:
    """The flat curve of AdhesionParams.constant_mu [-]: μ_c for σ ≥ CONST_MU_RAMP_SIGMA, rising linearly
    from 0 below."""
    ramp = sigma * _INV_RAMP
    return mu_c * (1.0 if 1.0 < ramp else ramp)             # μ_c · min(σ / σ_ramp, 1)


def mu_bar_scalar(theta: Theta, sigma: float) -> float:
    """μ̄(θ, σ) [-], seed 000 §2.1: the curve at v = 0, i.e. μ(θ, σ, 0) of eq. (1) (k1(0) = k2(0) = 1 exactly,
    so this is √σ / (θ1 + θ2 σ + θ3 σ²) to the last bit)."""
    return mu_scalar(theta, sigma, 0.0, _CURVE)


# ------------------------------------------------------------------------------ array wrappers, n cars
def _theta_cols(theta) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    theta = np.asarray(theta, dtype=float)
    return theta[..., 0], theta[..., 1], theta[..., 2]


def slip_ratio(s_mps: np.ndarray, v_mps: np.ndarray) -> np.ndarray:
    """`slip_ratio_scalar` per element: σ regularised near v = 0, clipped to [0, 1]."""
    return elementwise(slip_ratio_scalar, np.asarray(s_mps, dtype=float), np.asarray(v_mps, dtype=float))


def mu_bar(theta: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """`mu_bar_scalar` per element: μ̄(θ, σ), seed 000 §2.1."""
    t1, t2, t3 = _theta_cols(theta)
    return elementwise(lambda a, b, c, sig: mu_bar_scalar((a, b, c), sig), t1, t2, t3,
                       np.asarray(sigma, dtype=float))


def mu(theta: np.ndarray, sigma: np.ndarray, v: np.ndarray, p: AdhesionParams) -> np.ndarray:
    """`mu_scalar` per element: μ(θ, σ, v), eq. (1) seed 000."""
    t1, t2, t3 = _theta_cols(theta)
    return elementwise(lambda a, b, c, sig, vel: mu_scalar((a, b, c), sig, vel, p), t1, t2, t3,
                       np.asarray(sigma, dtype=float), np.asarray(v, dtype=float))


# ------------------------------------------------------------------------- closed-form peak, numpy
def sigma_opt_bar(theta: np.ndarray) -> np.ndarray:
    """Maximiser σ̄° = (−θ2 + √(θ2² + 12 θ1 θ3)) / (6 θ3) of μ̄, seed 000 §2.1."""
    t1, t2, t3 = _theta_cols(theta)
    return (-t2 + np.sqrt(t2 * t2 + 12.0 * t1 * t3)) / (6.0 * t3)  # seed 000 §2.1


def mu_opt_bar(theta: np.ndarray) -> np.ndarray:
    """Peak μ̄° = μ̄(θ, σ̄°), seed 000 §2.1."""
    return mu_bar(theta, sigma_opt_bar(theta))


def sigma_opt(theta: np.ndarray, v: np.ndarray, p: AdhesionParams) -> np.ndarray:
    """Maximiser σ°(θ, v) = σ̄° / k2(v) of μ(θ, ·, v), eq. (2) seed 000."""
    v = np.asarray(v, dtype=float)
    if p.constant_mu is not None:
        return np.broadcast_to(CONST_MU_RAMP_SIGMA, np.broadcast_shapes(np.shape(theta)[:-1], v.shape)).copy()
    if p.slip_speed_peak is not None:                          # σ° = ŝ / max(v, V_EPS) for seed 001's μ(s)
        shape = np.broadcast_shapes(np.shape(theta)[:-1], v.shape)
        return np.broadcast_to(p.slip_speed_peak[1] / np.maximum(v, V_EPS_MPS), shape).copy()
    return sigma_opt_bar(theta) / (1.0 + p.pi2_s_per_m * v)  # eq. (2) seed 000


def mu_opt(theta: np.ndarray, v: np.ndarray, p: AdhesionParams) -> np.ndarray:
    """Peak μ°(θ, v) = μ̄° / k1(v), eq. (2) seed 000."""
    v = np.asarray(v, dtype=float)
    if p.constant_mu is not None:
        return np.broadcast_to(p.constant_mu, np.broadcast_shapes(np.shape(theta)[:-1], v.shape)).copy()
    if p.slip_speed_peak is not None:                          # μ° = μ̂ for seed 001's μ(s)
        shape = np.broadcast_shapes(np.shape(theta)[:-1], v.shape)
        return np.broadcast_to(p.slip_speed_peak[0], shape).copy()
    return mu_opt_bar(theta) / (1.0 + p.pi1_s_per_m * v)  # eq. (2) seed 000
