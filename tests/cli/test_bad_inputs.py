"""Catalogue of bad inputs (issue #9, acceptance point 3).

Every bad input a user can give railhil -- a DBC, a scenario, a trace -- gives one line on stderr,
``error: ...``, naming the file, key or value and what was expected, exit code 2, no traceback; a
trace damaged part-way (a corrupt line, a BLF file cut in the middle of an object) still gives what
was read before the damage ("nothing already recorded is lost"), then the error, which says how many
frames were read.  Inside a running node, bad frames and bad controller outputs are counted in
NodeStats and handled, never raised, and the run's run.json shows them.

The catalogue is one table (``CASES``): each case has an id that says what is bad, the command line
(built from the files of the ``bad`` fixture), the words its error line must hold, and what stdout
must still show.  Cases run in-process through ``hil.cli.main`` (conftest's ``railhil``); a few run
end to end as the ``railhil`` console command in a subprocess.  A case the code does not pass yet is
``xfail(strict=True)`` with the reason: the owner of the named file fixes it and removes the mark.

Property tests of the codec and the E2E check live in tests/can/test_codec.py and tests/can/test_e2e.py;
the scenario loader's is here.  There is no serial / NMEA input path in the code yet (issue #7).
"""

from __future__ import annotations

import json
import math
import os
import random
import shutil
import subprocess
import sys
import typing
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np
import pytest
from can.io import blf
from conftest import CORPUS, assert_one_line_error, railhil
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel

from hil.can.codec import Codec
from hil.can.dbc import DEFAULT_DBC, load_dbc
from hil.errors import ScenarioError

VW = CORPUS / "opendbc" / "opendbc" / "dbc" / "vw_mqb.dbc"     # overlapping signals: cantools rejects it
RAILHIL = Path(sys.executable).with_name("railhil")
N_FRAMES = 3000                # frames of the good traces: 10 ms apart, several BLF containers
SCENARIO_BASE = "max_duration_s = 0.5\nseed = 5\n[train]\ncars = 1\n"   # short, should a case ever run


# --- the bad files ------------------------------------------------------------------------------------


def cyclic_frames(n: int) -> list[can.Message]:
    """`n` frames of the project DBC's BCU_DEMAND and BCU_STATUS, encoded by the codec, 5 ms apart."""
    db = load_dbc()
    codec = Codec(db)
    demand, status = codec.by_name("BCU_DEMAND"), codec.by_name("BCU_STATUS")
    out = []
    for k in range(n):
        fc = demand if k % 2 == 0 else status
        values = {"TargetDecel": 0.5, "BrakeStep": 3} if fc is demand else {}
        out.append(can.Message(timestamp=1.0 + 0.005 * k, arbitration_id=fc.frame_id, is_extended_id=False,
                               data=fc.encode(values), channel=0))
    return out


def write_trace(path: Path, frames: list[can.Message]) -> Path:
    """`frames` written with python-can's writer for the suffix of `path`."""
    with can.Logger(str(path)) as writer:
        for msg in frames:
            writer.on_message_received(msg)
    return path


def blf_objects(path: Path) -> list[tuple[int, int]]:
    """(offset, size) of each top-level object of a BLF file, as python-can's reader walks them."""
    data = path.read_bytes()
    pos = blf.FILE_HEADER_STRUCT.unpack_from(data)[1]
    out = []
    while pos + blf.OBJ_HEADER_BASE_STRUCT.size <= len(data):
        size = blf.OBJ_HEADER_BASE_STRUCT.unpack_from(data, pos)[3]
        out.append((pos, size))
        pos += size + size % 4
    return out


def read_count(path: Path) -> int:
    """Frames python-can's own reader gives for `path` (it ends a cut BLF file quietly)."""
    with can.LogReader(str(path)) as reader:
        return sum(1 for _ in reader)


def corrupt_line(path: Path, out: Path, number: int, old: str, new: str) -> int:
    """`path` with `old` replaced by `new` in its line `number` (1-based), written to `out`; returns
    the frames python-can reads from the lines before that one."""
    lines = path.read_text().splitlines(keepends=True)
    assert old in lines[number - 1], lines[number - 1]
    lines[number - 1] = lines[number - 1].replace(old, new, 1)
    out.write_text("".join(lines))
    before = out.with_name("before-" + out.name)
    before.write_text("".join(lines[: number - 1]))
    n = read_count(before)
    before.unlink()
    return n


