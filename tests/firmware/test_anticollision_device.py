"""The anti-collision device (firmware_py.acd), seed 002 §V steps 1–12: pure helpers, keyword tables for
the mode logic, table tests of one cycle (brake, hold, release, red light, stale data), step tests
through the node runtime's RxTable with the DBC's names, and a closed loop that stops behind a leader."""

import math
from pathlib import Path

import cantools
import pytest

from firmware_py.acd import (
    MEAN_EARTH_RADIUS_M,
    WGS84_A_M,
    WGS84_F,
    Acd,
    AcdInputs,
    AcdMode,
    AcdParams,
    Aspect,
    Cause,
    LeaderReport,
    OwnFix,
    SignalReport,
    TrainPosition,
    acd_evaluate,
    acd_mode_transition,
    braking_distance_m,
    haversine_m,
    max_advance_m,
    min_advance_m,
    pair_on_sections,
    required_decel_mps2,
)
from firmware_py.rx import RxTable
from hil.runtime.node import Binding
from plant_sim import geo

DBC = Path(__file__).resolve().parents[2] / "dbc" / "train_brake.dbc"
P = AcdParams()
LAT0, LON0, AZ = 56.9496, 24.1052, 63.0       # Riga; the track runs ENE


def ahead(d_m: float, az: float = AZ, lat: float = LAT0, lon: float = LON0) -> tuple[float, float]:
    """A point d_m [m] ahead of (lat, lon) along the geodesic of azimuth az (Karney, plant_sim.geo)."""
    la, lo, _ = geo.destination(lat, lon, az, d_m)
    return la, lo


# --- the distance formula ---------------------------------------------------------------------------

@pytest.mark.parametrize("lat", [0.0, 45.0, 56.9496, 70.0, -33.9])
@pytest.mark.parametrize("az", [0.0, 63.0, 90.0, 181.0, 300.0])
@pytest.mark.parametrize("dist", [1.0, 850.0, 10_000.0])
def test_haversine_agrees_with_plant_sim_geo_to_a_millimetre_over_10_km(lat, az, dist):
    lat2, lon2 = ahead(dist, az, lat, 24.1)
    mine = haversine_m(lat, 24.1, lat2, lon2)
    assert abs(mine - geo.haversine_m(lat, 24.1, lat2, lon2)) < 1e-3
    # and it is the sphere, not the ellipsoid: at most R1 / M0 − 1 (0.56 %) off the geodesic, M0 = a (1 − e²)
    # the smallest radius of curvature of the ellipsoid (north–south at the equator)
    e2 = WGS84_F * (2.0 - WGS84_F)
    assert mine == pytest.approx(dist, rel=MEAN_EARTH_RADIUS_M / (WGS84_A_M * (1.0 - e2)) - 1.0 + 1e-9)


def test_haversine_is_symmetric_and_zero_on_a_point():
    la, lo = ahead(1234.5)
    assert haversine_m(LAT0, LON0, la, lo) == haversine_m(la, lo, LAT0, LON0)
    assert haversine_m(LAT0, LON0, LAT0, LON0) == 0.0


# --- pure helpers -----------------------------------------------------------------------------------

@pytest.mark.parametrize("v, a, tr, expected", [
    (0.0, 1.0, 1.0, 0.0),
    (20.0, 1.0, 0.0, 200.0),          # v²/2a
    (20.0, 1.0, 1.0, 220.0),          # + v t_r
    (10.0, 0.5, 2.0, 120.0),
    (-3.0, 1.0, 1.0, 0.0),            # a negative speed (noise) brakes nothing
])
def test_braking_distance_table(v, a, tr, expected):
    assert braking_distance_m(v, a, tr) == pytest.approx(expected)


