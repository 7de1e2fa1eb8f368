"""Reference governor (seed 001 eq. 9, firmware_py.governor): unit tests and the safety property test.

The property test samples closed-loop states (150 per PI, two PIs) and requests, lets the governor choose
r, then runs the closed loop -- PI (eq. 16) through firmware_py.pi, cylinder lag (eq. 4), hysteresis
(eq. 10a) -- with r held constant for 8 s against friction sequences inside the inclusion that switch the
scheduling parameter ξ every 10 ms step (random bits, alternating, random interior values, random
blocks). The friction force F follows the inclusion F⁺ = a(ξ) F + (1 − a(ξ)) κ τ and the slip is read
back through the inverse of the issue's curve (s = f⁻¹(F) below the peak). Accepted states never lead to
s > s̄. The nonlinear slip ODE of eq. (3) itself, integrated at 1 ms by the plant, is checked on the
lockstep runs of tests/studies/wheel_slip/test_wheel_slip.py (s ≤ s̄ at every plant step).
"""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_py.governor import (
    GovernorParams,
    GovernorState,
    admissible,
    govern,
    governor_params,
    play,
    predict_peak_torque,
)
from firmware_py.pi import PIParams, pi_step
from plant_sim.adhesion import mu_slip_speed_scalar, mu_slip_speed_slope_scalar

G = 9.81
M, J, RW = 40_000.0, 600.0, 0.46          # one car: 4 x issue #4's wheelset (10 t, 150 kg m², 0.46 m)
N = M * G
S_BAR = 0.1                               # s̄, eq. (8)
MU_PK, S_PK = 0.2, 0.155                  # f_max = 0.2 M g at ŝ = 0.155 m/s (issue #4)
K = 1.0 / M + RW * RW / J                 # eq. (3)
PI_PARAMS = PIParams(kp=5e5 / G, ki=40e5 / G, out_min=0.0, out_max=450e3)      # 5 bar/g, 40 bar/(g s)
PI_AGGRESSIVE = PIParams(kp=5e5 / G, ki=300e5 / G, out_min=0.0, out_max=450e3)


def make_params(pi: PIParams = PI_PARAMS, **options) -> GovernorParams:
    return governor_params(
        dt_s=0.01, mass_kg=M, wheel_radius_m=RW, inertia_kgm2=J,
        friction_max_N=mu_slip_speed_scalar(S_BAR, MU_PK, S_PK) * N,
        slope_lo_N_per_mps=mu_slip_speed_slope_scalar(S_BAR, MU_PK, S_PK) * N,
        slope_hi_N_per_mps=mu_slip_speed_slope_scalar(0.0, MU_PK, S_PK) * N, tp_s=0.05,
        alpha_squeeze=0.16, beta_squeeze=-0.16 * 30e3, alpha_release=0.16, beta_release=0.0, pi=pi, **options)


GP = make_params()


def test_derived_constants_follow_the_paper():
    # κ = r/(J k): steady friction per torque, from eq. (3) with ṡ = 0
    assert GP.kappa == pytest.approx(RW / (J * K))
    # the torque ceiling's steady deceleration is μ(s̄) g (less the margin): the best constant r
    mu_bar = mu_slip_speed_scalar(S_BAR, MU_PK, S_PK)
    assert GP.decel_max_mps2 == pytest.approx(mu_bar * G * (1 - GP.margin_frac))
    assert 0.0 < GP.a_lo < GP.a_hi < 1.0
    assert GP.phi == pytest.approx(math.exp(-0.01 / 0.05))       # Tp = 50 ms, seed 001 §IV


@pytest.mark.parametrize("tau_prev, p, expected", [
    # squeeze line τ = 0.16 p − 4800 N m, release line τ = 0.16 p (0.3 bar above), eq. (6)
    (0.0, 100e3, 11_200.0),             # squeeze: lifted onto the squeeze line
    (20e3, 100e3, 16_000.0),            # release: pushed down onto the release line
    (14e3, 100e3, 14_000.0),            # between the lines: hold
    (5e3, 20e3, 3_200.0),               # release at low pressure
    (0.0, 10e3, 0.0),                   # below the preload: no torque
])
def test_play_is_eq_10a(tau_prev, p, expected):
    assert play(tau_prev, p, GP) == pytest.approx(expected)


def test_request_below_the_limit_passes_through_from_rest():
    x = GovernorState(0.0, 0.0, 0.0, 0.0)
    d = govern(x, 0.10 * G, GP)
    assert d.r_mps2 == 0.10 * G and not d.active and d.margin_Nm > 0.0


