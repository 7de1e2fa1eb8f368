"""The plant's step over all cars, compiled: the same scalar equations, run as machine code by numba.

`plant_sim.plant.Plant.step` used to spend its time in the per-car calls of the `*_scalar` functions of
`adhesion`, `brake` and `dynamics` (~60 Python calls a step, 20–25 µs). `step_cars` below runs one step of
all cars, calling those very functions, compiled by numba: each is marked `numba.extending.
register_jitable`, which leaves it a plain Python function for Python callers (the array wrappers, the
10 ms truth, the tests) and lets compiled code call it. So each equation keeps one implementation, its
Python source. The arithmetic is the same, operation for operation (no fast-math: no reassociation, no
fused multiply-add; `math.exp` and `math.sqrt` are the C library's), so the compiled step gives the
interpreted one's floats bit for bit: tests/plant/test_kernel.py runs `step_cars` compiled and
interpreted (`step_cars.py_func`) side by side and compares the bits.

How the parameters reach compiled code: a frozen dataclass cannot, so `as_record` copies the numeric
fields of one into a numpy record with the same field names (a tuple becomes a sub-array), and the
scalar functions read `bp.alpha_squeeze_Nm_per_Pa` or `table.fill_Pa[w]` from either. The state travels
as a few float arrays, rows named by the constants below: a call with five arrays costs ~0.6 µs to
dispatch, a record-like tuple ~2 µs.

Compiled code is cached (numba `cache=True`) in a folder named after a hash of the physics sources
(`cache_dir`): numba checks only the stamp of the file that holds the compiled function, so an edit of
an equation in brake.py would otherwise run stale machine code. A fresh checkout compiles once (a few
seconds) and then loads the machine code (~0.1 s). NUMBA_DISABLE_JIT=1 runs everything interpreted
(slow; for debugging).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
import tempfile
from pathlib import Path

import numba
import numpy as np
from numba.extending import register_jitable

from plant_sim.adhesion import (
    V_EPS_MPS,
    mu_constant_scalar,
    mu_slip_speed_scalar,
    mu_theta_scalar,
    slip_ratio_unclipped_scalar,
)
from plant_sim.brake import (
    cylinder_lag_scalar,
    cylinder_pressure_scalar,
    disc_temperature_scalar,
    hysteresis_torque_scalar,
    pad_friction_scalar,
)
from plant_sim.dynamics import (
    coupler_extension_scalar,
    coupler_force_scalar,
    coupler_rate_scalar,
    other_force_scalar,
    slip_rate_scalar,
)
from plant_sim.sensors import sensor_readings

# Adhesion is evaluated at s + S_EPS_MPS (chosen): the chord slope f/s is then finite and, at s = 0,
# very large (μ ∝ √s), so a braked car at rest is held by the static force the linearised step finds
# (up to τ/r) instead of creeping off and back to 0 every other step. The bias is ≲ 50 N per car on a
# free-rolling wheel, against c0 = 800 N of rolling resistance.
S_EPS_MPS = 1e-9

#: the sources compiled into `step_cars`: their hash names the cache folder
PHYSICS_SOURCES = ("adhesion.py", "brake.py", "dynamics.py", "sensors.py", "kernel.py")


def cache_dir() -> Path:
    """Where numba keeps the compiled step: <NUMBA_CACHE_DIR or plant_sim/__pycache__ or the temp
    folder>/numba-<hash of PHYSICS_SOURCES and numba's version>."""
    here = Path(__file__).resolve().parent
    digest = hashlib.sha256(numba.__version__.encode())
    for name in PHYSICS_SOURCES:
        digest.update((here / name).read_bytes())
    for base in (os.environ.get("NUMBA_CACHE_DIR"), here / "__pycache__",
                 Path(tempfile.gettempdir()) / "railhil-numba"):
        if base and (os.access(base, os.W_OK) or not Path(base).exists()
                     and os.access(Path(base).parent, os.W_OK)):
            return Path(base) / f"numba-{digest.hexdigest()[:16]}"
    return Path(tempfile.gettempdir()) / f"railhil-numba-{digest.hexdigest()[:16]}"


