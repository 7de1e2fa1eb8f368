"""`railhil trace plot`: PNG (matplotlib) and self-contained HTML (plotly) of DBC signals, the samples
equal to cantools' decoding (multiplexed signals included), only the needed ids decoded, and bad
input as one line `error: ...` with exit code 2.

The corpus lives outside the repository; RAILHIL_CORPUS points to it (default ../shared/corpus).
"""

from __future__ import annotations

import re
from pathlib import Path

import can
import cantools
import matplotlib.image
import pytest
from conftest import CORPUS, assert_one_line_error, railhil

from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.cli.trace import plot
from hil.report.run import run_scenario_lockstep
from hil.scenario import load_scenario
from hil.trace.readers import open_trace

ROOT = Path(__file__).resolve().parents[2]
TRAIN_DBC = ROOT / "dbc" / "train_brake.dbc"
NO_CORPUS = pytest.mark.skipif(not CORPUS.is_dir(),
                               reason=f"no trace corpus at {CORPUS} (set RAILHIL_CORPUS)")
ISSUE_1256 = CORPUS / "python-can" / "test" / "data" / "issue_1256.asc"
SOCIALLEDGE_DBC = CORPUS / "cantools" / "tests" / "files" / "dbc" / "socialledge.dbc"
MULTIPLEX_DBC = CORPUS / "cantools" / "tests" / "files" / "dbc" / "multiplex.dbc"






def cantools_series(trace: Path, dbc, message: str, signal: str) -> tuple[list[float], list[float]]:
    """(times, values) of one signal as cantools decodes the trace python-can reads."""
    m = dbc.get_message_by_name(message)
    t, v = [], []
    for msg in can.LogReader(str(trace)):
        if msg.arbitration_id != m.frame_id or msg.is_extended_id != m.is_extended_frame:
            continue
        decoded = m.decode(bytes(msg.data), decode_choices=False)
        if signal in decoded:
            t.append(msg.timestamp)
            v.append(float(decoded[signal]))
    return t, v


@pytest.fixture(scope="module")
def lockstep_trace(tmp_path_factory) -> Path:
    scenario = load_scenario(ROOT / "scenarios" / "default.toml").model_copy(update={"max_duration_s": 2.0})
    out = tmp_path_factory.mktemp("lockstep") / "run"
    run_scenario_lockstep(scenario, out)
    return out / "trace.blf"


