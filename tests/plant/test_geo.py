"""plant_sim.geo (WGS-84 track geometry, distances) and plant_sim.gps (the seeded receiver model)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_sim.errors import PlantConfigError
from plant_sim.geo import (
    MEAN_RADIUS_M,
    WGS84_B_M,
    TrackGeometry,
    destination,
    geodesic_m,
    haversine_m,
    offset_north_east,
    polyline_from_legs,
)
from plant_sim.gps import CEP_PER_SIGMA, GpsModel, GpsParams

# --- published distances -------------------------------------------------------------------------------


def test_geodesic_wellington_salamanca_matches_geographiclib_docs():
    # GeographicLib's documented example (Karney; geographiclib-geodesic README): "The distance is
    # 19959679.267 m." for Wellington, NZ (41.32S, 174.81E) to Salamanca, Spain (40.96N, 5.50W)
    assert geodesic_m(-41.32, 174.81, 40.96, -5.50) == pytest.approx(19_959_679.267, abs=1e-3)


def test_direct_problem_perth_matches_geographiclib_docs():
    # same README: 20000 km SW (azimuth 225) of Perth (32.06S, 115.74E) is (32.11195529, -63.95925278)
    lat, lon, _ = destination(-32.06, 115.74, 225.0, 20_000e3)
    assert (lat, lon) == (pytest.approx(32.11195529, abs=5e-9), pytest.approx(-63.95925278, abs=5e-9))


def test_haversine_bna_lax_matches_rosetta_code():
    # Rosetta Code "Haversine formula": Nashville BNA (36.12, -86.67) to Los Angeles LAX (33.94, -118.40)
    # with R = 6372.8 km is 2887.2599506071106 km
    d = haversine_m(36.12, -86.67, 33.94, -118.40, radius_m=6372.8e3)
    assert d == pytest.approx(2_887_259.9506, abs=1e-3)


def test_mean_radius_is_the_iugg_value():
    # R1 = (2a + b)/3 = 6 371 008.771 m (Moritz 2000, quoted 6 371 008.8 m); b = 6 356 752.3142 m (TR8350.2)
    assert WGS84_B_M == pytest.approx(6_356_752.3142, abs=1e-4)
    assert MEAN_RADIUS_M == pytest.approx(6_371_008.8, abs=0.05)


@settings(max_examples=200, deadline=None)
@given(lat=st.floats(-70, 70), lon=st.floats(-180, 180), az=st.floats(0, 360), d=st.floats(1.0, 5000.0))
def test_sphere_and_ellipsoid_agree_within_0_6_percent_on_train_distances(lat, lon, az, d):
    lat2, lon2, _ = destination(lat, lon, az, d)
    assert geodesic_m(lat, lon, lat2, lon2) == pytest.approx(d, abs=1e-6)
    # worst case: north-south at the equator, R1 / (a (1 - e^2)) - 1 = 0.56 %
    assert haversine_m(lat, lon, lat2, lon2) == pytest.approx(d, rel=0.006)


def test_offset_north_east_moves_by_that_many_metres():
    lat, lon = offset_north_east(56.95, 24.10, 30.0, -40.0)
    assert geodesic_m(56.95, 24.10, lat, lon) == pytest.approx(50.0, abs=1e-6)
    assert lat > 56.95 and lon < 24.10


# --- the track polyline -------------------------------------------------------------------------------

LEGS = [(30.0, 1000.0), (60.0, 2500.0), (45.0, 700.0), (200.0, 300.0)]


@pytest.fixture(scope="module")
def track():
    return TrackGeometry(polyline_from_legs(56.95, 24.10, LEGS))


def test_track_length_is_the_sum_of_its_legs(track):
    assert track.length_m == pytest.approx(sum(length for _, length in LEGS), abs=1e-6)
    assert track.s_knots_m[1:] == pytest.approx(np.cumsum([length for _, length in LEGS]), abs=1e-6)


def test_track_points_and_headings_at_the_knots(track):
    lat, lon, head = track.at(track.s_knots_m[:-1])
    assert lat == pytest.approx(track.lat_deg[:-1], abs=1e-12)
    assert lon == pytest.approx(track.lon_deg[:-1], abs=1e-12)
    assert head == pytest.approx([az for az, _ in LEGS], abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(frac=st.floats(0.0, 1.0))
def test_round_trip_s_to_latlon_to_s(track, frac):
    s = frac * track.length_m
    lat, lon, _ = track.at(s)
    s_back, offset = track.locate(lat, lon)
    assert s_back == pytest.approx(s, abs=1e-6)
    assert abs(offset) < 1e-6


@pytest.mark.parametrize("side, sign", [(90.0, 1.0), (-90.0, -1.0)])
def test_locate_a_point_beside_the_track(track, side, sign):
    s = 2222.0
    lat, lon, head = track.at(s)
    plat, plon, _ = destination(lat, lon, head + side, 12.5)
    s_back, offset = track.locate(plat, plon)
    assert s_back == pytest.approx(s, abs=1e-3)
    assert offset == pytest.approx(sign * 12.5, abs=1e-3)


def test_locate_in_a_range_where_the_track_passes_near_itself():
    hairpin = TrackGeometry(polyline_from_legs(50.0, 10.0, [(0.0, 1000.0), (90.0, 20.0), (180.0, 1000.0)]))
    lat, lon, _ = hairpin.at(500.0)       # on the way out
    assert hairpin.locate(lat, lon)[0] == pytest.approx(500.0, abs=1e-6)
    s_back, offset = hairpin.locate(lat, lon, s_range_m=(1020.0, 2020.0))   # searched on the way back
    assert s_back == pytest.approx(1520.0, abs=0.1)
    assert abs(offset) == pytest.approx(20.0, abs=0.05)


def test_beyond_the_ends_extrapolates_along_the_end_segments(track):
    lat, lon, head = track.at(track.length_m + 100.0)
    assert geodesic_m(track.lat_deg[-1], track.lon_deg[-1], lat, lon) == pytest.approx(100.0, abs=1e-6)
    lat, lon, _ = track.at(-50.0)
    assert geodesic_m(track.lat_deg[0], track.lon_deg[0], lat, lon) == pytest.approx(50.0, abs=1e-6)


@pytest.mark.parametrize("points, needle", [
    ([(50.0, 10.0)], "at least 2 points"),
    ([(50.0, 10.0), (95.0, 10.0)], "point 1"),
    ([(50.0, 10.0), (50.0, float("nan"))], "point 1"),
    ([(50.0, 10.0), "north"], "point 1"),
    ([(50.0, 10.0), (50.0, 10.0)], "coincide"),
])
def test_bad_polylines_are_one_line_errors(points, needle):
    with pytest.raises(PlantConfigError, match=needle) as info:
        TrackGeometry(points)
    assert "\n" not in str(info.value)


def test_bad_leg_is_an_error():
    with pytest.raises(PlantConfigError, match="leg 1"):
        polyline_from_legs(50.0, 10.0, [(0.0, 10.0), (90.0, -5.0)])


# --- the receiver model --------------------------------------------------------------------------------

QUIET = dict(dropout_rate_per_h=0.0, instability_rate_per_h=0.0)
LAT0, LON0 = 56.95, 24.10


def _run(params: GpsParams, seed: int, n: int, speed: float = 20.0, heading: float = 45.0):
    model = GpsModel(params, seed)
    return [model.fix(k * params.period_us, LAT0, LON0, speed, heading) for k in range(n)]


def test_same_seed_same_fixes_other_seed_other_fixes():
    p = GpsParams()
    assert _run(p, 7, 50) == _run(p, 7, 50)
    assert _run(p, 7, 50) != _run(p, 8, 50)


def test_horizontal_error_has_the_data_sheet_cep():
    fixes = _run(GpsParams(horiz_noise_tau_s=0.0, **QUIET), 1, 4000)
    err = np.array([geodesic_m(LAT0, LON0, f.lat_deg, f.lon_deg) for f in fixes])
    assert np.median(err) == pytest.approx(2.5, rel=0.08)          # NEO-6: 2.5 m CEP
    assert GpsParams().horiz_noise_std_m * CEP_PER_SIGMA == pytest.approx(2.5)


def test_position_error_is_correlated_in_time_as_a_gauss_markov_process():
    def lag1(params):
        fixes = _run(params, 3, 3000)
        north = np.array([(f.lat_deg - LAT0) for f in fixes])
        return np.corrcoef(north[:-1], north[1:])[0, 1]

    assert lag1(GpsParams(horiz_noise_tau_s=30.0, **QUIET)) == pytest.approx(math.exp(-1.0 / 30.0), abs=0.03)
    assert abs(lag1(GpsParams(horiz_noise_tau_s=0.0, **QUIET))) < 0.1


def test_speed_and_course_noise():
    p = GpsParams(**QUIET)
    fixes = _run(p, 4, 4000, speed=20.0, heading=10.0)
    speed_err = np.array([f.speed_mps for f in fixes]) - 20.0
    course_err = np.array([f.heading_deg for f in fixes]) - 10.0
    assert np.std(speed_err) == pytest.approx(p.speed_noise_std_mps, rel=0.1)
    # the course is the direction of the noisy velocity: σ ≈ σ_v / v rad
    assert np.std(course_err) == pytest.approx(math.degrees(p.speed_noise_std_mps / 20.0), rel=0.1)


def test_course_is_held_at_standstill():
    fixes = _run(GpsParams(**QUIET), 5, 50, speed=0.0, heading=123.0)
    assert {f.heading_deg for f in fixes} == {123.0}
    assert all(f.speed_mps >= 0.0 for f in fixes)


def test_dropouts_random_and_in_given_windows():
    p = GpsParams(dropout_rate_per_h=60.0, dropout_mean_s=8.0, instability_rate_per_h=0.0)
    fixes = _run(p, 6, 7200)
    lost = sum(not f.valid for f in fixes) / len(fixes)
    expected = 60.0 * 8.0 / 3600.0 / (1.0 + 60.0 * 8.0 / 3600.0)   # renewal: on / (on + off)
    assert lost == pytest.approx(expected, rel=0.35)
    assert all(math.isnan(f.lat_deg) and f.n_sats == 0 for f in fixes if not f.valid)

    windowed = _run(GpsParams(outages_s=((10.0, 20.0),), **QUIET), 6, 30)
    assert [k for k, f in enumerate(windowed) if not f.valid] == list(range(10, 20))


def test_signal_instability_gives_valid_fixes_tens_of_metres_off():
    p = GpsParams(dropout_rate_per_h=0.0, instability_rate_per_h=120.0)
    fixes = _run(p, 9, 3600)
    unstable = [f for f in fixes if f.unstable]
    stable = [f for f in fixes if not f.unstable]
    assert 0.05 < len(unstable) / len(fixes) < 0.3 and all(f.valid for f in fixes)
    err_u = np.median([geodesic_m(LAT0, LON0, f.lat_deg, f.lon_deg) for f in unstable])
    err_s = np.median([geodesic_m(LAT0, LON0, f.lat_deg, f.lon_deg) for f in stable])
    assert err_u > 10.0 * err_s and err_u > 15.0
    assert {(f.n_sats, f.hdop) for f in unstable} == {(p.n_sats_unstable, p.hdop_unstable)}


@pytest.mark.parametrize("kwargs, needle", [
    (dict(rate_hz=0.0), "rate_hz"), (dict(rate_hz=20.0), "rate_hz"),
    (dict(horiz_noise_std_m=-1.0), "horiz_noise_std_m"), (dict(dropout_mean_s=0.0), "dropout_mean_s"),
    (dict(n_sats=3.5), "n_sats"), (dict(outages_s=((5.0, 1.0),)), "outages_s"),
])
def test_bad_gps_params(kwargs, needle):
    with pytest.raises(PlantConfigError, match=needle):
        GpsParams(**kwargs)
