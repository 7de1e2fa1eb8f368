"""`railhil trace diff A B`: two lockstep runs with one seed are equal (exit 0), another seed differs
(exit 1, naming the signals); hand-built traces with known differences give exact figures; bad input
is one line `error: ...` with exit code 2.

The corpus lives outside the repository; RAILHIL_CORPUS points to it (default ../shared/corpus).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import can
import cantools
import pytest
from conftest import CORPUS, assert_one_line_error, railhil

from hil.report.run import run_scenario_lockstep
from hil.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
TRAIN_DBC = ROOT / "dbc" / "train_brake.dbc"
MULTIPLEX_DBC = CORPUS / "cantools" / "tests" / "files" / "dbc" / "multiplex.dbc"
NO_CORPUS = pytest.mark.skipif(not CORPUS.is_dir(),
                               reason=f"no trace corpus at {CORPUS} (set RAILHIL_CORPUS)")






def diff_json(capsys, *args) -> tuple[int, dict, str]:
    code, out, err = railhil(capsys, "trace", "diff", *args, "--format", "json")
    assert code in (0, 1), err
    return code, json.loads(out), err


def by_name(doc: dict) -> dict[str, dict]:
    return {m["name"] or m["id"]: m for m in doc["messages"]}


def signal(doc: dict, message: str, name: str) -> dict:
    return next(s for s in by_name(doc)[message]["signals"] if s["signal"] == name)


# --- lockstep runs --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def seeded_runs(tmp_path_factory) -> dict[str, Path]:
    """Three 2-s lockstep runs of the default scenario: seed 1 twice, seed 2 once."""
    scenario = load_scenario(ROOT / "scenarios" / "default.toml").model_copy(update={"max_duration_s": 2.0})
    base = tmp_path_factory.mktemp("seeds")
    runs = {}
    for name, seed in (("one", 1), ("one_again", 1), ("two", 2)):
        run_scenario_lockstep(scenario.model_copy(update={"seed": seed}), base / name)
        runs[name] = base / name / "trace.blf"
    return runs


def test_two_runs_with_the_same_seed_are_equal(capsys, seeded_runs):
    code, out, err = railhil(capsys, "trace", "diff", seeded_runs["one"], seeded_runs["one_again"],
                             "--dbc", TRAIN_DBC)
    assert code == 0, out + err
    last = out.strip().splitlines()[-1]
    assert last.startswith("trace diff: equal within tolerance:") and "frame pairs compared" in last
    assert "that differ" not in out


def test_another_seed_differs_and_names_the_signals(capsys, seeded_runs):
    code, out, err = railhil(capsys, "trace", "diff", seeded_runs["one"], seeded_runs["two"],
                             "--dbc", TRAIN_DBC)
    assert code == 1, err
    last = out.strip().splitlines()[-1]
    assert last.startswith("trace diff: DIFFER:") and "signals over tolerance" in last
    # the seed drives the sensor noise: the wheel-speed sensors differ, the driver's desk does not
    assert "PLANT_CAR1_SENSORS.AxleSpeed" in out
    code, doc, _ = diff_json(capsys, seeded_runs["one"], seeded_runs["two"], "--dbc", TRAIN_DBC)
    assert code == 1 and doc["equal"] is False
    axle = signal(doc, "PLANT_CAR1_SENSORS", "AxleSpeed")
    assert axle["over"] > 0 and axle["max_abs_delta"] > 0 and axle["compared"] == 200
    assert signal(doc, "DESK_CMD", "BrakeStep")["over"] == 0
    # the same figures from python-can and cantools directly
    db = cantools.database.load_file(str(TRAIN_DBC))
    a = [m for m in can.LogReader(str(seeded_runs["one"])) if m.arbitration_id == 0x101]
    b = [m for m in can.LogReader(str(seeded_runs["two"])) if m.arbitration_id == 0x101]
    deltas = [abs(db.decode_message(0x101, bytes(y.data))["AxleSpeed"]
                  - db.decode_message(0x101, bytes(x.data))["AxleSpeed"]) for x, y in zip(a, b, strict=True)]
    assert axle["over"] == sum(d > 0 for d in deltas)
    assert axle["max_abs_delta"] == pytest.approx(max(deltas), abs=1e-9)


def test_exit_codes_from_the_command_line(seeded_runs):
    def run(*args):
        return subprocess.run([sys.executable, "-m", "hil", "trace", "diff", *map(str, args)], cwd=ROOT,
                              capture_output=True, text=True, timeout=120)

    assert run(seeded_runs["one"], seeded_runs["one_again"], "--dbc", TRAIN_DBC).returncode == 0
    assert run(seeded_runs["one"], seeded_runs["two"], "--dbc", TRAIN_DBC).returncode == 1
    bad = run(seeded_runs["one"], seeded_runs["two"], "--dbc", TRAIN_DBC, "--tolerance", "-1")
    assert bad.returncode == 2 and bad.stderr.strip().startswith("error: --tolerance") and bad.stdout == ""


# --- hand-built traces with known differences -----------------------------------------------------


def std(t: float, arbitration_id: int, data: bytes) -> can.Message:
    """An 11-bit data frame (python-can's default is 29-bit)."""
    return can.Message(timestamp=t, arbitration_id=arbitration_id, is_extended_id=False, data=data)


def write(path: Path, frames: list[can.Message]) -> Path:
    with can.Logger(str(path)) as writer:
        for msg in frames:
            writer(msg)
    return path


@pytest.fixture(scope="module")
def known(tmp_path_factory) -> tuple[Path, Path]:
    """A and B (BLF, python-can's writer) with these differences, and nothing else:

    BCU_DEMAND (0x028), 10 frames each: TargetDecel of frame 3 is 0.55 in B (0.3 in A), of frame 7
    0.705 (0.7); frame 5 is 2 ms later in B.  DESK_CMD (0x018): 5 frames in A, 4 in B.  0x7FF (not in
    the DBC): 3 frames each, the 2nd one's last byte differs.  0x123 (not in the DBC): only in A.
    0x00000028 (29-bit; the DBC's 0x028 is 11-bit): only in B.
    """
    db = cantools.database.load_file(str(TRAIN_DBC))
    demand, desk = db.get_message_by_name("BCU_DEMAND"), db.get_message_by_name("DESK_CMD")

    def frames(side: str) -> list[can.Message]:
        out = []
        for k in range(10):
            decel = k / 10
            t = k / 100
            if side == "B" and k == 3:
                decel = 0.55
            if side == "B" and k == 7:
                decel = 0.705
            if side == "B" and k == 5:
                t += 0.002
            data = demand.encode({"CHECKSUM": 0, "COUNTER": k, "Mode": 1, "BrakeStep": 7,
                                  "TargetDecel": decel, "SecOCFreshness": k, "SecOCMAC": 0})
            out.append(std(t, demand.frame_id, data))
        for k in range(5 if side == "A" else 4):
            data = desk.encode({"CHECKSUM": 0, "COUNTER": k, "BrakeStep": 7, "EmergencyReq": 0,
                                "BrakeValve": 0, "SecOCFreshness": k, "SecOCMAC": 0})
            out.append(std(k / 50 + 0.005, desk.frame_id, data))
        for k in range(3):
            last = 4 if side == "B" and k == 1 else 3
            out.append(std(k / 20 + 0.001, 0x7FF, bytes([1, 2, last])))
        if side == "A":
            out += [std(0.002 + k / 10, 0x123, b"\x00") for k in range(2)]
        else:
            out.append(can.Message(timestamp=0.003, arbitration_id=0x28, is_extended_id=True, data=bytes(8)))
        return sorted(out, key=lambda m: m.timestamp)

    base = tmp_path_factory.mktemp("known")
    return write(base / "a.blf", frames("A")), write(base / "b.blf", frames("B"))


def test_known_differences_give_exact_figures(capsys, known):
    a, b = known
    code, doc, err = diff_json(capsys, a, b, "--dbc", TRAIN_DBC, "--time-tolerance", "0.001")
    assert code == 1
    m = by_name(doc)
    demand = m["BCU_DEMAND"]
    assert (demand["frames_a"], demand["frames_b"], demand["pairs"]) == (10, 10, 10)
    assert demand["time_over"] == 1 and demand["first_time_over_s"] == pytest.approx(0.05)
    assert demand["max_abs_dt_s"] == pytest.approx(0.002, abs=1e-9)
    decel = signal(doc, "BCU_DEMAND", "TargetDecel")
    assert (decel["compared"], decel["over"], decel["unpaired"]) == (10, 2, 0)
    assert decel["max_abs_delta"] == pytest.approx(0.25, abs=1e-9)
    assert decel["first_over_s"] == pytest.approx(0.03)
    assert (decel["first_over_a"], decel["first_over_b"]) == (pytest.approx(0.3), pytest.approx(0.55))
    assert decel["unit"] == "m/s^2"
    assert all(s["over"] == 0 for s in demand["signals"] if s["signal"] != "TargetDecel")
    desk = m["DESK_CMD"]
    assert (desk["frames_a"], desk["frames_b"], desk["pairs"], desk["only_in"]) == (5, 4, 4, None)
    assert all(s["over"] == 0 for s in desk["signals"])
    raw = m["0x7FF"]
    assert (raw["frames_a"], raw["frames_b"], raw["raw_differ"]) == (3, 3, 1)
    assert raw["first_raw_differ_s"] == pytest.approx(0.051) and raw["signals"] == []
    assert (m["0x123"]["only_in"], m["0x123"]["frames_a"], m["0x123"]["frames_b"]) == ("A", 2, 0)
    assert (m["0x00000028"]["only_in"], m["0x00000028"]["name"]) == ("B", None)   # 29-bit: not BCU_DEMAND
    differing = {k for k, v in m.items()
                 if v["frames_a"] != v["frames_b"] or v["time_over"] or v["raw_differ"]
                 or any(s["over"] or s["unpaired"] for s in v["signals"])}
    assert differing == {"BCU_DEMAND", "DESK_CMD", "0x7FF", "0x123", "0x00000028"}
    assert "1 ids only in A (0x123)" in doc["summary"] and "1 ids only in B (0x00000028)" in doc["summary"]
    assert "1 ids with different frame counts, A/B (0x018 5/4)" in doc["summary"]
    assert "1 of" in doc["summary"] and "BCU_DEMAND.TargetDecel" in doc["summary"]


def test_tolerances(capsys, known):
    a, b = known
    # the 0.005 step of frame 7 is within 0.01, the 0.25 step of frame 3 is not
    _, doc, _ = diff_json(capsys, a, b, "--dbc", TRAIN_DBC, "--tolerance", "0.01")
    assert signal(doc, "BCU_DEMAND", "TargetDecel")["over"] == 1
    _, doc, _ = diff_json(capsys, a, b, "--dbc", TRAIN_DBC,
                          "--signal-tolerance", "BCU_DEMAND.TargetDecel=0.3",
                          "--signal-tolerance", "TargetDecel=0.001")
    decel = signal(doc, "BCU_DEMAND", "TargetDecel")
    assert (decel["over"], decel["tolerance"]) == (0, 0.3)     # MESSAGE.NAME wins over NAME
    _, doc, _ = diff_json(capsys, a, b, "--dbc", TRAIN_DBC, "--signal-tolerance", "TargetDecel=inf")
    assert signal(doc, "BCU_DEMAND", "TargetDecel")["over"] == 0
    # timing: 2 ms is over the default of 0, within 5 ms, ignored with inf
    for tolerance, over in (("0", 1), ("0.005", 0), ("inf", 0)):
        _, doc, _ = diff_json(capsys, a, b, "--dbc", TRAIN_DBC, "--time-tolerance", tolerance)
        assert by_name(doc)["BCU_DEMAND"]["time_over"] == over, tolerance


def test_table_lists_what_differs_and_ends_with_the_summary(capsys, known):
    a, b = known
    code, out, _ = railhil(capsys, "trace", "diff", a, b, "--dbc", TRAIN_DBC, "--time-tolerance", "0.001")
    assert code == 1
    lines = out.strip().splitlines()
    assert lines[-1].startswith("trace diff: DIFFER:")
    rows = {line.split()[0]: line.split() for line in lines if line.startswith(("0x", "BCU_DEMAND."))}
    assert rows["BCU_DEMAND.TargetDecel"][1:6] == ["m/s^2", "10", "0.25", "0", "2"]
    assert rows["0x123"][-3:] == ["only", "in", "A"] and rows["0x018"][2:5] == ["5", "4", "4"]
    assert "BCU_DEMAND.Mode" not in out                                  # equal signals are not listed
    code, out, _ = railhil(capsys, "trace", "diff", a, b, "--dbc", TRAIN_DBC, "--all")
    assert "BCU_DEMAND.Mode" in out


def test_same_frames_in_another_format_are_equal(capsys, known, tmp_path):
    a, _ = known
    log = write(tmp_path / "a.log", list(can.LogReader(str(a))))         # candump -L text
    code, out, err = railhil(capsys, "trace", "diff", a, log, "--dbc", TRAIN_DBC, "--time-tolerance", "1e-6")
    assert code == 0, out + err


def test_align_start_compares_traces_recorded_at_other_times(capsys, known, tmp_path):
    a, _ = known
    frames = list(can.LogReader(str(a)))
    for msg in frames:
        msg.timestamp += 1_795_000_000.0    # a wall-clock recording
    later = write(tmp_path / "later.blf", frames)
    # neither trace is a run's: each is read from its first frame (hil.cli.trace.timebase), so they pair up
    code, doc, _ = diff_json(capsys, a, later, "--dbc", TRAIN_DBC, "--time-tolerance", "1e-6")
    assert code == 0, doc["summary"]
    code, doc, _ = diff_json(capsys, a, later, "--dbc", TRAIN_DBC, "--time-tolerance", "1e-6", "--absolute")
    assert code == 1 and by_name(doc)["BCU_DEMAND"]["time_over"] == 10        # as recorded: apart
    code, doc, _ = diff_json(capsys, a, later, "--dbc", TRAIN_DBC, "--time-tolerance", "1e-6", "--absolute",
                             "--align", "start")
    assert code == 0, doc["summary"]


def test_without_dbc_every_frame_is_compared_raw(capsys, known):
    a, b = known
    _, doc, _ = diff_json(capsys, a, b)
    m = by_name(doc)
    assert m["0x028"]["raw_differ"] == 2 and m["0x028"]["signals"] == []   # frames 3 and 7
    assert m["0x7FF"]["raw_differ"] == 1


@NO_CORPUS
def test_multiplexed_signals_carried_by_one_side_only_are_unpaired(capsys, tmp_path):
    db = cantools.database.load_file(str(MULTIPLEX_DBC))
    m = db.get_message_by_name("Message1")
    mux8 = {"Multiplexor": 8, "BIT_L": 1, "BIT_G": 0, "BIT_C": 1, "BIT_J": 0}
    mux24 = {**mux8, "Multiplexor": 24, "BIT_K": 1, "BIT_D": 0, "BIT_B": 0, "BIT_F": 0, "BIT_H": 0,
             "BIT_E": 0, "BIT_A": 0}

    def frames(values: list[dict]) -> list[can.Message]:
        return [can.Message(timestamp=k / 10, arbitration_id=m.frame_id, is_extended_id=True,
                            data=m.encode(v, strict=False)) for k, v in enumerate(values)]

    a = write(tmp_path / "a.blf", frames([mux8, mux8, mux8]))
    b = write(tmp_path / "b.blf", frames([mux8, mux24, mux8]))
    code, doc, _ = diff_json(capsys, a, b, "--dbc", MULTIPLEX_DBC)
    assert code == 1
    bit_k, bit_l = signal(doc, "Message1", "BIT_K"), signal(doc, "Message1", "BIT_L")
    assert (bit_k["unpaired"], bit_k["compared"]) == (1, 0)
    assert (bit_l["compared"], bit_l["over"], bit_l["unpaired"]) == (3, 0, 0)
    mux = signal(doc, "Message1", "Multiplexor")
    assert (mux["over"], mux["max_abs_delta"], mux["first_over_s"]) == (1, 16.0, pytest.approx(0.1))


# --- bad input ------------------------------------------------------------------------------------


@pytest.mark.parametrize("options, needles", [
    (["--signal-tolerance", "TargetDecel"], ["--signal-tolerance 'TargetDecel'", "NAME=ABS"]),
    (["--signal-tolerance", "TargetDecel=fast"], ["--signal-tolerance 'TargetDecel=fast'"]),
    (["--signal-tolerance", "TargetDecl=0.1"], ["train_brake.dbc", "'TargetDecl'", "TargetDecel"]),
    (["--signal-tolerance", "BCU_DEMAND.Decel=0.1"], ["BCU_DEMAND has no signal 'Decel'"]),
    (["--tolerance", "-0.5"], ["--tolerance -0.5"]),
    (["--time-tolerance", "nan"], ["--time-tolerance nan"]),
])
def test_bad_options_are_one_line_errors(capsys, known, options, needles):
    a, b = known
    code, _, err = railhil(capsys, "trace", "diff", a, b, "--dbc", TRAIN_DBC, *options)
    assert_one_line_error(code, err, *needles)


def test_bad_files_are_one_line_errors(capsys, known, tmp_path):
    a, _ = known
    missing = tmp_path / "missing.blf"
    assert_one_line_error(*railhil(capsys, "trace", "diff", a, missing, "--dbc", TRAIN_DBC)[::2],
                          str(missing), "no such trace file")
    assert_one_line_error(*railhil(capsys, "trace", "diff", a, a, "--signal-tolerance", "X=1")[::2],
                          "--signal-tolerance needs --dbc")
    garbage = tmp_path / "garbage.blf"
    garbage.write_bytes(bytes(range(256)) * 8)
    assert_one_line_error(*railhil(capsys, "trace", "diff", a, garbage, "--dbc", TRAIN_DBC)[::2],
                          str(garbage), "not readable as a Vector BLF binary trace")
