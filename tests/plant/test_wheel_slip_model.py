"""The plant against seed 001's equations (1)-(6): the foundation's implementation where it already models
them (slip dynamics, hysteresis), and the options added for seed 001 (slip-speed adhesion family, cylinder
lag with Tp, bounds on p and u). One implementation each: these tests call the plant's own functions.
"""

import math

import numpy as np
import pytest

from plant_sim.adhesion import mu, mu_opt, mu_slip_speed_scalar, mu_slip_speed_slope_scalar, sigma_opt
from plant_sim.brake import (
    WSP_FILL,
    WSP_HOLD,
    WSP_VENT,
    cylinder_lag_scalar,
    hysteresis_torque_scalar,
    lag_factor,
)
from plant_sim.dynamics import car_constants, slip_rate_scalar, wheel_acceleration_scalar
from plant_sim.errors import PlantConfigError
from plant_sim.params import AdhesionParams, BrakeParams, PlantParams, TrainParams
from plant_sim.plant import Plant
from plant_sim.track import Track

G = 9.81
# issue #4's set, one car = four of its wheelsets: M = 40 t, J = 600 kg m², r = 0.46 m, 4 x 4000 N m/bar
TP = TrainParams(masses_kg=(40_000.0,), wheel_inertia_kgm2=600.0, davis_c0_N=0.0, davis_c1_Ns_per_m=0.0,
                 davis_c2_Ns2_per_m2=0.0, davis_c2_lead_Ns2_per_m2=0.0)
BP = BrakeParams(alpha_squeeze_Nm_per_Pa=0.16, beta_squeeze_Nm=-0.16 * 30e3, alpha_release_Nm_per_Pa=0.16,
                 beta_release_Nm=0.0, pressure_model="lag", tp_s=0.05)
AP = AdhesionParams(slip_speed_peak=(0.2, 0.155))       # f_max = 0.2 M g, seed 001 §IV-A
PP = PlantParams(train=TP, brake=BP, adhesion=AP)
TRACK = Track.from_segments([(-1e4, "dry")])


# ------------------------------------------------------------------------------------ eqs. (1)-(3)
def test_slip_rate_is_eq_3():
    cc = car_constants(TP)
    m, r, j = 40_000.0, 0.46, 600.0
    for f, tau in [(0.0, 0.0), (50e3, 30e3), (70e3, 10e3), (1e3, 40e3)]:
        # ṡ = −(1/M + r²/J) f + (r/J) τ, eq. (3), with no other force on the car
        expected = -(1.0 / m + r * r / j) * f + r / j * tau
        assert slip_rate_scalar(0.0, f, tau, cc.inv_mass_per_kg[0], cc.r_over_J, cc.slip_gain_per_kg[0]) == \
            pytest.approx(expected, rel=1e-12)
        # eq. (1b) J ω̇ = r f + τ with the paper's signed τ (negative when braking): here τ ≥ 0 opposes ω
        assert wheel_acceleration_scalar(f, tau, r, cc.inv_J) == pytest.approx((r * f - tau) / j, rel=1e-12)


def test_constant_torque_settles_where_friction_balances_it():
    # seed 001 §II-A: the slip rises until f(s) = M r τ / (J + M r²)
    plant = Plant(PP, TRACK, v0_mps=30.0)
    p_set = 200e3
    for _ in range(1500):                                     # 1.5 s: cylinder (Tp = 50 ms) and slip settle
        plant.step(np.zeros(1), np.zeros(1, np.int64), np.array([p_set]))
    snap = plant.snapshot()
    tau = snap.tau[0]
    assert tau == pytest.approx(0.16 * p_set - 4800.0, rel=1e-6)       # on the squeeze line
    f = mu_slip_speed_scalar(snap.s[0], 0.2, 0.155) * 40_000.0 * G
    assert f == pytest.approx(40_000.0 * 0.46 * tau / (600.0 + 40_000.0 * 0.46**2), rel=2e-3)
    assert -plant.truth()["a_mps2"][0] == pytest.approx(f / 40_000.0, rel=2e-3)   # eq. (1a)


def test_torque_beyond_the_peak_makes_the_slip_run_away():
    # f_max = 0.2 M g cannot balance a torque above (J + M r²)/(M r) f_max: unstable slip, §II-A
    plant = Plant(PP, TRACK, v0_mps=30.0)
    tau_max = (600.0 + 40_000.0 * 0.46**2) / (40_000.0 * 0.46) * 0.2 * 40_000.0 * G
    p_set = (1.05 * tau_max + 4800.0) / 0.16
    for _ in range(2000):
        plant.step(np.zeros(1), np.zeros(1, np.int64), np.array([p_set]))
    assert plant.snapshot().s[0] > 1.0