def _compiled(fn):
    """fn compiled (numba nopython, IEEE arithmetic: error_model "numpy" gives inf/NaN where Python would
    raise), its machine code cached in `cache_dir()`; the caches of earlier sources are removed."""
    here = cache_dir()
    for old in here.parent.glob("numba-*"):
        if old != here:
            shutil.rmtree(old, ignore_errors=True)
    saved = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = str(here)
    try:
        return numba.njit(cache=True, error_model="numpy")(fn)
    finally:
        numba.config.CACHE_DIR = saved


@register_jitable
def integrate_car_scalar(x_m: float, v_mps: float, s_mps: float, s_reg_mps: float, f_N: float,
                         f_other_N: float, tau_Nm: float, inv_mass_per_kg: float, r_over_J: float,
                         slip_gain_per_kg: float, inv_dt_per_s: float, inv_mass_dt: float,
                         dt_s: float) -> tuple[float, float, float]:
    """One integrator step of one car (`plant_sim.plant`): (x [m], v [m/s], s [m/s]) at the end of the step.

    f is the adhesion force [N] at slip speed s_reg = s + S_EPS_MPS, f_other every other force on the car
    [N], tau the brake torque [N·m] over the step; inv_mass_dt = dt/m. Speeds: linearly-implicit Euler with
    the standstill handling, v ≥ 0 (a car cannot reverse) and 0 ≤ s ≤ v (0 ≤ ω ≤ v/r); position:
    symplectic Euler.
    """
    s_dot = slip_rate_scalar(f_other_N, f_N, tau_Nm, inv_mass_per_kg, r_over_J,
                             slip_gain_per_kg)                    # explicit ṡ, eq. (3) seed 001
    chord = f_N / s_reg_mps                                        # f(s) ≈ c·s, c > 0
    ds = s_dot / (inv_dt_per_s + slip_gain_per_kg * chord)         # (1 + dt (1/M + r²/J) c) Δs = dt ṡ
    f_new = f_N + chord * ds                                       # adhesion force over the step
    # v̇ = (F_other − f)/m, eq. (3) seed 003; a car cannot reverse: v ≥ 0
    v_new = v_mps + (f_other_N - f_new) * inv_mass_dt
    v_new = 0.0 if 0.0 > v_new else v_new
    s_new = s_mps + ds
    s_new = 0.0 if 0.0 > s_new else s_new
    s_new = v_new if v_new < s_new else s_new                      # 0 ≤ s ≤ v, i.e. 0 ≤ ω ≤ v/r
    return x_m + v_new * dt_s, v_new, s_new                        # ẋ = v at the new v: symplectic Euler


# ------------------------------------------------------------------------- parameters as numpy records
_RECORD_DTYPES: dict[tuple, np.dtype] = {}


def as_record(params) -> np.ndarray:
    """A one-element numpy record array with the numeric fields of a dataclass or NamedTuple `params`,
    same names (floats and ints as float64, bools as bool, tuples of numbers as float64 sub-arrays); the
    other fields (None, strings) are left out. `as_record(p)[0].name` reads like `p.name`."""
    if dataclasses.is_dataclass(params):
        items = [(f.name, getattr(params, f.name)) for f in dataclasses.fields(params)]
    else:
        items = list(params._asdict().items())
    spec, values = [], []
    for name, value in items:
        if isinstance(value, bool):
            spec.append((name, np.bool_))
        elif isinstance(value, int | float):
            spec.append((name, np.float64))
        elif isinstance(value, tuple) and value and all(isinstance(v, int | float) for v in value):
            spec.append((name, np.float64, (len(value),)))
        else:
            continue
        values.append(value)
    key = tuple(spec)
    dtype = _RECORD_DTYPES.get(key)
    if dtype is None:      # one dtype object per layout: numba dispatches ~2 µs slower on a new one
        dtype = _RECORD_DTYPES[key] = np.zeros(1, dtype=np.dtype(spec)).view(np.recarray).dtype
    rec = np.zeros(1, dtype=dtype).view(np.recarray)   # np.record: fields as attributes (same dtype)
    rec[0] = tuple(values)
    return rec


