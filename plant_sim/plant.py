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
    s = 0, which makes the linearised adhesion the static (rolling-constraint) force.
tests/plant/test_plant_integrator.py checks the step against a reference at dt = 0.1 ms.

Time is an integer count of microseconds, t_us = n_steps · dt_us.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plant_sim.adhesion import mu_cols, slip_ratio, slip_ratio_unclipped
from plant_sim.adhesion import mu_opt as _mu_opt
from plant_sim.adhesion import sigma_opt as _sigma_opt
from plant_sim.brake import (
    WSP_STATES,
    cylinder_pressure_step,
    hysteresis_torque,
    sanitize_valve_cmd,
    sanitize_wsp_valve,
    valve_table,
)
from plant_sim.dynamics import (
    CarConstants,
    car_constants,
    coupler_extension,
    coupler_force,
    coupler_rate,
    grade_curvature_resistance,
    other_forces,
    slip_rate,
)
from plant_sim.errors import PlantConfigError
from plant_sim.params import PlantParams, as_arrays
from plant_sim.sensors import SensorModel, Sensors
from plant_sim.track import Track

S_EPS_MPS = 1e-9  # keeps the chord slope f/s finite at s = 0 (where f = 0 too), chosen


@dataclass(frozen=True, slots=True, eq=False)
class StepConstants:
    """What the integrator needs besides the car constants, as arrays (see `as_arrays`)."""

    dt_s: np.ndarray               # 0-d
    inv_dt_per_s: np.ndarray       # 0-d
    inv_mass_dt: np.ndarray        # (n,) dt / m
    s_eps_mps: np.ndarray          # 0-d S_EPS_MPS
    zero: np.ndarray               # 0-d 0.0


def step_constants(dt_s: float, cc: CarConstants) -> StepConstants:
    return StepConstants(dt_s=np.array(dt_s), inv_dt_per_s=np.array(1.0 / dt_s),
                         inv_mass_dt=cc.inv_mass_per_kg * dt_s, s_eps_mps=np.array(S_EPS_MPS),
                         zero=np.array(0.0))


