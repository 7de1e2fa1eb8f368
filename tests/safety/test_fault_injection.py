"""Fault injection on the lockstep bus: each EN 50159 threat on a safety frame, a babbling node and a
node going bus-off, and what the E2E check of the receivers reports."""

import pytest
from conftest import DEFAULT, ROOT

from hil.errors import ScenarioError
from hil.report.run import run_scenario_lockstep
from hil.scenario import load_scenario, parse_scenario

T0 = 3.0                     # fault window start [s]; BCU_DEMAND runs every 10 ms
CYCLE_US = 10_000


def scenario_with(*faults, seconds=3.3, seed=1, dbc=None):
    base = load_scenario(DEFAULT)
    return parse_scenario({**base.model_dump(), "seed": seed, "max_duration_s": seconds,
                           "faults": list(faults), **({"dbc": str(dbc)} if dbc else {})})


def e2e_only_dbc(tmp_path):
    """The train DBC with BECU1_PRESS_CMD's SecOCDataID taken away: the frame keeps its layout, E2E
    covers all 8 bytes and nothing authenticates it -- the pressure command as it was before issue #9."""
    text = (ROOT / "dbc" / "train_brake.dbc").read_text()
    line = 'BA_ "SecOCDataID" BO_ 49 49;\n'
    assert line in text
    path = tmp_path / "e2e_only.dbc"
    path.write_text(text.replace(line, ""))
    return path


def e2e_events_after(report, node, message, t0_s=T0):
    events = report.outcome.node_stats[node]["e2e_events"]
    return [(t, status) for t, msg, status in events if msg == message and t >= t0_s * 1e6]


MAC, STALE = "SECOC_MAC_MISMATCH", "SECOC_STALE_FRESHNESS"
# what a receiver reports first, by (threat, authenticated): SecOC verifies before the E2E check
DETECTED_AS = {
    ("corruption", True): {MAC, STALE}, ("corruption", False): {"ERROR"},
    ("insertion", True): {MAC, STALE}, ("insertion", False): {"ERROR"},
    ("repetition", True): {STALE}, ("repetition", False): {"REPEATED"},
    ("deletion", True): {"OKSOMELOST", "NONEWDATA"}, ("deletion", False): {"OKSOMELOST", "NONEWDATA"},
    ("resequencing", True): {"WRONGSEQUENCE", "REPEATED", "OKSOMELOST", "NONEWDATA", STALE},
    ("resequencing", False): {"WRONGSEQUENCE", "REPEATED", "OKSOMELOST", "NONEWDATA"},
    ("delay", True): {"NONEWDATA", "OKSOMELOST", "WRONGSEQUENCE"},
    ("delay", False): {"NONEWDATA", "OKSOMELOST", "WRONGSEQUENCE"},
}
RECEIVERS = {"BCU_DEMAND": [f"BECU{i}" for i in range(1, 7)], "BECU1_PRESS_CMD": ["PLANT"]}


@pytest.mark.parametrize("message, authenticated", [("BCU_DEMAND", True), ("BECU1_PRESS_CMD", True),
                                                    ("BECU1_PRESS_CMD", False)])
@pytest.mark.parametrize("kind", sorted({k for k, _ in DETECTED_AS}))
def test_each_threat_on_a_safety_frame_is_detected_within_3_cycles(tmp_path, kind, message, authenticated):
    fault = {"kind": kind, "message": message, "from_s": T0, "to_s": T0 + 0.05}
    if kind == "delay":
        fault["delay_ms"] = 25.0
    dbc = None if authenticated else e2e_only_dbc(tmp_path)
    report = run_scenario_lockstep(scenario_with(fault, dbc=dbc), tmp_path / "run")
    assert report.outcome.faults["counts"][kind] >= 1
    first_injected_s = report.outcome.faults["events"][0][0]
    for receiver in RECEIVERS[message]:
        seen = e2e_events_after(report, receiver, message)
        assert seen, f"{receiver} never noticed the {kind}"
        t_us, status = seen[0]
        assert status in DETECTED_AS[kind, authenticated], (receiver, seen[:3])
        assert t_us - first_injected_s * 1e6 <= 3 * CYCLE_US, (receiver, t_us, first_injected_s)
    assert report.kpis["frames_lost"] == 0


def test_masquerade_passes_e2e_but_not_authentication(tmp_path):
    """E2E is not security: a rogue frame with the next counter and a correct CRC is accepted on an
    E2E-only frame, and the legitimate frame that follows is the one discarded as REPEATED; on an
    authenticated frame (the brake demand, the pressure command) the rogue frame (no key: a guessed
    MAC) is dropped, and the legitimate stream goes on unharmed."""
    rogue = {"kind": "masquerade", "message": "BECU1_PRESS_CMD", "from_s": T0, "to_s": T0 + 0.05,
             "signal": "CylPressureSet", "value": 0.0}
    report = run_scenario_lockstep(scenario_with(rogue, dbc=e2e_only_dbc(tmp_path)), tmp_path / "e2e")
    assert {s for _, s in e2e_events_after(report, "PLANT", "BECU1_PRESS_CMD")} == {"REPEATED"}
    report = run_scenario_lockstep(scenario_with(rogue), tmp_path / "press-signed")
    assert {s for _, s in e2e_events_after(report, "PLANT", "BECU1_PRESS_CMD")} == {MAC}
    signed = {"kind": "masquerade", "message": "BCU_DEMAND", "from_s": T0, "to_s": T0 + 0.05,
              "signal": "TargetDecel", "value": 0.0}
    report = run_scenario_lockstep(scenario_with(signed), tmp_path / "signed")
    assert report.outcome.faults["counts"]["masquerade"] == 5
    for becu in (f"BECU{i}" for i in range(1, 7)):
        assert {s for _, s in e2e_events_after(report, becu, "BCU_DEMAND")} == {MAC}
        assert report.outcome.node_stats[becu]["secoc_rejected"] == {"MAC mismatch": 5}