@pytest.mark.parametrize("v, t, a, expected", [
    (10.0, 0.0, 1.5, 0.0),
    (10.0, 2.0, 1.5, 20.0 - 3.0),     # v t − ½ a t²
    (10.0, 100.0, 2.0, 25.0),         # stood after 5 s: v²/2a, never reverses
    (0.0, 50.0, 1.5, 0.0),
])
def test_min_advance_table(v, t, a, expected):
    assert min_advance_m(v, t, a) == pytest.approx(expected)


def test_min_advance_is_continuous_and_monotonic_and_below_dead_reckoning():
    ts = [k * 0.25 for k in range(0, 200)]
    adv = [min_advance_m(12.0, t, 1.5) for t in ts]
    assert all(b >= a for a, b in zip(adv, adv[1:], strict=False))
    assert all(x <= 12.0 * t + 1e-12 for x, t in zip(adv, ts, strict=True))
    assert max_advance_m(12.0, 3.0, 1.0) == pytest.approx(36.0 + 4.5)


@pytest.mark.parametrize("v, d, m, tr, expected", [
    (20.0, 270.0, 50.0, 1.0, 1.0),    # 400 / (2 · (270 − 50 − 20))
    (20.0, 470.0, 50.0, 1.0, 0.5),
    (20.0, 60.0, 50.0, 1.0, math.inf),
    (0.0, 10.0, 50.0, 1.0, 0.0),
])
def test_required_decel_table(v, d, m, tr, expected):
    assert required_decel_mps2(v, d, m, tr) == pytest.approx(expected)


# --- mode logic: keyword table ----------------------------------------------------------------------

M, S, E = AcdMode.MONITORING, AcdMode.SERVICE, AcdMode.EMERGENCY


@pytest.mark.parametrize("mode, brake, emergency, clear, expected", [
    (M, False, False, True, M),       # nothing ahead
    (M, False, False, False, M),      # something ahead, far
    (M, True, False, False, S),       # step 10: brake
    (M, True, True, False, E),        # even emergency braking barely makes it
    (S, False, False, False, S),      # hold: not yet clear
    (S, True, False, False, S),
    (S, False, False, True, M),       # step 12: release
    (S, True, True, False, E),        # escalate
    (E, True, False, False, E),       # never steps down to service
    (E, False, False, False, E),      # hold
    (E, False, False, True, M),       # released
])
def test_mode_transition_table(mode, brake, emergency, clear, expected):
    assert acd_mode_transition(mode, brake=brake, emergency=emergency, clear=clear) == expected


# --- one cycle: brake, hold, release, red light, stale data ------------------------------------------

B20 = braking_distance_m(20.0, P.service_decel_mps2, P.reaction_s)     # 220 m at 20 m/s
BE20 = braking_distance_m(20.0, P.emergency_decel_mps2, P.emergency_reaction_s)


def situation(gap_m: float, *, own_speed=20.0, own_age=0.0, leader_speed=0.0, leader_age=0.0,
              leader_section=7, own_section=7, leader_id=2, signal=None) -> AcdInputs:
    """Own train at the origin running AZ; leader's last wagon gap_m ahead on the track."""
    la, lo = ahead(gap_m)
    leader = LeaderReport(leader_id, la, lo, leader_speed, leader_section, 180.0, leader_age)
    return AcdInputs(OwnFix(LAT0, LON0, own_speed, own_age), own_section, leader, signal)


def sphere(d_m: float) -> float:
    """The spherical distance the device computes to a point d_m [m] ahead on the ellipsoid."""
    la, lo = ahead(d_m)
    return haversine_m(LAT0, LON0, la, lo)


def red(d_m: float, aspect=Aspect.RED, age=0.0) -> SignalReport:
    la, lo = ahead(d_m)
    return SignalReport(int(aspect), la, lo, age)


