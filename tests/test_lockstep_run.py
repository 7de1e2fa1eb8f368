"""Lockstep runs of the default scenario: the run folder, determinism, decodability, plausibility."""

import json

import can
import cantools
import pytest
from conftest import DEFAULT

from hil.can.dbc import DEFAULT_DBC
from hil.runtime.run import run_scenario_lockstep
from hil.scenario import load_scenario


def test_run_folder_has_everything_and_the_trace_decodes(default_lockstep):
    out = default_lockstep.out_dir
    for name in ("trace.blf", "truth.csv", "kpis.json", "plot.png", "run.json"):
        assert (out / name).stat().st_size > 0, name
    db = cantools.database.load_file(str(DEFAULT_DBC))
    senders = set()
    n = 0
    with can.LogReader(str(out / "trace.blf")) as reader:
        for msg in reader:
            m = db.get_message_by_frame_id(msg.arbitration_id)
            db.decode_message(msg.arbitration_id, bytes(msg.data))     # raises if it does not decode
            senders.update(m.senders)
            n += 1
    k = default_lockstep.kpis
    assert n == k["frames_recorded"] == k["frames_sent"] - k["frames_in_flight"]
    assert k["frames_in_flight"] < 9          # at most one frame per node queued when the run stops
    assert k["frames_lost"] == 0 and k["frames_overwritten"] == 0
    assert senders == {"PLANT", "DESK", "BCU"} | {f"BECU{i}" for i in range(1, 7)}
    kpis = json.loads((out / "kpis.json").read_text())
    assert kpis == default_lockstep.kpis


def test_default_scenario_stops_plausibly(default_lockstep):
    k = default_lockstep.kpis
    assert k["stopped"] and default_lockstep.outcome.reason == "standstill"
    # v0 = 25 m/s at 1.0 m/s^2 full service: 312.5 m ideal; the demand ramp, the cylinder fill and
    # the wet section can only lengthen it, and not by more than a quarter.
    assert 312.5 < k["stopping_distance_m"] < 1.25 * 312.5
    assert 25.0 < k["time_to_stop_s"] < 40.0
    assert sum(k["wsp_activations"]) > 0                      # the wet section makes wheels slide
    assert all(s < 5.0 for s in k["max_slip_speed_mps"])      # ... and WSP keeps them from locking
    assert k["mean_abs_decel_error_mps2"] < 0.3


def test_same_seed_identical_trace_other_seed_different(default_lockstep, tmp_path):
    reference = (default_lockstep.out_dir / "trace.blf").read_bytes()
    scenario = load_scenario(DEFAULT)
    again = run_scenario_lockstep(scenario, tmp_path / "again")
    assert (again.out_dir / "trace.blf").read_bytes() == reference
    other = run_scenario_lockstep(scenario.model_copy(update={"seed": scenario.seed + 1}), tmp_path / "other")
    assert (other.out_dir / "trace.blf").read_bytes() != reference


@pytest.mark.parametrize("cars", [1, 8])
def test_one_and_eight_cars_run(tmp_path, cars):
    scenario = load_scenario(DEFAULT).model_copy(update={"max_duration_s": 3.0})
    scenario = scenario.model_copy(update={"train": scenario.train.model_copy(update={"cars": cars})})
    report = run_scenario_lockstep(scenario, tmp_path / "run")
    assert report.outcome.reason == "max_duration"
    assert len(report.kpis["wsp_activations"]) == cars
    assert set(report.kpis["frames_sent_by_node"]) == {"PLANT", "DESK", "BCU"} | {
        f"BECU{i}" for i in range(1, cars + 1)}
