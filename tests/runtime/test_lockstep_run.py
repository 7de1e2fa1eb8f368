"""Lockstep runs of the default scenario: the run folder, determinism, decodability, plausibility."""

import json

import can
import cantools
import pytest
from conftest import DEFAULT

from hil.can.dbc import DEFAULT_DBC
from hil.report.run import run_scenario_lockstep
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


# --- a run folder without figures, the trace read once, the DBC loaded once per process (issue #18) ---


def short_stop(seconds=1.5, name="stop_30kmh", **update):
    """A shipped scenario cut to `seconds`, with `update` on top (stop_30kmh: 2 cars)."""
    from hil.scenario import parse_scenario

    base = load_scenario(DEFAULT.parent / f"{name}.toml").model_dump()
    if name == "stop_30kmh":
        base["train"]["cars"] = 2
    return parse_scenario({**base, "max_duration_s": seconds, **update})


def test_a_run_reads_its_trace_once_and_kpis_match_pythons_can_reader(tmp_path, monkeypatch):
    """finish_run reads the trace once, as columns, for the demand, the frame count, the plausibility
    flags and the studies' signals (the wheel-slip governor's here); the figures agree with reading the
    file frame by frame with python-can's reader, as finish_run did before."""
    import hil.report.kpis as kpis_module
    from hil.can.codec import Codec
    from hil.can.dbc import load_dbc
    from hil.report.kpis import read_signal, read_signals
    from hil.report.run import plausibility_events

    reads, opened = [], []
    block_reader, log_reader = kpis_module.BlockReader, can.LogReader

    def counted(path, *a, **kw):
        reads.append(path)
        return block_reader(path, *a, **kw)

    def counted_log_reader(path, *a, **kw):         # every way python-can opens a trace to read it
        opened.append(path)
        return log_reader(path, *a, **kw)

    monkeypatch.setattr(kpis_module, "BlockReader", counted)
    monkeypatch.setattr(can, "LogReader", counted_log_reader)
    sensor = {"kind": "sensor", "car": 1, "sensor": "wheel_speed", "mode": "stuck", "value": 0.0,
              "from_s": 0.5, "to_s": 60.0}
    report = run_scenario_lockstep(short_stop(3.0, "rg_low_adhesion", faults=[sensor]), tmp_path / "run")
    assert reads == [tmp_path / "run" / "trace.blf"]
    assert len(opened) == 1                          # BlockReader's open_trace, and nothing else
    assert "wheel_slip" in report.kpis and report.kpis["plausibility_flags"]["SpeedSensorFault"]
    monkeypatch.undo()
    db = load_dbc(DEFAULT_DBC)
    codec = Codec(db)
    trace = tmp_path / "run" / "trace.blf"
    t, v, total = read_signal(trace, db, codec, "BCU_DEMAND", "TargetDecel")
    assert total == report.kpis["frames_recorded"]
    assert report.kpis["plausibility_flags"] == plausibility_events(trace, db, codec, 1)
    again = kpis_module.read_run_trace(trace, db, codec)
    got = read_signal(again, db, codec, "BCU_DEMAND", "TargetDecel")
    assert got[2] == total and got[0].tolist() == t.tolist() and got[1].tolist() == v.tolist()
    wanted = {"r": ("BECU1_DIAG", "GovernedDecel"), "none": ("NO_SUCH_MESSAGE", "X")}
    by_file, by_columns = read_signals(trace, db, codec, wanted), read_signals(again, db, codec, wanted)
    for name in wanted:
        assert [a.tolist() for a in by_file[name]] == [b.tolist() for b in by_columns[name]]


def test_without_plots_a_run_folder_keeps_trace_truth_and_kpis_and_figures_come_later(tmp_path):
    from hil.report.run import has_figures, write_figures

    scenario = short_stop()
    bare = run_scenario_lockstep(scenario, tmp_path / "bare", plots=False)
    full = run_scenario_lockstep(scenario, tmp_path / "full")
    assert sorted(p.name for p in (tmp_path / "bare").iterdir()) == ["kpis.json", "run.json", "trace.blf",
                                                                     "truth.csv"]
    assert [f.name for f in bare.files] == ["trace.blf", "truth.csv", "kpis.json", "run.json"]
    assert [f.name for f in full.files] == ["trace.blf", "truth.csv", "kpis.json", "plot.png", "run.json",
                                            "report.html"]
    assert (tmp_path / "bare" / "kpis.json").read_text() == (tmp_path / "full" / "kpis.json").read_text()
    assert not has_figures(tmp_path / "bare") and has_figures(tmp_path / "full")
    files = write_figures(tmp_path / "bare")
    assert [f.name for f in files] == ["plot.png", "report.html"] and has_figures(tmp_path / "bare")
    assert all(f.stat().st_size > 0 for f in files)


def test_the_dbc_is_loaded_once_per_process_while_the_file_is_unchanged(tmp_path):
    import os

    from hil.errors import DbcError
    from hil.runtime.run import loaded_dbc

    dbc = tmp_path / "copy.dbc"
    dbc.write_bytes(DEFAULT_DBC.read_bytes())
    first = loaded_dbc(dbc)
    assert loaded_dbc(dbc) is first                      # the same Database and Codec
    st = dbc.stat()
    os.utime(dbc, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))     # touched: loaded again
    assert loaded_dbc(dbc) is not first
    with pytest.raises(DbcError, match="no such DBC file"):
        loaded_dbc(tmp_path / "missing.dbc")


def test_a_finished_lockstep_run_holds_no_reference_cycle():
    """The event loop's parts refer to each other only downwards (events get the loop as an argument), so a
    run is freed when run_lockstep returns, not at a later full collection (which a campaign worker or the
    threat matrix, running run after run, would wait for: 25 MB a precise_stop cell once)."""
    import gc

    from hil.can.codec import loaded_dbc
    from hil.runtime.lockstep import LockstepLoop, run_lockstep

    scenario = load_scenario(DEFAULT).model_copy(update={"max_duration_s": 0.2})
    db, codec = loaded_dbc(scenario.dbc)
    gc.collect()
    gc.disable()
    try:
        run_lockstep(scenario, db, codec, writer=None)
        assert not [o for o in gc.get_objects() if isinstance(o, LockstepLoop)]
    finally:
        gc.enable()


def test_the_truth_log_crosses_a_process_boundary_as_its_columns(default_lockstep):
    """A real-time plant host sends its TruthLog to the runner pickled: the copy has the same columns and
    no plant (TruthLog.__reduce__; a compiled class pickles only through it)."""
    import pickle

    import numpy as np

    truth = default_lockstep.outcome.truth
    copy = pickle.loads(pickle.dumps(truth))
    assert copy.plant is None and copy.t_us == truth.t_us
    want, got = truth.columns(), copy.columns()
    assert list(got) == list(want) and all(np.array_equal(got[k], want[k]) for k in want)