@pytest.mark.parametrize("fault, message", [
    ({"kind": "babbling", "node": "BECU5", "from_s": T0, "to_s": T0 + 0.1}, "BCU_DEMAND"),
    ({"kind": "bus_off", "node": "BCU", "from_s": T0, "to_s": T0 + 0.1}, "BCU_DEMAND"),
])
def test_a_babbling_or_bus_off_node_silences_the_demand_and_receivers_time_out(tmp_path, fault, message):
    report = run_scenario_lockstep(scenario_with(fault), tmp_path / "run")
    seen = e2e_events_after(report, "BECU1", message)
    assert seen and seen[0][1] == "NONEWDATA"
    assert seen[0][0] - T0 * 1e6 <= 3 * CYCLE_US
    assert report.kpis["frames_lost"] == 0


def test_faults_are_seeded(tmp_path):
    fault = {"kind": "corruption", "message": "BCU_DEMAND", "from_s": T0, "to_s": T0 + 0.1,
             "probability": 0.5}
    a = run_scenario_lockstep(scenario_with(fault), tmp_path / "a").out_dir / "trace.blf"
    b = run_scenario_lockstep(scenario_with(fault), tmp_path / "b").out_dir / "trace.blf"
    c = run_scenario_lockstep(scenario_with(fault, seed=2), tmp_path / "c").out_dir / "trace.blf"
    assert a.read_bytes() == b.read_bytes() != c.read_bytes()


@pytest.mark.parametrize("fault, needle", [
    ({"kind": "corruption", "message": "BCU_DEMAN", "from_s": 1, "to_s": 2}, "closest: BCU_DEMAND"),
    ({"kind": "bus_off", "node": "BECU9", "from_s": 1, "to_s": 2}, "faults[0].node"),
    ({"kind": "masquerade", "message": "BCU_DEMAND", "signal": "TargetDecl", "value": 0, "from_s": 1,
      "to_s": 2}, "closest: TargetDecel"),
    ({"kind": "stuck", "message": "BECU2_STATUS", "signal": "SpeedEstt", "from_s": 1, "to_s": 2},
     "closest: SpeedEst"),
    ({"kind": "stuck", "message": "BECU7_STATUS", "signal": "SpeedEst", "from_s": 1, "to_s": 2},
     "faults[0].message"),                                          # a 6-car train: nobody sends it
    ({"kind": "stuck", "message": "BECU1_PRESS_CMD", "signal": "COUNTER", "from_s": 1, "to_s": 2},
     "E2E/SecOC protection"),
    ({"kind": "stuck", "message": "BECU1_PRESS_CMD", "signal": "SecOCMAC", "from_s": 1, "to_s": 2},
     "E2E/SecOC protection"),
    ({"kind": "stuck", "message": "BECU2_STATUS", "signal": "SpeedEst", "value": 700.0, "from_s": 1,
      "to_s": 2}, "faults[0].value"),
    ({"kind": "sensor", "car": 7, "sensor": "pressure", "mode": "stuck", "from_s": 1, "to_s": 2},
     "faults[0].car"),
])
def test_bad_fault_names_are_one_line_errors(tmp_path, fault, needle):
    with pytest.raises(ScenarioError, match=needle.replace("[", r"\[").replace("]", r"\]")):
        run_scenario_lockstep(scenario_with(fault), tmp_path / "x")


@pytest.mark.parametrize("fault, needle", [
    ({"kind": "corruption", "from_s": 1, "to_s": 2}, "needs 'message'"),
    ({"kind": "delay", "message": "BCU_DEMAND", "from_s": 1, "to_s": 2}, "delay_ms > 0"),
    ({"kind": "deletion", "message": "BCU_DEMAND", "from_s": 2, "to_s": 1}, "must be after from_s"),
    ({"kind": "melt", "message": "BCU_DEMAND", "from_s": 1, "to_s": 2}, "faults.0.kind"),
    ({"kind": "stuck", "message": "BECU2_STATUS", "from_s": 1, "to_s": 2}, "needs 'message' and 'signal'"),
    ({"kind": "sensor", "car": 1, "sensor": "wheel_speed", "from_s": 1, "to_s": 2}, "and 'mode'"),
    ({"kind": "sensor", "car": 1, "sensor": "wheel_speed", "mode": "bias", "from_s": 1, "to_s": 2},
     "needs 'value'"),
    ({"kind": "sensor", "car": 1, "sensor": "gyro", "mode": "stuck", "from_s": 1, "to_s": 2},
     "faults.0.sensor"),
    ({"kind": "sensor", "car": 1, "sensor": "pressure", "mode": "stuck", "probability": 0.5, "from_s": 1,
      "to_s": 2}, "not random"),
    ({"kind": "sensor", "car": 1, "sensor": "pressure", "mode": "bias", "value": float("nan"), "from_s": 1,
      "to_s": 2}, "finite"),
    ({"kind": "deletion", "message": "BCU_DEMAND", "car": 2, "from_s": 1, "to_s": 2}, "sensor faults only"),
])
def test_inconsistent_fault_entries_are_scenario_errors(fault, needle):
    with pytest.raises(ScenarioError, match=needle):
        scenario_with(fault)