# ----------------------------------------------------------------------- adhesion family μ(s), §II-A
@pytest.mark.parametrize("mu_pk, s_pk", [(0.2, 0.155), (0.1, 0.05), (0.35, 0.4)])
def test_slip_speed_curve_has_its_peak_where_configured(mu_pk, s_pk):
    s = np.linspace(0.0, 5 * s_pk, 50_001)
    m = np.array([mu_slip_speed_scalar(x, mu_pk, s_pk) for x in s])
    assert m[0] == 0.0
    assert s[np.argmax(m)] == pytest.approx(s_pk, rel=1e-3) and m.max() == pytest.approx(mu_pk, rel=1e-9)
    below = s <= s_pk
    assert np.all(np.diff(m[below]) > 0.0)                           # monotone below the peak
    assert np.all(np.diff(m[~below]) < 0.0)                          # falling beyond it (unstable slip)
    conc = s <= math.sqrt(3) * s_pk
    assert np.all(np.diff(m[conc], 2) <= 1e-15)                      # concave: the cone of Fig. 5
    slope = np.array([mu_slip_speed_slope_scalar(x, mu_pk, s_pk) for x in s[1:-1:97]])
    numeric = np.gradient(m, s)[1:-1:97]
    assert slope == pytest.approx(numeric, rel=1e-3, abs=1e-6)


def test_slip_speed_curve_through_the_plants_adhesion_functions():
    # μ(θ, σ, v) of the plant evaluates the slip-speed curve at s = σ max(v, V_EPS), independent of θ
    theta = np.array([[0.3, 6.5, 7.4], [1.2, 81.0, 17.6]])
    v = np.array([25.0, 25.0])
    s = np.array([0.1, 0.1])
    assert mu(theta, s / v, v, AP) == pytest.approx([mu_slip_speed_scalar(0.1, 0.2, 0.155)] * 2, rel=1e-12)
    assert mu_opt(theta, v, AP) == pytest.approx([0.2, 0.2])
    assert sigma_opt(theta, v, AP) == pytest.approx(0.155 / v)
    # the paper's numbers: μ(s̄ = 0.1) = 0.1822, i.e. r⁰ − μ(s̄) g = 0.0678 g for r⁰ = 0.25 g (§IV-A)
    assert mu_slip_speed_scalar(0.1, 0.2, 0.155) == pytest.approx(0.18222, abs=1e-5)


def test_a_sliding_wheels_friction_floor_only_acts_beyond_the_peak():
    """slip_speed_slide_ratio ρ: μ(s) never below ρ μ̂ beyond the peak; the rising branch (μ(0) = 0, the
    governor's cone below s̄) and the peak are untouched; in the plant a locked wheel spins back up."""
    s = np.linspace(0.0, 60.0, 60_001)
    plain = np.array([mu_slip_speed_scalar(x, 0.2, 0.155) for x in s])
    floored = np.array([mu_slip_speed_scalar(x, 0.2, 0.155, 0.04) for x in s])
    rising = s <= 0.155
    assert np.array_equal(plain[rising], floored[rising]) and floored[0] == 0.0
    assert floored.max() == pytest.approx(0.2, rel=1e-9)
    assert np.all(floored[~rising] >= 0.04) and np.all(floored == np.where(rising, plain,
                                                                               np.maximum(plain, 0.04)))
    assert plain[-1] < 0.002 and floored[-1] == 0.04                  # a locked wheel at 60 m/s
    floor = AdhesionParams(slip_speed_peak=(0.2, 0.155), slip_speed_slide_ratio=0.2)
    assert mu(np.zeros((1, 3)), np.array([1.0]), np.array([58.0]), floor)[0] == pytest.approx(0.04)
    with pytest.raises(PlantConfigError, match="slip_speed_slide_ratio"):
        AdhesionParams(slip_speed_peak=(0.2, 0.155), slip_speed_slide_ratio=1.0)
    # the compiled step: a wheel locked at 30 m/s with the brake off spins up (its friction, not zero)
    times = []
    for ap in (AP, floor):
        plant = Plant(PlantParams(train=TP, brake=BP, adhesion=ap), TRACK, v0_mps=30.0)
        plant.step(np.zeros(1), np.zeros(1, np.int64), np.array([450e3]))
        n = 0
        while plant.snapshot().s[0] < 29.0 and n < 5000:            # lock it: full pressure
            plant.step(np.zeros(1), np.zeros(1, np.int64), np.array([450e3]))
            n += 1
        k = 0
        while plant.snapshot().s[0] > 1.0 and k < 30_000:          # release: back within 1 m/s?
            plant.step(np.zeros(1), np.zeros(1, np.int64), np.array([0.0]))
            k += 1
        times.append(k)
    assert times[0] == 30_000 and times[1] < 10_000                  # 1 ms steps: never in 30 s / < 10 s


