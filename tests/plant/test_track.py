"""Track: rail condition θ(x) by segments (abrupt, smooth) or table, gradient and curvature profiles."""

import math

import numpy as np
import pytest

from plant_sim.errors import PlantConfigError
from plant_sim.params import RAIL_CONDITIONS
from plant_sim.track import Track

DRY = np.array(RAIL_CONDITIONS["dry"])
WET = np.array(RAIL_CONDITIONS["wet"])


def test_abrupt_transition_at_the_segment_start():
    track = Track.from_segments([(0.0, "dry"), (100.0, "wet"), (250.0, "dry")])
    theta = track.theta_at([-1e6, 0.0, 99.999, 100.0, 249.9, 250.0, 1e6])
    assert theta == pytest.approx(np.array([DRY, DRY, DRY, WET, WET, DRY, DRY]))


def test_smooth_transition_blends_theta_linearly_from_the_segment_start():
    track = Track.from_segments([(0.0, "dry"), (100.0, "wet", 40.0), (300.0, "dry")], transition_m=10.0)
    x = np.array([99.0, 100.0, 110.0, 120.0, 140.0, 200.0, 300.0, 305.0, 310.0, 311.0])
    lam = np.array([0.0, 0.0, 0.25, 0.5, 1.0, 1.0])[:, None]
    expected = np.vstack([DRY + lam * (WET - DRY),
                          WET, WET + 0.5 * (DRY - WET), DRY, DRY])
    assert track.theta_at(x) == pytest.approx(expected)


def test_a_transition_that_does_not_fit_is_rejected():
    with pytest.raises(PlantConfigError, match="does not fit"):
        Track.from_segments([(0.0, "dry"), (100.0, "wet", 60.0), (150.0, "dry")])


def test_table_form_interpolates_and_holds_beyond_the_ends():
    rows = [RAIL_CONDITIONS["extra_dry"], RAIL_CONDITIONS["wet"], RAIL_CONDITIONS["wet"]]
    track = Track.from_table([0.0, 50.0, 80.0], rows)
    t = np.array(rows)
    got = track.theta_at([-10.0, 0.0, 25.0, 50.0, 65.0, 80.0, 1000.0])
    assert got == pytest.approx(np.array([t[0], t[0], 0.5 * (t[0] + t[1]), t[1], t[1], t[2], t[2]]))


def test_theta_tuple_segments_are_accepted():
    track = Track.from_segments([(0.0, (0.4, 2.0, 50.0))])
    assert track.theta_at(5.0) == pytest.approx(np.array([[0.4, 2.0, 50.0]]))


def test_unknown_condition_names_it_and_the_known_ones():
    with pytest.raises(PlantConfigError) as err:
        Track.from_segments([(0.0, "dry"), (10.0, "icy")])
    msg = str(err.value)
    assert "'icy'" in msg and "segment 1" in msg
    for name in RAIL_CONDITIONS:
        assert name in msg
    assert isinstance(err.value, ValueError)


@pytest.mark.parametrize("segments, match", [
    ([], "at least one"),
    ([(10.0, "dry"), (5.0, "wet")], "not after"),
    ([(0.0, (1.0, 0.0, -2.0))], "θ3 > 0"),
    ([(0.0, (1.0, 2.0))], "tuple"),
    ([(0.0, "dry", -1.0)], "transition_m"),
])
def test_bad_segments_are_rejected(segments, match):
    with pytest.raises(PlantConfigError, match=match):
        Track.from_segments(segments)


def test_gradient_is_piecewise_constant_and_flat_before_the_first_point():
    track = Track.from_segments([(0.0, "dry")], gradient=[(100.0, 20.0), (300.0, -10.0)])
    got = track.sin_grade_at([0.0, 100.0, 299.0, 300.0, 5000.0])
    s20 = 0.02 / math.sqrt(1.0 + 0.02 ** 2)
    s10 = -0.01 / math.sqrt(1.0 + 0.01 ** 2)
    assert got == pytest.approx([0.0, s20, s20, s10, s10])


def test_curvature_degree_uses_the_30_48_m_chord_and_straights_are_zero():
    track = Track.from_segments([(0.0, "dry")], curvature=[(50.0, 300.0), (150.0, 0.0), (200.0, math.inf),
                                                          (250.0, -600.0)])
    got = track.curvature_degree_at([0.0, 60.0, 160.0, 210.0, 260.0])
    d300 = 180.0 / math.pi * 30.48 / 300.0
    assert got == pytest.approx([0.0, d300, 0.0, 0.0, d300 / 2.0])
    assert d300 == pytest.approx(5.82, abs=0.01)


def test_sample_gives_every_profile_and_where_the_interval_ends():
    track = Track.from_segments([(0.0, "dry"), (100.0, "wet", 20.0)], gradient=[(50.0, 10.0)])
    smp = track.sample([10.0, 60.0, 110.0, 200.0])
    assert smp.next_change_m == pytest.approx([50.0, 100.0, 120.0, math.inf])
    assert smp.theta == pytest.approx(track.theta_at([10.0, 60.0, 110.0, 200.0]))
    assert np.any(smp.dtheta_per_m[2]) and not np.any(smp.dtheta_per_m[[0, 1, 3]])


def test_track_is_immutable():
    track = Track.from_segments([(0.0, "dry"), (10.0, "wet")])
    assert track.knots_m.tolist() == [10.0]
    with pytest.raises(AttributeError):
        track._x = np.zeros(2)
    with pytest.raises(ValueError):
        track.knots_m[0] = 1.0
