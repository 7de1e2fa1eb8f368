"""E2E protection in the node runtime: senders fill counter and CRC of the frames the DBC marks,
receivers check them and keep unusable frames from the controllers."""

import random

import can
import cantools
import pytest
from conftest import DEFAULT

from hil.can import e2e, secoc
from hil.can.attributes import authentic_length, e2e_config, secoc_data_id
from hil.can.codec import Codec
from hil.can.dbc import DEFAULT_DBC, load_dbc
from hil.errors import DbcError
from hil.runtime.assembly import build_node
from hil.runtime.node import DEV_SECOC_KEY
from hil.scenario import load_scenario

SAFETY = {"BCU_EMERGENCY", "DESK_CMD", "DESK_TARGET", "ACD_BRAKE_REQ", "BCU_DEMAND", "BCU_BRAKE_CORR"} | {
    f"BECU{i}_{what}" for what in ("PRESS_CMD", "STATUS") for i in range(1, 9)}


def test_the_dbc_marks_exactly_the_safety_frames_profile_1_with_their_id_as_data_id():
    db = load_dbc(DEFAULT_DBC)
    marked = {m.name: e2e_config(m) for m in db.messages if e2e_config(m) is not None}
    assert set(marked) == SAFETY
    for name, cfg in marked.items():
        assert isinstance(cfg, e2e.P01Config) and cfg.data_id == db.get_message_by_name(name).frame_id


def test_every_safety_frame_of_a_lockstep_trace_checks_ok(default_lockstep):
    db = load_dbc(DEFAULT_DBC)
    configs = {m.frame_id: e2e_config(m) for m in db.messages if e2e_config(m) is not None}
    states = {fid: e2e.CheckState() for fid in configs}
    statuses: dict[str, dict[str, int]] = {}
    with can.LogReader(str(default_lockstep.out_dir / "trace.blf")) as reader:
        for msg in reader:
            cfg = configs.get(msg.arbitration_id)
            if cfg is None:
                continue
            authentic = authentic_length(db.get_message_by_frame_id(msg.arbitration_id))
            states[msg.arbitration_id], status = e2e.check(cfg, states[msg.arbitration_id],
                                                           bytes(msg.data)[:authentic])
            per = statuses.setdefault(cfg.name, {})
            per[status.value] = per.get(status.value, 0) + 1
    # the default train: 6 cars, no anti-collision device, no deceleration feedback
    assert set(statuses) == SAFETY - {"ACD_BRAKE_REQ", "BCU_BRAKE_CORR"} - {
        f"BECU{i}_{what}" for what in ("PRESS_CMD", "STATUS") for i in (7, 8)}
    for name, per in statuses.items():
        assert per.get("INITIAL") == 1 and set(per) == {"INITIAL", "OK"}, (name, per)
    stats = default_lockstep.outcome.node_stats
    assert stats["BECU1"]["e2e_status"]["OK"] > 4000
    assert stats["BECU1"]["e2e_discarded"] == 2                # the first frame of each of its 2 inputs


@pytest.fixture
def becu():
    scenario = load_scenario(DEFAULT)
    db = load_dbc(DEFAULT_DBC)
    return build_node("BECU1", scenario, db, Codec(db)), db


def demand_frames(db, n, decel=0.5):
    """n brake demands as the BCU sends them: E2E over bytes 0-3, then the SecOC trailer."""
    msg = db.get_message_by_name("BCU_DEMAND")
    cfg, state = e2e_config(msg), e2e.ProtectState()
    sender = secoc.SecOcSender(DEV_SECOC_KEY, secoc_data_id(msg))
    out = []
    for k in range(n):
        raw = msg.encode({"CHECKSUM": 0, "COUNTER": 0, "Mode": 1, "BrakeStep": 7, "SecOCFreshness": 0,
                          "SecOCMAC": 0, "TargetDecel": decel + 0.01 * k})
        out.append(sender.secure(e2e.protect(cfg, state, raw[:4])))
    return msg, out


