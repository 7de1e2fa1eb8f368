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
tests/plant/test_integrator.py checks the step against a reference at dt = 0.1 ms,
tests/plant/test_regression.py pins a trajectory of the default train.

Why the step is compiled, against the style guide's "vectorise over cars with numpy": at n ≤ 8 cars a
numpy call costs its fixed overhead (~0.45 µs) whatever the array size, and a vectorised step made ~62 of
them (37–40 µs a step). The per-car scalar functions on Python floats (the `*_scalar` functions of
`brake`, `dynamics`, `adhesion`) took ~16 µs a step, 25 % of a lockstep run's wall. `plant_sim.kernel`
compiles those same functions into one step over all cars with numba, bit-identical (same equations,
same order of operations): ~1 µs a step. The state lives in a few float arrays (rows named in
`plant_sim.kernel`); `snapshot()` copies it out as lists of Python floats, `sense()` and `truth()` as
numpy arrays.

Time is an integer count of microseconds, t_us = n_steps · dt_us.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from plant_sim import kernel
from plant_sim.adhesion import mu, slip_ratio
from plant_sim.adhesion import mu_opt as _mu_opt
from plant_sim.adhesion import sigma_opt as _sigma_opt
from plant_sim.brake import lag_factor, sanitize_wsp_valve, valve_table
from plant_sim.dynamics import (
    car_constants,
    coupler_extension,
    coupler_force,
    coupler_rate,
    grade_curvature_resistance_scalar,
)
from plant_sim.errors import PlantConfigError
from plant_sim.params import PadParams, PlantParams
from plant_sim.sensors import SensorModel, Sensors
from plant_sim.track import Track

