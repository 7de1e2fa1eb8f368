"""hil.studies.anticollision: seed 002's anti-collision device wired into runs — the leader's script, the
radio link and control centre model, the BCU's reading of ACD_BRAKE_REQ, the ACD node with its GPS serial line
(loop:// and a real pty, garbage on the line), the judgement on plant truth, and lockstep runs of the
three scenarios."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from firmware_py.acd import AcdBrakeRequest, AcdMode, AcdRequestParams, braking_distance_m
from firmware_py.bcu import Bcu, BcuParams
from firmware_py.rx import RxTable
from hil.errors import ScenarioError
from hil.scenario import load_scenario
from hil.studies.anticollision.kpis import judge, run_judged
from hil.studies.anticollision.nodes import AcdDevice, CentreModel, RadioLink, World
from hil.studies.anticollision.scenario import (
    AcdSpec,
    RadioSpec,
    acd_params,
    geometry,
    leader_motion,
    section_of,
)
from plant_sim.errors import PlantConfigError
from plant_sim.gps import GpsModel, GpsParams
from plant_sim.leader import LeaderMotion, SpeedChange

ROOT = Path(__file__).resolve().parents[3]
SCEN = ROOT / "scenarios"


# --- the leader's script ------------------------------------------------------------------------------

@pytest.mark.parametrize("t, s, v", [
    (0.0, 100.0, 20.0),
    (5.0, 200.0, 20.0),                            # cruising
    (15.0, 300.0 + 20.0 * 5.0 - 0.5 * 2.0 * 5.0**2, 10.0),   # braking at 2 m/s² since 10 s
    (20.0, 300.0 + 20.0**2 / (2 * 2.0), 0.0),      # stands at 20 s, v²/2a = 100 m on
    (100.0, 400.0, 0.0),                           # and stays
])
def test_leader_stops_suddenly(t, s, v):
    m = LeaderMotion(100.0, 20.0, [SpeedChange(10.0, 0.0, 2.0)])
    s_t, v_t, _ = m.state(t)
    assert s_t == pytest.approx(s) and v_t == pytest.approx(v)


def test_leader_crawls_and_a_change_cuts_the_previous_short():
    m = LeaderMotion(0.0, 10.0, [SpeedChange(2.0, 20.0, 1.0), SpeedChange(4.0, 1.0, 1.0)])
    # 2-4 s: accelerating from 10 (reaches 12 m/s at 4 s, cut short), then braking to 1 m/s (11 s)
    assert m.state(4.0)[1] == pytest.approx(12.0)
    assert m.state(15.0 + 11.0)[1] == pytest.approx(1.0)
    s = m.rear_m(np.linspace(0.0, 60.0, 601))
    assert np.all(np.diff(s) >= 0.0)                          # never reverses
    assert m.rear_m(60.0) - m.rear_m(50.0) == pytest.approx(10.0)   # crawling at 1 m/s


def test_leader_script_is_checked():
    with pytest.raises(PlantConfigError, match="change 0"):
        LeaderMotion(0.0, 10.0, [SpeedChange(1.0, 5.0, 0.0)])
    with pytest.raises(PlantConfigError, match="speed >= 0"):
        LeaderMotion(0.0, -1.0, [])


# --- radio link and control centre ----------------------------------------------------------------

def test_radio_link_delays_in_order_loses_in_outages_and_is_seeded():
    spec = RadioSpec(latency_s=0.3, jitter_s=0.2, loss=0.2,
                     outages=[{"start_s": 2.0, "duration_s": 1.5}])
    got = []
    for seed in (5, 5):
        link, out = RadioLink(spec, seed), []
        for k in range(100):                           # one message per 100 ms for 10 s
            link.send(k * 100_000, {"k": k})
            out += [(k * 100_000, m["k"]) for m in link.receive(k * 100_000)]
        got.append(out)
    assert got[0] == got[1]                            # seeded
    ks = [k for _, k in got[0]]
    assert ks == sorted(ks)                            # in order
    delays = [t - k * 100_000 for t, k in got[0]]
    assert 300_000 <= min(delays) and max(delays) <= 600_000   # latency + jitter, at the 100 ms polls
    assert not any(20 <= k < 35 for k in ks)           # sent in the outage: lost
    assert 0.05 < 1 - len(ks) / (100 - 15 - 5) < 0.4   # about 20 % lost besides (last 5 not due yet)


def test_centre_pairs_on_the_section_relays_and_unpairs_when_the_leader_leaves():
    spec = AcdSpec(track={"sections": [{"from_m": -1000.0, "id": 1}, {"from_m": 2000.0, "id": 2}]})
    geo = geometry(spec)

    def rep(train, s, t):
        lat, lon, head = geo.at(s)
        return {"train": train, "t": t, "lat": lat, "lon": lon, "speed": 10.0, "heading": head,
                "section": section_of(spec, s), "length": 150.0}

    c = CentreModel()
    assert c.report(rep("U2", 100.0, 0)) == [("U2", {"type": "pair", "leader": None})]   # the ack
    out = c.report(rep("U1", 900.0, 0))
    assert ("U2", {"type": "pair", "leader": "U1"}) in out
    assert any(t == "U2" and m["type"] == "leader_report" and m["train"] == "U1" for t, m in out)
    out = c.report(rep("U1", 950.0, 1))                 # step 6: U1's next report goes to U2
    assert [m["type"] for t, m in out if t == "U2"] == ["leader_report"]
    # every report is acknowledged with the train's pair: a lost "pair" message heals itself
    assert c.report(rep("U2", 110.0, 1)) == [("U2", {"type": "pair", "leader": "U1"})]
    out = c.report(rep("U1", 2100.0, 2))                # U1 left the section
    assert ("U2", {"type": "pair", "leader": None}) in out


# --- the BCU reads ACD_BRAKE_REQ ---------------------------------------------------------------------

STEPS = BcuParams().step_decel_mps2


def acd_bcu() -> Bcu:
    """A two-car BCU that obeys the ACD, as hil/studies/anticollision/nodes.py fits it."""
    return Bcu(2, sources=[AcdBrakeRequest(AcdRequestParams(full_service_mps2=STEPS[-1]))])


def bcu_rx(bcu: Bcu, now_us: int = 0, **values) -> RxTable:
    rx = RxTable(bcu.inputs)
    for i in range(1, bcu.n_cars + 1):
        rx.update([("SpeedEst", f"BECU{i}_STATUS.SpeedEst")], {"SpeedEst": 20.0}, now_us)
    rx.update([(k.split(".")[-1], k) for k in values], {k.split(".")[-1]: v for k, v in values.items()},
              now_us)
    return rx


def test_bcu_follows_the_acd_service_request_and_its_emergency():
    bcu = acd_bcu()
    assert "ACD_BRAKE_REQ.Request" in bcu.inputs and "ACD_BRAKE_REQ.Request" not in Bcu(2).inputs
    out = {}
    for k in range(200):                                # 2 s: the jerk limit has ramped up
        rx = bcu_rx(bcu, k * 10_000, BrakeStep=2, EmergencyReq=0,
                    **{"ACD_BRAKE_REQ.Request": 1, "ACD_BRAKE_REQ.RequestedDecel": 0.6})
        out = bcu.step(k * 10_000, rx)
    # the demand is the ACD's 0.6 m/s², above the desk's step 2 (2/7 m/s²); a service brake, Source NONE
    assert out["BrakeStep"] == 2 and out["TargetDecel"] == pytest.approx(0.6) and out["Source"] == 0
    assert out["Mode"] == 1 and out["Degraded"] == 0
    rx = bcu_rx(bcu, 2_000_000, BrakeStep=0, EmergencyReq=0,
                **{"ACD_BRAKE_REQ.Request": 2, "ACD_BRAKE_REQ.RequestedDecel": 1.3})
    out = bcu.step(2_000_000, rx)
    assert out["EmergencyActive"] == 1 and out["Source"] == 2           # the ACD demanded the emergency
    quiet = acd_bcu()                 # nothing heard from the ACD yet: the desk alone
    out = quiet.step(0, bcu_rx(quiet, 0, BrakeStep=7, EmergencyReq=0))
    assert out["Source"] == 0 and out["Degraded"] == 0 and out["Mode"] == 1


def test_bcu_ignores_a_stale_acd_request_and_says_degraded():
    bcu = acd_bcu()
    rx = bcu_rx(bcu, 0, BrakeStep=0, EmergencyReq=0,
                **{"ACD_BRAKE_REQ.Request": 2, "ACD_BRAKE_REQ.RequestedDecel": 1.3})
    assert bcu.step(0, rx)["EmergencyActive"] == 1
    bcu = acd_bcu()                   # the same request, heard 0.5 s ago: stale
    for i in range(1, 3):
        rx.update([("SpeedEst", f"BECU{i}_STATUS.SpeedEst")], {"SpeedEst": 20.0}, 500_000)
    out = bcu.step(500_000, rx)
    assert out["EmergencyActive"] == 0 and out["TargetDecel"] == 0.0 and out["Degraded"] == 1


def test_an_acd_falling_silent_while_it_brakes_keeps_its_request_until_standstill():
    """A lost or deleted ACD_BRAKE_REQ never releases a brake the ACD asked for (issue #19): its last
    request holds, Degraded, until the train stands; then, still silent, it requests nothing."""
    bcu = acd_bcu()
    for k in range(200):                                 # 2 s of SERVICE 0.6 m/s²: ramped up
        rx = bcu_rx(bcu, k * 10_000, BrakeStep=0, EmergencyReq=0,
                    **{"ACD_BRAKE_REQ.Request": 1, "ACD_BRAKE_REQ.RequestedDecel": 0.6})
        out = bcu.step(k * 10_000, rx)
    assert out["TargetDecel"] == pytest.approx(0.6)
    for k in range(200, 400):                            # the ACD is silent from 2 s on; the train moves
        for i in range(1, 3):
            rx.update([("SpeedEst", f"BECU{i}_STATUS.SpeedEst")], {"SpeedEst": 10.0}, k * 10_000)
        out = bcu.step(k * 10_000, rx)
        assert out["TargetDecel"] == pytest.approx(0.6) and out["Mode"] == 1
    assert out["Degraded"] == 1
    for i in range(1, 3):                                # standstill: the held request ends
        rx.update([("SpeedEst", f"BECU{i}_STATUS.SpeedEst")], {"SpeedEst": 0.0}, 4_000_000)
    for k in range(400, 600):
        out = bcu.step(k * 10_000, rx)
    assert out["TargetDecel"] == 0.0 and out["Degraded"] == 1


# --- the ACD node: GPS over the serial line ---------------------------------------------------------

def device_run(spec: AcdSpec, serial: str = "loop", seconds: float = 60.0, v0: float = 25.0):
    """The ACD node's controller in a closed loop with a point-mass train (the BCU's full service after
    the ACD's reaction time) and the World's radio frames: returns (device, gaps at each brake start,
    stop gap, modes)."""
    dev = AcdDevice(spec, seed=3, serial=serial)
    world = World(spec, seed=3)
    rx = RxTable(dev.inputs)
    x, v, t_us, modes, starts = 100.0, v0, 0, [], []
    motion = leader_motion(spec)
    lag = round(1.0 / 0.1)
    decel = []
    try:
        while t_us <= seconds * 1e6:
            out = world.step(t_us, x, v)
            keys = [k for k in out if k in dev.inputs]
            rx.update([(k, k) for k in keys], out, t_us)
            res = dev.step(t_us, rx)
            if res["Request"] and (not modes or not modes[-1]):
                starts.append(motion.rear_m(t_us / 1e6) - x)
            modes.append(res["Request"])
            decel.append(res["RequestedDecel"] if res["Request"] else 0.0)
            a = decel[-lag] if len(decel) >= lag else 0.0
            v = max(v - a * 0.1, 0.0)
            x += v * 0.1
            t_us += 100_000
    finally:
        dev.close()
    return dev, starts, motion.rear_m(t_us / 1e6) - x, modes


LEADER = {"rear_m": 1200.0, "initial_speed_kmh": 40.0, "profile": [{"at_s": 5.0, "speed_kmh": 0.0}]}


@pytest.mark.parametrize("protocol", ["nmea", "binary"])
def test_garbage_on_the_serial_line_is_counted_and_ignored(protocol):
    clean = AcdSpec(leader=LEADER, gps={"protocol": protocol, "rate_hz": 5.0, "instability": False})
    noisy = AcdSpec(leader=LEADER, gps={"protocol": protocol, "rate_hz": 5.0, "instability": False,
                                        "garbage_per_fix": 0.4})
    d0, starts0, stop0, _ = device_run(clean)
    d1, starts1, stop1, modes1 = device_run(noisy)
    st = d1.reader.stats
    assert d1.stats.corrupted > 0.25 * d1.stats.fixes_written          # ~40 % of fixes damaged
    assert sum(st.rejected.values()) >= d1.stats.corrupted * 0.5       # and seen as such
    assert "bad_checksum" in st.rejected and len(set(st.rejected)) >= 2
    assert st.accounted(d1.reader.decoder.pending)
    assert d0.stats.accepted > d1.stats.accepted > 0.4 * d0.stats.accepted
    # the device kept working: it braked for U1 about where the clean one did, and stopped behind it
    assert len(starts1) >= 1 and starts1[0] == pytest.approx(starts0[0], abs=30.0)
    assert 0.0 < stop1 and stop1 == pytest.approx(stop0, abs=30.0)
    assert AcdMode.EMERGENCY not in modes1


def test_the_acd_reads_nmea_from_a_real_pty_through_pyserial():
    spec = AcdSpec(leader=LEADER, gps={"rate_hz": 2.0, "garbage_per_fix": 0.2})
    dev, starts, stop, _ = device_run(spec, serial="pty", seconds=50.0)
    assert dev.link is not None and dev.link.port_name.startswith("/dev/pts/")
    assert dev.reader.stats.accepted["RMC"] > 50 and dev.stats.corrupted > 0
    assert len(starts) >= 1 and stop > 0.0


def test_the_acd_built_for_real_time_gets_a_pty_wherever_it_is_hosted():
    """serial = "auto": a pseudo-terminal for a node built for real time (hil.runtime.realtime.hosted_nodes:
    the grouped host, a host of its own, `railhil node ACD`), loop:// for lockstep; the process's name does
    not decide (the ACD runs in railhil-ECUS by default)."""
    from hil.can.codec import loaded_dbc
    from hil.runtime.assembly import build_node, building_for_realtime, for_realtime

    scenario = load_scenario(SCEN / "acd_anticollision.toml")
    db, codec = loaded_dbc(scenario.dbc)
    assert scenario.acd.gps.serial == "auto" and not building_for_realtime()
    with for_realtime():
        assert building_for_realtime()
        realtime = build_node("ACD", scenario, db, codec)
    lockstep = build_node("ACD", scenario, db, codec)
    assert not building_for_realtime()
    assert (realtime.controller.serial, lockstep.controller.serial) == ("pty", "loop")


def test_instability_episodes_are_dropped_by_hdop():
    """Instability episodes (plant_sim.gps: a valid fix off by tens of m, HDOP 4) fail the HDOP check."""
    spec = AcdSpec(leader=LEADER, gps={"rate_hz": 5.0})
    dev = AcdDevice(spec, seed=1)
    dev.receiver.gps = GpsModel(GpsParams(rate_hz=5.0, instability_rate_per_h=600.0, instability_mean_s=2.0,
                                 dropout_rate_per_h=0.0), 1)
    rx = RxTable(dev.inputs)
    keys = ("ACD_GNSS_TRUTH.TrackPos", "ACD_GNSS_TRUTH.Speed")
    errors = []
    try:
        for k in range(600):                                  # 60 s at 20 m/s
            s_true = 100.0 + 2.0 * k
            rx.update([(q, q) for q in keys], {keys[0]: s_true, keys[1]: 20.0}, k * 100_000)
            dev.step(k * 100_000, rx)
            if dev.own_s is not None:                              # against the truth at the fix's time
                errors.append(abs(dev.own_s - (100.0 + 20.0 * dev.fix[3] * 1e-6)))
    finally:
        dev.close()
    assert dev.stats.high_hdop > 20 and dev.stats.accepted > 100
    # what was accepted is within the receiver's noise (2.1 m σ per axis): no 30 m-σ jump got through
    assert max(errors) < 15.0


# --- the judgement on plant truth -------------------------------------------------------------------

def test_judge_finds_collisions_overruns_and_unnecessary_brakes():
    sc = load_scenario(SCEN / "acd_red_signal.toml")
    spec = sc.acd
    t = np.arange(0.0, 40.0, 0.01)
    half = 12.5
    x1 = 100.0 + 20.0 * t                            # never brakes: runs through the red signal at 900 m
    cols = {"t_s": t, "x_m_1": x1, "v_mps_1": np.full_like(t, 20.0)}
    req_t = np.arange(0.0, 40.0, 0.1)
    req = (req_t >= 1.0).astype(int)                  # braking (requested) from 1 s, far from anything
    j = judge(sc, cols, req_t, req)
    assert j.overruns == 1 and not j.collision
    assert j.applications == 1 and j.unnecessary == 1
    assert j.min_gap_m == pytest.approx(spec.leader.rear_m - (100.0 + half), abs=1.0)
    sc2 = load_scenario(SCEN / "acd_anticollision.toml")
    m = leader_motion(sc2.acd)
    x_hit = m.rear_m(t) - half + 5.0 * (t > 30)       # the front 5 m into U1's last wagon after 30 s
    j2 = judge(sc2, {"t_s": t, "x_m_1": x_hit, "v_mps_1": np.zeros_like(t)}, req_t, np.ones_like(req_t))
    assert j2.collision and j2.min_gap_m == pytest.approx(-5.0) and j2.unnecessary == 0


def test_acd_params_come_from_the_section():
    p = acd_params(AcdSpec(prediction=False, margin_m=30.0, release_hysteresis_m=60.0))
    assert (p.predict, p.margin_m, p.release_hysteresis_m, p.emergency_margin_m) == (False, 30.0, 60.0, 20.0)


def test_bad_acd_sections_are_one_line_errors(tmp_path):
    for sets, what in ((["acd.margin_m=200"], "release_hysteresis_m"),
                       (["acd.leader.train_id=2"], "train_id"),
                       (["acd.gps.rate_hz=20"], "rate_hz"),
                       (["acd.control_centre=nohost"], "HOST:PORT"),
                       (['acd.gps.protocol="morse"'], "protocol")):
        with pytest.raises(ScenarioError, match=what) as info:
            load_scenario(SCEN / "acd_anticollision.toml", sets=sets)
        assert "\n" not in str(info.value)


# --- lockstep runs of the scenarios ---------------------------------------------------------------

def judged(path: Path, *sets: str) -> dict:
    return run_judged(load_scenario(path, sets=list(sets)).model_dump_json())


def test_lockstep_red_signal_stops_short_of_it():
    r = judged(SCEN / "acd_red_signal.toml")
    assert r["end"] == "standstill" and r["overruns"] == 0
    assert 0.0 < r["min_signal_m"] < acd_params(AcdSpec()).release_hysteresis_m + 50.0
    assert r["applications"] == 1 and r["unnecessary"] == 0


def test_lockstep_radio_outage_stops_behind_the_leader_with_and_without_prediction():
    on = judged(SCEN / "acd_radio_outage.toml")
    off = judged(SCEN / "acd_radio_outage.toml", "acd.prediction=false")
    for r in (on, off):
        assert r["end"] == "standstill" and not r["collision"] and r["min_gap_m"] > 0.0
    # prediction brakes earlier on the stale data: it keeps a larger gap
    assert on["first_brake_s"] < off["first_brake_s"] and on["min_gap_m"] > off["min_gap_m"]


def test_lockstep_runs_are_reproducible_and_brake_where_b_says():
    short = ("train.cars=1", "acd.leader.rear_m=500", "acd.leader.profile.0.at_s=3")   # ~40 s simulated
    a = judged(SCEN / "acd_anticollision.toml", *short)
    b = judged(SCEN / "acd_anticollision.toml", *short)
    a.pop("wall_s"), b.pop("wall_s")
    assert a == b
    assert a["end"] == "standstill" and not a["collision"] and a["applications"] == 1
    p = acd_params(AcdSpec())
    assert p.margin_m * 0.5 < a["min_gap_m"] < p.release_hysteresis_m + p.margin_m
    # braking began about where ΔS reached B + margin at 80 km/h (the GPS and radio add tens of m)
    b = braking_distance_m(80 / 3.6, p.service_decel_mps2, p.reaction_s) + p.margin_m
    assert not math.isnan(a["first_brake_s"]) and a["min_gap_m"] < b


def test_study_command_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    from hil.cli.main import main

    for argv, what in ((["campaign", str(ROOT / "campaigns" / "mass_sweep.toml")], "no [acd] section"),
                       (["campaign", str(tmp_path / "none.toml")], "no such campaign file"),
                       (["campaign", str(ROOT / "campaigns" / "acd_random.toml"), "--jobs", "0"], "--jobs 0"),
                       (["judge", str(tmp_path)], "not a readable run folder")):
        assert main(["reproduce", "anticollision", *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1 and what in err and "Traceback" not in err
