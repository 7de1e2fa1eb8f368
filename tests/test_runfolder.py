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

ROOT = Path(__file__).resolve().parents[1]
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
