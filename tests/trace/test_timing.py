"""hil.trace.timing and `railhil timing`: cycle-time verdicts and measured bus load on synthetic BLF traces
written with python-can, on a corpus trace without a DBC, and on a short lockstep run."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import CORPUS

from hil.can.busload import with_functions
from hil.can.dbc import load_dbc
from hil.cli.main import main
from hil.trace.readers import open_trace
from hil.trace.timing import (
    analyse,
    analyse_chains,
    bus_load,
    frame_arrays,
    measure_periods,
    parse_chain,
    period_histogram,
)

ROOT = Path(__file__).resolve().parents[2]
ISSUE_1256 = CORPUS / "python-can" / "test" / "data" / "issue_1256.asc"

# FAST 0x100 10 ms (11-bit), SLOW 0x18FF0001 100 ms (29-bit), MID 0x200 50 ms, EVENT 0x300 no cycle
DBC_TEXT = """VERSION ""

NS_ :

BS_:

BU_: ECU

BO_ 256 FAST: 8 ECU
 SG_ a : 0|8@1+ (1,0) [0|255] "" Vector__XXX

BO_ 2566848513 SLOW: 4 ECU
 SG_ b : 0|8@1+ (1,0) [0|255] "" Vector__XXX

BO_ 512 MID: 2 ECU
 SG_ c : 0|8@1+ (1,0) [0|255] "" Vector__XXX