@pytest.fixture(scope="module")
def mux_trace(tmp_path_factory) -> Path:
    """Frames of cantools' multiplex.dbc Message1 (29-bit id) with multiplexer 8, 16, 24 in turn,
    encoded by cantools and written with python-can's BLF writer, plus frames of another id."""
    if not MULTIPLEX_DBC.is_file():
        pytest.skip(f"corpus file {MULTIPLEX_DBC} not present (set RAILHIL_CORPUS)")
    db = cantools.database.load_file(str(MULTIPLEX_DBC))
    m = db.get_message_by_name("Message1")
    path = tmp_path_factory.mktemp("mux") / "mux.blf"
    with can.Logger(str(path)) as writer:
        for k in range(30):
            mux = (8, 16, 24)[k % 3]
            values = {"Multiplexor": mux, "BIT_L": k % 2, "BIT_G": 1, "BIT_C": 0, "BIT_J": (k // 3) % 2}
            if mux == 24:
                values.update({"BIT_K": (k // 3) % 2, "BIT_D": 1, "BIT_B": 0, "BIT_F": 1, "BIT_H": 0,
                               "BIT_E": 1, "BIT_A": k % 2})
            data = m.encode(values, strict=False)
            writer(can.Message(timestamp=0.01 * k, arbitration_id=m.frame_id, is_extended_id=True, data=data))
            writer(can.Message(timestamp=0.01 * k + 0.001, arbitration_id=0x123, data=b"\x01\x02"))
    return path


def test_png_of_lockstep_signals_equals_cantools(capsys, lockstep_trace, tmp_path):
    out = tmp_path / "signals.png"
    code, stdout, err = railhil(capsys, "trace", "plot", lockstep_trace, "--dbc", TRAIN_DBC, "TargetDecel",
                                "PLANT_CAR1_SENSORS.AxleSpeed", "PLANT_CAR2_SENSORS.AxleSpeed",
                                "BCU_DEMAND.Mode", "-o", out)
    assert code == 0, err
    assert stdout.startswith(f"wrote {out}: 4 signals, 800 samples")
    image = matplotlib.image.imread(out)
    # one subplot per unit: m/s^2, rad/s (both AxleSpeeds), and the unitless Mode -> 3 rows
    assert image.shape[0] == round(100 * (1.0 + 2.6 * 3)) and image.shape[1] == 1100
    db = cantools.database.load_file(str(TRAIN_DBC))
    names = ["TargetDecel", "PLANT_CAR2_SENSORS.AxleSpeed"]
    refs = plot.resolve(Codec(load_dbc(TRAIN_DBC)), names, TRAIN_DBC)
    got = plot.collect(open_trace(lockstep_trace), refs)
    for series, (message, signal) in zip(got.series, [("BCU_DEMAND", "TargetDecel"),
                                                      ("PLANT_CAR2_SENSORS", "AxleSpeed")], strict=True):
        assert (series.t, series.v) == cantools_series(lockstep_trace, db, message, signal)
        assert len(series.t) == 200
    assert max(got.series[0].v) == pytest.approx(1.0)   # the full service step asks for 1.0 m/s^2


def test_only_the_needed_ids_are_decoded(lockstep_trace):
    codec = Codec(load_dbc(TRAIN_DBC))
    frames = list(can.LogReader(str(lockstep_trace)))
    demand = codec.by_name("BCU_DEMAND").frame_id
    got = plot.collect(frames, plot.resolve(codec, ["BCU_DEMAND.TargetDecel", "BCU_DEMAND.Mode"], TRAIN_DBC))
    assert got.frames == len(frames) > 2000
    assert got.decoded == sum(m.arbitration_id == demand for m in frames) == 200
    assert got.failed == 0


def test_html_is_one_self_contained_plotly_page(capsys, lockstep_trace, tmp_path):
    out = tmp_path / "signals.html"
    code, stdout, err = railhil(capsys, "trace", "plot", lockstep_trace, "--dbc", TRAIN_DBC,
                                "BECU1_PRESS_CMD.CylPressureSet", "PLANT_CAR1_SENSORS.CylPressure", "-o", out)
    assert code == 0, err
    html = out.read_text()
    assert not re.search(r"<script[^>]*\bsrc=", html)        # nothing fetched: plotly.js is inline
    assert len(html) > 1_000_000 and "Plotly.newPlot" in html
    assert "BECU1_PRESS_CMD.CylPressureSet" in html and "PLANT_CAR1_SENSORS.CylPressure" in html
    assert "[Pa]" in html                                    # one unit, one subplot, unit on the axis
    codec = Codec(load_dbc(TRAIN_DBC))
    got = plot.collect(open_trace(lockstep_trace),
                       plot.resolve(codec, ["BECU1_PRESS_CMD.CylPressureSet"], TRAIN_DBC))
    fig = plot.plotly_figure(plot.groups(got.series, "unit"), 0.0, "time [s]", "t")
    assert list(fig.data[0].y) == got.series[0].v and list(fig.data[0].x) == got.series[0].t


def test_start_end_window(capsys, lockstep_trace, tmp_path):
    codec = Codec(load_dbc(TRAIN_DBC))
    refs = plot.resolve(codec, ["TargetDecel"], TRAIN_DBC)
    got = plot.collect(open_trace(lockstep_trace), refs, 0.5, 1.0)
    assert got.series[0].t and all(0.5 <= t <= 1.0 for t in got.series[0].t)
    assert len(got.series[0].t) == sum(1 for m in can.LogReader(str(lockstep_trace))
                                       if m.arbitration_id == 0x28 and 0.5 <= m.timestamp <= 1.0)
    code, stdout, err = railhil(capsys, "trace", "plot", lockstep_trace, "--dbc", TRAIN_DBC, "TargetDecel",
                                "--start", "0.5", "--end", "1.0", "-o", tmp_path / "w.png")
    assert code == 0, err
    assert f"1 signals, {len(got.series[0].t)} samples" in stdout


def test_multiplexed_signals_have_samples_only_where_their_multiplexer_selects_them(capsys, mux_trace,
                                                                                     tmp_path):
    db = cantools.database.load_file(str(MULTIPLEX_DBC))
    codec = Codec(load_dbc(MULTIPLEX_DBC))
    got = plot.collect(open_trace(mux_trace), plot.resolve(codec, ["BIT_K", "BIT_L", "Multiplexor"],
                                                           MULTIPLEX_DBC))
    k, lsig, mux = got.series
    assert (k.t, k.v) == cantools_series(mux_trace, db, "Message1", "BIT_K")
    assert (lsig.t, lsig.v) == cantools_series(mux_trace, db, "Message1", "BIT_L")
    assert len(k.t) == 10 and len(lsig.t) == 30 and sorted(set(mux.v)) == [8.0, 16.0, 24.0]
    assert got.decoded == 30 and got.frames == 60
    for suffix in ("png", "html"):
        code, stdout, err = railhil(capsys, "trace", "plot", mux_trace, "--dbc", MULTIPLEX_DBC, "BIT_K",
                                    "BIT_L", "--subplots", "signal", "-o", tmp_path / f"mux.{suffix}")
        assert code == 0, err
        assert "2 signals, 40 samples" in stdout


@NO_CORPUS
def test_real_trace_with_its_dbc(capsys, tmp_path):
    db = cantools.database.load_file(str(SOCIALLEDGE_DBC))
    for suffix in ("png", "html"):
        out = tmp_path / f"issue_1256.{suffix}"
        code, stdout, err = railhil(capsys, "trace", "plot", ISSUE_1256, "--dbc", SOCIALLEDGE_DBC,
                                    "DRIVER_HEARTBEAT_cmd", "MOTOR_CMD_steer", "MOTOR_CMD_drive", "-o", out)
        assert code == 0, err
        assert out.stat().st_size > 10_000
    got = plot.collect(open_trace(ISSUE_1256), plot.resolve(Codec(load_dbc(SOCIALLEDGE_DBC)),
                                                            ["MOTOR_CMD_steer"], SOCIALLEDGE_DBC))
    expected = cantools_series(ISSUE_1256, db, "MOTOR_CMD", "MOTOR_CMD_steer")
    assert (got.series[0].t, got.series[0].v) == expected
    assert len(got.series[0].t) == 79


def test_the_time_axis_is_the_trace_time_base(tmp_path):
    from hil.cli.trace.timebase import RunOfTrace, TimeBase

    base = TimeBase()                                                   # a trace of no run: its first frame
    base.bind(1_795_321_814.75)
    assert base.axis_label() == "time [s] from the first frame (t0 = 1795321814.750000 s)"
    run = RunOfTrace(tmp_path, {"trace_t0_s": 1_795_321_814.5, "mode": "realtime"})
    assert TimeBase(run=run).axis_label() == "time [s] from the run's start (t0 = 1795321814.500000 s)"
    lockstep = RunOfTrace(tmp_path, {"trace_t0_s": 0.0})
    assert TimeBase(run=lockstep).axis_label() == "time [s] from the run's start"
    assert TimeBase(absolute=True).axis_label() == "time [s] (as recorded)"


# --- bad input ------------------------------------------------------------------------------------


def test_ambiguous_bare_name_lists_the_messages(capsys, lockstep_trace, tmp_path):
    code, _, err = railhil(capsys, "trace", "plot", lockstep_trace, "--dbc", TRAIN_DBC, "AxleSpeed",
                           "-o", tmp_path / "x.png")
    assert_one_line_error(code, err, "'AxleSpeed' is ambiguous", "PLANT_CAR1_SENSORS", "PLANT_CAR8_SENSORS",
                          "PLANT_CAR1_SENSORS.AxleSpeed")
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("signal, needles", [
    ("TargetDecl", ("no signal named 'TargetDecl'", "TargetDecel")),
    ("BCU_DEMANDS.TargetDecel", ("no message named 'BCU_DEMANDS'", "BCU_DEMAND")),
    ("BCU_DEMAND.TargetDecl", ("BCU_DEMAND has no signal 'TargetDecl'", "TargetDecel")),
])
def test_unknown_names_suggest_the_closest(capsys, lockstep_trace, tmp_path, signal, needles):
    code, _, err = railhil(capsys, "trace", "plot", lockstep_trace, "--dbc", TRAIN_DBC, signal,
                           "-o", tmp_path / "x.png")
    assert_one_line_error(code, err, str(TRAIN_DBC), *needles)


@pytest.mark.parametrize("name, needle", [("x.svg", "expected a file name ending in .png"),
                                          ("missing/x.png", "no such directory")])
def test_bad_output_file(capsys, lockstep_trace, tmp_path, name, needle):
    code, _, err = railhil(capsys, "trace", "plot", lockstep_trace, "--dbc", TRAIN_DBC, "TargetDecel",
                           "-o", tmp_path / name)
    assert_one_line_error(code, err, "-o", needle)


def test_signal_absent_from_the_trace_is_an_error(capsys, lockstep_trace, tmp_path):
    # the default scenario has no ACD: ACD_BRAKE_REQ is in the DBC but never on the bus
    code, _, err = railhil(capsys, "trace", "plot", lockstep_trace, "--dbc", TRAIN_DBC, "RequestedDecel",
                           "-o", tmp_path / "x.png")
    assert_one_line_error(code, err, str(lockstep_trace), "no frame carries ACD_BRAKE_REQ.RequestedDecel")
    code, _, err = railhil(capsys, "trace", "plot", lockstep_trace, "--dbc", TRAIN_DBC, "RequestedDecel",
                           "TargetDecel", "-o", tmp_path / "x.png")
    assert code == 0 and "notice:" in err and "ACD_BRAKE_REQ.RequestedDecel" in err
