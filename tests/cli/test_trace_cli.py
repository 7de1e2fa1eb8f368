"""`railhil trace stats|decode`: every corpus trace python-can reads, decoding equal to cantools, filters,
and bad input as one line `error: ...` with exit code 2.

The corpus lives outside the repository; RAILHIL_CORPUS points to it (default ../shared/corpus).
"""

from __future__ import annotations

import csv
import io
import json
import subprocess
import sys
from pathlib import Path

import can
import cantools
import pytest
from can.io.player import MESSAGE_READERS
from cantools.database.namedsignalvalue import NamedSignalValue
from conftest import CORPUS, assert_one_line_error, railhil

from hil.report.run import run_scenario_lockstep
from hil.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
TRAIN_DBC = ROOT / "dbc" / "train_brake.dbc"
NO_CORPUS = pytest.mark.skipif(not CORPUS.is_dir(),
                               reason=f"no trace corpus at {CORPUS} (set RAILHIL_CORPUS)")
CANDUMP = CORPUS / "SavvyCAN" / "examples" / "candump.log"
LEAF_DBC = CORPUS / "SavvyCAN" / "examples" / "LeafPowertrainBus.dbc"
CANTOOLS_DBC = CORPUS / "cantools" / "tests" / "files" / "dbc"
OPENDBC = CORPUS / "opendbc" / "opendbc" / "dbc"
PYCAN_DATA = CORPUS / "python-can" / "test" / "data"


def readable(path: Path) -> bool:
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    return bool(suffixes) and suffixes[-1] in MESSAGE_READERS and suffixes[-1] != ".mf4"  # no asammdf here


CORPUS_TRACES = sorted(p for p in CORPUS.rglob("*") if p.is_file() and readable(p)) if CORPUS.is_dir() else []
TRACE_PARAMS = [pytest.param(p, id=str(p.relative_to(CORPUS))) for p in CORPUS_TRACES] or [
    pytest.param(None, marks=pytest.mark.skip(reason=f"no trace corpus at {CORPUS} (set RAILHIL_CORPUS)"))]




def railhil_process(*args: str, stdin: bytes | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", *map(str, args)], input=stdin, capture_output=True,
                          cwd=ROOT, timeout=120)




def jsonl(text: str) -> list[dict]:
    return [json.loads(line) for line in text.splitlines()]


def cantools_values(db, msg: can.Message) -> dict[str, float]:
    return {k: float(v) for k, v in db.decode_message(msg.arbitration_id, bytes(msg.data),
                                                      decode_choices=False).items()}


def cantools_names(db, msg: can.Message) -> dict[str, str]:
    """The value-table names cantools gives the frame's values that are in their tables."""
    return {k: str(v) for k, v in db.decode_message(msg.arbitration_id, bytes(msg.data)).items()
            if isinstance(v, NamedSignalValue)}


@pytest.fixture(scope="module")
def lockstep_trace(tmp_path_factory) -> Path:
    scenario = load_scenario(ROOT / "scenarios" / "default.toml").model_copy(update={"max_duration_s": 2.0})
    out = tmp_path_factory.mktemp("lockstep") / "run"
    run_scenario_lockstep(scenario, out)
    return out / "trace.blf"


# --- stats --------------------------------------------------------------------------------------


@pytest.mark.parametrize("path", TRACE_PARAMS)
def test_stats_reads_every_corpus_trace(capsys, path):
    expected = list(can.LogReader(path))
    assert expected, f"python-can reads no frame from {path}"
    code, out, err = railhil(capsys, "trace", "stats", path, "--format", "csv")
    assert code == 0, err
    rows = list(csv.DictReader(io.StringIO(out)))
    assert sum(int(r["count"]) for r in rows) == len(expected)
    assert f"{path}: {len(expected)} frames" in err  # the header line goes to stderr with csv
    n_err = sum(m.is_error_frame for m in expected)
    assert sum(int(r["count"]) for r in rows if r["kind"] == "error") == n_err
    n_rtr = sum(m.is_remote_frame and not m.is_error_frame for m in expected)
    assert sum(int(r["count"]) for r in rows if r["kind"] == "remote") == n_rtr