@pytest.mark.parametrize("bad", [(0.0, 0.155), (0.2, 0.0), (2.5, 0.1), (0.2, -1.0)])
def test_slip_speed_curve_rejects_bad_peaks(bad):
    with pytest.raises(PlantConfigError, match="slip_speed_peak"):
        AdhesionParams(slip_speed_peak=bad)


# ------------------------------------------------------------------------------ cylinder, eqs. (4)-(5)
def test_lag_step_response_is_first_order_with_tp():
    phi = lag_factor(BP, 1e-3)
    p, t = 0.0, 0.0
    for _ in range(200):
        p = cylinder_lag_scalar(p, 300e3, WSP_FILL, phi, BP.p_max_Pa)
        t += 1e-3
        assert p == pytest.approx(300e3 * (1.0 - math.exp(-t / 0.05)), rel=1e-9)   # ṗ = (u − p)/Tp


@pytest.mark.parametrize("p0, u, w, expected", [
    (100e3, 900e3, WSP_FILL, None),      # u > p̄ is bounded to p̄ (5b), p stays ≤ p̄ (5a)
    (100e3, -50e3, WSP_FILL, 0.0),       # u < 0 is bounded to 0
    (100e3, math.nan, WSP_FILL, 0.0),    # nothing valid commanded: towards 0
    (100e3, 300e3, WSP_HOLD, 100e3),     # WSP holds: pressure unchanged
    (100e3, 300e3, WSP_VENT, 0.0),       # WSP vents: u = 0, §II-C
])
def test_lag_bounds_and_wsp(p0, u, w, expected):
    phi = lag_factor(BP, 1e-3)
    p = p0
    for _ in range(5000):
        p = cylinder_lag_scalar(p, u, w, phi, BP.p_max_Pa)
        assert 0.0 <= p <= BP.p_max_Pa                               # eq. (5a)
    assert p == pytest.approx(BP.p_max_Pa if expected is None else expected, abs=1e-6)


def test_lag_plant_rejects_wrong_set_point_count():
    plant = Plant(PP, TRACK, v0_mps=10.0)
    with pytest.raises(PlantConfigError, match="pressure set-points"):
        plant.step(np.zeros(1), np.zeros(1, np.int64), np.zeros(2))


def test_brake_params_validate_the_new_options():
    with pytest.raises(PlantConfigError, match="pressure_model"):
        BrakeParams(pressure_model="pneumatic")
    with pytest.raises(PlantConfigError, match="tp_s"):
        BrakeParams(tp_s=0.0)


# --------------------------------------------------------------------------- hysteresis, eqs. (6), (10a)
def test_hysteresis_is_eq_6_in_the_continuous_limit():
    # a slow pressure cycle: τ rises with ᾱ ṗ on the squeeze line, holds while p crosses to the release
    # line (0.3 bar), falls with α̲ ṗ on it, holds again on the way back (Fig. 3)
    ps = np.concatenate([np.linspace(0, 250e3, 2501), np.linspace(250e3, 100e3, 1501)[1:],
                         np.linspace(100e3, 250e3, 1501)[1:]])
    tau, taus = 0.0, []
    for p in ps:
        tau = hysteresis_torque_scalar(tau, p, BP)
        taus.append(tau)
    taus = np.array(taus)
    dtau, dp = np.diff(taus), np.diff(ps)
    on_sq = np.isclose(taus, 0.16 * ps - 4800.0) & (taus > 0)
    on_rel = np.isclose(taus, 0.16 * ps)
    squeeze = on_sq[:-1] & on_sq[1:] & (dp > 0)        # both ends on the squeeze line
    release = on_rel[:-1] & on_rel[1:] & (dp < 0)      # both ends on the release line
    hold = ~on_sq[1:] & ~on_rel[1:] & ~on_sq[:-1] & ~on_rel[:-1] & (taus[1:] > 0)
    assert np.allclose(dtau[squeeze], 0.16 * dp[squeeze])             # ᾱ ṗ
    assert np.allclose(dtau[release], 0.16 * dp[release])             # α̲ ṗ
    assert np.all(dtau[hold] == 0.0)                                  # τ̇ = 0 otherwise
    # each reversal holds the torque over exactly the 0.3 bar between the lines
    first_release = np.flatnonzero(release)[0]
    assert ps[2500] - ps[first_release] == pytest.approx(30e3, abs=200.0)
    assert squeeze.sum() > 0 and release.sum() > 0 and hold.sum() > 0


def test_default_plant_is_unchanged_by_the_options():
    # the defaults select the foundation's plant: the EP valve model and seed 000's adhesion curve
    d = PlantParams()
    assert d.brake.pressure_model == "valve" and d.adhesion.slip_speed_peak is None
