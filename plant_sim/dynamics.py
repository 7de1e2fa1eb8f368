"""Longitudinal train and wheel dynamics: pure force and derivative functions.

The `*_scalar` functions are the implementation: one car (or one coupler), Python floats, called per car
by the plant's step (why scalar: `plant_sim.plant`). The functions without the suffix are their array
wrappers over the n cars (n − 1 couplers), for tests and the plant's 10 ms truth.

Sign conventions: x, v > 0 in the running direction; car 1 leads (largest x). Forces that brake or
resist (adhesion f, Davis f_r, grade + curvature f_c) are positive when they oppose the motion. The
braking torque τ ≥ 0 opposes the wheel's rotation and the adhesion force f = μN ≥ 0 (eq. (1a) seed 001,
N = m g, computed in the plant's step) acts backwards on the car body and forwards on the wheel's tread,
so seed 001's eq. (1b) J ω̇ = r f + τ (its τ is signed) reads J ω̇ = r f − τ here. Coupler force Φ_i > 0
is tension between cars i and i+1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba.extending import register_jitable

from plant_sim.elementwise import elementwise
from plant_sim.params import TrainParams


@dataclass(frozen=True, slots=True, eq=False)
class CarConstants:
    """Constants derived once from TrainParams, as Python floats: a tuple of n for what differs between
    cars, one float for what all cars (all couplers) share."""

    mass_kg: tuple[float, ...]
    inv_mass_per_kg: tuple[float, ...]
    normal_force_N: tuple[float, ...]    # N = m g, eq. (1a) seed 001 (one lumped wheelset per car)
    slip_gain_per_kg: tuple[float, ...]  # 1/M + r²/J of eq. (3) seed 001
    c2_Ns2_per_m2: tuple[float, ...]     # Davis c2 per car (the lead car's nose adds drag), eq. (4) seed 003
    r_m: float
    inv_J: float                         # 1/J [1/(kg m²)]
    r_over_J: float                      # r/J [1/(kg m)]
    c0_N: float                          # Davis coefficients, eq. (4) seed 003
    c1_Ns_per_m: float
    car_pitch_m: float                   # rest distance of car centres (2d + l0, eq. (1) seed 003)
    k_N_per_m: float                     # coupler κ, eq. (2) seed 003
    k_eps_N_per_m3: float                # κ ε
    c_Ns_per_m: float                    # coupler damping
    stroke_m: float                      # draft-gear travel before the solid stop
    stop_k_N_per_m: float                # end-stop stiffness
    stop_chi_Ns_per_m2: float            # end-stop Hunt–Crossley damping


def car_constants(tp: TrainParams) -> CarConstants:
    m = tuple(float(mi) for mi in tp.masses_kg)
    r, J = tp.wheel_radius_m, tp.wheel_inertia_kgm2
    c2 = (tp.davis_c2_lead_Ns2_per_m2,) + (tp.davis_c2_Ns2_per_m2,) * (len(m) - 1)
    return CarConstants(
        mass_kg=m, inv_mass_per_kg=tuple(1.0 / mi for mi in m),
        normal_force_N=tuple(mi * tp.g_mps2 for mi in m),
        slip_gain_per_kg=tuple(1.0 / mi + r * r / J for mi in m), c2_Ns2_per_m2=c2,
        r_m=r, inv_J=1.0 / J, r_over_J=r / J, c0_N=tp.davis_c0_N, c1_Ns_per_m=tp.davis_c1_Ns_per_m,
        car_pitch_m=tp.car_pitch_m, k_N_per_m=tp.coupler_k_N_per_m,
        k_eps_N_per_m3=tp.coupler_k_N_per_m * tp.coupler_eps_per_m2, c_Ns_per_m=tp.coupler_c_Ns_per_m,
        stroke_m=tp.coupler_stroke_m, stop_k_N_per_m=tp.coupler_stop_k_N_per_m,
        stop_chi_Ns_per_m2=tp.coupler_stop_chi_Ns_per_m2)


# ------------------------------------------------------------------------ scalar: one car or coupler
@register_jitable
def coupler_extension_scalar(x_front_m: float, x_rear_m: float, pitch_m: float) -> float:
    """Δl = x_i − x_{i+1} − (2d + l0) [m] of the coupler between cars i and i+1, eq. (1) seed 003, > 0
    stretched."""
    return x_front_m - x_rear_m - pitch_m  # x_i − x_{i+1} − (2d + l0), eq. (1) seed 003


@register_jitable
def coupler_rate_scalar(v_front_mps: float, v_rear_mps: float) -> float:
    """dΔl/dt = v_i − v_{i+1} [m/s], > 0 stretching."""
    return v_front_mps - v_rear_mps


@register_jitable
def coupler_force_scalar(dl_m: float, dl_rate_mps: float, cc: CarConstants) -> float:
    """Φ [N], > 0 in tension: hardening spring, eq. (2) seed 003, + damping + solid end stop (chosen)."""
    phi = ((cc.k_N_per_m + cc.k_eps_N_per_m3 * (dl_m * dl_m)) * dl_m   # κ(1 + εΔl²)Δl, eq. (2) seed 003
           + cc.c_Ns_per_m * dl_rate_mps)                               # draft-gear damping, chosen
    stroke = cc.stroke_m
    if dl_m > stroke or dl_m < -stroke:                                # the coupler is solid
        b = dl_m - (stroke if dl_m > stroke else -stroke)              # penetration into the stop
        phi += cc.stop_k_N_per_m * b + cc.stop_chi_Ns_per_m2 * abs(b) * dl_rate_mps  # k b + χ|b|ḃ, chosen
    return phi


@register_jitable
def davis_resistance_scalar(v_mps: float, c0_N: float, c1_Ns_per_m: float, c2_Ns2_per_m2: float) -> float:
    """f_r = c0 + c1 v + c2 v² [N], eq. (4) seed 003 (v ≥ 0)."""
    return c0_N + v_mps * (c1_Ns_per_m + c2_Ns2_per_m2 * v_mps)  # eq. (4), seed 003


def grade_curvature_resistance_scalar(mass_kg: float, sin_grade: float, curvature_deg: float,
                                      g_mps2: float) -> float:
    """f_c = m g sin θ + 0.004 m D_c [N], eq. (5) seed 003 (D_c in degrees per 30.48 m chord)."""
    return mass_kg * (g_mps2 * sin_grade + 0.004 * curvature_deg)  # eq. (5), seed 003


@register_jitable
def other_force_scalar(v_mps: float, phi_front_N: float, phi_rear_N: float, static_force_N: float,
                       c1_Ns_per_m: float, c2_Ns2_per_m2: float) -> float:
    """F_other,i = Φ_{i−1} − Φ_i − f_r,i − f_c,i [N]: every force on car i but adhesion, eq. (3) seed 003.

    phi_front = Φ_{i−1} (0 for the leading car), phi_rear = Φ_i (0 for the last car). static_force =
    −(c0 + f_c) is the speed-independent part (Davis' c0 and grade + curvature, eqs. (4) and (5) seed
    003); it changes only with the track, so the plant computes it once per track interval.
    """
    resist = static_force_N - davis_resistance_scalar(v_mps, 0.0, c1_Ns_per_m, c2_Ns2_per_m2)  # − f_r − f_c
    return resist + (phi_front_N - phi_rear_N)                        # + Φ_{i−1} − Φ_i, eq. (3) seed 003


def slip_speed_scalar(v_mps: float, omega_rad_s: float, r_m: float) -> float:
    """s = v − r ω [m/s], eq. (2) seed 001."""
    return v_mps - r_m * omega_rad_s  # eq. (2), seed 001


def car_acceleration_scalar(f_other_N: float, f_adh_N: float, inv_mass_per_kg: float) -> float:
    """v̇ = (F_other − f)/m [m/s²], i.e. m_i v̇_i = −f_i − f_r − f_c + Φ_{i−1} − Φ_i: eq. (3) seed 003 with
    F_a = f, the adhesion force of eq. (1a) seed 001."""
    return (f_other_N - f_adh_N) * inv_mass_per_kg  # eq. (3) seed 003, eq. (1a) seed 001


def wheel_acceleration_scalar(f_adh_N: float, tau_Nm: float, r_m: float, inv_J: float) -> float:
    """ω̇ = (r f − τ)/J [rad/s²], eq. (1b) seed 001 with τ ≥ 0 opposing the rotation."""
    return (r_m * f_adh_N - tau_Nm) * inv_J  # eq. (1b), seed 001


@register_jitable
def slip_rate_scalar(f_other_N: float, f_adh_N: float, tau_Nm: float, inv_mass_per_kg: float, r_over_J: float,
                     slip_gain_per_kg: float) -> float:
    """ṡ = v̇ − r ω̇ = F_other/M + (r/J) τ − (1/M + r²/J) f [m/s²], eq. (3) seed 001 plus the car's other
    forces."""
    return f_other_N * inv_mass_per_kg + tau_Nm * r_over_J - f_adh_N * slip_gain_per_kg  # eq. (3), s. 001


# ------------------------------------------------------------------------------ array wrappers, n cars
def _f(a) -> np.ndarray:
    return np.asarray(a, dtype=float)


def coupler_rate(v: np.ndarray, cc: CarConstants) -> np.ndarray:
    """`coupler_rate_scalar` per coupler, shape (..., n−1) for speeds (..., n)."""
    v = _f(v)
    return elementwise(coupler_rate_scalar, v[..., :-1], v[..., 1:])


def coupler_extension(x: np.ndarray, cc: CarConstants) -> np.ndarray:
    """`coupler_extension_scalar` per coupler, shape (..., n−1) for positions (..., n)."""
    x = _f(x)
    return elementwise(coupler_extension_scalar, x[..., :-1], x[..., 1:], params=(cc.car_pitch_m,))


def coupler_force(dl: np.ndarray, dl_rate: np.ndarray, cc: CarConstants) -> np.ndarray:
    """`coupler_force_scalar` per coupler."""
    return elementwise(coupler_force_scalar, _f(dl), _f(dl_rate), params=(cc,))


def other_forces(v: np.ndarray, phi: np.ndarray, static_force: np.ndarray, cc: CarConstants) -> np.ndarray:
    """`other_force_scalar` per car, from the n − 1 coupler forces phi (Φ_0 = Φ_n = 0 at the train's ends)."""
    phi_ends = np.concatenate([[0.0], _f(phi), [0.0]])
    return elementwise(other_force_scalar, _f(v), phi_ends[:-1], phi_ends[1:], _f(static_force),
                       cc.c1_Ns_per_m, np.array(cc.c2_Ns2_per_m2))


def davis_resistance(v: np.ndarray, cc: CarConstants) -> np.ndarray:
    """`davis_resistance_scalar` per car, eq. (4) seed 003."""
    return elementwise(davis_resistance_scalar, _f(v), cc.c0_N, cc.c1_Ns_per_m, np.array(cc.c2_Ns2_per_m2))


def grade_curvature_resistance(mass_kg: np.ndarray, sin_grade: np.ndarray, curvature_deg: np.ndarray,
                               g_mps2: float) -> np.ndarray:
    """`grade_curvature_resistance_scalar` per car, eq. (5) seed 003."""
    return elementwise(grade_curvature_resistance_scalar, _f(mass_kg), _f(sin_grade), _f(curvature_deg),
                       float(g_mps2))


def slip_speed(v: np.ndarray, omega: np.ndarray, r_m: float) -> np.ndarray:
    """`slip_speed_scalar` per car, eq. (2) seed 001."""
    return elementwise(slip_speed_scalar, _f(v), _f(omega), float(r_m))


def car_acceleration(f_other: np.ndarray, f_adh: np.ndarray, cc: CarConstants) -> np.ndarray:
    """`car_acceleration_scalar` per car, eq. (3) seed 003."""
    return elementwise(car_acceleration_scalar, _f(f_other), _f(f_adh), np.array(cc.inv_mass_per_kg))


def wheel_acceleration(f_adh: np.ndarray, tau: np.ndarray, cc: CarConstants) -> np.ndarray:
    """`wheel_acceleration_scalar` per car, eq. (1b) seed 001."""
    return elementwise(wheel_acceleration_scalar, _f(f_adh), _f(tau), cc.r_m, cc.inv_J)


def slip_rate(f_other: np.ndarray, f_adh: np.ndarray, tau: np.ndarray, cc: CarConstants) -> np.ndarray:
    """`slip_rate_scalar` per car, eq. (3) seed 001."""
    return elementwise(slip_rate_scalar, _f(f_other), _f(f_adh), _f(tau), np.array(cc.inv_mass_per_kg),
                       cc.r_over_J, np.array(cc.slip_gain_per_kg))