_F8, _I8 = np.dtype(np.float64), np.dtype(np.int64)   # the inputs' usual types (dtypes are singletons)
S_EPS_MPS = kernel.S_EPS_MPS                 # adhesion at s + S_EPS_MPS (plant_sim.kernel)
integrate_car_scalar = kernel.integrate_car_scalar   # one car's integrator step (plant_sim.kernel)


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
        self._lag = params.brake.pressure_model == "lag"      # cylinder follows CylPressureSet, eq. (4)
        self._cc = cc = car_constants(tp)
        self._pad = params.pad                  # variable pad friction, seed 004 eqs. (24)-(25), or None
        self._n_steps = 0
        self.bad_inputs = 0                     # non-finite valve commands and invalid WSP states received
        self._shape = (n,)
        k = kernel
        # the state (rows of plant_sim.kernel): car centre x, speed v, wheel slip speed s = v − rω, cylinder
        # pressure p, brake torque τ, ... and the inputs of the last step as applied
        st = self._st = np.zeros((k.N_STATE, n))
        st[k.X] = [float(x0_m) - tp.car_pitch_m * float(i) for i in range(n)]
        st[k.V] = float(v0_mps)
        st[k.V_PREV] = st[k.V]                  # for v̇ of the last step
        if self._pad is not None:
            st[k.MU_PAD] = self._pad.mu_nominal
            st[k.TEMP] = self._pad.initial_temp_rise_K
        # per car, what the step needs besides the track: (1/m, 1/M + r²/J, dt/m, N = m g, Davis c2)
        car = self._car = np.zeros((k.N_CAR, n))
        car[k.INV_M], car[k.GAIN] = cc.inv_mass_per_kg, cc.slip_gain_per_kg
        car[k.INV_M_DT] = [im * dt for im in cc.inv_mass_per_kg]
        car[k.NORMAL], car[k.C2] = cc.normal_force_N, cc.c2_Ns2_per_m2
        ap, bp = params.adhesion, params.brake
        ks = self._k = np.zeros(k.N_SCALAR)
        ks[k.DT], ks[k.INV_DT] = dt, 1.0 / dt
        ks[k.LAG], ks[k.LAG_PHI], ks[k.P_MAX] = float(self._lag), lag_factor(bp, dt), bp.p_max_Pa
        ks[k.PAD] = float(self._pad is not None)
        ks[k.INV_PAD_NOMINAL] = 1.0 / self._pad.mu_nominal if self._pad is not None else 0.0
        ks[k.INV_R] = 1.0 / cc.r_m
        if ap.constant_mu is not None:
            ks[k.ADHESION], ks[k.CONST_MU] = k.ADHESION_CONSTANT, ap.constant_mu
        elif ap.slip_speed_peak is not None:
            ks[k.ADHESION] = k.ADHESION_SLIP_SPEED
            ks[k.MU_PEAK], ks[k.S_PEAK] = ap.slip_speed_peak
            ks[k.MU_SLIDE] = ap.slip_speed_slide_ratio * ap.slip_speed_peak[0]
        else:
            ks[k.ADHESION] = k.ADHESION_THETA
        ks[k.C1], ks[k.R_OVER_J], ks[k.PITCH] = cc.c1_Ns_per_m, cc.r_over_J, cc.car_pitch_m
        self._recs = (k.as_record(bp), k.as_record(valve_table(bp, dt)), k.as_record(cc), k.as_record(ap),
                      k.as_record(self._pad if self._pad is not None else PadParams()))
        self._tr = np.zeros((k.N_TRACK, n))
        self._no_set = np.zeros(n)
        self._sensors = SensorModel(params.sensors, int(seed), kernel.readings)
        self._refresh_track()
        kernel.warm_up(self._st, self._tr, self._car, self._k, self._recs)   # machine code loaded here

    # ------------------------------------------------------------------------------------------------- track
    def _refresh_track(self) -> None:
        """Look the track up at the cars' positions and keep what stays constant until a car meets a knot."""
        k, tr = kernel, self._tr
        x = self._st[k.X].copy()
        smp = self.track.sample(x)
        tr[k.THETA1:k.THETA3 + 1] = smp.theta.T                       # θ = (θ1, θ2, θ3) per car
        self._sin = smp.sin_grade
        cc, g = self._cc, self._tp.g_mps2
        # −(c0 + f_c), eqs. (4)–(5) seed 003, per car
        tr[k.STATIC] = [-(cc.c0_N + grade_curvature_resistance_scalar(m, sg, dc, g))
                        for m, sg, dc in zip(cc.mass_kg, smp.sin_grade.tolist(), smp.curvature_deg.tolist(),
                                             strict=True)]
        self._k[k.BUDGET] = float(np.min(smp.next_change_m - x))       # > 0: no car on a new interval before
        # θ is affine in x on each interval: for the cars inside a smooth blend it is updated every step,
        # θ = θ_anchor + dθ/dx · (x − anchor), as `Track.sample` does
        tr[k.LIVE] = np.any(smp.dtheta_per_m != 0.0, axis=1)
        tr[k.ANCHOR] = smp.anchor_m
        tr[k.TA1:k.TA3 + 1] = smp.theta_anchor.T
        tr[k.DTH1:k.DTH3 + 1] = smp.dtheta_per_m.T

    # ------------------------------------------------------------------------------------------------- step
    @property
    def t_us(self) -> int:
        """Simulated time [µs]."""
        return self._n_steps * self._dt_us

    @property
    def lead_position_m(self) -> float:
        """Track position of car 1's front [m] (the truth's x of car 1)."""
        return float(self._st[kernel.X, 0])

    @property
    def n_cars(self) -> int:
        return self._n

    @property
    def max_slip_mps(self) -> np.ndarray:
        """Largest slip speed v − rω of each car over EVERY step since the start [m/s] (a live view)."""
        return self._st[kernel.S_MAX]

    def step(self, valve_cmd: np.ndarray, wsp_valve: np.ndarray,
             pressure_set: np.ndarray | None = None) -> None:
        """Advance one dt_us with per-car EP valve openings (float in [−1, 1]) and WSP valve states (0/1/2).

        Out-of-range openings are clipped; non-finite ones are taken as 0 (valve closed, pressure held)
        and invalid WSP states as 0 (FILL, dump valve inactive), both counted in `bad_inputs`.
        With BrakeParams.pressure_model = "lag" the cylinders follow `pressure_set` [Pa] per car instead
        (first-order lag, eq. (4) seed 001; `brake.cylinder_lag_scalar`) and valve_cmd is not used.
        """
        u = valve_cmd if valve_cmd.__class__ is np.ndarray and valve_cmd.dtype is _F8 else \
            np.asarray(valve_cmd, dtype=float)
        w = wsp_valve if wsp_valve.__class__ is np.ndarray else np.asarray(wsp_valve)
        if u.shape != self._shape or w.shape != self._shape:
            raise PlantConfigError(f"Plant.step: need {self._n} valve commands and WSP states, "
                                   f"got shapes {u.shape} and {w.shape}")
        if w.dtype is not _I8 and w.dtype.kind not in "iufb":          # not numbers at all
            w, n_bad = sanitize_wsp_valve(w)
            self.bad_inputs += n_bad
        ps = self._no_set
        if self._lag and pressure_set is not None:
            ps = np.asarray(pressure_set, dtype=float)
            if ps.shape != self._shape:
                raise PlantConfigError(f"Plant.step: need {self._n} pressure set-points, got {ps.size}")
        refresh, n_bad = kernel.step_cars(self._st, self._tr, self._car, self._k, self._recs, u, w, ps)
        self.bad_inputs += n_bad
        self._n_steps += 1
        if refresh:
            self._refresh_track()

    # ----------------------------------------------------------------------------------------------- outputs
    @property
    def stopped(self) -> bool:
        """Every car at standstill."""
        return not self._st[kernel.V].any()

    def _accel(self) -> np.ndarray:
        return (self._st[kernel.V] - self._st[kernel.V_PREV]) * (1.0 / self._dt)

    def _omega(self) -> np.ndarray:
        return (self._st[kernel.V] - self._st[kernel.S]) * (1.0 / self._cc.r_m)

    def sense(self) -> Sensors:
        """What the cars' sensors report now (noisy, quantised, seeded)."""
        return self._sensors.read(self._omega(), self._st[kernel.P], self._accel(), self._sin,
                                  self._tp.g_mps2)

    def snapshot(self) -> TruthSnapshot:
        """The raw state behind `truth()`, cheap enough to take every sample of a run: lists of Python
        floats (a copy). `truth_series` turns snapshots into truth."""
        k = kernel
        rows = self._st.tolist()
        pad = self._pad is not None
        return TruthSnapshot(rows[k.X], rows[k.V_PREV], rows[k.V], rows[k.S], rows[k.P], rows[k.TAU],
                             rows[k.F_OTHER], rows[k.U], [int(w) for w in rows[k.W]],
                             self._tr[k.THETA1:k.THETA3 + 1].T.tolist(), rows[k.S_MAX], rows[k.PS],
                             rows[k.TAU_BRAKE], rows[k.MU_PAD] if pad else [], rows[k.TEMP] if pad else [])

    def truth_record(self) -> TruthSnapshot:
        """`snapshot()` as numpy rows of one copy of the state (~3 µs against ~15 µs for the lists): what
        the truth log keeps every sample; `truth_series` takes either."""
        k = kernel
        c = self._st.copy()
        none = np.zeros(0)
        pad = self._pad is not None
        return TruthSnapshot(c[k.X], c[k.V_PREV], c[k.V], c[k.S], c[k.P], c[k.TAU], c[k.F_OTHER], c[k.U],
                             c[k.W], self._tr[k.THETA1:k.THETA3 + 1].T.copy(), c[k.S_MAX], c[k.PS],
                             c[k.TAU_BRAKE], c[k.MU_PAD] if pad else none, c[k.TEMP] if pad else none)

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
