"""Adhesion curve of seed 000 §2.1: closed-form peak against a numerical search, θ table, helpers."""

import numpy as np
import pytest

from plant_sim.adhesion import (
    CONST_MU_RAMP_SIGMA,
    mu,
    mu_bar,
    mu_opt,
    mu_opt_bar,
    sigma_opt,
    sigma_opt_bar,
    slip_ratio,
)
from plant_sim.errors import PlantConfigError
from plant_sim.params import (
    LOCKED_RATIO,
    RAIL_CONDITIONS,
    RAIL_PEAKS,
    AdhesionParams,
    theta2_for_locked_ratio,
    theta_from_peak,
)

AP = AdhesionParams()
SIGMA_GRID = np.linspace(0.0, 1.0, 40_001)   # step 2.5e-5 (≥ 300 points below the smallest peak, σ° = 0.0075)


@pytest.mark.parametrize("name", sorted(RAIL_CONDITIONS))
@pytest.mark.parametrize("v", [0.0, 10.0, 25.0, 40.0])
def test_numerical_peak_matches_closed_form(name, v):
    theta = np.array([RAIL_CONDITIONS[name]])
    curve = mu(theta, SIGMA_GRID, np.full(SIGMA_GRID.shape, v), AP)
    k = 1.0 + v / 40.0                          # k1 = k2 = 1 + v/40, seed 000 §3
    i = int(np.argmax(curve))
    # refine the grid maximum with a parabola through its neighbours
    y0, y1, y2 = curve[i - 1:i + 2]
    h = SIGMA_GRID[1] - SIGMA_GRID[0]
    sig_num = SIGMA_GRID[i] + 0.5 * h * (y0 - y2) / (y0 - 2 * y1 + y2)
    assert sig_num == pytest.approx(float(sigma_opt_bar(theta)[0]) / k, rel=1e-3)
    assert curve.max() == pytest.approx(float(mu_opt_bar(theta)[0]) / k, rel=1e-3)
    assert float(sigma_opt(theta, np.array([v]), AP)[0]) == pytest.approx(float(sigma_opt_bar(theta)[0]) / k)
    assert float(mu_opt(theta, np.array([v]), AP)[0]) == pytest.approx(float(mu_opt_bar(theta)[0]) / k)


@pytest.mark.parametrize("name", sorted(RAIL_CONDITIONS))
def test_table_has_the_documented_peaks_and_locked_wheel_adhesion(name):
    theta = np.array([RAIL_CONDITIONS[name]])
    s_opt, m_opt = RAIL_PEAKS[name]
    assert sigma_opt_bar(theta)[0] == pytest.approx(s_opt, rel=1e-9)
    assert mu_opt_bar(theta)[0] == pytest.approx(m_opt, rel=1e-9)
    assert mu_bar(theta, np.array([1.0]))[0] == pytest.approx(LOCKED_RATIO * m_opt, rel=1e-9)


def test_mu_bar_is_mu_at_rest_and_the_closed_form_to_the_last_bit():
    theta = np.array([RAIL_CONDITIONS["wet"]])
    t1, t2, t3 = RAIL_CONDITIONS["wet"]
    sig = np.linspace(0.0, 1.0, 101)
    assert mu_bar(theta, sig).tolist() == (np.sqrt(sig) / (t1 + sig * (t2 + t3 * sig))).tolist()
    assert mu_bar(theta, sig).tolist() == mu(theta, sig, np.zeros(101), AdhesionParams(0.3, 0.7)).tolist()


def test_conditions_are_ordered_from_extra_dry_to_extra_wet():
    peaks = [float(mu_opt_bar(np.array([RAIL_CONDITIONS[c]]))[0])
             for c in ("extra_dry", "dry", "wet", "extra_wet")]
    assert peaks == sorted(peaks, reverse=True)


@pytest.mark.parametrize("sigma_o, mu_o, theta2", [
    (0.04, 0.35, 0.0), (0.03, 0.25, 5.0), (0.02, 0.10, 0.0), (0.015, 0.05, 60.0), (0.1, 0.6, 1.0),
])
def test_theta_from_peak_round_trips(sigma_o, mu_o, theta2):
    theta = np.array([theta_from_peak(sigma_o, mu_o, theta2)])
    assert theta[0, 1] == theta2
    assert sigma_opt_bar(theta)[0] == pytest.approx(sigma_o, rel=1e-12)
    assert mu_opt_bar(theta)[0] == pytest.approx(mu_o, rel=1e-12)


def test_theta2_for_locked_ratio_round_trips():
    theta2 = theta2_for_locked_ratio(0.03, 0.25, 0.15)
    theta = np.array([theta_from_peak(0.03, 0.25, theta2)])
    assert mu_bar(theta, np.array([1.0]))[0] == pytest.approx(0.15 * 0.25, rel=1e-12)


def test_theta_from_peak_rejects_an_infeasible_theta2():
    with pytest.raises(PlantConfigError, match="theta2"):
        theta_from_peak(0.02, 0.1, 40.0)      # θ3 would be negative
    with pytest.raises(PlantConfigError, match="sigma_opt"):
        theta_from_peak(0.0, 0.1)


def test_speed_factors_scale_the_curve_as_eq_1():
    theta = np.array([RAIL_CONDITIONS["dry"]])
    sig = np.array([0.01, 0.05, 0.3])
    ap = AdhesionParams(pi1_s_per_m=0.02, pi2_s_per_m=0.05)
    v = np.full(3, 20.0)
    assert mu(theta, sig, v, ap) == pytest.approx(mu_bar(theta, 2.0 * sig) / 1.4, rel=1e-12)


def test_slip_ratio_is_regularised_and_clipped():
    s = np.array([0.0, 0.5, 0.2, 0.2, 3.0, -1.0])
    v = np.array([20.0, 20.0, 0.1, 0.0, 1.0, 5.0])
    assert slip_ratio(s, v) == pytest.approx([0.0, 0.025, 0.4, 0.4, 1.0, 0.0])


def test_constant_mu_is_flat_beyond_its_ramp():
    ap = AdhesionParams(constant_mu=0.1)
    theta = np.array([RAIL_CONDITIONS["wet"]] * 4)
    sig = np.array([0.0, CONST_MU_RAMP_SIGMA / 2, 0.3, 1.0])
    assert mu(theta, sig, np.full(4, 30.0), ap) == pytest.approx([0.0, 0.05, 0.1, 0.1])
    assert mu_opt(theta, np.full(4, 30.0), ap) == pytest.approx([0.1] * 4)
    assert sigma_opt(theta, np.full(4, 30.0), ap) == pytest.approx([CONST_MU_RAMP_SIGMA] * 4)