def test_receiver_discards_corrupt_repeated_and_initial_frames(becu):
    node, db = becu
    msg, frames = demand_frames(db, 4)
    fid = msg.frame_id
    node.receive(fid, frames[0], 0)
    assert node.rx.e2e["BCU_DEMAND"] is e2e.Status.INITIAL
    assert node.rx["TargetDecel"] != node.rx["TargetDecel"]         # NaN: the first frame is not used
    node.receive(fid, frames[1], 10_000)
    assert node.rx.e2e["BCU_DEMAND"] is e2e.Status.OK
    assert node.rx["TargetDecel"] == pytest.approx(0.51, abs=0.01)
    corrupt = bytearray(frames[2])
    corrupt[3] ^= 0x10                                              # one bit of the payload
    node.receive(fid, bytes(corrupt), 20_000)                      # authentication drops it
    assert node.stats.secoc_rejected == {"MAC mismatch": 1}
    assert node.rx["TargetDecel"] == pytest.approx(0.51, abs=0.01)  # kept the last good value
    node.receive(fid, frames[1], 21_000)                           # a replayed old frame
    assert node.stats.secoc_rejected == {"MAC mismatch": 1, "replay/stale freshness": 1}
    assert node.rx["TargetDecel"] == pytest.approx(0.51, abs=0.01)
    node.receive(fid, frames[3], 30_000)                           # frame 2 lost: still usable
    assert node.rx.e2e["BCU_DEMAND"] is e2e.Status.OKSOMELOST
    assert node.rx["TargetDecel"] == pytest.approx(0.53, abs=0.01)
    assert node.stats.e2e_discarded == 1                           # the INITIAL one
    assert [s for _, _, s in node.stats.e2e_events] == [
        "INITIAL", "SECOC_MAC_MISMATCH", "SECOC_STALE_FRESHNESS", "OKSOMELOST"]


def test_an_e2e_error_behind_a_valid_mac_is_discarded(becu):
    """A sender whose E2E CRC is wrong (a fault before authentication) is caught by the E2E check."""
    node, db = becu
    msg, frames = demand_frames(db, 2)
    sender = secoc.SecOcSender(DEV_SECOC_KEY, secoc_data_id(msg), freshness=2)
    node.receive(msg.frame_id, frames[0], 0)
    node.receive(msg.frame_id, frames[1], 10_000)
    bad = bytearray(frames[1][:4])
    bad[0] ^= 0xFF
    node.receive(msg.frame_id, sender.secure(bytes(bad)), 20_000)
    assert node.rx.e2e["BCU_DEMAND"] is e2e.Status.ERROR and node.stats.e2e_discarded == 2


def test_a_silent_sender_gives_nonewdata_once_per_message_cycle(becu):
    node, db = becu
    msg, frames = demand_frames(db, 2)
    node.receive(msg.frame_id, frames[0], 3_000)
    node.receive(msg.frame_id, frames[1], 13_000)
    for k in range(2, 8):                                           # BECU1 runs every 10 ms
        node.cycle(3_000 + 10_000 * k)
    assert node.rx.e2e["BCU_DEMAND"] is e2e.Status.NONEWDATA
    assert node.stats.e2e_status["NONEWDATA"] >= 5                  # BCU_DEMAND (10 ms): one per cycle


def test_sender_fills_counter_and_crc(becu):
    node, db = becu
    frames = [d for k in range(3) for fc, d in node.cycle(3_000 + 10_000 * k) if fc.name == "BECU1_PRESS_CMD"]
    msg = db.get_message_by_name("BECU1_PRESS_CMD")
    cfg, state = e2e_config(msg), e2e.CheckState()
    seen = []
    for data in frames:                     # E2E covers the authentic part, before the SecOC trailer
        state, status = e2e.check(cfg, state, data[:cfg.length])
        seen.append(status)
    assert cfg.length == 4
    assert seen == [e2e.Status.INITIAL, e2e.Status.OK, e2e.Status.OK]
    assert [msg.decode(d)["COUNTER"] for d in frames] == [0, 1, 2]