@dataclass
class Bad:
    """The files of the catalogue (module-scoped: built once)."""

    dir: Path
    good_blf: Path
    good_scenario: Path
    files: dict[str, Path] = field(default_factory=dict)
    read_before: dict[str, int] = field(default_factory=dict)   # frames readable before the damage
    syntax_line: int = 0

    def __getitem__(self, key: str) -> Path:
        return self.files[key]


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> Bad:
    d = tmp_path_factory.mktemp("bad-inputs")
    frames = cyclic_frames(N_FRAMES)
    good_blf = write_trace(d / "good.blf", frames)
    good_scenario = d / "good.toml"
    good_scenario.write_text(SCENARIO_BASE)
    b = Bad(d, good_blf, good_scenario)
    f = b.files
    dbc_text = DEFAULT_DBC.read_text()
    dbc_lines = dbc_text.splitlines(keepends=True)

    # DBCs
    f["dbc_missing"] = d / "missing.dbc"
    f["dbc_empty"] = d / "empty.dbc"
    f["dbc_empty"].write_bytes(b"")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    f["dbc_png"] = d / "picture.dbc"
    plt.imsave(f["dbc_png"], np.zeros((4, 4)), format="png")
    assert f["dbc_png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    f["dbc_garbage"] = d / "garbage.dbc"
    f["dbc_garbage"].write_bytes(bytes(random.Random(9).randrange(1, 256) for _ in range(400)))  # no NUL
    b.syntax_line = next(i for i, line in enumerate(dbc_lines, 1) if line.startswith(" SG_ TargetDecel"))
    broken = list(dbc_lines)
    broken[b.syntax_line - 1] = broken[b.syntax_line - 1].replace(" : 19|13@1+", " : nineteen|13@1+")
    f["dbc_syntax"] = d / "syntax.dbc"
    f["dbc_syntax"].write_text("".join(broken))
    f["dbc_collide"] = d / "collide.dbc"              # one more message on BCU_DEMAND's id
    assert "BO_ 40 BCU_DEMAND:" in dbc_text and "\nCM_ " in dbc_text
    f["dbc_collide"].write_text(dbc_text.replace(
        "\nCM_ ", '\nBO_ 40 BCU_DEMAND_COPY: 8 BCU\n SG_ Copy : 0|8@1+ (1,0) [0|255] "" BECU1\n\nCM_ ', 1))
    f["dbc_overlap"] = d / "overlap.dbc"              # BrakeStep moved into TargetDecel's bits
    assert " SG_ BrakeStep : 16|3@1+" in dbc_text
    f["dbc_overlap"].write_text(dbc_text.replace(" SG_ BrakeStep : 16|3@1+", " SG_ BrakeStep : 20|3@1+"))
    f["dbc_dir"] = d / "folder.dbc"
    f["dbc_dir"].mkdir()
    for key in [k for k in f if k.startswith("dbc_")] + ["dbc_vw"]:
        path = f[key] if key != "dbc_vw" else VW
        scen = d / f"uses-{key}.toml"
        scen.write_text(f"dbc = {json.dumps(str(path))}\n" + SCENARIO_BASE)
        f["scen_" + key] = scen

    # scenarios
    scenarios = {
        "not_toml": "this is = = not TOML\n",
        "unknown_top": "nmae = 'x'\n" + SCENARIO_BASE,
        "unknown_nested": SCENARIO_BASE + "car = 3\n",
        "wrong_type": SCENARIO_BASE.replace("cars = 1", "cars = 'six'"),
        "out_of_range": SCENARIO_BASE.replace("cars = 1", "cars = 9"),
        "nan_bounded": SCENARIO_BASE.replace("max_duration_s = 0.5", "max_duration_s = nan"),
        "inf_bounded": SCENARIO_BASE + "initial_speed_kmh = inf\n",
        "nan_unbounded": SCENARIO_BASE + "start_position_m = nan\n",
        "inf_desk_target": SCENARIO_BASE + "[[desk]]\nat_s = 0.1\ntarget_stop_m = inf\n",
        "fault_kind": SCENARIO_BASE + "[[faults]]\nkind = 'explode'\nfrom_s = 0.1\nto_s = 0.2\n",
        "fault_window": SCENARIO_BASE + "[[faults]]\nkind = 'deletion'\nmessage = 'BCU_DEMAND'\n"
                                        "from_s = 0.3\nto_s = 0.2\n",
        "fault_no_message": SCENARIO_BASE + "[[faults]]\nkind = 'deletion'\nfrom_s = 0.1\nto_s = 0.2\n",
        "fault_unknown_key": SCENARIO_BASE + "[[faults]]\nkind = 'deletion'\nmessage = 'BCU_DEMAND'\n"
                                             "from_s = 0.1\nto_s = 0.2\nprobabilty = 0.5\n",
        "fault_unknown_message": SCENARIO_BASE + "[[faults]]\nkind = 'deletion'\nmessage = 'BCU_DEMANT'\n"
                                                 "from_s = 0.1\nto_s = 0.2\n",
        "fault_nan_value": SCENARIO_BASE + "[[faults]]\nkind = 'masquerade'\nmessage = 'BCU_DEMAND'\n"
                                           "signal = 'TargetDecel'\nvalue = nan\nfrom_s = 0.1\nto_s = 0.2\n",
        "faults_not_a_list": "faults = 3\n" + SCENARIO_BASE,
    }
    for key, text in scenarios.items():
        f["scen_" + key] = d / f"{key}.toml"
        f["scen_" + key].write_text(text)
    f["scen_missing"] = d / "missing.toml"
    f["scen_binary"] = d / "binary.toml"
    f["scen_binary"].write_bytes(b"\xff\xfe\x00\x01 not text")
    f["scen_dir"] = d / "folder.toml"
    f["scen_dir"].mkdir()

    # traces
    for suffix in ("blf", "asc", "log"):
        f[f"empty_{suffix}"] = d / f"empty.{suffix}"
        f[f"empty_{suffix}"].write_bytes(b"")
    objects = blf_objects(good_blf)
    assert len(objects) >= 2, objects      # the cut lands inside the second log container
    pos, size = objects[1]
    f["cut_blf"] = d / "cut.blf"
    f["cut_blf"].write_bytes(good_blf.read_bytes()[: pos + size // 2])
    b.read_before["cut_blf"] = read_count(f["cut_blf"])
    assert 0 < b.read_before["cut_blf"] < N_FRAMES
    f["cut_blf_at_container"] = d / "cut-between-containers.blf"   # whole objects, but the header says more
    f["cut_blf_at_container"].write_bytes(good_blf.read_bytes()[: pos])
    b.read_before["cut_blf_at_container"] = read_count(f["cut_blf_at_container"])
    good_asc = write_trace(d / "good.asc", frames[:200])
    f["corrupt_asc"] = d / "corrupt.asc"
    asc_line = next(i for i, line in enumerate(good_asc.read_text().splitlines(), 1)
                    if i > 60 and " 28 " in line and " Rx " in line)
    b.read_before["corrupt_asc"] = corrupt_line(good_asc, f["corrupt_asc"], asc_line, " 28 ", " 2G8 ")
    good_log = write_trace(d / "good.log", frames[:200])
    f["corrupt_log"] = d / "corrupt.log"
    b.read_before["corrupt_log"] = corrupt_line(good_log, f["corrupt_log"], 101, "#", "#ZZ")
    f["not_gzip"] = d / "plain.log.gz"                 # candump text, named as if gzip-compressed
    shutil.copy(good_log, f["not_gzip"])
    f["unknown_ext"] = d / "trace.txt"
    shutil.copy(good_log, f["unknown_ext"])
    f["trace_dir"] = d / "folder.blf"
    f["trace_dir"].mkdir()
    f["trace_missing"] = d / "missing.blf"
    return b


# --- the catalogue ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    id: str                                  # what is bad
    argv: typing.Callable[[Bad], list]       # the command line
    needles: typing.Callable[[Bad], tuple]   # what the one error line must name
    stdout: typing.Callable[[Bad, str], None] | None = None   # what must still reach stdout
    xfail: str | None = None                 # why it does not pass yet (strict)
    subprocess: bool = False                 # end to end: the `railhil` console command


def decode(b: Bad, key: str) -> list:
    return ["trace", "decode", b[key], "--dbc", DEFAULT_DBC]


def timing(b: Bad, key: str) -> list:
    return ["timing", b[key], "--dbc", DEFAULT_DBC]


def stats(b: Bad, key: str) -> list:
    return ["trace", "stats", b[key]]


def replay(b: Bad, key: str) -> list:
    return ["trace", "replay", b[key], "-i", "virtual", "--max-speed", "-q"]


def run(b: Bad, key: str) -> list:
    return ["run", b[key], "--lockstep", "-q", "--out", b.dir / f"run-{key}"]


def stats_shows(key: str):
    def check(b: Bad, out: str) -> None:
        assert f": {b.read_before[key]} frames" in out.splitlines()[0], out[:300]
    return check


def decode_shows(key: str):
    def check(b: Bad, out: str) -> None:
        assert len(out.splitlines()) == 1 + b.read_before[key], out[-300:]   # header + a row per frame
    return check


def timing_shows(key: str):
    def check(b: Bad, out: str) -> None:
        assert f": {b.read_before[key]} frames over" in out.splitlines()[0], out[:300]
    return check


def replay_shows(key: str):
    def check(b: Bad, out: str) -> None:
        sent = next(line for line in out.splitlines() if line.startswith("frames sent"))
        assert int(sent.split()[-1]) == b.read_before[key], out
    return check


SCENARIO_PY = "hil/scenario/model.py (not this helper's file)"
DBC_CASES = [
    ("dbc_missing", lambda b: ("missing.dbc", "no such DBC file")),
    ("dbc_empty", lambda b: ("empty.dbc", "empty file", "expected a DBC")),
    ("dbc_png", lambda b: ("picture.dbc", "binary file", "expected a DBC")),
    ("dbc_garbage", lambda b: ("garbage.dbc", "not a loadable DBC", "line 1")),
    ("dbc_syntax", lambda b: ("syntax.dbc", "not a loadable DBC", f"line {b.syntax_line}")),
    ("dbc_vw", lambda b: ("vw_mqb.dbc", "not a loadable DBC", "overlapping")),
    ("dbc_collide", lambda b: ("collide.dbc", "BCU_DEMAND, BCU_DEMAND_COPY", "same frame id 0x28")),
    ("dbc_overlap", lambda b: ("overlap.dbc", "overlapping", "BCU_DEMAND")),
    ("dbc_dir", lambda b: ("folder.dbc", "directory", "expected a DBC")),
]


def _dbc_path(b: Bad, key: str) -> Path:
    return VW if key == "dbc_vw" else b[key]


CASES: list[Case] = []
for _key, _needles in DBC_CASES:
    CASES += [
        Case(f"{_key}-run", lambda b, k=_key: run(b, "scen_" + k), _needles),
        Case(f"{_key}-decode", lambda b, k=_key: ["trace", "decode", b.good_blf, "--dbc", _dbc_path(b, k)],
             _needles),
        Case(f"{_key}-timing", lambda b, k=_key: ["timing", b.good_blf, "--dbc", _dbc_path(b, k)], _needles),
        Case(f"{_key}-stats", lambda b, k=_key: ["trace", "stats", b.good_blf, "--dbc", _dbc_path(b, k)],
             _needles),
    ]
CASES += [
    Case("dbc_without_the_train_messages-run", lambda b: run(b, "scen_leaf"),
         lambda b: ("LeafPowertrainBus.dbc", "PLANT_CAR1_SENSORS")),
    # scenarios
    Case("scenario_not_toml", lambda b: run(b, "scen_not_toml"),
         lambda b: ("not_toml.toml", "not valid TOML", "line 1")),
    Case("scenario_unknown_top_key_names_the_closest", lambda b: run(b, "scen_unknown_top"),
         lambda b: ("unknown_top.toml", "'nmae'", "name")),
    Case("scenario_unknown_nested_key_names_the_closest", lambda b: run(b, "scen_unknown_nested"),
         lambda b: ("unknown_nested.toml", "'train.car'", "cars")),
    Case("scenario_unknown_key_is_named", lambda b: run(b, "scen_unknown_nested"),
         lambda b: ("unknown_nested.toml", "'train.car'", "not a scenario key")),
    Case("scenario_wrong_type", lambda b: run(b, "scen_wrong_type"),
         lambda b: ("wrong_type.toml", "train.cars", "'six'", "integer")),
    Case("scenario_out_of_range", lambda b: run(b, "scen_out_of_range"),
         lambda b: ("out_of_range.toml", "train.cars", "9", "less than or equal to 8")),
    Case("scenario_nan_in_a_bounded_number", lambda b: run(b, "scen_nan_bounded"),
         lambda b: ("nan_bounded.toml", "max_duration_s", "nan")),
    Case("scenario_inf_in_a_bounded_number", lambda b: run(b, "scen_inf_bounded"),
         lambda b: ("inf_bounded.toml", "train.initial_speed_kmh", "inf")),
    Case("scenario_nan_in_an_unbounded_number", lambda b: run(b, "scen_nan_unbounded"),
         lambda b: ("nan_unbounded.toml", "train.start_position_m", "nan")),
    Case("scenario_inf_desk_target", lambda b: run(b, "scen_inf_desk_target"),
         lambda b: ("inf_desk_target.toml", "target_stop_m", "inf")),
    Case("scenario_fault_unknown_kind", lambda b: run(b, "scen_fault_kind"),
         lambda b: ("fault_kind.toml", "faults.0.kind", "'explode'", "'deletion'")),
    Case("scenario_fault_window_backwards", lambda b: run(b, "scen_fault_window"),
         lambda b: ("fault_window.toml", "faults.0", "to_s 0.2 must be after from_s 0.3")),
    Case("scenario_fault_without_message", lambda b: run(b, "scen_fault_no_message"),
         lambda b: ("fault_no_message.toml", "faults.0", "needs 'message'")),
    Case("scenario_fault_unknown_key", lambda b: run(b, "scen_fault_unknown_key"),
         lambda b: ("fault_unknown_key.toml", "faults.0.probabilty", "not a scenario key")),
    Case("scenario_fault_message_not_in_dbc", lambda b: run(b, "scen_fault_unknown_message"),
         lambda b: ("faults[0].message", "'BCU_DEMANT'", "closest: BCU_DEMAND")),
    Case("scenario_fault_nan_value", lambda b: run(b, "scen_fault_nan_value"),
         lambda b: ("fault_nan_value.toml", "faults.0.value", "nan")),
    Case("scenario_faults_not_a_list", lambda b: run(b, "scen_faults_not_a_list"),
         lambda b: ("faults_not_a_list.toml", "'faults'", "valid list")),
    Case("scenario_missing", lambda b: run(b, "scen_missing"),
         lambda b: ("missing.toml", "no such scenario")),
    Case("scenario_binary", lambda b: run(b, "scen_binary"), lambda b: ("binary.toml", "cannot read")),
    Case("scenario_directory", lambda b: run(b, "scen_dir"), lambda b: ("folder.toml", "directory")),
    # traces
    *[Case(f"trace_empty_{s}-{name}", lambda b, s=s, fn=fn: fn(b, f"empty_{s}"),
           lambda b, s=s: (f"empty.{s}", "empty file", "no CAN frames"))
      for s in ("blf", "asc", "log")
      for name, fn in (("stats", stats), ("decode", decode), ("timing", timing))],
    Case("trace_empty_blf-replay", lambda b: replay(b, "empty_blf"), lambda b: ("empty.blf", "empty file")),
    *[Case(f"{key}-{name}", lambda b, key=key, fn=fn: fn(b, key),
           lambda b, key=key: (b[key].name, "truncated", "Vector BLF",
                               f"{b.read_before[key]} frames read before the cut"),
           stdout=shows(key))
      for key in ("cut_blf", "cut_blf_at_container")
      for name, fn, shows in (("stats", stats, stats_shows), ("decode", decode, decode_shows),
                              ("timing", timing, timing_shows), ("replay", replay, replay_shows))],
    *[Case(f"{key}-{name}", lambda b, key=key, fn=fn: fn(b, key),
           lambda b, key=key, what=what: (b[key].name, what, "2G8" if key == "corrupt_asc" else "ZZ",
                                          f"after {b.read_before[key]} frames"),
           stdout=shows(key))
      for key, what in (("corrupt_asc", "Vector ASC"), ("corrupt_log", "line 101"))
      for name, fn, shows in (("stats", stats, stats_shows), ("decode", decode, decode_shows),
                              ("timing", timing, timing_shows), ("replay", replay, replay_shows))],
    *[Case(f"trace_not_gzip-{name}", lambda b, fn=fn: fn(b, "not_gzip"),
           lambda b: ("plain.log.gz", "gzip", "Not a gzipped file"))
      for name, fn in (("stats", stats), ("decode", decode), ("timing", timing), ("replay", replay))],
    *[Case(f"trace_unknown_extension-{name}", lambda b, fn=fn: fn(b, "unknown_ext"),
           lambda b: ("trace.txt", "unknown trace format '.txt'", ".blf"))
      for name, fn in (("stats", stats), ("decode", decode), ("timing", timing), ("replay", replay))],
    *[Case(f"trace_directory-{name}", lambda b, fn=fn: fn(b, "trace_dir"),
           lambda b: ("folder.blf", "not a file"))
      for name, fn in (("stats", stats), ("decode", decode), ("timing", timing))],
    *[Case(f"trace_missing-{name}", lambda b, fn=fn: fn(b, "trace_missing"),
           lambda b: ("missing.blf", "no such trace file"))
      for name, fn in (("stats", stats), ("decode", decode), ("timing", timing), ("replay", replay))],
    # a few end to end, as the console command
    Case("e2e-dbc_collide-decode", lambda b: ["trace", "decode", b.good_blf, "--dbc", b["dbc_collide"]],
         lambda b: ("collide.dbc", "same frame id 0x28"), subprocess=True),
    Case("e2e-cut_blf-stats", lambda b: stats(b, "cut_blf"),
         lambda b: ("cut.blf", "truncated", f"{b.read_before['cut_blf']} frames read before the cut"),
         stdout=stats_shows("cut_blf"), subprocess=True),
    Case("e2e-scenario_wrong_type", lambda b: run(b, "scen_wrong_type"),
         lambda b: ("wrong_type.toml", "train.cars", "'six'"), subprocess=True),
    Case("e2e-corrupt_log-timing", lambda b: timing(b, "corrupt_log"),
         lambda b: ("corrupt.log", "line 101", "ZZ"), stdout=timing_shows("corrupt_log"), subprocess=True),
]


def _params() -> list:
    return [pytest.param(case, id=case.id,
                         marks=[pytest.mark.xfail(strict=True, reason=case.xfail)] if case.xfail else [])
            for case in CASES]


def check_one_line_error(code: int, out: str, err: str, needles: tuple) -> None:
    """Exit 2, one line `error: ...` naming each needle, no traceback on stdout or stderr."""
    assert "Traceback" not in err and "Traceback" not in out, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for needle in needles:
        assert str(needle) in lines[0], (needle, lines[0])
    assert code == 2, (code, err)


@pytest.fixture(scope="module")
def leaf_scenario(bad):
    leaf = CORPUS / "SavvyCAN" / "examples" / "LeafPowertrainBus.dbc"
    bad.files["scen_leaf"] = bad.dir / "uses-leaf.toml"
    bad.files["scen_leaf"].write_text(f"dbc = {json.dumps(str(leaf))}\n" + SCENARIO_BASE)


@pytest.mark.parametrize("case", _params())
def test_bad_input(case: Case, bad: Bad, leaf_scenario, capsys):
    argv = [str(a) for a in case.argv(bad)]
    if case.subprocess:
        proc = subprocess.run([str(RAILHIL), *argv], capture_output=True, text=True, cwd=bad.dir, timeout=300)
        code, out, err = proc.returncode, proc.stdout, proc.stderr
    else:
        code, out, err = railhil(capsys, *argv)
    check_one_line_error(code, out, err, case.needles(bad))
    if case.stdout is not None:
        case.stdout(bad, out)


def test_permission_denied_trace_and_dbc(bad):
    """A trace or DBC the user may not read: one line naming the file and the system's reason.  As
    root (who reads every file) the command runs without the capabilities that bypass file modes."""
    locked_trace = bad.dir / "locked.blf"
    locked_dbc = bad.dir / "locked.dbc"
    shutil.copy(bad.good_blf, locked_trace)
    shutil.copy(DEFAULT_DBC, locked_dbc)
    os.chmod(locked_trace, 0)
    os.chmod(locked_dbc, 0)
    prefix: list[str] = []
    if os.geteuid() == 0:
        setpriv = shutil.which("setpriv")
        if setpriv is None:
            pytest.skip("running as root without setpriv: cannot take away the right to read any file")
        prefix = [setpriv, "--inh-caps=-all", "--ambient-caps=-all",
                  "--bounding-set=-dac_override,-dac_read_search"]
    for argv, needles in (
        (["trace", "stats", locked_trace], ("locked.blf", "Permission denied")),
        (["timing", locked_trace, "--dbc", DEFAULT_DBC], ("locked.blf", "Permission denied")),
        (["trace", "decode", bad.good_blf, "--dbc", locked_dbc], ("locked.dbc", "Permission denied")),
    ):
        proc = subprocess.run([*prefix, str(RAILHIL), *map(str, argv)], capture_output=True, text=True,
                              timeout=120)
        check_one_line_error(proc.returncode, proc.stdout, proc.stderr, needles)


def test_an_unexpected_exception_is_one_line_and_debug_shows_the_traceback(bad, capsys, monkeypatch):
    """A bug (an exception that is not a RailhilError) still prints one line, exit 1, saying how to get
    the traceback; --debug gives it.  The bug is injected into `trace stats`' table builder."""
    import hil.cli.trace.stats as stats

    def broken(frames):
        raise KeyError("injected bug")

    monkeypatch.setattr(stats, "collect_stats", broken)
    argv = ["trace", "stats", str(bad.good_blf)]
    code, out, err = railhil(capsys, *argv)
    assert code == 1 and "Traceback" not in err
    assert err.count("\n") == 1 and err.startswith("error: internal error") and "--debug" in err
    assert "KeyError" in err and "injected bug" in err
    with pytest.raises(KeyError):
        railhil(capsys, "--debug", *argv)


# --- inside a running node: counted and handled, never raised -----------------------------------------


@pytest.fixture(scope="module")
def small_scenario(tmp_path_factory):
    from hil.scenario import load_scenario

    path = tmp_path_factory.mktemp("node-scenario") / "short.toml"
    path.write_text("max_duration_s = 1.0\nseed = 3\n[train]\ncars = 1\n"
                    "[[desk]]\nat_s = 0.1\nbrake_step = 7\n")
    return load_scenario(path)


def becu1(scenario, controller=None, safe: dict | None = None):
    """The BECU1 node of the scenario as hil.runtime.assembly builds it, optionally with another controller
    and
    safe outputs."""
    from hil.runtime.assembly import build_node
    from hil.runtime.node import Node

    db = load_dbc()
    codec = Codec(db)
    node = build_node("BECU1", scenario, db, codec)
    if controller is None and safe is None:
        return node, codec
    from hil.runtime.assembly import becu_messages
    from hil.runtime.node import Binding

    ctrl = controller or node.controller
    rx, tx = becu_messages(1)
    binding = Binding.build(db, "BECU1", ctrl.INPUTS, ctrl.OUTPUTS, rx, tx)
    return Node("BECU1", ctrl, binding, codec, db, node.period_us, node.offset_us, safe_outputs=safe), codec


class Faulty:
    """A real controller with a fault in a time window [µs]: raises, returns NaN or +inf, an
    out-of-range value (1 GPa cylinder pressure), or a value that is not a number."""

    def __init__(self, inner, kind: str, start_us: int = 0, end_us: int = 1 << 62) -> None:
        self.inner, self.kind, self.start_us, self.end_us = inner, kind, start_us, end_us
        self.INPUTS, self.OUTPUTS = inner.INPUTS, inner.OUTPUTS
        self.faults = 0

    def step(self, now_us, rx):
        out = self.inner.step(now_us, rx)
        if not self.start_us <= now_us < self.end_us:
            return out
        self.faults += 1
        if self.kind == "raise":
            raise ZeroDivisionError("injected fault")
        if self.kind == "none":
            return None
        value = {"nan": math.nan, "inf": math.inf, "range": 1e9, "text": "full"}[self.kind]
        return {**out, "CylPressureSet": value}


def press_cmd(codec, frames) -> dict:
    fc = codec.by_name("BECU1_PRESS_CMD")
    return next(fc.decode(data) for c, data in frames if c is fc)


def test_node_counts_a_frame_with_a_short_dlc_and_ignores_it(small_scenario):
    node, codec = becu1(small_scenario)
    fc = codec.by_name("PLANT_CAR1_SENSORS")
    good = fc.encode({name: 1.0 for name in fc.signal_names})
    node.receive(fc.frame_id, good[:3], 1000)                 # DLC 3 of 8
    assert node.stats.bad_frames == 1
    assert all(math.isnan(node.rx[k]) for k in node.rx)      # nothing taken from it
    node.receive(fc.frame_id, good, 2000)
    assert node.stats.bad_frames == 1 and node.stats.frames_received == 1


def test_node_takes_the_first_bytes_of_a_frame_longer_than_its_dlc(small_scenario):
    """A longer frame (a CAN FD frame of a classic message) is decoded from its first 8 bytes, as
    cantools' allow_excess and AUTOSAR's DLC check (at least the configured length) do."""
    node, codec = becu1(small_scenario)
    reference, _ = becu1(small_scenario)
    fc = codec.by_name("PLANT_CAR1_SENSORS")
    good = fc.encode({name: 1.0 for name in fc.signal_names})
    node.receive(fc.frame_id, good + bytes(4), 1000)
    reference.receive(fc.frame_id, good, 1000)
    assert node.stats.bad_frames == 0 and node.stats.frames_received == 1
    assert np.array_equal([node.rx[k] for k in node.rx], [reference.rx[k] for k in reference.rx],
                          equal_nan=True)
    assert sum(not math.isnan(node.rx[k]) for k in node.rx) > 0


def test_node_ignores_a_frame_of_an_id_not_in_the_dbc(small_scenario):
    node, codec = becu1(small_scenario)
    assert 0x7F0 not in codec
    node.receive(0x7F0, bytes(8), 1000)
    assert node.stats.frames_received == 0 and node.stats.bad_frames == 0


def test_node_counts_a_frame_of_an_id_not_in_the_dbc(small_scenario):
    node, _ = becu1(small_scenario)
    node.receive(0x7F0, bytes(8), 1000)
    assert node.stats.as_dict().get("unknown_frames") == 1


@pytest.mark.parametrize("kind", ["nan", "inf"])
def test_node_replaces_a_non_finite_output_by_its_safe_value(small_scenario, kind):
    node, _ = becu1(small_scenario)
    faulty = Faulty(node.controller, kind)
    node, codec = becu1(small_scenario, faulty, safe={"CylPressureSet": 0.0})
    frames = node.cycle(node.offset_us)
    assert node.stats.bad_outputs == faulty.faults == 1
    assert press_cmd(codec, frames)["CylPressureSet"] == 0.0


def test_node_saturates_an_out_of_range_output_and_the_codec_counts_it(small_scenario):
    node, _ = becu1(small_scenario)
    faulty = Faulty(node.controller, "range")
    node, codec = becu1(small_scenario, faulty, safe={})
    fc = codec.by_name("BECU1_PRESS_CMD")
    before = fc.clamped
    frames = node.cycle(node.offset_us)
    top = fc.message.get_signal_by_name("CylPressureSet").maximum
    assert press_cmd(codec, frames)["CylPressureSet"] == top
    assert fc.clamped - before == 1


def test_node_counts_an_out_of_range_output(small_scenario):
    node, _ = becu1(small_scenario)
    node, _ = becu1(small_scenario, Faulty(node.controller, "range"), safe={})
    node.cycle(node.offset_us)
    assert node.stats.as_dict().get("clamped_outputs") == 1


def test_node_sends_safe_values_when_step_raises(small_scenario):
    node, _ = becu1(small_scenario)
    faulty = Faulty(node.controller, "raise")
    node, codec = becu1(small_scenario, faulty, safe={"CylPressureSet": 0.0, "ValveCmd": -1.0})
    frames = node.cycle(node.offset_us)
    assert node.stats.step_errors == 1 and "ZeroDivisionError: injected fault" in node.stats.last_error
    values = press_cmd(codec, frames)
    assert values["CylPressureSet"] == 0.0 and values["ValveCmd"] == -1.0


@pytest.mark.parametrize("kind", ["none", "text"])
def test_node_survives_a_step_that_returns_no_numbers(small_scenario, kind):
    node, _ = becu1(small_scenario)
    node, _ = becu1(small_scenario, Faulty(node.controller, kind), safe={"CylPressureSet": 0.0})
    node.cycle(node.offset_us)
    assert node.stats.step_errors + node.stats.bad_outputs == 1


FAULT_WINDOWS_US = {"raise": (300_000, 350_000), "nan": (400_000, 450_000), "range": (500_000, 550_000)}


@pytest.fixture(scope="module")
def faulty_run(small_scenario, tmp_path_factory):
    """A 1 s lockstep run (public API: hil.report.run.run_scenario_lockstep) whose BECU1 controller raises,
    returns NaN and returns an out-of-range pressure, each in its own window: the fault is injected by
    wrapping the real controller that hil.runtime.assembly builds; bus, trace and DBC are the real ones."""
    import hil.runtime.lockstep
    from hil.report.run import run_scenario_lockstep

    real_build = hil.runtime.lockstep.build_node
    injected: dict[str, Faulty] = {}

    def build_node(name, *args, **kwargs):
        node = real_build(name, *args, **kwargs)
        if name == "BECU1":
            ctrl = node.controller
            for kind, (start, end) in FAULT_WINDOWS_US.items():
                ctrl = injected[kind] = Faulty(ctrl, kind, start, end)
            node.controller = ctrl
        return node

    out = tmp_path_factory.mktemp("faulty-run") / "run"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(hil.runtime.lockstep, "build_node", build_node)
        report = run_scenario_lockstep(small_scenario, out)
    return report, injected


def test_a_lockstep_run_counts_controller_faults_and_keeps_its_trace(faulty_run):
    report, injected = faulty_run
    assert report.outcome.reason == "max_duration"        # the run went on to its end
    run_json = json.loads((report.out_dir / "run.json").read_text())
    stats = run_json["node_stats"]["BECU1"]
    assert injected["raise"].faults > 0 and stats["step_errors"] == injected["raise"].faults
    assert "injected fault" in stats["last_error"]
    assert injected["nan"].faults > 0 and stats["bad_outputs"] == injected["nan"].faults
    with can.LogReader(str(report.out_dir / "trace.blf")) as reader:   # nothing recorded is lost
        stamps = [m.timestamp for m in reader]
    assert len(stamps) == report.kpis["frames_recorded"] > 0
    assert max(stamps) > 0.9 * report.outcome.end_us / 1e6


def test_a_lockstep_run_shows_out_of_range_outputs_in_run_json(faulty_run):
    report, injected = faulty_run
    stats = json.loads((report.out_dir / "run.json").read_text())["node_stats"]["BECU1"]
    assert injected["range"].faults > 0 and stats.get("clamped_outputs") == injected["range"].faults


# --- the scenario loader: loads, or one ScenarioError line; never anything else -----------------------


def _models_in(annotation) -> list[type[BaseModel]]:
    """The pydantic models inside a field's annotation (through Optional, list, dict, Annotated)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in typing.get_args(annotation) for m in _models_in(arg)]


def _is_list(annotation) -> bool:
    if typing.get_origin(annotation) is list:
        return True
    return any(_is_list(a) for a in typing.get_args(annotation) if typing.get_origin(annotation) is not dict)


KEY_TEXT = st.text("abcdefghijklmnopqrstuvwxyz_0123456789", min_size=1, max_size=12)
SCALARS = st.one_of(
    st.integers(-10**6, 10**6), st.integers(-2**63, 2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(st.characters(codec="utf-8", exclude_categories=("Cs", "Cc")), max_size=12),
    st.booleans(), st.sampled_from(["dry", "wet", "BCU_DEMAND", "TargetDecel", "deletion", "bit", "decel"]),
)
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(KEY_TEXT, inner, max_size=3)),
                      max_leaves=8)


def document(model: type[BaseModel], depth: int = 0) -> st.SearchStrategy[dict]:
    """Documents of `model`'s real keys (nested tables and arrays of tables as the model has them)
    with random values, and random junk keys."""
    fields = {}
    for name, info in model.model_fields.items():
        models = _models_in(info.annotation)
        if models and depth < 3:
            sub = document(models[0], depth + 1)
            fields[name] = st.one_of(st.lists(sub, max_size=3), VALUES) if _is_list(info.annotation) \
                else st.one_of(sub, VALUES)
        else:
            fields[name] = VALUES
    real = st.fixed_dictionaries({}, optional=fields)
    junk = st.dictionaries(KEY_TEXT, VALUES, max_size=2)
    return st.builds(lambda a, b: {**b, **a}, real, st.one_of(st.just({}), junk))


def toml_value(value) -> str:
    """`value` as a TOML literal (arrays and inline tables for the nested ones)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) \
            else repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, list):
        return "[" + ", ".join(map(toml_value, value)) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) + "}"


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=document(__import__("hil.scenario", fromlist=["Scenario"]).Scenario))
def test_scenario_loader_loads_or_raises_one_scenario_error_line(tmp_path_factory, doc):
    from hil.scenario import Scenario, load_scenario

    path = tmp_path_factory.mktemp("scen") / "s.toml"
    path.write_text("".join(f"{json.dumps(k)} = {toml_value(v)}\n" for k, v in doc.items()))
    try:
        scenario = load_scenario(path)
    except ScenarioError as exc:
        text = str(exc)
        assert "\n" not in text and text.startswith(str(path)), text
    else:
        assert isinstance(scenario, Scenario)


def test_faults_in_a_real_time_run_are_refused_not_dropped(tmp_path, capsys):
    """[[faults]] are injected by the lockstep run: a real-time run of such a scenario says so."""
    scenario = tmp_path / "faulty.toml"
    scenario.write_text('name = "faulty"\nmax_duration_s = 1\n[[faults]]\nkind = "deletion"\n'
                        'message = "BCU_DEMAND"\nfrom_s = 0.1\nto_s = 0.2\n')
    code, out, err = railhil(capsys, "run", scenario, "--realtime", "--out", tmp_path / "run")
    assert_one_line_error(code, err, "[[faults]]", "deletion", "--lockstep")
    assert not (tmp_path / "run").exists()
