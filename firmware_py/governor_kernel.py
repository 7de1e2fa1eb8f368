"""The reference governor's prediction loop compiled by numba, and the scalar equations it shares with the
controllers: the one `clip`, the PI step of the shared PI primitive, the brake's play operator.

numba compiles a function from its Python bytecode; the build compiles the rest of firmware_py with mypyc,
which leaves none.  So what numba compiles lives here, in the one module the build leaves as Python: the
loop of `firmware_py.governor.predict_peak_torque` (`predict_loop`) and the functions it calls, each a
plain Python function when called from Python and inlined into the loop when numba compiles it
(`register_jitable`).  The controllers call these same functions (`firmware_py.limits.clip`,
`firmware_py.pi.pi_step` and `PI.update`, `firmware_py.governor.play`), so the PI the BECU runs and the PI
its governor predicts are one implementation.  NUMBA_DISABLE_JIT=1 runs `predict_loop` as Python, to the
same bits (tests/firmware/test_governor.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
from numba.extending import register_jitable

F = TypeVar("F", bound=Callable[..., Any])


def jitable(fn: F) -> F:
    """`fn` itself, registered with numba (`register_jitable`): Python when called from Python, compiled
    into a numba-compiled function that calls it."""
    register_jitable(fn)
    return fn


def compiled(fn: F) -> F:
    """`fn` compiled by numba (nopython, machine code cached beside the source, numpy's error model: a
    division by zero gives inf or NaN as in numpy, no exception)."""
    # numba has no type information; its dispatcher takes fn's arguments and returns what fn returns
    return cast(F, numba.njit(cache=True, error_model="numpy")(fn))


@jitable
def clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


@jitable
def pi_step_scalar(kp: float, ki: float, out_min: float, out_max: float, i: float, error: float, dt_s: float,
                   feedforward: float, freeze: bool) -> tuple[float, float, bool]:
    """One step of the shared PI (firmware_py.pi.pi_step) on plain numbers: (output, next integrator,
    saturated).  u = clip(ff + kp·e + i⁺) with i⁺ = i + ki·e·dt, except that i is kept when frozen or when
    the unclipped output is beyond a limit and the error pushes further into it (conditional
    anti-windup)."""
    i_next = i if freeze else i + ki * error * dt_s
    unclipped = feedforward + kp * error + i_next
    out = clip(unclipped, out_min, out_max)
    # conditional anti-windup: keep the old integrator when it would push further into the limit
    winding_up = (unclipped > out_max and error > 0.0) or (unclipped < out_min and error < 0.0)
    return out, (i if winding_up else i_next), unclipped != out


@jitable
def play_scalar(tau_prev: float, p: float, alpha_sq: float, beta_sq: float, alpha_rel: float,
                beta_rel: float) -> float:
    """Brake torque after the pressure moved to p: eq. (10a) of seed 001 as a play operator between the
    squeeze line ᾱ p + β̄ and the release line α̲ p + β̲, clipped at 0 [N m] (firmware_py.governor.play)."""
    sq = alpha_sq * p + beta_sq
    rel = alpha_rel * p + beta_rel
    tau = sq if sq > tau_prev else tau_prev
    tau = rel if rel < tau else tau
    return 0.0 if tau < 0.0 else tau


@compiled
def predict_loop(i: float, p: float, tau: float, f: float, res: float, r: float, vertex: int,
                 stop_above: float, kp: float, ki: float, out_min: float, out_max: float, dt: float, m: float,
                 kappa: float, phi: float, a_lo: float, a_hi: float, alpha_sq: float, beta_sq: float,
                 alpha_rel: float, beta_rel: float, tol_f: float, tol_p: float,
                 horizon: int) -> tuple[float, bool]:
    """The loop of `firmware_py.governor.predict_peak_torque` on plain numbers: the closed loop of the
    governor's module docstring with r held constant, (largest torque, settled).  vertex: the friction
    schedule, 0 the decel-minimising adversary, 1 a = ā throughout, 2 a = a̲ throughout
    (firmware_py.governor.VERTEX_CODES)."""
    peak = tau
    f_target = max(m * r - res, 0.0)        # r below R/M: the brake released, the resistance alone
    for k in range(horizon):
        e = r - (f + res) / m                                          # error of eq. (16), v̇ = (F + R)/M
        u, i, _ = pi_step_scalar(kp, ki, out_min, out_max, i, e, dt, 0.0, False)  # eq. (16), (5b)
        p = u + (p - u) * phi                                          # eq. (4), exact ZOH step
        tau = play_scalar(tau, p, alpha_sq, beta_sq, alpha_rel, beta_rel)   # eq. (10a)
        ft = kappa * tau
        if vertex == 0:
            a = a_hi if f < ft else a_lo                               # decel-minimising friction lag
        else:
            a = a_hi if vertex == 1 else a_lo
        f = a * f + (1.0 - a) * ft                                     # slip inclusion, in F
        if tau > peak:
            peak = tau
            if peak > stop_above:
                return peak, False
        if k % 10 == 9 and abs(f - f_target) < tol_f and abs(u - p) < tol_p:
            return peak, True
    return peak, False


def warm_up() -> None:
    """Compile `predict_loop` (or load its cached machine code) now, not in a node's first cycle."""
    predict_loop(0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0, math.inf, 1.0, 1.0, 0.0, 1.0, 0.01, 1.0, 1.0, 0.5, 0.5, 0.9,
                 1.0, 0.0, 1.0, 0.0, 1.0, 1.0, 10)