@pytest.mark.parametrize("name, mode, inputs, expected_mode, expected_cause", [
    # brake: ΔS just inside / outside B + margin (the ellipsoid-sphere difference stays far below 1 m)
    ("brake", M, situation(B20 + P.margin_m - 2.0), S, Cause.LEADER),
    ("no brake", M, situation(B20 + P.margin_m + 2.0), M, Cause.NONE),
    ("emergency", M, situation(BE20 + P.emergency_margin_m - 2.0), E, Cause.LEADER),
    ("service, not yet emergency", M, situation(BE20 + P.emergency_margin_m + 2.0), S, Cause.LEADER),
    # hold: braking, leader moving, but ΔS inside B + hysteresis
    ("hold", S, situation(B20 + P.release_hysteresis_m - 2.0, leader_speed=5.0), S, Cause.LEADER),
    ("hold, leader stands", S, situation(B20 + 1000.0, leader_speed=0.0), S, Cause.LEADER),
    ("hold emergency", E, situation(B20 + P.margin_m + 5.0, leader_speed=5.0), E, Cause.LEADER),
    # release (steps 11–12): leader moves away (faster than us) and ΔS beyond B + hysteresis
    ("release", S, situation(B20 + P.release_hysteresis_m + 2.0, leader_speed=25.0), M, Cause.NONE),
    ("hold, leader moves but slower than us", S, situation(B20 + P.release_hysteresis_m + 2.0,
                                                           leader_speed=5.0), S, Cause.LEADER),
    ("release, leader left section", S, situation(50.0, leader_section=8), M, Cause.NONE),
    ("release, no leader", S, AcdInputs(OwnFix(LAT0, LON0, 20.0, 0.0), 7, None, None), M, Cause.NONE),
    ("other section ignored", M, situation(30.0, leader_section=9), M, Cause.NONE),
    ("unknown own section: leader counts", M, situation(30.0, own_section=None), E, Cause.LEADER),
    # red light at or under the braking distance: braking at once
    ("red within B", M, AcdInputs(OwnFix(LAT0, LON0, 20.0, 0.0), 7, None, red(B20 + P.margin_m - 2.0)), S,
     Cause.RED_SIGNAL),
    ("red very near", M, AcdInputs(OwnFix(LAT0, LON0, 20.0, 0.0), 7, None, red(BE20)), E, Cause.RED_SIGNAL),
    ("red far", M, AcdInputs(OwnFix(LAT0, LON0, 20.0, 0.0), 7, None, red(B20 + P.margin_m + 2.0)), M,
     Cause.NONE),
    ("green near", M, AcdInputs(OwnFix(LAT0, LON0, 20.0, 0.0), 7, None, red(BE20, Aspect.GREEN)), M,
     Cause.NONE),
    ("red holds braking", S, situation(5000.0, leader_speed=10.0, signal=red(B20 + 500.0)), S,
     Cause.RED_SIGNAL),
    ("red turns green: release", S,
     AcdInputs(OwnFix(LAT0, LON0, 20.0, 0.0), 7, None, red(B20, Aspect.GREEN)), M, Cause.NONE),
    # stale data
    ("stale green counts as red", M, AcdInputs(OwnFix(LAT0, LON0, 20.0, 0.0), 7, None,
                                               red(B20 + P.margin_m - 2.0, Aspect.GREEN,
                                                   age=P.signal_fresh_s + 1.0)), S,
     Cause.RED_SIGNAL),
    ("late report: no release", S,
     situation(B20 + 1000.0, leader_speed=5.0, leader_age=P.leader_fresh_s + 1.0), S, Cause.LEADER),
    ("old own fix brakes earlier", M, situation(B20 + P.margin_m + 40.0, own_age=2.0), S, Cause.LEADER),
    ("no own fix: hold", S, AcdInputs(None, 7, None, None), S, Cause.NONE),
    ("no own fix: nothing", M, AcdInputs(None, 7, None, None), M, Cause.NONE),
])
def test_one_cycle_table(name, mode, inputs, expected_mode, expected_cause):
    dec = acd_evaluate(P, mode, inputs)
    assert (dec.mode, dec.cause) == (expected_mode, expected_cause), name