# ------------------------------------------------------------------------------ the arrays of the step
# rows of the state array (n cars each)
X, V, V_PREV, S, P, TAU, TAU_BRAKE, F_OTHER, S_MAX, MU_PAD, TEMP, U, W, PS = range(14)
N_STATE = 14
# rows of the track array: θ per car, −(c0 + f_c) per car, and the cars inside a smooth θ blend
# (LIVE = 1: θ = θ_anchor + dθ/dx · (x − anchor) every step)
THETA1, THETA2, THETA3, STATIC, LIVE, ANCHOR, TA1, TA2, TA3, DTH1, DTH2, DTH3 = range(12)
N_TRACK = 12
# rows of the per-car constants: 1/m, 1/M + r²/J, dt/m, N = m g, Davis c2
INV_M, GAIN, INV_M_DT, NORMAL, C2 = range(5)
N_CAR = 5
# the scalars: step, the models in use and their constants; BUDGET is the distance [m] the cars may still
# move before one meets a track knot (the step decrements it; ≤ 0: look the track up again)
DT, INV_DT, LAG, LAG_PHI, P_MAX, PAD, INV_PAD_NOMINAL, INV_R, ADHESION, CONST_MU, MU_PEAK, S_PEAK, MU_SLIDE, \
    C1, R_OVER_J, PITCH, BUDGET = range(17)
N_SCALAR = 17
ADHESION_THETA, ADHESION_SLIP_SPEED, ADHESION_CONSTANT = 0.0, 1.0, 2.0   # the curve of `adhesion.mu_scalar`

@register_jitable
def _mu(t1, t2, t3, sigma, v, k, ap):
    """`adhesion.mu_scalar` with the curve chosen by k[ADHESION] (a record cannot hold None)."""
    mode = k[ADHESION]
    if mode == ADHESION_CONSTANT:
        return mu_constant_scalar(sigma, k[CONST_MU])
    if mode == ADHESION_SLIP_SPEED:
        return mu_slip_speed_scalar(sigma * (V_EPS_MPS if V_EPS_MPS > v else v), k[MU_PEAK], k[S_PEAK],
                                    k[MU_SLIDE])
    return mu_theta_scalar((t1, t2, t3), sigma, v, ap)