def semi_implicit_speeds(v: np.ndarray, s: np.ndarray, f: np.ndarray, f_other: np.ndarray, tau: np.ndarray,
                         cc: CarConstants, sc: StepConstants) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One linearly-implicit Euler step of car speed v and slip speed s (module docstring).

    f is the adhesion force at (v, s), f_other every other force on the car, tau the brake torque over
    the step. Returns (v, s) at the end of the step and the adhesion force applied over it.
    """
    s_dot = slip_rate(f_other, f, tau, cc)                          # explicit ṡ, eq. (3) seed 001
    chord = f / (s + sc.s_eps_mps)                                  # f(s) ≈ c·s, c ≥ 0
    ds = s_dot / (sc.inv_dt_per_s + cc.slip_gain_per_kg * chord)    # (1 + dt (1/M + r²/J) c) Δs = dt ṡ
    f_new = f + chord * ds                                          # adhesion force over the step
    # v̇ = (F_other − f)/m, eq. (3) seed 003; a car cannot reverse
    v_new = np.maximum(v + (f_other - f_new) * sc.inv_mass_dt, sc.zero)
    s_new = np.minimum(np.maximum(s + ds, sc.zero), v_new)          # 0 ≤ ω ≤ v/r
    return v_new, s_new, f_new


class Plant:
    """The train on its track. Car 1 is the leading car; inputs and outputs are arrays, one entry per car."""

    def __init__(self, params: PlantParams, track: Track, v0_mps: float, x0_m: float = 0.0,
                 seed: int = 0) -> None:
        if not (math.isfinite(v0_mps) and v0_mps >= 0.0):
            raise PlantConfigError(f"Plant: v0_mps must be finite and >= 0, got {v0_mps!r}")
        if not math.isfinite(x0_m):
            raise PlantConfigError(f"Plant: x0_m must be finite, got {x0_m!r}")
        if not isinstance(seed, int | np.integer) or isinstance(seed, bool) or seed < 0:
            raise PlantConfigError(f"Plant: seed must be an int >= 0, got {seed!r}")
        self.params = params
        self.track = track
        tp = params.train
        n = params.n_cars
        self._n = n
        self._tp, self._ap = tp, params.adhesion
        self._bpa, self._apa = as_arrays(params.brake), as_arrays(params.adhesion)
        self._valve_table = valve_table(params.brake, params.dt_us * 1e-6)
        self._cc = cc = car_constants(tp)
        self._sc = step_constants(params.dt_us * 1e-6, cc)
        self._dt_us = params.dt_us
        self._dt = params.dt_us * 1e-6
        self._n_steps = 0
        self.bad_inputs = 0                     # non-finite valve commands and invalid WSP states received

        # state: car centre x, speed v, wheel slip speed s = v − rω, cylinder pressure p, brake torque τ
        self._x = x0_m - tp.car_pitch_m * np.arange(n, dtype=float)
        self._v = np.full(n, float(v0_mps))
        self._v_prev = self._v                  # for v̇ of the last step
        self._s = np.zeros(n)                   # rolling: ω = v/r
        self._p = np.zeros(n)
        self._tau = np.zeros(n)
        self._u_list: list = [0.0] * n          # inputs of the last step, as applied
        self._w_list: list = [0] * n
        self._shape = (n,)
        self._f = np.zeros(n)                   # adhesion force applied over the last step
        self._ones = np.ones(n)
        self._sensors = SensorModel(params.sensors, int(seed))
        self._refresh_track()

    # ------------------------------------------------------------------------------------------------- track
    def _refresh_track(self) -> None:
        """Look the track up at the cars' positions and cache what stays constant until a car meets a knot."""
        smp = self.track.sample(self._x)
        self._theta = tuple(np.ascontiguousarray(smp.theta.T))         # θ1, θ2, θ3, each (n,)
        self._sin = smp.sin_grade
        f_c = grade_curvature_resistance(self._cc.mass_kg, smp.sin_grade, smp.curvature_deg, self._tp.g_mps2)
        self._static_force = -(self._cc.c0_N + f_c)                    # −(c0 + f_c), eqs. (4)–(5) seed 003
        self._budget_m = float(np.min(smp.next_change_m - self._x))    # > 0: no car on a new interval before
        # θ is affine in x on each interval: inside a smooth blend it is updated every step from these
        self._theta_live = bool(np.any(smp.dtheta_per_m))
        self._theta_anchor = np.ascontiguousarray(smp.theta_anchor.T)  # (3, n)
        self._dtheta = np.ascontiguousarray(smp.dtheta_per_m.T)         # (3, n)
        self._anchor_m = smp.anchor_m

    # ------------------------------------------------------------------------------------------------- step
    @property
    def t_us(self) -> int:
        """Simulated time [µs]."""
        return self._n_steps * self._dt_us

    @property
    def n_cars(self) -> int:
        return self._n

    def step(self, valve_cmd: np.ndarray, wsp_valve: np.ndarray) -> None:
        """Advance one dt_us with the EP valve openings (float in [−1, 1]) and WSP valve states (0/1/2) per car.

        Out-of-range openings are clipped; non-finite ones are taken as 0 (valve closed, pressure held)
        and invalid WSP states as 0 (FILL, dump valve inactive), both counted in `bad_inputs`.
        """
        u = np.asarray(valve_cmd, dtype=float)
        w = np.asarray(wsp_valve)
        if u.shape != self._shape or w.shape != self._shape:
            raise PlantConfigError(f"Plant.step: need {self._n} valve commands and WSP states, "
                                   f"got shapes {u.shape} and {w.shape}")
        u_list, w_list = u.tolist(), w.tolist()                         # checked in Python: cheaper at n ≈ 6
        if not (-1.0 <= min(u_list) and max(u_list) <= 1.0 and math.isfinite(math.fsum(u_list))):
            u, n_bad = sanitize_valve_cmd(u)
            self.bad_inputs += n_bad
            u_list = u.tolist()
        if w_list != self._w_list:                                      # validate only when it changes
            if not (w.dtype.kind in "iu" and WSP_STATES.issuperset(w_list)):
                w, n_bad = sanitize_wsp_valve(w)
                self.bad_inputs += n_bad
                w_list = w.tolist()
        cc, sc = self._cc, self._sc
        if any(u_list) or any(w_list):                                  # else p and τ stay as they are
            p = cylinder_pressure_step(self._p, u, w, sc.dt_s, self._bpa, self._valve_table)
            tau = hysteresis_torque(self._tau, p, self._bpa)            # eq. (10a) seed 001
        else:
            p, tau = self._p, self._tau

        # forces at the start of the step
        x, v, s = self._x, self._v, self._s
        phi = coupler_force(coupler_extension(x, cc), coupler_rate(v, cc), cc)
        f_other = other_forces(v, phi, self._static_force, cc)
        t1, t2, t3 = self._theta
        f = mu_cols(t1, t2, t3, slip_ratio_unclipped(s, v), v, self._apa) * cc.normal_force_N  # f = μN
        v_new, s_new, f_new = semi_implicit_speeds(v, s, f, f_other, tau, cc, sc)
        x_new = x + v_new * sc.dt_s                                     # symplectic Euler

        self._x, self._v_prev, self._v, self._s = x_new, v, v_new, s_new
        self._p, self._tau, self._f = p, tau, f_new
        self._u_list, self._w_list = u_list, w_list
        self._n_steps += 1
        self._budget_m -= self._dt * self._ones.dot(v_new)              # ≥ the farthest any car moved
        if self._budget_m <= 0.0:
            self._refresh_track()
        elif self._theta_live:                                          # θ(x) on the current intervals
            self._theta = tuple(self._theta_anchor + self._dtheta * (x_new - self._anchor_m))

    # ----------------------------------------------------------------------------------------------- outputs
    @property
    def stopped(self) -> bool:
        """Every car at standstill."""
        return not self._v.any()

    def _accel(self) -> np.ndarray:
        return (self._v - self._v_prev) * (1.0 / self._dt)

    def _omega(self) -> np.ndarray:
        return (self._v - self._s) * (1.0 / self._cc.r_m)

    def sense(self) -> Sensors:
        """What the cars' sensors report now (noisy, quantised, seeded)."""
        return self._sensors.read(self._omega(), self._p, self._accel(), self._sin, self._tp.g_mps2)

    def truth(self) -> dict[str, np.ndarray]:
        """Ground truth per car (and per coupler), copies."""
        tp, ap = self._tp, self._ap  # noqa: F841
        x, v, s = self._x, self._v, self._s
        theta = np.column_stack(self._theta)
        sigma = slip_ratio(s, v)
        dl = coupler_extension(x, self._cc)
        return {
            "x_m": x.copy(),
            "v_mps": v.copy(),
            "a_mps2": self._accel(),
            "omega_rad_s": self._omega(),
            "slip_speed_mps": s.copy(),
            "slip_ratio": sigma,
            "mu": mu_cols(*self._theta, sigma, v, ap),
            "mu_opt": _mu_opt(theta, v, ap),
            "sigma_opt": _sigma_opt(theta, v, ap),
            "p_Pa": self._p.copy(),
            "tau_Nm": self._tau.copy(),
            "valve_cmd": np.clip(np.array(self._u_list, dtype=float), -1.0, 1.0),
            "wsp_valve": np.array(self._w_list, dtype=np.int64),
            "brake_force_N": self._f.copy(),
            "coupler_dl_m": dl,
            "coupler_force_N": coupler_force(dl, coupler_rate(v, self._cc), self._cc),
        }
