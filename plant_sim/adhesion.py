"""Wheel-rail adhesion μ(θ(x), σ, v), seed 000 §2.1: pure functions, vectorised over cars.

θ arrays are shaped (n, 3) (one row θ = (θ1, θ2, θ3) per car), σ and v are shaped (n,); a single car is
n = 1. σ is the slip RATIO (v − rω)/v ∈ [0, 1] of a braking wheel.
"""

from __future__ import annotations

import numpy as np

from plant_sim.params import AdhesionParams

# Slip-ratio regularisation (representative value, chosen): σ = s / max(v, V_EPS_MPS). Below 0.5 m/s the
# slip ratio of seed 000 (which divides by v) becomes s / 0.5, i.e. adhesion turns into a function of the
# slip speed s, as in seed 001's slip-speed model; this keeps the wheel dynamics bounded as v → 0
# (the slope dμ/ds = μ'(σ)/v would otherwise grow without bound) and σ finite at standstill.
V_EPS_MPS = 0.5
# With AdhesionParams.constant_mu the curve is flat at μ_c for σ ≥ 0.001 and rises linearly from 0 below
# (chosen): a free-rolling wheel (σ = 0) transmits no force, a slipping or locked one transmits μ_c.
CONST_MU_RAMP_SIGMA = 1e-3
# literals as 0-d arrays: numpy runs a ufunc faster on two arrays than on an array and a Python float
_ONE, _INV_RAMP, _V_EPS = np.array(1.0), np.array(1.0 / CONST_MU_RAMP_SIGMA), np.array(V_EPS_MPS)


def slip_ratio(s_mps: np.ndarray, v_mps: np.ndarray) -> np.ndarray:
    """σ = s / v (seed 000 §2.1, s = v − rω of eq. (2) seed 001), regularised near v = 0, clipped to [0, 1]."""
    return np.clip(slip_ratio_unclipped(np.asarray(s_mps, dtype=float), v_mps), 0.0, 1.0)


def slip_ratio_unclipped(s_mps: np.ndarray, v_mps: np.ndarray) -> np.ndarray:
    """σ = s / max(v, V_EPS_MPS) without the clip: the plant keeps 0 ≤ s ≤ v, hence σ ∈ [0, 1] already."""
    return s_mps / np.maximum(v_mps, _V_EPS)


def mu_bar(theta: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """μ̄(θ, σ) = √σ / (θ1 + θ2 σ + θ3 σ²), seed 000 §2.1 (the curve at v = 0)."""
    theta = np.asarray(theta, dtype=float)
    return _mu_bar_cols(theta[..., 0], theta[..., 1], theta[..., 2], np.asarray(sigma, dtype=float))


def _mu_bar_cols(t1, t2, t3, sigma):
    return np.sqrt(sigma) / (t1 + sigma * (t2 + t3 * sigma))  # μ̄(θ, σ), seed 000 §2.1


def mu(theta: np.ndarray, sigma: np.ndarray, v: np.ndarray, p: AdhesionParams) -> np.ndarray:
    """μ(θ, σ, v) = μ̄(θ, k2(v) σ) / k1(v), eq. (1) seed 000, with k_i(v) = 1 + π_i v."""
    theta = np.asarray(theta, dtype=float)
    return mu_cols(theta[..., 0], theta[..., 1], theta[..., 2], np.asarray(sigma, dtype=float),
                   np.asarray(v, dtype=float), p)


def mu_cols(t1, t2, t3, sigma, v, p: AdhesionParams):
    """`mu` with θ given as its three columns (the plant keeps them so); p's fields may be 0-d arrays."""
    if p.constant_mu is not None:
        return p.constant_mu * np.minimum(sigma * _INV_RAMP, _ONE)  # flat μ (test hook)
    k1 = p.pi1_s_per_m * v + _ONE                                  # k1(v) = 1 + π1 v, seed 000 §2.1
    k2 = k1 if p.pi2_s_per_m is p.pi1_s_per_m else p.pi2_s_per_m * v + _ONE  # k2(v) = 1 + π2 v
    return _mu_bar_cols(t1, t2, t3, k2 * sigma) / k1              # μ̄(θ, k2 σ) / k1(v), eq. (1) seed 000


def sigma_opt_bar(theta: np.ndarray) -> np.ndarray:
    """Maximiser σ̄° = (−θ2 + √(θ2² + 12 θ1 θ3)) / (6 θ3) of μ̄, seed 000 §2.1."""
    theta = np.asarray(theta, dtype=float)
    t1, t2, t3 = theta[..., 0], theta[..., 1], theta[..., 2]
    return (-t2 + np.sqrt(t2 * t2 + 12.0 * t1 * t3)) / (6.0 * t3)  # seed 000 §2.1


def mu_opt_bar(theta: np.ndarray) -> np.ndarray:
    """Peak μ̄° = μ̄(θ, σ̄°), seed 000 §2.1."""
    return mu_bar(theta, sigma_opt_bar(theta))


def sigma_opt(theta: np.ndarray, v: np.ndarray, p: AdhesionParams) -> np.ndarray:
    """Maximiser σ°(θ, v) = σ̄° / k2(v) of μ(θ, ·, v), eq. (2) seed 000."""
    v = np.asarray(v, dtype=float)
    if p.constant_mu is not None:
        return np.broadcast_to(CONST_MU_RAMP_SIGMA, np.broadcast_shapes(np.shape(theta)[:-1], v.shape)).copy()
    return sigma_opt_bar(theta) / (1.0 + p.pi2_s_per_m * v)  # eq. (2) seed 000


def mu_opt(theta: np.ndarray, v: np.ndarray, p: AdhesionParams) -> np.ndarray:
    """Peak μ°(θ, v) = μ̄° / k1(v), eq. (2) seed 000."""
    v = np.asarray(v, dtype=float)
    if p.constant_mu is not None:
        return np.broadcast_to(p.constant_mu, np.broadcast_shapes(np.shape(theta)[:-1], v.shape)).copy()
    return mu_opt_bar(theta) / (1.0 + p.pi1_s_per_m * v)  # eq. (2) seed 000
