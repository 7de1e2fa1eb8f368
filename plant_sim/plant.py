"""The plant: n cars with couplers, wheelsets, brakes and sensors on a track, stepped at a fixed dt.

A thin fixed-step integrator around the pure physics of `adhesion`, `brake` and `dynamics`
(python-control's NonlinearIOSystem style: state, inputs and params in, next state out).

Integrator (one step of dt = dt_us, 1 ms by default):
  * cylinder pressure: exact for the valve inputs held over the step (constant-rate valves, then clip);
  * brake torque: the algebraic play operator (10a) of seed 001 at the new pressure;
  * car speed v and wheel slip speed s = v − rω: linearly-implicit (Rosenbrock/W-) Euler. The slip
    dynamics ṡ = (F − f)/M − (r² f − r τ)/J are stiff at low speed (the slope df/ds = N μ'(σ)/v grows as
    v → 0, and μ ∝ √σ makes it unbounded at σ = 0). The adhesion force is linearised over the step by its
    chord f(s) ≈ c·s with c = f(s_n)/s_n ≥ 0, so s_{n+1} = s_n + dt ṡ_n / (1 + dt (1/M + r²/J) c): stable
    for any c, first-order accurate, monotone towards the equilibrium, exact at it. v takes the same
    linearised force, so v and ω stay consistent.
  * position x: semi-implicit (symplectic) Euler with the new v, which keeps the coupler oscillations
    stable at dt = 1 ms (highest mode ω·dt ≈ 0.03).
  * standstill: a car whose speed would cross zero stops at v = 0 (brakes and resistances cannot reverse
    motion; rolling backwards is not modelled); the slip speed is clipped to [0, v], i.e. 0 ≤ ω ≤ v/r,
    a locked wheel has ω = 0 and s = v. A braked car at rest stays at rest: the chord slope is huge at
    s ≈ 0, which makes the linearised adhesion the static (rolling-constraint) force.
tests/plant/test_plant_integrator.py checks the step against a reference at dt = 0.1 ms,
tests/plant/test_plant_regression.py pins a trajectory of the default train.

Why the step is scalar, against the style guide's "vectorise over cars with numpy": at n ≤ 8 cars a
numpy call costs its fixed overhead (~0.45 µs) whatever the array size, and the vectorised step made ~62 of
them: 37–40 µs per step on its own, 50–60 µs inside the lockstep HIL, which then ran the default scenario
at 8–9.5x real time, short of the 10x acceptance point. The step is therefore a loop over the cars calling
scalar functions on Python floats (the `*_scalar` functions of `brake`, `dynamics`, `adhesion` and
`integrate_car_scalar` below): ~16 µs per step on its own, ~24 µs in the HIL (11–12x real time), with
results bit-identical to the vectorised step's (same equations, same order of operations). Each equation
has this one implementation; the array functions of those modules wrap it (`plant_sim.elementwise`) for
tests and for `truth()`, which runs every 10 ms. What the step still spends above a fully inlined loop
(~12 µs) is Python's call overhead, ~60 calls a step: the price of keeping one function per equation.
The state is kept as lists of Python floats and turned into numpy arrays only by `sense()` and `truth()`.

Time is an integer count of microseconds, t_us = n_steps · dt_us.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from plant_sim.adhesion import mu, mu_scalar, slip_ratio, slip_ratio_unclipped_scalar
from plant_sim.adhesion import mu_opt as _mu_opt
from plant_sim.adhesion import sigma_opt as _sigma_opt
from plant_sim.brake import (
    WSP_STATES,
    cylinder_lag_scalar,
    cylinder_pressure_scalar,
    disc_temperature_scalar,
    hysteresis_torque_scalar,
    lag_factor,
    pad_friction_scalar,
    sanitize_valve_cmd,
    sanitize_wsp_valve,
    valve_table,
)
from plant_sim.dynamics import (
    car_constants,
    coupler_extension,
    coupler_extension_scalar,
    coupler_force,
    coupler_force_scalar,
    coupler_rate,
    coupler_rate_scalar,
    grade_curvature_resistance_scalar,
    other_force_scalar,
    slip_rate_scalar,
)
from plant_sim.errors import PlantConfigError
from plant_sim.params import PlantParams
from plant_sim.sensors import SensorModel, Sensors
from plant_sim.track import Track

# Adhesion is evaluated at s + S_EPS_MPS (chosen): the chord slope f/s is then finite and, at s = 0,
# very large (μ ∝ √s), so a braked car at rest is held by the static force the linearised step finds
# (up to τ/r) instead of creeping off and back to 0 every other step. The bias is ≲ 50 N per car on a
# free-rolling wheel, against c0 = 800 N of rolling resistance.
S_EPS_MPS = 1e-9


def integrate_car_scalar(x_m: float, v_mps: float, s_mps: float, s_reg_mps: float, f_N: float,
                         f_other_N: float, tau_Nm: float, inv_mass_per_kg: float, r_over_J: float,
                         slip_gain_per_kg: float, inv_dt_per_s: float, inv_mass_dt: float,
                         dt_s: float) -> tuple[float, float, float]:
    """One integrator step of one car (module docstring): (x [m], v [m/s], s [m/s]) at the end of the step.

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
    # (max/min written out, `b if b > a else a` = max(a, b): the builtins cost ~0.1–0.25 µs a call)
    v_new = v_mps + (f_other_N - f_new) * inv_mass_dt
    v_new = 0.0 if 0.0 > v_new else v_new
    s_new = s_mps + ds
    s_new = 0.0 if 0.0 > s_new else s_new
    s_new = v_new if v_new < s_new else s_new                      # 0 ≤ s ≤ v, i.e. 0 ≤ ω ≤ v/r
    return x_m + v_new * dt_s, v_new, s_new                        # ẋ = v at the new v: symplectic Euler