def step_cars(st, tr, car, k, recs, u_in, w_in, ps_in):
    """One step dt of every car, in place: the body of `Plant.step` (see `plant_sim.plant`).

    The inputs are checked first and kept in st[U], st[W], st[PS] as applied: a non-finite valve opening
    counts as bad and is taken as 0, the others are clipped to [−1, 1] (`brake.sanitize_valve_cmd`); a WSP
    state other than 0, 1, 2 counts as bad and is taken as FILL (`brake.sanitize_wsp_valve`); the
    pressure set-points are used as given ("lag" model; `brake.cylinder_lag_scalar` reads NaN as 0).
    recs = (BrakeParams, ValveTable, CarConstants, AdhesionParams, PadParams) as `as_record` arrays.

    Returns (look the track up again: a car reached a knot, k[BUDGET] ≤ 0; the number of bad inputs).
    """
    bp, table, cc, ap, pp = recs[0][0], recs[1][0], recs[2][0], recs[3][0], recs[4][0]
    n = st.shape[1]
    x, v, s, p, tau_line = st[X], st[V], st[S], st[P], st[TAU]
    u, w = st[U], st[W]
    n_bad = 0
    for i in range(n):
        u_i = u_in[i]
        if u_i - u_i != 0.0:                                        # inf or NaN: valve closed
            n_bad += 1
            u_i = 0.0
        u_i = -1.0 if u_i < -1.0 else u_i
        u[i] = 1.0 if u_i > 1.0 else u_i
        w_i = float(w_in[i])
        if w_i == 0.0 or w_i == 1.0 or w_i == 2.0:                  # WSP_FILL, WSP_HOLD, WSP_VENT
            w[i] = w_i
        else:
            n_bad += 1
            w[i] = 0.0
        if k[LAG] != 0.0:
            st[PS, i] = ps_in[i]
    # brake: cylinder pressure and the torque of the hysteresis line
    if k[LAG] != 0.0:
        for i in range(n):
            p_i = cylinder_lag_scalar(p[i], st[PS, i], int(w[i]), k[LAG_PHI], k[P_MAX])  # (4)-(5) seed 001
            p[i] = p_i
            tau_line[i] = hysteresis_torque_scalar(tau_line[i], p_i, bp)      # eq. (10a) seed 001
    else:
        moved = False
        for i in range(n):
            if u[i] != 0.0 or w[i] != 0.0:
                moved = True
        if moved:                                                   # else p and τ stay as they are
            for i in range(n):
                p_i = cylinder_pressure_scalar(p[i], u[i], int(w[i]), table)
                p[i] = p_i
                tau_line[i] = hysteresis_torque_scalar(tau_line[i], p_i, bp)  # eq. (10a) seed 001
    # the torque acting on the wheel: the pad's friction now (eqs. (24)-(25) seed 004), at the start speeds
    tau = st[TAU_BRAKE]
    if k[PAD] != 0.0:
        for i in range(n):
            omega = (v[i] - s[i]) * k[INV_R]
            mu_d = pad_friction_scalar(omega, st[TEMP, i], pp)                            # eq. (25), seed 004
            tau_i = tau_line[i] * mu_d * k[INV_PAD_NOMINAL]                         # eq. (24), seed 004
            st[MU_PAD, i] = mu_d
            tau[i] = tau_i
            st[TEMP, i] = disc_temperature_scalar(st[TEMP, i], tau_i, omega, k[DT], pp)
    else:
        for i in range(n):
            tau[i] = tau_line[i]
    # forces at the start of the step: couplers (Φ = 0 ahead of the first and behind the last car) ...
    phi = np.zeros(n + 1)
    for i in range(n - 1):                                          # coupler i: cars i, i + 1
        phi[i + 1] = coupler_force_scalar(coupler_extension_scalar(x[i], x[i + 1], k[PITCH]),
                                    coupler_rate_scalar(v[i], v[i + 1]), cc)
    # ... then per car: other forces, adhesion, and the integrator step
    st[V_PREV, :] = v
    v_top = 0.0
    for i in range(n):
        v_i = v[i]
        f_other = other_force_scalar(v_i, phi[i], phi[i + 1], tr[STATIC, i], k[C1], car[C2, i])
        s_reg = s[i] + S_EPS_MPS                                   # > 0 (see S_EPS_MPS)
        sigma = slip_ratio_unclipped_scalar(s_reg, v_i)
        # f = μN, eq. (1a) seed 001
        f = _mu(tr[THETA1, i], tr[THETA2, i], tr[THETA3, i], sigma, v_i, k, ap) * car[NORMAL, i]
        x_i, v_new, s_new = integrate_car_scalar(x[i], v_i, s[i], s_reg, f, f_other, tau[i], car[INV_M, i],
                                       k[R_OVER_J], car[GAIN, i], k[INV_DT], car[INV_M_DT, i], k[DT])
        x[i], v[i], s[i] = x_i, v_new, s_new
        st[F_OTHER, i] = f_other
        if s_new > st[S_MAX, i]:
            st[S_MAX, i] = s_new
        if i == 0 or v_new > v_top:
            v_top = v_new
    k[BUDGET] -= k[DT] * v_top                                      # the farthest any car moved
    if k[BUDGET] <= 0.0:
        return True, n_bad
    for i in range(n):                                              # θ(x) on the current intervals
        if tr[LIVE, i] != 0.0:
            dx = x[i] - tr[ANCHOR, i]
            tr[THETA1, i] = tr[TA1, i] + tr[DTH1, i] * dx
            tr[THETA2, i] = tr[TA2, i] + tr[DTH2, i] * dx
            tr[THETA3, i] = tr[TA3, i] + tr[DTH3, i] * dx
    return False, n_bad


step_cars = _compiled(step_cars)
readings = _compiled(sensor_readings)


def warm_up(st: np.ndarray, tr: np.ndarray, car: np.ndarray, k: np.ndarray, recs: tuple) -> None:
    """Load (or compile) the machine code of `step_cars` and `readings` for the plant's usual input types
    now, on copies of its arrays, so that a run's first step does not pay for it (~0.2 s from the cache,
    a few seconds the first time)."""
    if not getattr(step_cars, "signatures", True):          # compiled and not loaded yet
        n = st.shape[1]
        step_cars(st.copy(), tr.copy(), car, k.copy(), recs, np.zeros(n), np.zeros(n, dtype=np.int64),
                  np.zeros(n))
        z = np.zeros(n)
        readings(z, z, z, z, 1.0, np.ones(3), np.ones(3), np.zeros((3, n)), np.zeros((3, n)))
