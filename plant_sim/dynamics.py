"""Longitudinal train and wheel dynamics: pure force and derivative functions, vectorised over cars.

Sign conventions: x, v > 0 in the running direction; car 1 leads (largest x). Forces that brake or
resist (adhesion f, Davis f_r, grade + curvature f_c) are positive when they oppose the motion. The
braking torque τ ≥ 0 opposes the wheel's rotation and the adhesion force f = μN ≥ 0 acts backwards on the
car body and forwards on the wheel's tread, so seed 001's eq. (1b) J ω̇ = r f + τ (its τ is signed)
reads J ω̇ = r f − τ here. Coupler force Φ_i > 0 is tension between cars i and i+1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plant_sim.params import TrainParams


@dataclass(frozen=True, slots=True, eq=False)
class CarConstants:
    """Constant arrays derived once from TrainParams: per car shape (n,), per coupler shape (n−1,).

    The plant's step multiplies by these arrays rather than by Python floats (numpy is faster on two
    arrays than on an array and a scalar, and the step is dominated by call overhead at n ≈ 6).
    """

    mass_kg: np.ndarray
    inv_mass_per_kg: np.ndarray
    normal_force_N: np.ndarray       # N = m g, eq. (1a) seed 001 (one lumped wheelset per car)
    slip_gain_per_kg: np.ndarray     # 1/M + r²/J of eq. (3) seed 001
    r_over_J: np.ndarray             # r/J [1/(kg m)]
    r_m: float
    inv_J: float                     # 1/J [1/(kg m²)]
    c0_N: np.ndarray                 # Davis coefficients per car, eq. (4) seed 003
    c1_Ns_per_m: np.ndarray
    c2_Ns2_per_m2: np.ndarray
    incidence: np.ndarray            # (n−1, n) path-graph incidence E: (E x)_i = x_i − x_{i+1}
    minus_incidence_T: np.ndarray    # (n, n−1) −Eᵀ: (−Eᵀ Φ)_i = Φ_{i−1} − Φ_i
    car_pitch_m: np.ndarray          # per coupler: rest distance of car centres (2d + l0, eq. (1) seed 003)
    k_N_per_m: np.ndarray            # per coupler: κ, eq. (2) seed 003
    k_eps_N_per_m3: np.ndarray       # per coupler: κ ε
    c_Ns_per_m: np.ndarray           # per coupler: damping
    stroke_m: float                  # draft-gear travel before the solid stop
    stop_k_N_per_m: np.ndarray       # per coupler: end-stop stiffness


def car_constants(tp: TrainParams) -> CarConstants:
    m = np.array(tp.masses_kg, dtype=float)
    n = m.size
    r, J = tp.wheel_radius_m, tp.wheel_inertia_kgm2
    c2 = np.full(n, tp.davis_c2_Ns2_per_m2)
    c2[0] = tp.davis_c2_lead_Ns2_per_m2          # the lead car's nose adds aerodynamic drag
    nc = n - 1
    incidence = np.eye(n)[:-1] - np.eye(n)[1:]
    return CarConstants(
        mass_kg=m, inv_mass_per_kg=1.0 / m, normal_force_N=m * tp.g_mps2,
        slip_gain_per_kg=1.0 / m + r * r / J, r_over_J=np.full(n, r / J), r_m=r, inv_J=1.0 / J,
        c0_N=np.full(n, tp.davis_c0_N), c1_Ns_per_m=np.full(n, tp.davis_c1_Ns_per_m), c2_Ns2_per_m2=c2,
        incidence=incidence, minus_incidence_T=np.ascontiguousarray(-incidence.T),
        car_pitch_m=np.full(nc, tp.car_pitch_m), k_N_per_m=np.full(nc, tp.coupler_k_N_per_m),
        k_eps_N_per_m3=np.full(nc, tp.coupler_k_N_per_m * tp.coupler_eps_per_m2),
        c_Ns_per_m=np.full(nc, tp.coupler_c_Ns_per_m), stroke_m=tp.coupler_stroke_m,
        stop_k_N_per_m=np.full(nc, tp.coupler_stop_k_N_per_m))


def coupler_rate(v: np.ndarray, cc: CarConstants) -> np.ndarray:
    """dΔl_i/dt = v_i − v_{i+1} [m/s], > 0 stretching; shape (n−1,)."""
    return cc.incidence.dot(v)


def coupler_extension(x: np.ndarray, cc: CarConstants) -> np.ndarray:
    """Δl_i = x_i − x_{i+1} − (2d + l0) [m], eq. (1) seed 003, > 0 stretched; shape (n−1,)."""
    return cc.incidence.dot(x) - cc.car_pitch_m  # x_i − x_{i+1} − (2d + l0), eq. (1) seed 003


def coupler_force(dl: np.ndarray, dl_rate: np.ndarray, cc: CarConstants) -> np.ndarray:
    """Φ_i [N], > 0 in tension: hardening spring, eq. (2) seed 003, + damping + solid end stop (chosen)."""
    phi = (cc.k_N_per_m + cc.k_eps_N_per_m3 * (dl * dl)) * dl   # κ(1 + εΔl²)Δl, eq. (2) seed 003
    phi += cc.c_Ns_per_m * dl_rate                               # draft-gear damping, chosen
    if dl.dot(dl) > cc.stroke_m * cc.stroke_m:                   # else no |Δl| exceeds the stroke
        beyond = dl - np.minimum(np.maximum(dl, -cc.stroke_m), cc.stroke_m)
        phi += cc.stop_k_N_per_m * beyond                        # solid end stop, chosen
    return phi


def other_forces(v: np.ndarray, phi: np.ndarray, static_force: np.ndarray, cc: CarConstants) -> np.ndarray:
    """F_other,i = Φ_{i−1} − Φ_i − f_r,i − f_c,i [N]: every force on car i but adhesion, eq. (3) seed 003.

    static_force = −(c0 + f_c) is the speed-independent part (Davis' c0 and grade + curvature, eqs. (4)
    and (5) seed 003); it changes only with the track, so the plant computes it once per track interval.
    """
    resist = static_force - v * (cc.c1_Ns_per_m + cc.c2_Ns2_per_m2 * v)  # − f_r − f_c, eqs. (3)–(5) seed 003
    return resist + cc.minus_incidence_T.dot(phi)                        # + Φ_{i−1} − Φ_i, eq. (3) seed 003


def davis_resistance(v: np.ndarray, cc: CarConstants) -> np.ndarray:
    """f_r = c0 + c1 v + c2 v² [N], eq. (4) seed 003 (v ≥ 0)."""
    return cc.c0_N + v * (cc.c1_Ns_per_m + cc.c2_Ns2_per_m2 * v)  # eq. (4), seed 003


def grade_curvature_resistance(mass_kg: np.ndarray, sin_grade: np.ndarray, curvature_deg: np.ndarray,
                               g_mps2: float) -> np.ndarray:
    """f_c = m g sin θ + 0.004 m D_c [N], eq. (5) seed 003 (D_c in degrees per 30.48 m chord)."""
    return mass_kg * (g_mps2 * sin_grade + 0.004 * curvature_deg)  # eq. (5), seed 003


def slip_speed(v: np.ndarray, omega: np.ndarray, r_m: float) -> np.ndarray:
    """s = v − r ω [m/s], eq. (2) seed 001."""
    return v - r_m * omega  # eq. (2), seed 001


def adhesion_force(mu: np.ndarray, normal_force_N: np.ndarray) -> np.ndarray:
    """f = μ N [N], eq. (1a) seed 001."""
    return mu * normal_force_N  # eq. (1a), seed 001


def car_acceleration(f_other: np.ndarray, f_adh: np.ndarray, cc: CarConstants) -> np.ndarray:
    """v̇ = (F_other − f)/m: m_i v̇_i = −f_i − f_r − f_c + Φ_{i−1} − Φ_i, eq. (3) seed 003 with F_a = f (1a, s. 001)."""
    return (f_other - f_adh) * cc.inv_mass_per_kg  # eq. (3) seed 003, eq. (1a) seed 001


def wheel_acceleration(f_adh: np.ndarray, tau: np.ndarray, cc: CarConstants) -> np.ndarray:
    """ω̇ = (r f − τ)/J, eq. (1b) seed 001 with τ ≥ 0 opposing the rotation."""
    return (cc.r_m * f_adh - tau) * cc.inv_J  # eq. (1b), seed 001


def slip_rate(f_other: np.ndarray, f_adh: np.ndarray, tau: np.ndarray, cc: CarConstants) -> np.ndarray:
    """ṡ = v̇ − r ω̇ = F_other/M + (r/J) τ − (1/M + r²/J) f, eq. (3) seed 001 plus the car's other forces."""
    return f_other * cc.inv_mass_per_kg + tau * cc.r_over_J - f_adh * cc.slip_gain_per_kg  # eq. (3), s. 001