class TruthSnapshot(NamedTuple):
    """The plant's raw state at one instant, per car (lists of floats as the step holds them)."""

    x: list          # car centre position [m]
    v_prev: list     # speed one step earlier [m/s] (for v̇)
    v: list          # speed [m/s]
    s: list          # slip speed v − rω [m/s]
    p: list          # cylinder pressure [Pa]
    tau: list        # brake torque [N m]
    f_other: list    # every force on the car but adhesion, over the last step [N]
    u: list          # EP valve command applied over the last step [-]
    w: list          # WSP dump valve state applied over the last step (0 FILL, 1 HOLD, 2 VENT)
    theta: list      # adhesion curve parameters (θ1, θ2, θ3) at the car
    s_max: list      # largest slip speed v − rω over EVERY integration step since the start [m/s]
    p_set: list      # cylinder pressure set-point applied over the last step [Pa] ("lag" model; else 0)
    tau_brake: list  # brake torque acting on the wheel over the last step [N m]: tau, times μ_d/μ_nominal
    #                  with a variable pad friction (eq. (24) seed 004)
    mu_pad: list     # pad/disc friction coefficient μ_d over the last step (eq. (25) seed 004); [] without
    temp_rise: list  # disc temperature rise T_d [K] at the end of the last step; [] without a pad model