def test_brake_threshold_is_exactly_b_plus_margin_on_the_sphere():
    """At the threshold the decision flips: ΔS computed by the device against B + margin."""
    target = B20 + P.margin_m
    lo = acd_evaluate(P, M, situation(target - 0.05)).leader_gap_m
    assert lo == pytest.approx(sphere(target - 0.05))
    # find the flip by bisection on the input distance; it must sit at ΔS = B + margin within 1 mm
    a, b = target - 5.0, target + 5.0
    for _ in range(40):
        mid = (a + b) / 2
        if acd_evaluate(P, M, situation(mid)).mode == S:
            a = mid
        else:
            b = mid
    assert sphere(a) == pytest.approx(target, abs=1e-3)


def test_requested_decel_adapts_to_the_room_left():
    """Service braking asks for the deceleration that stops margin short of the obstacle, within limits."""
    d = B20 + P.margin_m - 2.0
    dec = acd_evaluate(P, M, situation(d))
    expected = 20.0 ** 2 / (2 * (dec.distance_m - P.margin_m - 20.0 * P.reaction_s))
    assert dec.requested_decel_mps2 == pytest.approx(min(expected, P.service_decel_mps2))
    # holding far away with a slow train: the smallest service request, not zero
    hold = acd_evaluate(P, S, situation(2000.0, own_speed=3.0, leader_speed=0.0))
    assert hold.mode == S and hold.requested_decel_mps2 == P.min_decel_mps2
    assert acd_evaluate(P, M, situation(BE20)).requested_decel_mps2 == P.emergency_decel_mps2


@pytest.mark.parametrize("leader_speed", [0.0, 8.0, 25.0])
def test_prediction_margin_grows_with_the_age_of_the_leader_report(leader_speed):
    """Dead reckoning: the nominal gap moves with the leader's reported speed; the uncertainty margin
    (the leader may have braked hard) is 0 on a fresh report and never shrinks as the report ages."""
    ages = [0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 60.0]
    decs = [acd_evaluate(P, M, situation(3000.0, leader_speed=leader_speed, leader_age=a)) for a in ages]
    base = decs[0].leader_gap_m
    assert decs[0].uncertainty_m == pytest.approx(0.0, abs=1e-9)
    for a, dec in zip(ages, decs, strict=True):
        assert dec.leader_gap_nominal_m == pytest.approx(base + leader_speed * a)
        worst = min_advance_m(leader_speed, a, P.leader_decel_max_mps2)
        assert dec.leader_gap_m == pytest.approx(base + worst)
        assert dec.leader_late == (a > P.leader_fresh_s)
    unc = [d.uncertainty_m for d in decs]
    assert all(y >= x for x, y in zip(unc, unc[1:], strict=False))
    if leader_speed > 0:
        assert unc[-1] > 0.0
        # lost radio: the leader is a standing obstacle at its furthest-back possible position
        stop = leader_speed ** 2 / (2 * P.leader_decel_max_mps2)
        assert decs[-1].leader_gap_m == pytest.approx(base + stop)


def test_late_report_brakes_where_a_fresh_one_would_not():
    """The leader runs at 15 m/s, its last wagon now 100 m beyond B + margin.  A report 1 s old, dead
    reckoned: the follower need not brake.  The report of 20 s ago, dead reckoned to the same nominal
    position: the leader may have stopped meanwhile, and the follower brakes on the prediction."""
    now_gap = B20 + P.margin_m + 100.0
    fresh = acd_evaluate(P, M, situation(now_gap - 15.0 * 1.0, leader_speed=15.0, leader_age=1.0))
    late = acd_evaluate(P, M, situation(now_gap - 15.0 * 20.0, leader_speed=15.0, leader_age=20.0))
    # the same nominal position, up to the sphere's 0.3 % here over the 300 m dead reckoned
    assert fresh.leader_gap_nominal_m == pytest.approx(late.leader_gap_nominal_m, abs=2.0)
    assert fresh.mode == M and not fresh.leader_late
    assert late.mode != M and late.leader_late