@NO_CORPUS
def test_stats_table_keeps_11_and_29_bit_ids_apart_and_marks_error_and_remote_frames(capsys):
    code, out, err = railhil(capsys, "trace", "stats", PYCAN_DATA / "logfile.asc")
    assert code == 0, err
    header, columns, *rows = out.splitlines()
    assert header.startswith(f"{PYCAN_DATA / 'logfile.asc'}: 20 frames (4 error, 4 remote) over 28.305898 s")
    assert columns.split()[:4] == ["id", "frame", "kind", "name"]
    by_id = {tuple(r.split()[:3]) for r in rows}
    assert ("0x18EBFF00", "ext", "data") in by_id and ("0x300", "std", "remote") in by_id
    assert ("0x300", "std+fd", "data") in by_id
    assert rows[-1].split()[:2] == ["error", "4"]  # error frames last, one row


def test_stats_with_dbc_names_messages_and_computes_rate_and_period(capsys, lockstep_trace):
    code, out, err = railhil(capsys, "trace", "stats", lockstep_trace, "--dbc", TRAIN_DBC,
                             "--format", "jsonl")
    assert code == 0, err
    rows = {r["name"]: r for r in jsonl(out)}
    demand = rows["BCU_DEMAND"]  # 10 ms cycle in train_brake.dbc
    assert demand["id"] == "0x028" and demand["dlc"] == "8"
    # 10 ms schedule; the lockstep bus model delays each frame by its arbitration and transmission time
    assert float(demand["period_ms"]) == pytest.approx(10.0, rel=0.01)
    assert float(demand["rate_hz"]) == pytest.approx(100.0, rel=0.02)
    ids = [int(r["id"], 16) for r in jsonl(out)]
    assert ids == sorted(ids)


# --- decode -------------------------------------------------------------------------------------


@NO_CORPUS
def test_decode_candump_with_the_leaf_dbc_shows_every_frame_raw(capsys):
    # the SavvyCAN capture is not from a Leaf: none of its 180 ids is in LeafPowertrainBus.dbc
    code, out, err = railhil(capsys, "trace", "decode", CANDUMP, "--dbc", LEAF_DBC, "--format", "jsonl")
    assert code == 0, err
    rows = jsonl(out)
    assert len(rows) == 12974 and all(r["name"] is None and "data" in r for r in rows)
    assert "0 frames decoded, 12974 with ids not in" in err


@NO_CORPUS
@pytest.mark.parametrize("trace, dbc", [
    (CANDUMP, CANTOOLS_DBC / "abs.dbc"),
    (CANDUMP, OPENDBC / "toyota_prius_2010_pt.dbc"),
    (PYCAN_DATA / "issue_1256.asc", CANTOOLS_DBC / "socialledge.dbc"),
], ids=["candump+abs", "candump+prius", "issue_1256+socialledge"])
def test_decode_equals_cantools(capsys, trace, dbc):
    """Real traces against DBCs whose ids overlap theirs: every frame decodes as cantools decodes it (its
    numbers, and the names of the values in their tables), or fails where cantools fails (shown raw with
    the reason, never raised)."""
    db = cantools.database.load_file(str(dbc))
    known = {(m.frame_id, m.is_extended_frame) for m in db.messages}
    frames = list(can.LogReader(trace))
    # --absolute: the timestamps as recorded, as cantools prints them (by default: from the first frame)
    code, out, err = railhil(capsys, "trace", "decode", trace, "--dbc", dbc, "--format", "jsonl",
                             "--absolute")
    assert code == 0, err
    rows = jsonl(out)
    assert len(rows) == len(frames)
    decoded = failed = 0
    for msg, row in zip(frames, rows, strict=True):
        assert row["t"] == msg.timestamp
        if (msg.arbitration_id, msg.is_extended_id) not in known:
            assert row["name"] is None and row["data"] == bytes(msg.data).hex().upper()
        elif "signals" in row:
            decoded += 1
            assert row["signals"] == cantools_values(db, msg)
            assert row["choices"] == cantools_names(db, msg)
        else:
            failed += 1
            assert row["error"]
            with pytest.raises(Exception):  # noqa: B017 - cantools raises several types
                db.decode_message(msg.arbitration_id, bytes(msg.data), decode_choices=False)
    assert decoded + failed > 0
    assert f"{decoded} frames decoded" in err and f"{failed} failed to decode" in err


