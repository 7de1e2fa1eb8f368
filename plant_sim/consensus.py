"""The train as seed 003 models it (§2.1): n cars with hardening-spring couplers and force actuation.

    ẋ_i = v_i,   m_i v̇_i = −F_a,i + Φ_{i−1} − Φ_i − f_r,i − f_c,i + d_i(t)          eq. (3), seed 003
    F_a,i = K_b,i u_i  (limited by the rail's adhesion while the car skids)             eq. (3), seed 003
    Φ_i = κ_i (1 + ε_i Δl_i²) Δl_i,   Δl_i = x_i − x_{i+1} − (2d + l0)                 eqs. (1)-(2)
    f_r,i = c0 + c1 v_i + c2 v_i²                                                       eq. (4)
    f_c,i = m_i g sin θ + 0.004 m_i D_c                                                 eq. (5)

The coupler, Davis and slope/curvature functions are the foundation's (plant_sim.dynamics, `*_scalar`);
this module adds what seed 003 has and the foundation's plant has not: the actuator is a braking force
K_b u instead of a pneumatic cylinder and a wheel, the rail condition of each car can deteriorate at a
given time (the car skids: its braking force is capped at μ_poor m g) and is restored after a delay
(adhesion control, §4 case 2), and a sinusoidal external disturbance force d_i(t) (§4 case 3).

Sign conventions as plant_sim.dynamics: car 1 leads (largest x), x and v > 0 forwards, F_a > 0 brakes,
Φ > 0 is tension. Time is an integer count of microseconds; the integrator is a fixed step (semi-implicit
Euler: v first, then x with the new v), pure numerics, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from plant_sim.dynamics import (
    CarConstants,
    car_constants,
    coupler_extension_scalar,
    coupler_force_scalar,
    davis_resistance_scalar,
    grade_curvature_resistance_scalar,
)
from plant_sim.errors import PlantConfigError
from plant_sim.params import TrainParams


@dataclass(frozen=True)
class RailEvent:
    """Rail condition of one car: from `start_us` for `skid_us` the car skids and its braking force is at
    most μ m g (the braking capacity falls); afterwards adhesion control restores full capacity (§4 case 2,
    seed 003: "after 1 s of skidding, the adhesion control is only employed to restore the braking
    capacity")."""

    start_us: int                   # deterioration time [µs]
    skid_us: int                    # skidding duration before adhesion control restores capacity [µs]
    mu: float                       # adhesion while skidding [-]: |F_a| ≤ μ m g


@dataclass(frozen=True)
class Disturbance:
    """d_i(t) = amplitude_N[i] sin(2π f (t − t0) + phase_rad[i]) for t ≥ t0, 0 before [N] (§4 case 3)."""

    start_us: int
    amplitude_N: tuple[float, ...]
    freq_hz: float
    phase_rad: tuple[float, ...]


@dataclass(frozen=True)
class ConsensusPlantParams:
    """The multi-car train of seed 003. Masses, κ, ε from Table 2; Davis coefficients are the
    foundation's (the paper gives none); 2d + l0 = 10 m so that Table 2's positions 10 m apart leave
    every coupler at rest length at t0."""

    train: TrainParams
    brake_gain: tuple[float, ...]   # K_b,i [N per unit of u], eq. (3); 1.0: u is a force in N
    dt_us: int = 1_000              # integration step [µs]: the paper's 1 ms sampling, §4
    sin_grade: float = 0.0          # sin θ_c of the track [-], eq. (5) (+ uphill)
    curvature_deg: float = 0.0      # D_c [deg per 30.48 m chord], eq. (5)
    rail: tuple[RailEvent | None, ...] = ()          # per car; () or None: fine rail
    disturbance: Disturbance | None = None
    v0_mps: tuple[float, ...] = ()  # initial speeds [m/s]
    x0_m: tuple[float, ...] = ()    # initial positions [m]
    cc: CarConstants = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        n = self.train.n_cars
        for name in ("brake_gain", "v0_mps", "x0_m"):
            val = getattr(self, name)
            if len(val) != n or not all(math.isfinite(x) for x in val):
                raise PlantConfigError(f"ConsensusPlantParams.{name} needs {n} finite values, got {val!r}")
        if not all(k > 0 for k in self.brake_gain):
            raise PlantConfigError(f"ConsensusPlantParams.brake_gain must be > 0, got {self.brake_gain!r}")
        if self.rail and len(self.rail) != n:
            raise PlantConfigError(f"ConsensusPlantParams.rail needs {n} entries (None = fine), "
                                   f"got {len(self.rail)}")
        if self.dt_us <= 0:
            raise PlantConfigError(f"ConsensusPlantParams.dt_us must be > 0, got {self.dt_us}")
        d = self.disturbance
        if d is not None and (len(d.amplitude_N) != n or len(d.phase_rad) != n):
            raise PlantConfigError(f"Disturbance needs {n} amplitudes and phases")
        object.__setattr__(self, "cc", car_constants(self.train))


def capacity_N(p: ConsensusPlantParams, car: int, t_us: int) -> float:
    """Largest braking force car `car` (0-based) can apply at t [N]: ∞ on fine rail, μ m g while it skids."""
    ev = p.rail[car] if p.rail else None
    if ev is None or not (ev.start_us <= t_us < ev.start_us + ev.skid_us):
        return math.inf
    return ev.mu * p.train.masses_kg[car] * p.train.g_mps2


def actuator_force_N(u: float, gain: float, cap_N: float) -> float:
    """F_a = K_b u [N], eq. (3) seed 003, limited to ±cap (adhesion, both braking and traction)."""
    f = gain * u                                      # F_a = K_b u, eq. (3) seed 003
    return max(-cap_N, min(cap_N, f))


def disturbance_N(d: Disturbance | None, car: int, t_us: int) -> float:
    """d_i(t) [N], the sinusoidal external disturbance of §4 case 3 (> 0 pushes the car forwards)."""
    if d is None or t_us < d.start_us:
        return 0.0
    phase = 2.0 * math.pi * d.freq_hz * (t_us - d.start_us) * 1e-6 + d.phase_rad[car]
    return d.amplitude_N[car] * math.sin(phase)


@dataclass
class ConsensusState:
    t_us: int
    x: np.ndarray                   # positions [m]
    v: np.ndarray                   # speeds [m/s]


@dataclass(frozen=True)
class ConsensusForces:
    """Every force of eq. (3) at one instant, per car [N] (couplers: n − 1)."""

    dl_m: np.ndarray                # Δl_i, eq. (1)
    phi_N: np.ndarray               # Φ_i, eq. (2)
    fa_N: np.ndarray                # F_a,i actually applied
    resist_N: np.ndarray            # f_r,i + f_c,i, eqs. (4)-(5)
    dist_N: np.ndarray              # d_i
    accel_mps2: np.ndarray          # v̇_i
    skidding: np.ndarray            # 1 while the car's capacity is reduced


def forces(p: ConsensusPlantParams, t_us: int, x: np.ndarray, v: np.ndarray,
           u: np.ndarray) -> ConsensusForces:
    """The right-hand side of eq. (3) seed 003 at (t, x, v, u) (pure)."""
    cc, tp = p.cc, p.train
    n = tp.n_cars
    dl = np.array([coupler_extension_scalar(x[i], x[i + 1], cc.car_pitch_m) for i in range(n - 1)])
    phi = np.array([coupler_force_scalar(dl[i], v[i] - v[i + 1], cc) for i in range(n - 1)])
    fa = np.empty(n)
    res = np.empty(n)
    dist = np.empty(n)
    acc = np.empty(n)
    skid = np.zeros(n)
    for i in range(n):
        cap = capacity_N(p, i, t_us)
        skid[i] = cap < math.inf
        fa[i] = actuator_force_N(float(u[i]), p.brake_gain[i], cap)
        res[i] = (davis_resistance_scalar(max(float(v[i]), 0.0), cc.c0_N, cc.c1_Ns_per_m, cc.c2_Ns2_per_m2[i])
                  + grade_curvature_resistance_scalar(cc.mass_kg[i], p.sin_grade, p.curvature_deg, tp.g_mps2))
        dist[i] = disturbance_N(p.disturbance, i, t_us)
        front = phi[i - 1] if i > 0 else 0.0
        rear = phi[i] if i < n - 1 else 0.0
        # m_i v̇_i = −F_a,i + Φ_{i−1} − Φ_i − f_i + d_i, eq. (3) seed 003 (+ d_i of §4 case 3)
        acc[i] = (-fa[i] + front - rear - res[i] + dist[i]) * cc.inv_mass_per_kg[i]
    return ConsensusForces(dl, phi, fa, res, dist, acc, skid)


class ConsensusPlant:
    """The train of seed 003 stepping at p.dt_us under force commands u [units of K_b]."""

    def __init__(self, p: ConsensusPlantParams) -> None:
        self.p = p
        self.state = ConsensusState(0, np.array(p.x0_m, dtype=float), np.array(p.v0_mps, dtype=float))
        self.last = forces(p, 0, self.state.x, self.state.v, np.zeros(p.train.n_cars))
        self.max_abs_dl_m = np.abs(self.last.dl_m)    # largest |Δl| per coupler over every step [m]

    def step(self, u: np.ndarray) -> ConsensusForces:
        """Integrate one step with commands u held (zero-order hold); returns the forces at its start."""
        s = self.state
        f = forces(self.p, s.t_us, s.x, s.v, u)
        dt = self.p.dt_us * 1e-6
        v_new = s.v + f.accel_mps2 * dt
        s.x = s.x + v_new * dt
        s.v = v_new
        s.t_us += self.p.dt_us
        self.last = f
        if f.dl_m.size:
            dl_now = np.abs(s.x[:-1] - s.x[1:] - self.p.cc.car_pitch_m)
            self.max_abs_dl_m = np.maximum(self.max_abs_dl_m, dl_now)
        return f