def test_params_are_checked():
    with pytest.raises(ValueError, match="release_hysteresis_m"):
        AcdParams(margin_m=100.0, release_hysteresis_m=50.0)
    with pytest.raises(ValueError, match="service_decel_mps2"):
        AcdParams(service_decel_mps2=0.0)


def test_leader_position_of_the_locomotive_subtracts_the_length():
    p_front = AcdParams(leader_pos_is_front=True)
    dec = acd_evaluate(p_front, M, situation(1000.0))
    assert dec.leader_gap_m == pytest.approx(sphere(1000.0) - 180.0)


# --- the controller class through the node runtime's RxTable ----------------------------------------

def test_acd_names_are_the_dbcs():
    db = cantools.database.load_file(DBC)
    binding = Binding.build(db, "ACD", Acd.INPUTS, Acd.OUTPUTS,
                            rx_messages=["RADIO_LEADER_POS", "RADIO_LEADER_INFO", "RADIO_SIGNAL"],
                            tx_messages=["ACD_BRAKE_REQ", "ACD_STATUS"])
    assert set(binding.inputs) == set(Acd.INPUTS)
    msg = db.get_message_by_name("ACD_BRAKE_REQ")
    req = msg.get_signal_by_name("Request")
    assert {int(k): str(v) for k, v in req.choices.items()} == {m.value: n for m, n in zip(
        AcdMode, ("NONE", "SERVICE", "EMERGENCY"), strict=True)}
    aspect = db.get_message_by_name("RADIO_SIGNAL").get_signal_by_name("Aspect")
    assert {int(k): str(v) for k, v in aspect.choices.items()} == {a.value: a.name for a in Aspect}
    status = db.get_message_by_name("ACD_STATUS")
    assert P.no_obstacle_m == status.get_signal_by_name("DistanceToObstacle").maximum
    assert P.cycle_us == msg.cycle_time * 1000


def radio(rx: RxTable, t_us: int, *, lat, lon, leader_id=2, section=7, speed=0.0, length=180.0, age=0.0):
    rx.update([("Latitude", "RADIO_LEADER_POS.Latitude"), ("Longitude", "RADIO_LEADER_POS.Longitude")],
              {"Latitude": lat, "Longitude": lon}, t_us)
    rx.update([(k.split(".")[1], k) for k in Acd.INPUTS[2:7]],
              {"LeaderId": leader_id, "RouteSection": section, "Speed": speed, "TrainLength": length,
               "AgeOfReport": age}, t_us)


def acd_rx() -> RxTable:
    """The radio frames and the own-train inputs (GPS over serial, route section), as the ACD device
    (hil.studies.anticollision.nodes.AcdDevice) gives them to the firmware."""
    return RxTable(Acd.INPUTS + Acd.LOCAL_INPUTS)


def test_step_uses_the_time_since_the_radio_frame_arrived():
    acd = Acd()
    rx = acd_rx()
    rx.receive(dict(OwnLatitude=LAT0, OwnLongitude=LON0, OwnSpeed=20.0, OwnFixValid=1, OwnFixAge=0.0,
                    OwnRouteSection=7), 0)
    la, lo = ahead(3000.0)
    radio(rx, 0, lat=la, lon=lo, speed=10.0, age=0.4)
    out = acd.step(100_000, rx)
    assert out["Request"] == 0
    assert acd.last.leader_gap_nominal_m == pytest.approx(sphere(3000.0) + 10.0 * 0.5)
    out = acd.step(5_000_000, rx)                 # no new radio frame for 5 s: predicted, late
    assert acd.last.leader_late
    assert acd.last.leader_gap_nominal_m == pytest.approx(sphere(3000.0) + 10.0 * 5.4)
    assert out["DistanceToObstacle"] == pytest.approx(acd.last.leader_gap_m)