def test_decode_lockstep_trace_with_a_message_filter(capsys, lockstep_trace):
    db = cantools.database.load_file(str(TRAIN_DBC))
    frame_id = db.get_message_by_name("BCU_DEMAND").frame_id
    frames = [m for m in can.LogReader(lockstep_trace) if m.arbitration_id == frame_id]
    code, out, err = railhil(capsys, "trace", "decode", lockstep_trace, "--dbc", TRAIN_DBC,
                             "--message", "BCU_DEMAND", "--format", "jsonl")
    assert code == 0, err
    rows = jsonl(out)
    assert len(rows) == len(frames) == 200
    for msg, row in zip(frames, rows, strict=True):
        assert row["name"] == "BCU_DEMAND" and row["id"] == f"0x{frame_id:03X}"
        assert row["signals"] == cantools_values(db, msg)
        assert row["choices"] == cantools_names(db, msg) and row["choices"]["Mode"] in (
            "RELEASED", "SERVICE", "EMERGENCY")
        assert row["units"] == {"TargetDecel": "m/s^2"}


def test_decode_table_and_signal_filter(capsys, lockstep_trace):
    code, out, err = railhil(capsys, "trace", "decode", lockstep_trace, "--dbc", TRAIN_DBC,
                             "--signal", "AxleSpeed", "--end", "0.05")
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0].split() == ["t_s", "id", "name", "signals"]
    # AxleSpeed is in rad/s: its number, then its unit
    assert lines[1:] and all(line.split()[3].startswith("AxleSpeed=") and line.split()[4:] == ["rad/s"]
                             for line in lines[1:])


def test_decode_start_end_and_id_filters(capsys, lockstep_trace):
    frames = [m for m in can.LogReader(lockstep_trace)
              if m.arbitration_id in (0x101, 0x28) and 0.5 <= m.timestamp <= 1.0]
    code, out, err = railhil(capsys, "trace", "decode", lockstep_trace, "--dbc", TRAIN_DBC, "--id", "0x101",
                             "--id", "40", "--start", "0.5", "--end", "1.0", "--format", "csv")
    assert code == 0, err
    rows = list(csv.DictReader(io.StringIO(out)))
    assert rows and list(rows[0]) == ["t", "id", "name", "signal", "value", "error", "unit", "choice"]
    assert {r["id"] for r in rows} == {"0x101", "0x028"}
    assert all(0.5 <= float(r["t"]) <= 1.0 for r in rows)
    assert len({(r["t"], r["id"]) for r in rows}) == len(frames)


def test_unknown_message_and_signal_names_are_one_line_errors_with_the_closest(capsys, lockstep_trace):
    code, out, err = railhil(capsys, "trace", "decode", lockstep_trace, "--dbc", TRAIN_DBC,
                             "--message", "BCU_DEMAN", "--signal", "AxelSpeed")
    assert_one_line_error(code, err, "train_brake.dbc", "'BCU_DEMAN'", "BCU_DEMAND", "'AxelSpeed'",
                          "AxleSpeed")
    code, out, err = railhil(capsys, "trace", "decode", lockstep_trace, "--dbc", TRAIN_DBC, "--id", "0xZZ")
    assert_one_line_error(code, err, "--id", "0xZZ")


# --- start-up: each subcommand imported when it runs ---------------------------------------------