def test_infeasible_request_is_cut_to_the_steady_state_limit():
    x = GovernorState(0.0, 0.0, 0.0, 0.0)
    d = govern(x, 0.25 * G, GP)
    assert d.active
    best = GP.decel_max_mps2 / (1.0 + GP.settle_frac)
    assert best - 0.003 <= d.r_mps2 <= best
    # and the chosen r is admissible, the requested one is not
    assert admissible(x, d.r_mps2, GP)[0] and not admissible(x, 0.25 * G, GP)[0]


def test_wound_up_state_is_governed_below_what_it_would_accept_at_rest():
    # integrator and pressure high, torque near the ceiling: the governor must lower r well below μ(s̄)
    tau = 0.97 * GP.torque_max_Nm
    p = (tau + 4800.0) / 0.16
    x = GovernorState(integrator_Pa=p + 40e3, pressure_Pa=p, torque_Nm=tau, friction_N=0.8 * GP.kappa * tau)
    d = govern(x, 0.25 * G, GP)
    assert d.active and d.r_mps2 < 0.9 * GP.decel_max_mps2


def test_outside_the_admissible_set_returns_zero_and_a_negative_margin():
    x = GovernorState(integrator_Pa=450e3, pressure_Pa=400e3, torque_Nm=1.5 * GP.torque_max_Nm,
                      friction_N=0.0)
    d = govern(x, 0.2 * G, GP)
    assert d.r_mps2 == 0.0 and not d.feasible and d.margin_Nm < 0.0


def test_previous_reference_is_kept_when_still_admissible():
    x = GovernorState(0.0, 0.0, 0.0, 0.0)
    first = govern(x, 0.25 * G, GP)
    again = govern(x, 0.25 * G, GP, r_prev=first.r_mps2)
    assert again.r_mps2 >= first.r_mps2 - GP.resolution_mps2 and again.evaluations <= first.evaluations


def test_running_resistance_raises_the_limit_by_r_over_m_and_a_small_request_releases_the_brake():
    """With a running resistance R held over the horizon the friction a constant r needs is M r − R: the
    steady-state limit rises by R/M, the predicted torque settles at (M r − R)/κ, and a request below R/M
    is admissible with the brake released (its steady state: no friction at all)."""
    res = 0.03 * M * G
    x = GovernorState(0.0, 0.0, 0.0, 0.0, resistance_N=res)
    d = govern(x, 0.25 * G, GP)
    best = GP.decel_max_mps2 / (1.0 + GP.settle_frac) + res / M
    assert d.active and best - 0.003 <= d.r_mps2 <= best
    assert d.r_mps2 > govern(GovernorState(0.0, 0.0, 0.0, 0.0), 0.25 * G, GP).r_mps2 + 0.9 * res / M
    peak, settled = predict_peak_torque(x, 0.15 * G, GP)
    assert settled and peak == pytest.approx((M * 0.15 * G - res) / GP.kappa, rel=0.02)
    assert admissible(x, 0.02 * G, GP)[0] and govern(x, 0.02 * G, GP).r_mps2 == 0.02 * G


@pytest.mark.parametrize("vertex", ["adversary", "slow", "fast"])
def test_prediction_settles_to_the_steady_state(vertex):
    peak, settled = predict_peak_torque(GovernorState(0.0, 0.0, 0.0, 0.0), 0.15 * G, GP, vertex)
    assert settled and peak == pytest.approx(M * 0.15 * G / GP.kappa, rel=0.02)


# ------------------------------------------------------------------------------------- the property
def slip_of_friction(f_N: float) -> float:
    """s = f⁻¹(F) on [0, ŝ] for the curve μ(s) = 2 μ̂ x/(1 + x²), x = s/ŝ (the root below the peak)."""
    m = min(f_N / N / MU_PK, 1.0)
    return S_PK * (1.0 - math.sqrt(1.0 - m * m)) / m if m > 0.0 else 0.0


def run_switching(gp: GovernorParams, x: GovernorState, r: float, xi: list[int | float]) -> float:
    """Closed loop with r held constant and the friction lag switching with ξ_k every step (a_k =
    ξ_k a̲ + (1 − ξ_k) ā); returns the largest slip speed reached [m/s], through the curve's inverse."""
    i, p, tau, f = x.integrator_Pa, x.pressure_Pa, x.torque_Nm, x.friction_N
    s_max = slip_of_friction(f)
    for xi_k in xi:
        u, i, _ = pi_step(gp.pi, i, r - f / gp.mass_kg, gp.dt_s)       # eq. (16) through the shared PI
        assert 0.0 <= u <= gp.pi.out_max                                # eq. (5b)
        p = u + (p - u) * gp.phi                                        # eq. (4)
        assert 0.0 <= p <= gp.pi.out_max                                # eq. (5a)
        tau = play(tau, p, gp)                                          # eq. (10a)
        a = xi_k * gp.a_lo + (1.0 - xi_k) * gp.a_hi
        f = a * f + (1.0 - a) * gp.kappa * tau
        s_max = max(s_max, slip_of_friction(f))
    return s_max