def test_step_keeps_the_last_valid_fix_and_ages_it():
    acd = Acd()
    rx = acd_rx()
    rx.receive(dict(OwnLatitude=LAT0, OwnLongitude=LON0, OwnSpeed=20.0, OwnFixValid=1, OwnFixAge=0.2,
                    OwnRouteSection=7), 0)
    la, lo = ahead(2000.0)
    radio(rx, 0, lat=la, lon=lo)
    acd.step(0, rx)
    assert acd.last.speed_worst_mps == pytest.approx(20.0 + P.own_accel_max_mps2 * 0.2)
    rx.receive({"OwnFixValid": 0, "OwnLatitude": float("nan")}, 3_000_000)   # tunnel: no fix
    acd.step(3_000_000, rx)
    assert acd.last.speed_worst_mps == pytest.approx(20.0 + P.own_accel_max_mps2 * 3.2)
    assert acd.last.leader_gap_m == pytest.approx(sphere(2000.0) - max_advance_m(20.0, 3.2, 1.0))


def test_leader_id_zero_means_no_leader_and_outputs_fit_the_dbc():
    db = cantools.database.load_file(DBC)
    msg = db.get_message_by_name("ACD_BRAKE_REQ")
    acd = Acd()
    rx = acd_rx()
    rx.receive(dict(OwnLatitude=LAT0, OwnLongitude=LON0, OwnSpeed=20.0, OwnFixValid=1, OwnFixAge=0.0), 0)
    la, lo = ahead(20.0)
    radio(rx, 0, lat=la, lon=lo, leader_id=0)
    out = acd.step(0, rx)
    assert out == {"Request": 0, "RequestedDecel": 0.0, "DistanceToObstacle": P.no_obstacle_m}
    radio(rx, 0, lat=la, lon=lo, leader_id=3)
    out = acd.step(100_000, rx)
    assert out["Request"] == int(AcdMode.EMERGENCY)
    data = msg.encode({"CHECKSUM": 0, "COUNTER": 0, "SecOCFreshness": 0, "SecOCMAC": 0,
                       **{k: out[k] for k in ("Request", "RequestedDecel")}})
    back = msg.decode(data, decode_choices=False)
    assert back["Request"] == 2 and back["RequestedDecel"] == pytest.approx(P.emergency_decel_mps2)


def test_closed_loop_stops_behind_a_standing_leader_and_releases_when_it_leaves():
    """A follower at 25 m/s on a 5 km straight behind a standing train.  The brake answers the request
    after the reaction time (first-order, no better than the ACD assumes).  The follower must stop
    short of the leader's last wagon by at least part of the margin, hold while the leader stands, and
    release once the leader has driven off far enough."""
    acd = Acd()
    rx = acd_rx()
    dt_us = P.cycle_us
    dt_s = dt_us * 1e-6
    x, v, cmd = 0.0, 25.0, []
    leader_x, leader_v = 3000.0, 0.0
    delay_cycles = round(P.reaction_s / dt_s)
    modes, gaps, stop_gap = [], [], None
    for k in range(3000):
        t_us = k * dt_us
        lat, lon = ahead(x)
        rx.receive(dict(OwnLatitude=lat, OwnLongitude=lon, OwnSpeed=v, OwnFixValid=1, OwnFixAge=0.0,
                        OwnRouteSection=7), t_us)
        if k % 10 == 0:                                          # the radio: 1 Hz (DBC)
            la, lo = ahead(leader_x)
            radio(rx, t_us, lat=la, lon=lo, speed=leader_v)
        out = acd.step(t_us, rx)
        modes.append(out["Request"])
        gaps.append(acd.last.leader_gap_m)
        cmd.append(out["RequestedDecel"] if out["Request"] else 0.0)
        a = cmd[k - delay_cycles] if k >= delay_cycles else 0.0     # the brake acts t_r later
        v = max(v - a * dt_s, 0.0)
        x += v * dt_s
        if v == 0.0 and stop_gap is None:
            stop_gap = leader_x - x
        if k == 1500:                                             # 150 s: the leader drives off
            leader_v = 15.0
        leader_x += leader_v * dt_s
    assert AcdMode.EMERGENCY not in modes
    first = modes.index(AcdMode.SERVICE)
    # braking began when ΔS reached B + margin at 25 m/s, not earlier
    b_then = braking_distance_m(25.0, P.service_decel_mps2, P.reaction_s) + P.margin_m
    assert gaps[first] <= b_then < gaps[first - 1]
    assert stop_gap is not None and P.margin_m * 0.5 < stop_gap < P.release_hysteresis_m + P.margin_m
    assert all(m == AcdMode.SERVICE for m in modes[first:1500])  # held while the leader stood
    assert modes[-1] == AcdMode.MONITORING                       # released after it left