def test_help_lists_every_command_without_importing_them():
    """`railhil --help` lists each subcommand with its help line from hil.cli.main, the same line as
    the subcommand's module gives; `railhil trace ...` does not import the other subcommands."""
    from hil.cli.main import COMMANDS, build_parser

    assert build_parser().format_help() == build_parser(list(COMMANDS)).format_help()
    code = ("import sys; from hil.cli.main import main\n"
            "try:\n    main(['trace', 'decode', '--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in sys.modules if m in ('hil.cli.run', 'hil.cli.timing', 'hil.scenario')))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == "[]"
    assert "--dbc DBC" in proc.stdout


@pytest.mark.parametrize("args", [["trace", "stats", "{trace}"],
                                  ["trace", "decode", "{trace}", "--dbc", "{dbc}"],
                                  ["timing", "{trace}", "--dbc", "{dbc}"]], ids=["stats", "decode", "timing"])
def test_trace_commands_do_not_load_the_compiled_bus_model(lockstep_trace, args):
    """Reading a trace needs no numba (0.12 s of every start-up): the response-time analysis orders frames
    by hil.can.busload.arbitration_key, not through the bit-timed bus model (hil.can.bustiming)."""
    argv = [a.format(trace=lockstep_trace, dbc=TRAIN_DBC) for a in args]
    code = ("import sys; from hil.cli.main import main\n"
            f"try:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
            "print('numba' in sys.modules, file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.stderr.splitlines()[-1] == "False", proc.stderr[-500:]
    assert proc.stdout.strip(), proc.stderr[-500:]           # it did its job: a table, frames, verdicts


# --- bad input ------------------------------------------------------------------------------------


def test_missing_trace_file(capsys, tmp_path):
    missing = tmp_path / "nothing.blf"
    code, _, err = railhil(capsys, "trace", "stats", missing)
    assert_one_line_error(code, err, str(missing), "no such trace file")


@pytest.mark.parametrize("name, needle", [
    ("garbage.blf", "not readable as a Vector BLF binary trace"),
    ("garbage.asc.gz", "gzip-compressed"),
    ("garbage.log", "not readable as a candump -L text trace"),
    ("garbage.xyz", "unknown trace format"),
])
def test_garbage_trace_file(capsys, tmp_path, name, needle):
    bad = tmp_path / name
    bad.write_bytes(bytes(range(256)) * 8)
    assert_one_line_error(*railhil(capsys, "trace", "stats", bad)[::2], str(bad), needle)


@pytest.mark.parametrize("name, needle", [("words.asc", "no CAN frames found (expected a Vector ASC"),
                                          ("words.trc", "PEAK TRC"),
                                          ("words.log", "line 1")])
def test_text_of_another_format_is_an_error(capsys, tmp_path, name, needle):
    bad = tmp_path / name
    bad.write_text("hello world\nnot a trace\n")
    assert_one_line_error(*railhil(capsys, "trace", "stats", bad)[::2], str(bad), needle)


@NO_CORPUS
def test_dbc_cantools_rejects_exits_2_with_one_line():
    vw = OPENDBC / "vw_mqb.dbc"                      # overlapping signals: cantools rejects it strictly
    proc = railhil_process("trace", "decode", CANDUMP, "--dbc", vw)
    assert_one_line_error(proc.returncode, proc.stderr.decode(), str(vw), "not a loadable DBC")
    assert proc.stdout == b""


@NO_CORPUS
def test_a_dbc_with_a_value_table_naming_no_signal_is_read_and_says_so():
    """opendbc's tesla_can.dbc has VAL_ 568 UI_mapSpeedLimit, a signal message 568 no longer has: cantools
    rejects the file; railhil leaves the value table out, says so in one notice, and decodes."""
    tesla = OPENDBC / "tesla_can.dbc"
    proc = railhil_process("trace", "decode", CANDUMP, "--dbc", tesla, "--format", "csv")
    assert proc.returncode == 0, proc.stderr
    notices = [line for line in proc.stderr.decode().splitlines() if line.startswith("notice: ")]
    assert notices == [f"notice: {tesla}: VAL_ 568 UI_mapSpeedLimit names no signal of its message; the "
                       "value table is left out"], proc.stderr


@NO_CORPUS
def test_stdin_candump_text():
    proc = railhil_process("trace", "stats", "-", stdin=CANDUMP.read_bytes())
    assert proc.returncode == 0, proc.stderr
    header = proc.stdout.decode().splitlines()[0]
    assert header == ("<stdin>: 12974 frames (0 error, 0 remote) over 8.000000 s, 180 ids; times from the "
                      "first frame: t0 = 166.000000 s")


@NO_CORPUS
def test_closed_pipe_is_not_a_traceback():
    cmd = [sys.executable, "-m", "hil", "trace", "decode", str(CANDUMP), "--dbc", str(LEAF_DBC)]
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT) as proc:
        proc.stdout.readline()
        proc.stdout.close()  # `| head -1`
        err = proc.stderr.read().decode()
        assert proc.wait(timeout=60) == 0
    assert "Traceback" not in err and "BrokenPipe" not in err