class Plant:
    """The train on its track. Car 1 is the leading car; inputs and outputs are arrays, one entry per car."""

    def __init__(self, params: PlantParams, track: Track, v0_mps: float, x0_m: float = 0.0,
                 seed: int = 0) -> None:
        if not (math.isfinite(v0_mps) and v0_mps >= 0.0):
            raise PlantConfigError(f"Plant: v0_mps must be finite and >= 0, got {v0_mps!r}")
        if not (math.isfinite(x0_m) and abs(x0_m) < 1e9):   # float spacing stays ≪ coupler travel
            raise PlantConfigError(f"Plant: x0_m must be finite and within ±1e9 m, got {x0_m!r}")
        if not isinstance(seed, int | np.integer) or isinstance(seed, bool) or seed < 0:
            raise PlantConfigError(f"Plant: seed must be an int >= 0, got {seed!r}")
        self.params = params
        self.track = track
        tp = params.train
        n = params.n_cars
        self._n = n
        self._tp, self._ap, self._bp = tp, params.adhesion, params.brake
        self._dt_us = params.dt_us
        self._dt = dt = params.dt_us * 1e-6
        self._inv_dt = 1.0 / dt
        self._valve_table = valve_table(params.brake, dt)
        self._lag = params.brake.pressure_model == "lag"      # cylinder follows CylPressureSet, eq. (4)
        self._phi = lag_factor(params.brake, dt)
        self._cc = cc = car_constants(tp)
        # per car, what the step needs besides the track: (1/m, 1/M + r²/J, dt/m, N = m g, Davis c2)
        self._car_k = tuple(zip(cc.inv_mass_per_kg, cc.slip_gain_per_kg,
                                [im * dt for im in cc.inv_mass_per_kg], cc.normal_force_N, cc.c2_Ns2_per_m2,
                                strict=True))
        self._n_steps = 0
        self.bad_inputs = 0                     # non-finite valve commands and invalid WSP states received

        # state, lists of Python floats (one per car): car centre x, speed v, wheel slip speed s = v − rω,
        # cylinder pressure p, brake torque τ
        self._x = [float(x0_m) - tp.car_pitch_m * float(i) for i in range(n)]
        self._v = [float(v0_mps)] * n
        self._v_prev = self._v                  # for v̇ of the last step
        self._s = [0.0] * n                     # rolling: ω = v/r
        self._p = [0.0] * n
        self._tau = [0.0] * n
        self._u_list: list = [0.0] * n          # inputs of the last step, as applied
        self._ps_list: list = [0.0] * n         # pressure set-points of the last step ("lag" model)
        self._s_max: list = [0.0] * n           # running max of s over every step (seed 001: s ≤ s̄ always)
        self._w_list: list = [0] * n
        self._shape = (n,)
        self._f_other = [0.0] * n               # every force but adhesion over the last step
        # variable pad friction (seed 004 eqs. (24)-(25)): friction coefficient and disc temperature rise
        self._pad = params.pad
        self._mu_pad: list = [params.pad.mu_nominal] * n if params.pad else []
        self._temp: list = [params.pad.initial_temp_rise_K] * n if params.pad else []
        self._tau_brake: list = self._tau
        self._sensors = SensorModel(params.sensors, int(seed))
        self._refresh_track()

    # ------------------------------------------------------------------------------------------------- track
    def _refresh_track(self) -> None:
        """Look the track up at the cars' positions and cache what stays constant until a car meets a knot."""
        x = np.array(self._x)
        smp = self.track.sample(x)
        self._theta = [tuple(row) for row in smp.theta.tolist()]       # θ = (θ1, θ2, θ3) per car
        self._sin = smp.sin_grade
        cc, g = self._cc, self._tp.g_mps2
        # −(c0 + f_c), eqs. (4)–(5) seed 003, joined to the car's constants for the step
        static_force = [-(cc.c0_N + grade_curvature_resistance_scalar(m, sg, dc, g))
                        for m, sg, dc in zip(cc.mass_kg, smp.sin_grade.tolist(), smp.curvature_deg.tolist(),
                                             strict=True)]
        self._car = [(static,) + k for static, k in zip(static_force, self._car_k, strict=True)]
        self._budget_m = float(np.min(smp.next_change_m - x))          # > 0: no car on a new interval before
        # θ is affine in x on each interval: for the cars inside a smooth blend it is updated every step,
        # θ = θ_anchor + dθ/dx · (x − anchor), as `Track.sample` does
        self._theta_live = [
            (i, xa, *th, *dth) for i, (xa, th, dth) in enumerate(zip(
                smp.anchor_m.tolist(), smp.theta_anchor.tolist(), smp.dtheta_per_m.tolist(), strict=True))
            if any(dth)]

    # ------------------------------------------------------------------------------------------------- step
    @property
    def t_us(self) -> int:
        """Simulated time [µs]."""
        return self._n_steps * self._dt_us

    @property
    def lead_position_m(self) -> float:
        """Track position of car 1's front [m] (the truth's x of car 1)."""
        return self._x[0]

    @property
    def n_cars(self) -> int:
        return self._n

    def step(self, valve_cmd: np.ndarray, wsp_valve: np.ndarray,
             pressure_set: np.ndarray | None = None) -> None:
        """Advance one dt_us with per-car EP valve openings (float in [−1, 1]) and WSP valve states (0/1/2).

        Out-of-range openings are clipped; non-finite ones are taken as 0 (valve closed, pressure held)
        and invalid WSP states as 0 (FILL, dump valve inactive), both counted in `bad_inputs`.
        With BrakeParams.pressure_model = "lag" the cylinders follow `pressure_set` [Pa] per car instead
        (first-order lag, eq. (4) seed 001; `brake.cylinder_lag_scalar`) and valve_cmd is not used.
        """
        u = np.asarray(valve_cmd, dtype=float)
        w = np.asarray(wsp_valve)
        if u.shape != self._shape or w.shape != self._shape:
            raise PlantConfigError(f"Plant.step: need {self._n} valve commands and WSP states, "
                                   f"got shapes {u.shape} and {w.shape}")
        u_list, w_list = u.tolist(), w.tolist()
        # inputs equal to the last ones applied are valid (the controllers update them every 10 ms)
        if u_list != self._u_list and not (-1.0 <= min(u_list) and max(u_list) <= 1.0
                                           and math.isfinite(sum(u_list))):  # NaN too
            u, n_bad = sanitize_valve_cmd(u)
            self.bad_inputs += n_bad
            u_list = u.tolist()
        if w.dtype.kind not in "iu" or (w_list != self._w_list and not WSP_STATES.issuperset(w_list)):
            w, n_bad = sanitize_wsp_valve(w)
            self.bad_inputs += n_bad
            w_list = w.tolist()
        if self._lag:
            ps = [0.0] * self._n if pressure_set is None else np.asarray(pressure_set, dtype=float).tolist()
            if len(ps) != self._n:
                raise PlantConfigError(f"Plant.step: need {self._n} pressure set-points, got {len(ps)}")
            self._ps_list = ps
            phi, p_max, bp = self._phi, self._bp.p_max_Pa, self._bp
            p, tau = [], []
            for p_i, tau_i, ps_i, w_i in zip(self._p, self._tau, ps, w_list, strict=True):
                p_i = cylinder_lag_scalar(p_i, ps_i, w_i, phi, p_max)   # eq. (4)-(5) seed 001
                p.append(p_i)
                tau.append(hysteresis_torque_scalar(tau_i, p_i, bp))    # eq. (10a) seed 001
        elif any(u_list) or any(w_list):                                # else p and τ stay as they are
            table, bp = self._valve_table, self._bp
            p, tau = [], []
            for p_i, tau_i, u_i, w_i in zip(self._p, self._tau, u_list, w_list, strict=True):
                p_i = cylinder_pressure_scalar(p_i, u_i, w_i, table)
                p.append(p_i)
                tau.append(hysteresis_torque_scalar(tau_i, p_i, bp))    # eq. (10a) seed 001
        else:
            p, tau = self._p, self._tau

        x, v, s = self._x, self._v, self._s
        tau_line = tau                         # the hysteresis state: torque at the nominal pad friction
        if self._pad is not None:
            tau = self._pad_step(tau, v, s)
        # forces at the start of the step: couplers (Φ = 0 ahead of the first and behind the last car) ...
        cc = self._cc
        pitch = cc.car_pitch_m
        phi = [0.0]
        phi += [coupler_force_scalar(coupler_extension_scalar(x_f, x_r, pitch), coupler_rate_scalar(v_f, v_r),
                                     cc)
                for x_f, x_r, v_f, v_r in zip(x, x[1:], v, v[1:], strict=False)]   # coupler i: cars i, i+1
        phi.append(0.0)
        # ... then per car: other forces, adhesion, and the integrator step
        ap, c1, r_over_J, inv_dt, dt = self._ap, cc.c1_Ns_per_m, cc.r_over_J, self._inv_dt, self._dt
        x_new, v_new, s_new, f_others = [], [], [], []
        for x_i, v_i, s_i, tau_i, theta_i, phi_f, phi_r, (static, inv_m, gain, inv_m_dt, normal, c2) in zip(
                x, v, s, tau, self._theta, phi, phi[1:], self._car, strict=False):   # phi: n + 1 entries
            f_other = other_force_scalar(v_i, phi_f, phi_r, static, c1, c2)
            s_reg = s_i + S_EPS_MPS                                     # > 0 (see S_EPS_MPS)
            # f = μN, eq. (1a) seed 001
            f = mu_scalar(theta_i, slip_ratio_unclipped_scalar(s_reg, v_i), v_i, ap) * normal
            x_i, v_i, s_i = integrate_car_scalar(x_i, v_i, s_i, s_reg, f, f_other, tau_i, inv_m, r_over_J,
                                                 gain, inv_dt, inv_m_dt, dt)
            x_new.append(x_i)
            v_new.append(v_i)
            s_new.append(s_i)
            f_others.append(f_other)

        self._x, self._v_prev, self._v, self._s = x_new, v, v_new, s_new
        self._s_max = list(map(max, self._s_max, s_new))
        self._p, self._tau, self._tau_brake, self._f_other = p, tau_line, tau, f_others
        self._u_list, self._w_list = u_list, w_list
        self._n_steps += 1
        self._budget_m -= dt * max(v_new)                               # the farthest any car moved
        if self._budget_m <= 0.0:
            self._refresh_track()
        elif self._theta_live:                                          # θ(x) on the current intervals
            theta = self._theta
            for i, xa, a1, a2, a3, d1, d2, d3 in self._theta_live:
                dx = x_new[i] - xa
                theta[i] = (a1 + d1 * dx, a2 + d2 * dx, a3 + d3 * dx)

    def _pad_step(self, tau_line: list, v: list, s: list) -> list:
        """Brake torques [N m] with the pad's friction now (eq. (24) seed 004: τ = τ_line μ_d/μ_nominal,
        μ_d from eq. (25) at the wheel's speed and the disc's temperature); advances the temperatures."""
        pp, dt, inv_r = self._pad, self._dt, 1.0 / self._cc.r_m
        ratio = 1.0 / pp.mu_nominal
        mus, temps, taus = [], [], []
        for tau_i, v_i, s_i, temp_i in zip(tau_line, v, s, self._temp, strict=True):
            omega = (v_i - s_i) * inv_r
            mu_d = pad_friction_scalar(omega, temp_i, pp)                    # eq. (25), seed 004
            tau_i = tau_i * mu_d * ratio                                     # eq. (24), seed 004
            mus.append(mu_d)
            taus.append(tau_i)
            temps.append(disc_temperature_scalar(temp_i, tau_i, omega, dt, pp))
        self._mu_pad, self._temp = mus, temps
        return taus

    # ----------------------------------------------------------------------------------------------- outputs
    @property
    def stopped(self) -> bool:
        """Every car at standstill."""
        return not any(self._v)

    def _accel(self) -> np.ndarray:
        return (np.array(self._v) - np.array(self._v_prev)) * (1.0 / self._dt)

    def _omega(self) -> np.ndarray:
        return (np.array(self._v) - np.array(self._s)) * (1.0 / self._cc.r_m)

    def sense(self) -> Sensors:
        """What the cars' sensors report now (noisy, quantised, seeded)."""
        return self._sensors.read(self._omega(), np.array(self._p), self._accel(), self._sin, self._tp.g_mps2)

    def snapshot(self) -> TruthSnapshot:
        """The raw state behind `truth()`, cheap enough to take every sample of a run.

        The step replaces its state lists rather than changing them, so they are shared, not copied;
        θ is copied because a blend updates it in place. `truth_series` turns snapshots into truth.
        """
        return TruthSnapshot(self._x, self._v_prev, self._v, self._s, self._p, self._tau, self._f_other,
                             self._u_list, self._w_list, list(self._theta), self._s_max, self._ps_list,
                             self._tau_brake, self._mu_pad, self._temp)

    def truth_series(self, snaps: Sequence[TruthSnapshot]) -> dict[str, np.ndarray]:
        """Ground truth for a sequence of snapshots: the keys of `truth()`, arrays (k, n) per car and
        (k, n − 1) per coupler, derived in one pass at the end of a run rather than every sample."""
        ap, cc = self._ap, self._cc
        cols = list(zip(*snaps, strict=True))
        x, v_prev, v, s, p, _, f_other, u, w, theta, s_max, p_set = (np.array(col) for col in cols[:12])
        tau = np.array(cols[12])                                # the torque acting on the wheel
        pad = {}
        if self._pad is not None:
            pad = {"mu_pad": np.array(cols[13], dtype=float),       # μ_d, eq. (25) seed 004
                   "disc_temp_rise_K": np.array(cols[14], dtype=float)}
        sigma = slip_ratio(s, v)
        dl = coupler_extension(x, cc)
        accel = (v - v_prev) * (1.0 / self._dt)
        return {
            "x_m": x,
            "v_mps": v,
            "a_mps2": accel,
            "omega_rad_s": (v - s) * (1.0 / cc.r_m),
            "slip_speed_mps": s,
            # running max of s over every integration step since the start (not only these samples)
            "slip_speed_max_mps": s_max.astype(float),
            "slip_ratio": sigma,
            "mu": mu(theta, sigma, v, ap),
            "mu_opt": _mu_opt(theta, v, ap),
            "sigma_opt": _sigma_opt(theta, v, ap),
            "p_Pa": p.astype(float),
            "tau_Nm": tau.astype(float),
            "p_set_Pa": p_set.astype(float),        # "lag" model: CylPressureSet as applied; else 0
            "valve_cmd": np.clip(u.astype(float), -1.0, 1.0),
            "wsp_valve": w.astype(np.int64),
            # the adhesion force that moved the car over the last step, F_other − m v̇ (eq. (3) seed 003);
            # at standstill it is the static force holding the car, not the linearised f
            "brake_force_N": f_other - np.array(cc.mass_kg) * accel,
            "coupler_dl_m": dl,
            "coupler_force_N": coupler_force(dl, coupler_rate(v, cc), cc),
            **pad,
        }

    def truth(self) -> dict[str, np.ndarray]:
        """Ground truth per car (and per coupler) now, fresh arrays."""
        return {key: series[0] for key, series in self.truth_series([self.snapshot()]).items()}