@pytest.mark.parametrize("attrs, needle", [
    ('BA_ "E2EProfile" BO_ 1800 1;', "E2EProfile P01 needs the E2EDataID attribute"),
    ('BA_ "E2EProfile" BO_ 1800 2;', "E2EDataIDList"),
])
def test_incomplete_e2e_attributes_are_one_line_dbc_errors(tmp_path, attrs, needle):
    text = """VERSION ""
BU_: A B
BO_ 1800 X: 8 A
 SG_ CHECKSUM : 0|8@1+ (1,0) [0|255] "" B
 SG_ COUNTER : 8|4@1+ (1,0) [0|15] "" B
BA_DEF_ BO_ "E2EProfile" ENUM "NONE","P01","P02";
BA_DEF_ BO_ "E2EDataID" INT 0 65535;
BA_DEF_DEF_ "E2EProfile" "NONE";
""" + attrs + "\n"
    path = tmp_path / "x.dbc"
    path.write_text(text)
    db = cantools.database.load_file(str(path))
    with pytest.raises(DbcError, match=needle):
        e2e_config(db.get_message_by_name("X"))


def verify_all(trace_path, key, name="BCU_DEMAND"):
    db = load_dbc(DEFAULT_DBC)
    msg = db.get_message_by_name(name)
    receiver = secoc.SecOcReceiver(key, secoc_data_id(msg))
    verdicts = []
    with can.LogReader(str(trace_path)) as reader:
        for frame in reader:
            if frame.arbitration_id == msg.frame_id:
                verdicts.append(receiver.verify(bytes(frame.data)).accepted)
    return verdicts


def test_authenticated_frames_of_a_run_verify_with_the_scenario_key(default_lockstep, tmp_path):
    from hil.report.run import run_scenario_lockstep
    from hil.scenario import parse_scenario

    assert all(verify_all(default_lockstep.out_dir / "trace.blf", DEV_SECOC_KEY))   # no [secoc]: dev key
    key = "000102030405060708090a0b0c0d0e0f"
    base = load_scenario(DEFAULT)
    keyed = parse_scenario({**base.model_dump(), "max_duration_s": 1.0,
                            "secoc": {"keys": {"BCU_DEMAND": key}}})
    report = run_scenario_lockstep(keyed, tmp_path / "run")
    verdicts = verify_all(tmp_path / "run" / "trace.blf", bytes.fromhex(key))
    assert len(verdicts) > 90 and all(verdicts)
    assert not any(verify_all(tmp_path / "run" / "trace.blf", DEV_SECOC_KEY))
    assert report.outcome.node_stats["BECU1"]["secoc_rejected"] == {}              # both ends agree


def test_a_bad_key_is_a_one_line_scenario_error():
    from hil.errors import ScenarioError
    from hil.scenario import parse_scenario

    with pytest.raises(ScenarioError, match="secoc.keys.*BCU_DEMAND must be 16 bytes as 32 hex digits"):
        parse_scenario({"secoc": {"keys": {"BCU_DEMAND": "abc"}}})


def test_cycles_check_missing_frames_by_the_one_and_a_half_cycle_rule(becu):
    """Node.cycle skips its E2E checks until the earliest one is due; the statuses must be those of
    looking at every check every cycle: NONEWDATA once now - last ≥ 1.5 message cycles."""
    node, db = becu
    msg, frames = demand_frames(db, 40)
    rng = random.Random(5)
    cycle_us = int(msg.cycle_time) * 1000
    cfg = e2e_config(msg)
    state, last_us, expected = e2e.CheckState(), 0, []
    now, sent = 0, 0
    while now < 400_000:
        now += rng.choice((1_000, 7_000, 10_000, 16_000, 31_000))
        if rng.random() < 0.6 and sent < len(frames):             # a frame, at an irregular time
            t = now - rng.randrange(0, 1_000)
            node.receive(msg.frame_id, frames[sent], t)
            state, status = e2e.check(cfg, state, frames[sent][:4])
            last_us = t
            expected.append(status.value)
            sent += 1
        node.cycle(now)
        if 2 * (now - last_us) >= 3 * cycle_us:                   # the rule, spelled out
            state, status = e2e.check(cfg, state, None)
            last_us += cycle_us
            expected.append(status.value)
    seen = [s for _, name, s in node.stats.e2e_events if name == "BCU_DEMAND"]
    assert seen == [s for s in expected if s != "OK"] and "NONEWDATA" in seen
    assert node.rx.e2e["BCU_DEMAND"].value == expected[-1]
