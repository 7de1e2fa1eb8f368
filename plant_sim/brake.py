"""Pneumatic brake per car: EP valve, WSP dump valve, brake cylinder, pressure → torque hysteresis.

Pure functions of (state, inputs, params). The `*_scalar` functions are the implementation: one car,
Python floats, called per car by the plant's step (why scalar: `plant_sim.plant`); `cylinder_pressure_step`
and `hysteresis_torque` are their array wrappers over cars (`plant_sim.elementwise`). The input sanitizers
are numpy: they run only when an input is bad.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from plant_sim.elementwise import elementwise
from plant_sim.params import BrakeParams, PadParams

# WSP dump-valve states (the DBC's WspValve signal)
WSP_FILL = 0   # normal: the EP valve acts on the cylinder
WSP_HOLD = 1   # cylinder isolated: pressure held
WSP_VENT = 2   # cylinder dumped to atmosphere by the WSP valve
WSP_STATES = frozenset((WSP_FILL, WSP_HOLD, WSP_VENT))


def sanitize_valve_cmd(valve_cmd: np.ndarray) -> tuple[np.ndarray, int]:
    """EP valve opening clipped to [−1, 1]; non-finite entries become 0 (valve closed: pressure held).

    Returns the clean array and how many entries were non-finite.
    """
    u = np.asarray(valve_cmd, dtype=float)
    bad = ~np.isfinite(u)
    n_bad = int(np.count_nonzero(bad))
    if n_bad:
        u = np.where(bad, 0.0, u)
    return np.minimum(np.maximum(u, -1.0), 1.0), n_bad


def sanitize_wsp_valve(wsp_valve: np.ndarray) -> tuple[np.ndarray, int]:
    """WSP valve states as intp in {0, 1, 2}; anything else becomes WSP_FILL (the dump valve does nothing).

    Returns the clean array and how many entries were invalid.
    """
    w = np.asarray(wsp_valve)
    with np.errstate(invalid="ignore"):
        valid = (w == WSP_FILL) | (w == WSP_HOLD) | (w == WSP_VENT)
    n_bad = int(valid.size - np.count_nonzero(valid))
    return np.where(valid, w, WSP_FILL).astype(np.intp), n_bad


class ValveTable(NamedTuple):
    """Pressure change over one step by WSP state (index 0 FILL, 1 HOLD, 2 VENT): for opening u of a car
    in WSP state w, dp = u·fill[w] if u > 0, u·vent[w] if u < 0, plus dump[w]; then 0 ≤ p ≤ p̄."""

    fill_Pa: tuple[float, float, float]   # per unit opening
    vent_Pa: tuple[float, float, float]   # per unit opening
    dump_Pa: tuple[float, float, float]
    vent_ge_fill: bool    # vent rate ≥ fill rate: u·fill (u > 0) / u·vent (u < 0) is the smaller product
    p_max_Pa: float       # reservoir pressure p̄


def valve_table(bp: BrakeParams, dt_s: float) -> ValveTable:
    """The valves' pressure change over a step of dt_s [s], by WSP state (see ValveTable)."""
    dt_s = float(dt_s)
    fill, vent, dump = [0.0] * 3, [0.0] * 3, [0.0] * 3
    fill[WSP_FILL] = bp.fill_rate_Pa_per_s * dt_s       # FILL: the EP valve fills (u > 0) ...
    vent[WSP_FILL] = bp.vent_rate_Pa_per_s * dt_s       # ... or vents (u < 0); HOLD: nothing moves
    dump[WSP_VENT] = -bp.wsp_vent_rate_Pa_per_s * dt_s  # VENT: the dump valve empties the cylinder
    return ValveTable(tuple(fill), tuple(vent), tuple(dump),
                      bool(bp.vent_rate_Pa_per_s >= bp.fill_rate_Pa_per_s), float(bp.p_max_Pa))