# --- steps 4–5: pairing on a route section ----------------------------------------------------------

def test_pairing_orders_trains_along_the_running_direction():
    pts = {n: ahead(d) for n, d in (("A", 0.0), ("B", 900.0), ("C", 2500.0))}
    trains = [TrainPosition("C", *pts["C"], 4, AZ), TrainPosition("A", *pts["A"], 4, None),
              TrainPosition("B", *pts["B"], 4, AZ + 2.0), TrainPosition("X", *pts["B"], 5, AZ)]
    assert pair_on_sections(trains) == {"A": ("B", None), "B": ("C", "A"), "C": (None, "B"),
                                        "X": (None, None)}
    back = [TrainPosition(t.train, t.lat_deg, t.lon_deg, t.route_section, (AZ + 180.0) % 360)
            for t in trains]
    assert pair_on_sections(back)["B"] == ("A", "C")
    no_heading = [TrainPosition(t.train, t.lat_deg, t.lon_deg, 4, None) for t in trains[:3]]
    assert pair_on_sections(no_heading) == {"A": (None, None), "B": (None, None), "C": (None, None)}


# --- prediction off: the paper's plain algorithm (for the campaign's comparison) ---------------------

P_OFF = AcdParams(predict=False)


@pytest.mark.parametrize("own_age, leader_speed, leader_age", [
    (0.0, 0.0, 0.0), (2.0, 0.0, 0.0), (0.0, 20.0, 4.0), (3.0, 10.0, 5.0)])
def test_without_prediction_the_ages_are_ignored(own_age, leader_speed, leader_age):
    inp = situation(1000.0, own_age=own_age, leader_speed=leader_speed, leader_age=leader_age)
    dec = acd_evaluate(P_OFF, M, inp)
    assert dec.leader_gap_m == pytest.approx(sphere(1000.0))                 # ΔS as reported
    assert dec.speed_worst_mps == pytest.approx(20.0)                        # B at the fix's speed
    assert dec.uncertainty_m == pytest.approx(0.0)
    on = acd_evaluate(P, M, inp)
    # prediction moves a standing leader not at all and the own train forward: a smaller gap; a moving
    # leader is credited with the least it can have run since its report
    expected = sphere(1000.0) - max_advance_m(20.0, own_age, P.own_accel_max_mps2) + min_advance_m(
        leader_speed, leader_age, P.leader_decel_max_mps2)
    assert on.leader_gap_m == pytest.approx(expected)
    assert dec.leader_late == on.leader_late                                 # freshness rules stay


def test_without_prediction_a_stale_signal_still_counts_as_red():
    inp = AcdInputs(OwnFix(LAT0, LON0, 20.0, 0.0), 7, None, red(200.0, aspect=Aspect.GREEN, age=5.0))
    assert acd_evaluate(P_OFF, M, inp).mode == AcdMode.SERVICE