def xi_sequences(rng: random.Random, n: int) -> list[list[float]]:
    """Adversarial schedules: random bits every step, alternating, random values in [0, 1], blocks."""
    return [
        [rng.randint(0, 1) for _ in range(n)],
        [k % 2 for k in range(n)],
        [(k + 1) % 2 for k in range(n)],
        [rng.random() for _ in range(n)],
        [(k // rng.randint(2, 30)) % 2 for k in range(n)],
    ]


@st.composite
def states(draw):
    """Closed-loop states with s ≤ s̄ now: torque between the hysteresis lines at the pressure, F ≤ F̄."""
    p = draw(st.floats(0.0, 350e3))
    sq, rel = GP.alpha_squeeze * p + GP.beta_squeeze, GP.alpha_release * p + GP.beta_release
    tau = draw(st.floats(max(sq, 0.0), max(rel, 0.0))) if rel > 0.0 else 0.0
    f = draw(st.floats(0.0, GP.friction_max_N))
    i = draw(st.floats(-50e3, 450e3))
    return GovernorState(integrator_Pa=i, pressure_Pa=p, torque_Nm=tau, friction_N=f)


@pytest.mark.parametrize("pi", [PI_PARAMS, PI_AGGRESSIVE], ids=["fig8_pi", "aggressive_pi"])
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
@given(x=states(), r0_g=st.floats(0.0, 0.3), seed=st.integers(0, 2**31 - 1))
def test_accepted_states_never_leave_the_stable_slip_region(pi, x, r0_g, seed):
    gp = make_params(pi)
    d = govern(x, r0_g * G, gp)
    if not d.feasible:
        return                                        # nothing admissible from here: nothing claimed
    assert 0.0 <= d.r_mps2 <= r0_g * G
    rng = random.Random(seed)
    for xi in xi_sequences(rng, 800):                 # 8 s with r held constant
        assert run_switching(gp, x, d.r_mps2, xi) <= S_BAR * (1.0 + 1e-9)


def test_the_property_is_not_vacuous():
    # the same check catches an ungoverned request: r⁰ = 0.25 g from rest leaves the stable-slip region
    x = GovernorState(0.0, 0.0, 0.0, 0.0)
    assert not admissible(x, 0.25 * G, GP)[0]
    assert run_switching(GP, x, 0.25 * G, [0] * 800) > S_BAR
    # and a governed one from the same state does not, under every schedule
    d = govern(x, 0.25 * G, GP)
    for xi in xi_sequences(random.Random(1), 800):
        assert run_switching(GP, x, d.r_mps2, xi) <= S_BAR


def test_the_compiled_prediction_is_the_python_loop_to_the_bit():
    """predict_loop runs compiled (numba); as plain Python (its py_func, what NUMBA_DISABLE_JIT=1 runs) it
    gives the same peak torque and settled flag, bit for bit, on random states, references, resistances and
    vertices."""
    from firmware_py.governor import VERTEX_CODES
    from firmware_py.governor_kernel import predict_loop

    rng = random.Random(7)
    pi = GP.pi
    for _ in range(500):
        args = (rng.uniform(-1e5, 5e5), rng.uniform(0.0, 4.5e5), rng.uniform(0.0, 1.5 * GP.torque_max_Nm),
                rng.uniform(0.0, 1.2 * GP.friction_max_N), rng.choice([0.0, rng.uniform(0.0, 3e4)]),
                rng.uniform(0.0, 3.0), rng.choice(list(VERTEX_CODES.values())),
                rng.choice([math.inf, GP.torque_limit_Nm]), pi.kp, pi.ki, pi.out_min, pi.out_max, GP.dt_s,
                GP.mass_kg, GP.kappa, GP.phi, GP.a_lo, GP.a_hi, GP.alpha_squeeze, GP.beta_squeeze,
                GP.alpha_release, GP.beta_release, GP.settle_frac * GP.friction_max_N,
                GP.settle_frac * pi.out_max, GP.horizon_steps)
        assert predict_loop(*args) == predict_loop.py_func(*args)