# ------------------------------------------------------------------------------------ scalar: one car
# max(a, b) is written `b if b > a else a` and min(a, b) `b if b < a else a` (the same value, NaN and ±0
# included): the builtins cost ~0.1–0.25 µs a call, and these run for every car at every step.
@register_jitable
def cylinder_pressure_scalar(p_Pa: float, valve_cmd: float, wsp_valve: int, table: ValveTable) -> float:
    """Cylinder pressure [Pa] after one step, exact for inputs held over the step (table = valve_table).

    EP valve with opening valve_cmd ∈ [−1, 1] (finite; `sanitize_valve_cmd` makes it so): dp/dt =
    valve_cmd · fill_rate if > 0, else valve_cmd · vent_rate. The WSP dump valve (wsp_valve ∈ {0, 1, 2})
    overrides it: FILL (0) lets the EP valve act, HOLD (1) isolates the cylinder (dp/dt = 0), VENT (2)
    dumps it (dp/dt = −wsp_vent_rate). The result is clipped to [0, p̄] (eq. (5a) seed 001). A pressure
    controller closing the loop on the valve turns this into the first-order lag of eq. (4) seed 001.
    """
    by_fill, by_vent = valve_cmd * table.fill_Pa[wsp_valve], valve_cmd * table.vent_Pa[wsp_valve]
    # EP valve: u·fill for u > 0, u·vent for u < 0, i.e. the smaller product if vent ≥ fill, else the larger
    if table.vent_ge_fill:
        ep = by_vent if by_vent < by_fill else by_fill              # min(by_fill, by_vent)
    else:
        ep = by_vent if by_vent > by_fill else by_fill              # max(by_fill, by_vent)
    p = p_Pa + ep + table.dump_Pa[wsp_valve]
    p = 0.0 if 0.0 > p else p                                       # 0 ≤ p ...
    p_max = table.p_max_Pa
    return p_max if p_max < p else p                                # ... ≤ p̄, eq. (5a) seed 001


def lag_factor(bp: BrakeParams, dt_s: float) -> float:
    """φ = exp(−dt/Tp) [-]: the exact step of ṗ = (u − p)/Tp (eq. (4), seed 001 §IV) for u held over dt_s."""
    return math.exp(-float(dt_s) / bp.tp_s)


@register_jitable
def cylinder_lag_scalar(p_Pa: float, p_set_Pa: float, wsp_valve: int, phi: float, p_max_Pa: float) -> float:
    """Cylinder pressure [Pa] after one step of the "lag" model (BrakeParams.pressure_model), exact for a
    set-point held over the step: p⁺ = u + (p − u) φ with φ = lag_factor (eq. (4) with Tp, seed 001 §IV).

    The set-point is bounded to 0 ≤ u ≤ p̄ (eq. (5b)); the WSP dump valve overrides it: HOLD (1) keeps p,
    VENT (2) vents with u = 0 (seed 001 §II-C). Non-finite set-points count as 0 (nothing commanded).
    """
    if wsp_valve == WSP_HOLD:
        return p_Pa
    u = 0.0 if (wsp_valve == WSP_VENT or not (p_set_Pa > 0.0)) else p_set_Pa   # NaN -> 0
    u = p_max_Pa if p_max_Pa < u else u                                           # 0 ≤ u ≤ p̄, eq. (5b)
    p = u + (p_Pa - u) * phi                                                      # eq. (4), seed 001 §IV
    p = 0.0 if 0.0 > p else p
    return p_max_Pa if p_max_Pa < p else p                                        # 0 ≤ p ≤ p̄, eq. (5a)