BO_ 768 EVENT: 1 ECU
 SG_ d : 0|8@1+ (1,0) [0|255] "" Vector__XXX

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_ "Baudrate" INT 10000 1000000;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_DEF_DEF_ "Baudrate" 500000;
BA_ "Baudrate" 500000;
BA_ "GenMsgCycleTime" BO_ 256 10;
BA_ "GenMsgCycleTime" BO_ 2566848513 100;
BA_ "GenMsgCycleTime" BO_ 512 50;
"""
FAST, SLOW, MID = (0x100, False, 8), (0x18FF0001, True, 4), (0x200, False, 2)
T0 = 1000.0  # trace start time [s]


@pytest.fixture
def dbc(tmp_path: Path) -> Path:
    path = tmp_path / "small.dbc"
    path.write_text(DBC_TEXT)
    return path


def write_blf(path: Path, frames: list[tuple[float, tuple[int, bool, int]]]) -> Path:
    with can.BLFWriter(str(path)) as writer:
        for t, (arb, ext, dlc) in sorted(frames, key=lambda f: f[0]):
            writer.on_message_received(can.Message(timestamp=t, arbitration_id=arb, is_extended_id=ext,
                                                   dlc=dlc, data=bytes(dlc)))
    return path


def cyclic(msg: tuple, period_s: float, n: int, start: float = T0, jitter: np.ndarray | None = None) -> list:
    times = start + period_s * np.arange(n) + (0 if jitter is None else jitter)
    return [(float(t), msg) for t in times]


def report_of(path: Path, dbc: Path, **kw):
    return analyse(frame_arrays(open_trace(path)), load_dbc(dbc), bitrate_bps=500_000, **kw)


def by_name(report) -> dict:
    return {m.name: m for m in report.messages}


def all_three(n_fast: int = 200) -> list:
    """2 s of FAST, SLOW and MID, exact periods."""
    return cyclic(FAST, 0.010, n_fast) + cyclic(SLOW, 0.100, n_fast // 10, 0.003 + T0) + \
        cyclic(MID, 0.050, n_fast // 5, 0.005 + T0)


@pytest.mark.parametrize(("period_ms", "cycle_ms", "verdict"), [
    (10.0, 10, "PASS"),
    (10.9, 10, "PASS"),  # within +10 %: neither late nor burst
    (9.2, 10, "PASS"),
    (11.5, 10, "FAIL"),  # mean outside ±10 %
    (8.5, 10, "FAIL"),
])
def test_exact_periods(tmp_path, dbc, period_ms, cycle_ms, verdict):
    n = 100
    frames = cyclic(FAST, period_ms / 1e3, n) + cyclic(SLOW, 0.1, 5, T0 + 0.001) + \
        cyclic(MID, 0.05, 10, T0 + 0.002)  # both end before FAST: FAST ends the trace
    rep = report_of(write_blf(tmp_path / "t.blf", frames), dbc)
    m = by_name(rep)["FAST"]
    assert m.stats.count == n
    for figure in (m.stats.mean_ms, m.stats.p50_ms, m.stats.p99_ms, m.stats.min_ms, m.stats.max_ms):
        assert figure == pytest.approx(period_ms, abs=1e-5)
    assert m.stats.sigma_ms == pytest.approx(0, abs=1e-5)
    assert m.jitter_max_ms == pytest.approx(abs(period_ms - cycle_ms), abs=1e-5)
    assert m.missed == 0
    assert m.verdict == verdict, m.reason
    assert (m.late, m.bursts) == ((n - 1, 0) if period_ms > 11 else (0, n - 1) if period_ms < 9 else (0, 0))


def test_all_pass_exit_0(tmp_path, dbc, capsys):
    trace = write_blf(tmp_path / "t.blf", all_three())
    rep = report_of(trace, dbc)
    assert [m.verdict for m in rep.messages] == ["PASS", "PASS", "PASS"]
    assert [m.name for m in rep.messages] == ["FAST", "MID", "SLOW"]  # 11-bit first, then 29-bit
    assert rep.ok and rep.unknown == {} and rep.non_cyclic == 0
    assert main(["timing", str(trace), "--dbc", str(dbc)]) == 0
    out = capsys.readouterr().out
    assert "3 PASS, 0 FAIL, 0 MISSING" in out and "bus load: average" in out


def test_seeded_jitter(tmp_path, dbc):
    rng = np.random.default_rng(1256)
    n, sd = 2000, 0.0005  # 0.5 ms gaussian jitter on each send time of a 10 ms message
    jitter = rng.normal(0, sd, n)
    frames = cyclic(FAST, 0.010, n, jitter=jitter) + cyclic(SLOW, 0.1, n // 10, T0 + 0.003) + \
        cyclic(MID, 0.05, n // 5, T0 + 0.004)
    m = by_name(report_of(write_blf(tmp_path / "t.blf", frames), dbc))["FAST"]
    # periods = 10 ms + diff of iid N(0, sd): mean 10 ms, sigma sqrt(2)·sd, p99 ≈ 10 + 2.326·sqrt(2)·sd
    expected = np.diff(T0 + 0.010 * np.arange(n) + jitter) * 1e3
    assert m.stats.mean_ms == pytest.approx(expected.mean(), abs=1e-5)
    assert m.stats.mean_ms == pytest.approx(10.0, abs=0.01)
    assert m.stats.sigma_ms == pytest.approx(np.sqrt(2) * sd * 1e3, rel=0.05)
    assert m.stats.p99_ms == pytest.approx(10 + 2.326 * np.sqrt(2) * sd * 1e3, abs=0.15)
    assert m.verdict == "PASS" and m.missed == 0
    # a tolerance tighter than the jitter makes periods late and bursts, and still PASSes on the mean
    tight = by_name(report_of(tmp_path / "t.blf", dbc, overrides={"FAST": 0.05}))["FAST"]
    assert tight.tolerance == 0.05 and tight.late > 0 and tight.bursts > 0 and tight.verdict == "PASS"


def test_dropped_frame(tmp_path, dbc, capsys):
    frames = all_three()
    del frames[50]  # one FAST frame
    trace = write_blf(tmp_path / "t.blf", frames)
    m = by_name(report_of(trace, dbc))["FAST"]
    assert (m.missed, m.late, m.bursts) == (1, 1, 0)
    assert m.stats.max_ms == pytest.approx(20.0, abs=1e-5)
    assert m.verdict == "FAIL" and "1 frame missed" in m.reason
    assert main(["timing", str(trace), "--dbc", str(dbc)]) == 1
    # three frames gone in a row: missed 3
    frames = all_three()
    del frames[50:53]
    m = by_name(report_of(write_blf(tmp_path / "t3.blf", frames), dbc))["FAST"]
    assert (m.missed, m.late) == (3, 1)


@pytest.mark.parametrize(("shifts_ms", "missed", "verdict"), [
    ({50: 7.0}, 0, "PASS"),                  # 17 ms then 3 ms: a late frame, not a missed one
    ({50: 16.0, 51: 6.2}, 0, "PASS"),        # 26 ms, 0.2 ms, 3.8 ms: a sender catching up after a stall
    ({50: 7.7, 51: 12.1, 52: 2.3}, 0, "PASS"),   # 17.7, 14.4, 0.2, 7.7 ms: two late periods, then caught up
    ({k: 12.0 for k in range(50, 200)}, 1, "FAIL"),   # 22 ms then 10 ms on: the schedule slipped
    ({199: 30.0}, 0, "PASS"),                # the trace's last frame 40 ms late: teardown, not judged
])
def test_late_frames_made_up_are_not_missed(tmp_path, dbc, shifts_ms, missed, verdict):
    frames = all_three()
    fast = [k for k, (_, msg) in enumerate(frames) if msg == FAST]
    for index, shift in shifts_ms.items():
        t, msg = frames[fast[index]]
        frames[fast[index]] = (t + shift * 1e-3, msg)
    m = by_name(report_of(write_blf(tmp_path / "t.blf", frames), dbc))["FAST"]
    assert (m.missed, m.verdict) == (missed, verdict), m.reason


def test_doubled_frames_are_bursts(tmp_path, dbc):
    frames = all_three()
    frames += [(t + 0.0005, msg) for t, msg in frames[100:105]]  # 5 FAST frames sent twice
    m = by_name(report_of(write_blf(tmp_path / "t.blf", frames), dbc))["FAST"]
    assert m.bursts == 5 and m.missed == 0 and m.late == 0
    assert m.stats.count == 205 and m.stats.min_ms == pytest.approx(0.5, abs=1e-5)
    assert m.verdict == "PASS"  # the mean, 1990 ms / 204, is within 10 %


def test_missing_message_and_unknown_ids(tmp_path, dbc, capsys):
    frames = cyclic(FAST, 0.010, 200) + cyclic(SLOW, 0.100, 20, T0 + 0.003)
    frames += cyclic((0x100, True, 8), 0.02, 7)  # 29-bit 0x100: not FAST, not in the DBC
    frames += cyclic((0x300, False, 1), 0.3, 3)  # EVENT: in the DBC, no cycle time
    trace = write_blf(tmp_path / "t.blf", frames)
    rep = report_of(trace, dbc)
    got = by_name(rep)
    assert got["MID"].verdict == "MISSING" and got["MID"].stats is None
    assert got["FAST"].stats.count == 200 and got["FAST"].verdict == "PASS"
    assert rep.unknown == {(0x100, True): 7} and rep.non_cyclic == 3
    assert main(["timing", str(trace), "--dbc", str(dbc), "--format", "json"]) == 1
    obj = json.loads(capsys.readouterr().out)
    assert obj["summary"] == {"PASS": 2, "FAIL": 0, "MISSING": 1}
    assert obj["unknown_ids"] == {"0x00000100": 7}


def test_stopped_message_fails(tmp_path, dbc):
    frames = cyclic(FAST, 0.010, 100) + cyclic(SLOW, 0.1, 20, T0 + 0.003) + cyclic(MID, 0.05, 40, T0 + 0.004)
    m = by_name(report_of(write_blf(tmp_path / "t.blf", frames), dbc))["FAST"]
    assert m.missed == 0 and m.stopped and m.verdict == "FAIL" and "stopped" in m.reason


def test_bus_load_exact(tmp_path):
    n = 1000  # 8-byte 11-bit frames spread over exactly 1 s
    trace = write_blf(tmp_path / "load.blf", [(T0 + float(t), FAST) for t in np.linspace(0, 1, n)])
    load = bus_load(frame_arrays(open_trace(trace)), 500_000, window_s=0.1)
    assert load.bits == n * 135
    assert load.average == pytest.approx(n * 135 / 500_000, rel=1e-6)
    assert load.frames == n and load.error_frames == 0
    # 1000 frames evenly over 1 s: a 0.1 s window holds 100 of them (101 at most with both ends)
    assert 100 * 135 / 0.1 / 500_000 <= load.peak <= 101 * 135 / 0.1 / 500_000


def test_bus_load_peak_and_29_bit(tmp_path):
    frames = [(T0 + i * 0.01, SLOW) for i in range(100)] + [(T0 + 0.5 + i * 1e-4, SLOW) for i in range(50)]
    arrays = frame_arrays(open_trace(write_blf(tmp_path / "p.blf", frames)))
    load = bus_load(arrays, 250_000, 0.008)
    assert load.bits == 150 * frame_bits_29_4()
    assert load.peak_at_s == pytest.approx(arrays.t.min() + 0.5, abs=1e-6)  # BLF times may be rebased
    # the burst of 50 and the cyclic frame at 0.5 s
    assert load.peak == pytest.approx(51 * frame_bits_29_4() / 0.008 / 250_000, rel=1e-6)


def frame_bits_29_4() -> int:
    return 80 + 10 * 4  # Davis 2007 worst case, 29-bit, 4 bytes


def test_bitrate_required(tmp_path, capsys):
    path = tmp_path / "nobaud.dbc"
    path.write_text(DBC_TEXT.split("BA_DEF_ BO_")[0] + 'BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;\n'
                    'BA_DEF_DEF_ "GenMsgCycleTime" 0;\nBA_ "GenMsgCycleTime" BO_ 256 10;\n')
    trace = write_blf(tmp_path / "t.blf", cyclic(FAST, 0.01, 10))
    assert main(["timing", str(trace), "--dbc", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Baudrate" in err and err.count("\n") == 1
    assert main(["timing", str(trace), "--dbc", str(path), "--bitrate", "250000"]) == 0


@pytest.mark.parametrize("argv", [
    ["--tolerance", "1.5"],
    ["--override", "NOPE=0.2"],
    ["--override", "FAST"],
    ["--window", "0"],
])
def test_bad_options_exit_2(tmp_path, dbc, capsys, argv):
    trace = write_blf(tmp_path / "t.blf", all_three())
    assert main(["timing", str(trace), "--dbc", str(dbc), *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1


def test_junit(tmp_path, dbc):
    frames = all_three()
    del frames[50]
    frames = [f for f in frames if f[1] != MID]
    trace = write_blf(tmp_path / "t.blf", frames)
    out = tmp_path / "timing.xml"
    assert main(["timing", str(trace), "--dbc", str(dbc), "--format", "junit", "-o", str(out)]) == 1
    suite = ET.parse(out).getroot()
    assert suite.tag == "testsuite" and suite.get("name") == "railhil.timing"
    cases = suite.findall("testcase")
    assert len(cases) == 3 == int(suite.get("tests"))
    failures = {c.get("name").split()[0]: c.find("failure") for c in cases}
    assert failures["SLOW"] is None
    assert failures["FAST"].get("type") == "FAIL" and "missed" in failures["FAST"].get("message")
    assert failures["MID"].get("type") == "MISSING"
    assert suite.get("failures") == "2"


@pytest.mark.skipif(not ISSUE_1256.is_file(), reason=f"corpus trace {ISSUE_1256} absent")
def test_periods_without_dbc_issue_1256(capsys):
    periods = measure_periods(frame_arrays(open_trace(ISSUE_1256)))
    means = {i: s.mean_ms for (i, ext), s in periods.items() if not ext}
    expected = {0x010: 100, 0x011: 30, 0x012: 50, 0x064: 10, 0x065: 100, 0x066: 100}
    assert set(means) == set(expected)
    for i, cycle in expected.items():
        assert means[i] == pytest.approx(cycle, rel=0.01), hex(i)
        assert periods[(i, False)].p50_ms == pytest.approx(cycle, rel=0.01), hex(i)
    assert main(["timing", str(ISSUE_1256), "--periods-only"]) == 0
    assert "0x064" in capsys.readouterr().out


def test_lockstep_run_passes(tmp_path):
    from hil.can.busload import train_frame_ids
    from hil.report.run import run_scenario_lockstep
    from hil.runtime.run import TRACE_NAME
    from hil.scenario import load_scenario

    scenario = load_scenario(ROOT / "scenarios" / "default.toml").model_copy(update={"max_duration_s": 3.0})
    run_scenario_lockstep(scenario, tmp_path)
    db = load_dbc(ROOT / "dbc" / "train_brake.dbc")
    rep = analyse(frame_arrays(open_trace(tmp_path / TRACE_NAME)), db, bitrate_bps=500_000)
    seen = [m for m in rep.messages if m.verdict != "MISSING"]
    assert seen, "no cyclic frame in the run"
    assert all(m.verdict == "PASS" for m in seen), [(m.name, m.reason) for m in seen if m.verdict != "PASS"]
    assert rep.unknown == {}
    missing = {m.arbitration_id for m in rep.messages if m.verdict == "MISSING"}
    # only frames that the default run does not send (RADIO_, ACD_, cars beyond its train) are missing
    assert not missing & set(train_frame_ids(db, scenario.train.cars))
    assert 0 < rep.load.average < 1 and rep.load.peak >= rep.load.average


def test_cli_on_a_lockstep_run_passes_when_unsent_frames_are_ignored(tmp_path, capsys):
    from hil.cli.main import main
    from hil.report.run import run_scenario_lockstep
    from hil.runtime.run import TRACE_NAME
    from hil.scenario import load_scenario

    scenario = load_scenario(ROOT / "scenarios" / "default.toml").model_copy(update={"max_duration_s": 2.0})
    run_scenario_lockstep(scenario, tmp_path)
    args = ["timing", str(tmp_path / TRACE_NAME), "--dbc", str(ROOT / "dbc" / "train_brake.dbc")]
    assert main(args) == 0                               # the run's trace: what the run sends (run.json)
    assert "cyclic messages of the DBC that its nodes do not send" in capsys.readouterr().out
    assert main(args + ["--all-messages"]) == 1          # every message: cars 7-8 are MISSING
    capsys.readouterr()
    # the optional functions' frames (ACD, radio, the studies') are out of scope unless --function names them
    assert main(args + ["--ignore", "*7_*", "--ignore", "*8_*", "--function", "anticollision"]) == 1
    capsys.readouterr()
    old = {v: k for k, v in __import__("hil.cli.aliases", fromlist=["FUNCTIONS"]).FUNCTIONS.items()}
    assert main(args + ["--ignore", "*7_*", "--ignore", "*8_*", "--function", old["anticollision"]]) == 1
    assert f"notice: --function '{old['anticollision']}' is now 'anticollision'" in capsys.readouterr().err
    ignore = ["--ignore", "*7_*", "--ignore", "*8_*"]
    assert main(args + ignore + ["--format", "json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert len(report["messages"]) == 35 and {m["verdict"] for m in report["messages"]} == {"PASS"}
    # the bit-timed lockstep bus never exceeds the response-time bound, and the driver's brake step
    # (at 0.5 s) reaches the first car's brake cylinder within 50 ms
    chain = "DESK_CMD.BrakeStep -> BCU_DEMAND.TargetDecel -> BECU1_PRESS_CMD.CylPressureSet -> " \
            "PLANT_CAR1_SENSORS.CylPressure"
    assert main(args + ignore + ["--rta", "--chain", chain, "--chain-max-ms", "50", "--format", "json"]) == 0
    report = json.loads(capsys.readouterr().out)
    rta = report["rta"]["messages"]
    assert len(rta) == 35 and all(m["schedulable"] and m["verdict"] == "PASS" for m in rta)
    assert all(m["c_us"] <= m["measured"]["max_us"] <= m["response_us"] for m in rta)
    (chain_report,) = report["chains"]
    assert chain_report["instances"] == chain_report["completed"] == 1 and chain_report["verdict"] == "PASS"
    assert 0 < chain_report["end_to_end"]["max_ms"] <= 50
    assert main(args + ["--ignore", "RADO_*"]) == 2      # a pattern that matches nothing is a typo
    assert "RADO_*" in capsys.readouterr().err


def test_million_frames_analysed_fast():
    """The analysis is vectorised: 10^6 frames of 100 ids in well under a few seconds (reading a
    trace file is python-can's reader, about 6 µs a frame, and is not timed here)."""
    import time

    from hil.trace.timing import KIND_DATA, FrameArrays

    n, n_ids = 1_000_000, 100
    ids = np.tile(np.arange(0x100, 0x100 + n_ids), n // n_ids)
    arrays = FrameArrays(t=np.arange(n) * 1e-4, arbitration_id=ids.astype(np.int64),
                         extended=np.zeros(n, bool), dlc=np.full(n, 8), kind=np.full(n, KIND_DATA, np.int8),
                         fd=np.zeros(n, bool))
    start = time.perf_counter()
    periods = measure_periods(arrays)
    load = bus_load(arrays, 500_000)
    elapsed = time.perf_counter() - start
    assert len(periods) == n_ids and periods[(0x100, False)].mean_ms == pytest.approx(10.0)
    assert load.bits == n * 135
    assert elapsed < 5.0, f"{elapsed:.2f} s"


# --- period histograms -------------------------------------------------------------------------------


def test_histogram_counts(tmp_path, dbc, capsys):
    """FAST: 200 frames at 10 ms, frame 50 dropped (one 20 ms period), frame 100 sent twice 0.4 ms
    apart (0.4 + 9.6 ms): 196 periods of 10 ms, one each of 9.6, 20 and 0.4 ms."""
    frames = all_three()
    fast = [k for k, (_, m) in enumerate(frames) if m == FAST]
    frames.append((frames[fast[100]][0] + 0.0004, FAST))
    del frames[fast[50]]
    trace = write_blf(tmp_path / "t.blf", frames)
    m = by_name(report_of(trace, dbc))["FAST"]
    h = period_histogram(m.stats.periods_ms, m.cycle_ms, m.tolerance)
    assert h.bin_ms == pytest.approx(0.2)  # tolerance 10 % of 10 ms / 5
    assert len(h.counts) == 51
    assert h.edges_ms[0] == pytest.approx(4.9) and h.edges_ms[-1] == pytest.approx(15.1)
    assert h.counts[25] == 196 and h.edges_ms[25] < 10 < h.edges_ms[26]  # the middle bin holds T
    assert h.counts[23] == 1 and h.edges_ms[23] <= 9.6 < h.edges_ms[24]
    assert (h.below, h.above, h.total) == (1, 1, 199)
    assert int(h.counts.sum()) == 197
    tight = period_histogram(m.stats.periods_ms, 10, 0.05)
    assert tight.bin_ms == pytest.approx(0.1) and tight.counts[len(tight.counts) // 2] == 196
    assert main(["timing", str(trace), "--dbc", str(dbc), "--histogram", "FAST"]) == 1  # a frame missed
    out = capsys.readouterr().out
    assert "periods of FAST (0x100), cycle 10 ms, bin 0.200 ms, 199 periods" in out
    bars = {line.split("ms")[0].strip(): line for line in out.splitlines() if " ms  " in line}
    assert "#" * 40 in bars["9.900 - 10.100"] and bars["9.900 - 10.100"].split()[4] == "196"
    assert "< 4.900" in bars and ">= 15.100" in bars
    assert main(["timing", str(trace), "--dbc", str(dbc), "--format", "json"]) == 1
    obj = json.loads(capsys.readouterr().out)
    hist = {x["name"]: x["histogram"] for x in obj["messages"]}
    assert hist["FAST"]["counts"][25] == 196 and (hist["FAST"]["below"], hist["FAST"]["above"]) == (1, 1)
    assert len(hist["FAST"]["edges_ms"]) == 52 and sum(hist["SLOW"]["counts"]) == 19


# --- latency chains ----------------------------------------------------------------------------------

CHAIN_DBC = """VERSION ""

NS_ :

BS_:

BU_: ECU

BO_ 256 CAUSE: 2 ECU
 SG_ a : 0|8@1+ (1,0) [0|255] "" Vector__XXX
 SG_ a2 : 8|8@1+ (1,0) [0|255] "" Vector__XXX

BO_ 512 RESP: 1 ECU
 SG_ b : 0|8@1+ (1,0) [0|255] "" Vector__XXX

BO_ 768 EFFECT: 1 ECU
 SG_ c : 0|8@1+ (1,0) [0|255] "" Vector__XXX

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_ "Baudrate" INT 10000 1000000;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_DEF_DEF_ "Baudrate" 500000;
BA_ "Baudrate" 500000;
BA_ "GenMsgCycleTime" BO_ 256 10;
BA_ "GenMsgCycleTime" BO_ 512 10;
BA_ "GenMsgCycleTime" BO_ 768 10;
"""


def step(t_ms: float, changes: list[tuple[float, int]]) -> int:
    """The value at t_ms of a signal that takes value v from time t on, for each (t, v)."""
    value = 0
    for at, v in changes:
        if t_ms >= at:
            value = v
    return value


def chain_trace(path: Path, db, end_ms: int = 1000) -> Path:
    """CAUSE at 0, 10, ... ms, a (and a2 in the same frame) 1 from 100 ms, 2 from 500, 3 from 900;
    RESP at 3, 13, ... ms, b 1 from 123 ms, 2 from 513; EFFECT at 7, 17, ... ms, c 1 from 137, 2 from
    517.  Noise that must not count: 29-bit frames of id 0x200 changing every time, and a CAUSE frame
    too short to decode."""
    cause, resp, effect = (db.get_message_by_name(n) for n in ("CAUSE", "RESP", "EFFECT"))
    a_steps = [(100, 1), (500, 2), (900, 3)]
    frames = []
    for k in range(end_ms // 10):
        t = 10.0 * k
        a = step(t, a_steps)
        frames.append((t, 0x100, False, cause.encode({"a": a, "a2": a})))
        frames.append((t + 3, 0x200, False, resp.encode({"b": step(t + 3, [(123, 1), (513, 2)])})))
        frames.append((t + 7, 0x300, False, effect.encode({"c": step(t + 7, [(137, 1), (517, 2)])})))
        frames.append((t + 5, 0x200, True, bytes([k % 256])))
    frames.append((55.0, 0x100, False, b"\x07"))
    with can.BLFWriter(str(path)) as writer:
        for t, arb, ext, data in sorted(frames, key=lambda f: f[0]):
            writer.on_message_received(can.Message(timestamp=T0 + t / 1e3, arbitration_id=arb,
                                                   is_extended_id=ext, dlc=len(data), data=data))
    return path


@pytest.fixture
def chain_files(tmp_path):
    dbc_path = tmp_path / "chain.dbc"
    dbc_path.write_text(CHAIN_DBC)
    db = load_dbc(dbc_path)
    return dbc_path, db, chain_trace(tmp_path / "chain.blf", db)


def chains_of(trace: Path, db, texts: list[str], max_ms: float | None = None):
    frames = list(open_trace(trace))
    end = max(m.timestamp for m in frames)
    return analyse_chains(frames, [parse_chain(t, db) for t in texts], end, max_ms)


def test_chain_exact_latencies(chain_files):
    _, db, trace = chain_files
    (r,) = chains_of(trace, db, ["CAUSE.a -> RESP.b -> EFFECT.c"])
    # instances at 100 ms (-> 123 -> 137) and 500 ms (-> 513 -> 517); the one at 900 ms never gets a b
    assert (r.instances, r.completed, r.incomplete) == (3, 2, 1)
    first, second = r.links
    assert first.count == 2 and first.max_ms == pytest.approx(23, abs=1e-6)
    assert first.p50_ms == pytest.approx(18, abs=1e-6)  # linear percentile of 13 and 23
    assert second.count == 2 and second.max_ms == pytest.approx(14, abs=1e-6)
    assert r.end_to_end.count == 2 and r.end_to_end.max_ms == pytest.approx(37, abs=1e-6)
    assert r.end_to_end.p50_ms == pytest.approx(27, abs=1e-6) and r.end_to_end.p99_ms == pytest.approx(36.8)
    assert r.verdict is None and r.undecodable == 1  # the 1-byte CAUSE frame
    bare, same, every = chains_of(trace, db, ["CAUSE.a -> RESP", "CAUSE.a -> CAUSE.a2", "CAUSE -> CAUSE"])
    assert (bare.completed, bare.end_to_end.max_ms, bare.end_to_end.p50_ms) == (3, pytest.approx(3),
                                                                                 pytest.approx(3))
    assert same.completed == 3 and same.end_to_end.max_ms == 0  # the same frame: latency 0
    assert every.instances == 101 and every.end_to_end.max_ms == 0  # 100 frames + the short one


@pytest.mark.parametrize(("max_ms", "verdict", "why"), [
    (100.0, "PASS", ""),                        # the incomplete instance began 97 ms before the end
    (40.0, "FAIL", "1 instance not completed within 40 ms"),  # 900 ms < 997 - 40: overdue
    (30.0, "FAIL", "1 instance over 30 ms (max 37.000 ms)"),
])
def test_chain_verdicts(chain_files, max_ms, verdict, why):
    _, db, trace = chain_files
    (r,) = chains_of(trace, db, ["CAUSE.a -> RESP.b -> EFFECT.c"], max_ms)
    assert r.verdict == verdict and why in r.reason


def test_chain_cli_outputs(chain_files, tmp_path, capsys):
    dbc_path, _, trace = chain_files
    base = ["timing", str(trace), "--dbc", str(dbc_path), "--chain", "CAUSE.a -> RESP.b -> EFFECT.c"]
    assert main(base + ["--chain-max-ms", "100"]) == 0
    out = capsys.readouterr().out
    assert "chain 1: CAUSE.a -> RESP.b -> EFFECT.c" in out
    assert "3 instances, 2 completed, 1 incomplete, 1 frames did not decode; PASS (limit 100 ms)" in out
    e2e = next(line for line in out.splitlines() if line.startswith("end to end")).split()
    assert e2e[3:] == ["2", "27.000", "36.800", "37.000"]
    assert main(base + ["--chain", "CAUSE.a -> RESP", "--chain-max-ms", "30", "--format", "json"]) == 1
    obj = json.loads(capsys.readouterr().out)
    first, second = obj["chains"]
    assert first["verdict"] == "FAIL" and second["verdict"] == "PASS" and not obj["ok"]
    assert first["link_latency"][0] == {"from": "CAUSE.a", "to": "RESP.b", "count": 2, "p50_ms": 18.0,
                                        "p99_ms": 22.9, "max_ms": 23.0}
    xml_path = tmp_path / "chains.xml"
    assert main(base + ["--chain", "CAUSE.a -> RESP", "--chain-max-ms", "30", "--format", "junit",
                        "-o", str(xml_path)]) == 1
    suite = ET.parse(xml_path).getroot()
    chains = [c for c in suite.findall("testcase") if c.get("classname") == "railhil.timing.chain"]
    assert [c.get("name") for c in chains] == ["CAUSE.a -> RESP.b -> EFFECT.c", "CAUSE.a -> RESP"]
    assert chains[0].find("failure") is not None and chains[1].find("failure") is None
    assert json.loads(chains[1].find("system-out").text)["end_to_end"]["count"] == 3
    assert int(suite.get("tests")) == 5 and int(suite.get("failures")) == 1  # 3 messages + 2 chains


@pytest.mark.parametrize(("argv", "words"), [
    (["--chain", "NOPE.a -> RESP.b"], ["'NOPE'", "closest"]),
    (["--chain", "CAUSE.zz -> RESP.b"], ["CAUSE", "no signal 'zz'"]),
    (["--chain", "CAUSE.a"], ["at least two links"]),
    (["--chain", "CAUSE. -> RESP"], ["no signal name"]),
    (["--chain-max-ms", "5"], ["--chain-max-ms"]),
    (["--chain", "CAUSE -> RESP", "--chain-max-ms", "-1"], ["--chain-max-ms -1"]),
    (["--jitter", "CAUSE=5"], ["--rta"]),
    (["--rta", "--jitter", "CAUSE=x"], ["CAUSE=x", "µs"]),
    (["--rta", "--jitter", "NOPE=5"], ["NOPE", "closest"]),
    (["--histogram", "NOPE"], ["NOPE", "closest"]),
])
def test_chain_and_rta_option_errors(chain_files, capsys, argv, words):
    dbc_path, _, trace = chain_files
    assert main(["timing", str(trace), "--dbc", str(dbc_path), *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1
    for word in words:
        assert word in err


@pytest.mark.parametrize(("argv", "words"), [
    ([], ["a trace file is required"]),
    (["--rta"], ["--rta needs --dbc"]),
    (["--rta", "--dbc", "{dbc}", "--chain", "FAST -> MID"], ["--chain needs a trace"]),
    (["--rta", "--dbc", "{dbc}", "--histogram", "FAST"], ["--histogram needs a trace"]),
])
def test_no_trace_errors(dbc, capsys, argv, words):
    assert main(["timing", *[a.format(dbc=dbc) for a in argv]]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and all(w in err for w in words)


# --- response-time analysis in the CLI ----------------------------------------------------------------


def test_rta_alone_on_the_train_dbc(tmp_path, capsys):
    from hil.can.busload import static_load

    db_path = ROOT / "dbc" / "train_brake.dbc"
    db = with_functions(load_dbc(db_path), [])      # by default the base train's frames only
    cyclic = [m.name for m in db.messages if m.cycle_time]
    assert main(["timing", "--rta", "--dbc", str(db_path)]) == 0
    out = capsys.readouterr().out
    assert f"utilisation {100 * static_load(db).total:.2f} %" in out
    rows = [line.split() for line in out.splitlines() if line.split() and line.split()[0] in cyclic]
    assert len(rows) == len(cyclic) and all(r[-1] == "PASS" for r in rows)
    assert f"{len(cyclic)} of {len(cyclic)} schedulable" in out
    assert main(["timing", "--rta", "--dbc", str(db_path), "--format", "json"]) == 0
    rta = json.loads(capsys.readouterr().out)["rta"]
    assert rta["ok"] and rta["schedulable"] == len(cyclic) == len(rta["messages"])
    assert all(m["response_us"] <= m["deadline_us"] for m in rta["messages"])
    xml_path = tmp_path / "rta.xml"
    assert main(["timing", "--rta", "--dbc", str(db_path), "--format", "junit", "-o", str(xml_path)]) == 0
    suite = ET.parse(xml_path).getroot()
    assert int(suite.get("tests")) == len(cyclic) and suite.get("failures") == "0"
    assert {c.get("classname") for c in suite.findall("testcase")} == {"railhil.timing.rta"}


def test_rta_alone_overloaded_exit_1(dbc, capsys):
    """At 10 kbit/s a worst-case 8-byte frame takes 13.5 ms: FAST (10 ms) alone overloads the bus."""
    assert main(["timing", "--rta", "--dbc", str(dbc), "--bitrate", "10000", "--format", "json"]) == 1
    msgs = {m["name"]: m for m in json.loads(capsys.readouterr().out)["rta"]["messages"]}
    assert msgs["FAST"]["unbounded"] and msgs["FAST"]["response_us"] is None
    assert msgs["FAST"]["verdict"] == "FAIL" and "100 %" in msgs["FAST"]["reason"]


def test_rta_against_a_trace(tmp_path, dbc, capsys):
    """500 kbit/s: C = 270 µs (FAST, 8 bytes), 150 (MID, 2), 240 (SLOW, 29-bit 4 bytes); FAST's bound
    is B + C = 240 + 270 = 510 µs.  Exact periods: every frame measures C.  FAST frames 0.6 ms late
    in two of every ten cycles measure 870 µs: FAIL, until --jitter FAST=600 raises the bound to 1110 µs."""
    trace = write_blf(tmp_path / "t.blf", all_three())
    assert main(["timing", str(trace), "--dbc", str(dbc), "--rta", "--format", "json"]) == 0
    rta = {m["name"]: m for m in json.loads(capsys.readouterr().out)["rta"]["messages"]}
    assert rta["FAST"]["response_us"] == 510 and rta["SLOW"]["response_us"] == 660
    for m in rta.values():
        assert m["measured"]["max_us"] == pytest.approx(m["c_us"], abs=0.01) and m["verdict"] == "PASS"
    frames = all_three()
    fast = [k for k, (_, m) in enumerate(frames) if m == FAST]
    for n, k in enumerate(fast):
        if n % 10 in (4, 5):  # symmetric about the middle of the 200 frames: the fitted slope is exact
            frames[k] = (frames[k][0] + 0.0006, FAST)
    late = write_blf(tmp_path / "late.blf", frames)
    assert main(["timing", str(late), "--dbc", str(dbc), "--rta"]) == 1
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("  FAST: FAIL: measured response"))
    assert "FAST: FAIL: measured response 0.870 ms > bound 0.510 ms" in line
    assert main(["timing", str(late), "--dbc", str(dbc), "--rta", "--jitter", "FAST=600", "--format",
                 "json"]) == 0
    fast_rta = json.loads(capsys.readouterr().out)["rta"]["messages"][0]
    assert fast_rta["response_us"] == 1110 and fast_rta["measured"]["max_us"] == pytest.approx(870, abs=0.01)
