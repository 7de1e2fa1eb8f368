"""A run folder in Python: `railhil.open_run` / `hil.open_run` and `open_trace` give the truth, the KPIs,
the scenario, the decoded signals (equal to cantools') and the frames."""

from __future__ import annotations

import json
from pathlib import Path

import can
import cantools
import numpy as np
import pytest

import hil
import railhil
from hil.report.runfolder import RunFolderError

ROOT = Path(__file__).resolve().parents[2]
DBC = ROOT / "dbc" / "train_brake.dbc"


@pytest.fixture(scope="module")
def run(default_lockstep):
    return railhil.open_run(default_lockstep.out_dir)


def test_railhil_and_hil_give_the_same_api():
    assert railhil.open_run is hil.open_run and railhil.open_trace is hil.open_trace
    with pytest.raises(AttributeError):
        railhil.nonesuch    # noqa: B018


def test_truth_kpis_and_scenario(run, default_lockstep):
    truth = run.truth
    assert truth.index.name == "t_s" and truth.index[0] == 0.0
    assert {"v_mps_1", "p_Pa_6", "slip_speed_mps_4", "coupler_dl_m_5"} <= set(truth.columns)
    assert truth["v_mps_1"].iloc[0] == pytest.approx(25.0)
    assert run.kpis == json.loads((default_lockstep.out_dir / "kpis.json").read_text())
    assert run.scenario.name == "default" and run.scenario.train.cars == 6
    assert "default" in repr(run) and "lockstep" in repr(run)


def test_signals_are_cantools_decoding_on_the_run_time_axis(run, default_lockstep):
    db = cantools.database.load_file(str(DBC))
    msg = db.get_message_by_name("BCU_DEMAND")
    t, v = [], []
    with can.LogReader(str(default_lockstep.out_dir / "trace.blf")) as reader:
        for m in reader:
            if m.arbitration_id == msg.frame_id:
                t.append(m.timestamp)
                v.append(msg.decode(bytes(m.data))["TargetDecel"])
    s = run.signal("BCU_DEMAND.TargetDecel")
    assert s.name == "BCU_DEMAND.TargetDecel" and s.attrs["unit"] == "m/s^2"
    assert np.array_equal(s.index.to_numpy(), np.asarray(t)) and np.allclose(s.to_numpy(), v, atol=1e-12)
    assert run.signal("TargetDecel").equals(s)                      # a bare name one message has
    both = run.signals("TargetDecel", "PLANT_CAR1_SENSORS.CylPressure")
    assert list(both.columns) == ["BCU_DEMAND.TargetDecel", "PLANT_CAR1_SENSORS.CylPressure"]
    assert both.index.is_monotonic_increasing
    assert both.attrs["units"]["PLANT_CAR1_SENSORS.CylPressure"] == "Pa"
    status = run.message("BCU_STATUS")
    assert "Mode" in status.columns and status.attrs["choices"]["Mode"][1.0] == "SERVICE"


def test_frames_are_every_frame_of_the_trace(run, default_lockstep):
    frames = run.frames
    assert len(frames) == default_lockstep.kpis["frames_recorded"]
    assert set(frames.columns) >= {"t", "id", "extended", "dlc", "data", "message"}
    first = frames.iloc[0]
    assert first["message"] == "PLANT_CAR1_SENSORS" and len(first["data"]) == 8


def test_open_trace_reads_any_trace_with_a_dbc(default_lockstep):
    trace = railhil.open_trace(default_lockstep.out_dir / "trace.blf", dbc=DBC)
    assert len(trace.frames) == default_lockstep.kpis["frames_recorded"]
    assert trace.signal("PLANT_CAR2_SENSORS.AxleSpeed").attrs["unit"] == "rad/s"


def test_bad_names_and_folders_are_one_line_errors(run, tmp_path):
    with pytest.raises(RunFolderError, match="no signal of that name") as err:
        run.signal("AxelSpeed")
    assert "closest" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(RunFolderError, match="8 messages have it"):
        run.signal("AxleSpeed")                                     # every car's sensor frame has one
    with pytest.raises(RunFolderError, match="has no signal 'Nope'"):
        run.signal("BCU_DEMAND.Nope")
    with pytest.raises(RunFolderError, match="not a run folder"):
        railhil.open_run(tmp_path)


def test_truth_csv_reads_back_what_was_written_and_names_a_malformed_file(tmp_path):
    from hil.errors import RailhilError
    from hil.runtime.truth import read_truth_csv, write_truth_csv

    cols = {"t_s": np.array([0.0, 0.01, 0.02]), "v_mps_1": np.array([25.0, np.nan, -1.25e-7])}
    write_truth_csv(cols, tmp_path / "truth.csv")
    back = read_truth_csv(tmp_path / "truth.csv")
    assert list(back) == ["t_s", "v_mps_1"]
    assert all(np.array_equal(back[k], cols[k], equal_nan=True) for k in cols)
    write_truth_csv({"t_s": np.array([0.5]), "v_mps_1": np.array([3.0])}, tmp_path / "one.csv")
    assert read_truth_csv(tmp_path / "one.csv")["v_mps_1"].tolist() == [3.0]       # one sample: 1-d
    (tmp_path / "none.csv").write_text("t_s,v_mps_1\r\n")
    assert read_truth_csv(tmp_path / "none.csv")["t_s"].size == 0
    for name, text in (("word.csv", "t_s,v\r\n0,fast\r\n"), ("wide.csv", "t_s,v\r\n0,1,2\r\n")):
        (tmp_path / name).write_text(text)
        with pytest.raises(RailhilError, match=name):
            read_truth_csv(tmp_path / name)