@register_jitable
def hysteresis_torque_scalar(tau_prev_Nm: float, p_Pa: float, bp: BrakeParams) -> float:
    """Brake torque τ ≥ 0 [N·m] at cylinder pressure p [Pa], eq. (10a) seed 001 as a play operator.

    The squeeze line τ = ᾱ p + β̄ lies below the release line τ = α̲ p + β̲ (same p). The three cases
    of (10a), with τ⁻ = tau_prev:
      squeeze  τ⁻ ≤ ᾱ p + β̄  → τ = ᾱ p + β̄   (pressure rose past the squeeze line: torque rises on it)
      release  τ⁻ ≥ α̲ p + β̲  → τ = α̲ p + β̲   (pressure fell past the release line: torque falls on it)
      hold     otherwise     → τ = τ⁻         (between the lines: torque does not respond)
    (10a)'s conditions u ≥ p / u ≤ p are implied: τ⁻ can only lie below the squeeze line if p rose since
    the last step, above the release line if it fell. The torque is then clipped at 0 (block off the disc).
    """
    squeeze = bp.alpha_squeeze_Nm_per_Pa * p_Pa + bp.beta_squeeze_Nm   # squeeze line, eq. (6) seed 001
    release = bp.alpha_release_Nm_per_Pa * p_Pa + bp.beta_release_Nm   # release line, eq. (6) seed 001
    tau = squeeze if squeeze > tau_prev_Nm else tau_prev_Nm   # squeeze case of (10a): lifted onto the line
    tau = release if release < tau else tau                    # release case of (10a): pushed down onto it
    return 0.0 if 0.0 > tau else tau                           # hold case leaves τ⁻; torque never negative


@register_jitable
def pad_friction_scalar(omega_rad_s: float, temp_rise_K: float, pp: PadParams) -> float:
    """μ_d [-] of the pad on the disc, eq. (25) seed 004: μ_d0 (n_v e^{m_v v_d} + 1)(n_T e^{m_T T_d} + 1),
    v_d = |ω| r_f the sliding speed [m/s], T_d the disc's temperature rise [K]."""
    v_d = abs(omega_rad_s) * pp.friction_radius_m
    return (pp.mu_steady * (pp.n_v * math.exp(pp.m_v_s_per_m * v_d) + 1.0)        # eq. (25), seed 004
            * (pp.n_T * math.exp(pp.m_T_per_K * temp_rise_K) + 1.0))


@register_jitable
def disc_temperature_scalar(temp_rise_K: float, tau_Nm: float, omega_rad_s: float, dt_s: float,
                            pp: PadParams) -> float:
    """Disc temperature rise [K] after dt_s: C dT/dt = η τ |ω| − G T (braking power in, conduction and
    convection out); explicit Euler (C/G = 30 s ≫ dt)."""
    power_W = pp.heat_fraction * tau_Nm * abs(omega_rad_s)                        # F_b v = τ ω
    return temp_rise_K + dt_s * (power_W - pp.cooling_W_per_K * temp_rise_K) / pp.heat_capacity_J_per_K


# ------------------------------------------------------------------------------ array wrappers, n cars
def cylinder_pressure_step(p: np.ndarray, valve_cmd: np.ndarray, wsp_valve: np.ndarray, dt_s: float,
                           bp: BrakeParams, table: ValveTable | None = None) -> np.ndarray:
    """`cylinder_pressure_scalar` per car: pressures [Pa] after dt_s [s]; wsp_valve ints in {0, 1, 2}.

    table = valve_table(bp, dt_s), computed here unless the caller keeps it.
    """
    table = valve_table(bp, dt_s) if table is None else table
    u = np.asarray(valve_cmd, dtype=float)
    return elementwise(cylinder_pressure_scalar, np.asarray(p, dtype=float), u,
                       np.asarray(wsp_valve).astype(np.intp), params=(table,))


def hysteresis_torque(tau_prev: np.ndarray, p: np.ndarray, bp: BrakeParams) -> np.ndarray:
    """`hysteresis_torque_scalar` per car: brake torques [N·m] at pressures p [Pa], eq. (10a) seed 001."""
    return elementwise(hysteresis_torque_scalar, np.asarray(tau_prev, dtype=float),
                       np.asarray(p, dtype=float), params=(bp,))
