"""One run of a scenario, in lockstep or real time, and the run folder it leaves."""

from __future__ import annotations

import json
import platform
import sys
from dataclasses import dataclass
from pathlib import Path

import can

from hil.can.codec import Codec
from hil.can.dbc import DEFAULT_DBC, load_dbc
from hil.report.html import run_metadata, write_run_report
from hil.report.kpis import (
    RunView,
    check_out_dir,
    compute_kpis,
    read_signal,
    study_kpis,
    write_kpis,
    write_truth_csv,
)
from hil.report.plots import plot_run, study_plots
from hil.report.summary import summary_lines
from hil.runtime.desk import DeskScript
from hil.runtime.lockstep import prepare_lockstep, run_lockstep
from hil.runtime.outcome import RunOutcome, realtime_verdict
from hil.scenario import Scenario
from hil.trace.writers import open_writer

TRACE_NAME = "trace.blf"       # the default trace's name; [trace] format chooses another (trace_name)


def trace_name(scenario: Scenario) -> str:
    """The trace file of a run folder: trace.<format> ([trace] format; python-can picks its writer by
    the suffix)."""
    return f"trace.{scenario.trace.format}"


@dataclass
class RunReport:
    out_dir: Path
    outcome: RunOutcome
    kpis: dict
    files: list[Path]

    def summary(self) -> list[str]:
        o = self.outcome
        head = (f"{o.mode} run: {o.end_us / 1e6:.2f} s simulated in {o.wall_s:.2f} s wall "
                f"({o.end_us / 1e6 / max(o.wall_s, 1e-9):.1f}x real time), ended by {o.reason}")
        return [head] + summary_lines(self.kpis, self.files)


def plausibility_events(trace: Path, db, codec: Codec, n_cars: int, t0_s: float = 0.0,
                        speed: float = 1.0) -> dict[str, dict[str, float]]:
    """When the ECUs first flagged a sensor or a car (issue #9), from the trace: simulated time [s]
    of the first BECUn_DIAG frame with SpeedSensorFault / AccelSensorFault = 1 and of the first
    BCU_STATUS frame with a car's CarsImplausible bit, by flag and car ("car2")."""
    watch: dict[int, tuple[object, str]] = {}
    for i in range(1, n_cars + 1):
        watch[db.get_message_by_name(f"BECU{i}_DIAG").frame_id] = (codec.by_name(f"BECU{i}_DIAG"), f"car{i}")
    status = db.get_message_by_name("BCU_STATUS").frame_id
    watch[status] = (codec.by_name("BCU_STATUS"), "")
    first: dict[str, dict[str, float]] = {}

    def flag(kind: str, car: str, t: float) -> None:
        first.setdefault(kind, {}).setdefault(car, round(t, 4))

    with can.LogReader(str(trace)) as reader:
        for msg in reader:
            hit = watch.get(msg.arbitration_id)
            if hit is None or msg.is_error_frame or msg.is_remote_frame:
                continue
            fc, car = hit
            values = fc.decode(bytes(msg.data))
            t = (msg.timestamp - t0_s) * speed
            if msg.arbitration_id == status:
                bits = int(values.get("CarsImplausible", 0))
                for k in range(n_cars):
                    if bits >> k & 1:
                        flag("CarsImplausible", f"car{k + 1}", t)
                continue
            for sig in ("SpeedSensorFault", "AccelSensorFault"):
                if values.get(sig, 0) >= 0.5:
                    flag(sig, car, t)
    return first


def dbc_path_of(scenario: Scenario) -> Path:
    return Path(scenario.dbc) if scenario.dbc else DEFAULT_DBC


def finish_run(scenario: Scenario, outcome: RunOutcome, out_dir: Path, db, codec: Codec,
               trace_t0_s: float = 0.0, trace_speed: float = 1.0, extra: dict | None = None,
               interactive_report: bool = True) -> RunReport:
    trace = out_dir / trace_name(scenario)
    cols = outcome.truth.columns()
    truth_csv = out_dir / "truth.csv"
    write_truth_csv(cols, truth_csv)
    *target, recorded = read_signal(trace, db, codec, "BCU_DEMAND", "TargetDecel", t0_s=trace_t0_s,
                                    speed=trace_speed)
    brake_us = DeskScript(scenario.desk).first_brake_us()
    brake_s = None if brake_us is None else brake_us / 1e6
    kpis = compute_kpis(scenario, cols, target, brake_s, outcome.frames_by_node, recorded,
                        outcome.frames_in_flight, outcome.frames_overwritten, outcome.frames_faulted)
    view = RunView.of(scenario, cols, tuple(target), brake_s, out_dir=out_dir, trace=trace, db=db,
                      codec=codec, trace_t0_s=trace_t0_s, trace_speed=trace_speed, mode=outcome.mode)
    kpis.update(study_kpis(view))                    # each study's own, under its name
    if outcome.bus is not None:
        worst = max(outcome.bus["messages"].items(), key=lambda kv: kv[1]["response_max_us"],
                    default=(None, {"response_max_us": 0.0}))
        kpis["bus"] = {
            "bitrate_bps": outcome.bus["bitrate_bps"],
            "load": round(outcome.bus["load"], 5) if outcome.bus["load"] is not None else None,
            "worst_response_us": worst[1]["response_max_us"],
            "worst_response_message": worst[0],
            "deadline_misses": sum(m["deadline_misses"] for m in outcome.bus["messages"].values()),
        }
    detected: dict[str, int] = {}              # what the receivers' E2E / SecOC checks reported
    for stats in outcome.node_stats.values():
        for _, _, status in stats.get("e2e_events") or ():
            if status != "INITIAL":
                detected[status] = detected.get(status, 0) + 1
    kpis["protection_events"] = dict(sorted(detected.items()))
    if outcome.faults is not None:
        kpis["faults_injected"] = dict(sorted(outcome.faults["counts"].items()))
    flagged = plausibility_events(trace, db, codec, scenario.train.cars, trace_t0_s, trace_speed)
    if flagged or outcome.faults is not None:
        kpis["plausibility_flags"] = flagged       # first time [s] each sensor / car was flagged
    if outcome.mode == "realtime":
        kpis["realtime"] = realtime_verdict(outcome.node_stats)
    kpis["mode"] = outcome.mode
    kpis["seed"] = scenario.seed
    kpis["simulated_s"] = outcome.end_us / 1e6
    kpis["end_reason"] = outcome.reason
    kpis_json = out_dir / "kpis.json"
    write_kpis(kpis, kpis_json)
    plot = plot_run(scenario, cols, out_dir / "plot.png",
                    f"{scenario.name} ({outcome.mode}, seed {scenario.seed})")
    figures = study_plots(view)
    meta = {
        "scenario": scenario.model_dump(mode="json"),
        "mode": outcome.mode,
        "dbc": str(dbc_path_of(scenario)),
        "python": sys.version.split()[0],
        "python_can": can.__version__,
        "platform": platform.platform(),
        "trace": trace.name,
        "trace_t0_s": trace_t0_s,
        "node_stats": outcome.node_stats,
        "bus_timing": outcome.bus,
        "faults": outcome.faults,
        "wall_s": round(outcome.wall_s, 3),
        **run_metadata(dbc_path_of(scenario), scenario.seed),   # versions, DBC SHA-256, git commit
        **(extra or {}),
    }
    run_json = out_dir / "run.json"
    run_json.write_text(json.dumps(meta, indent=2, default=str) + "\n")
    report = write_run_report(out_dir, interactive_report)       # report.html: one self-contained page
    return RunReport(out_dir, outcome, kpis, [trace, truth_csv, kpis_json, plot, *figures, run_json, report])


def run_scenario_lockstep(scenario: Scenario, out_dir: Path, progress=None,
                          interactive_report: bool = True) -> RunReport:
    dbc_path = dbc_path_of(scenario)
    db = load_dbc(dbc_path)
    codec = Codec(db)
    setup = prepare_lockstep(scenario, db, codec, str(dbc_path))   # bad input: no run folder is left
    out_dir = check_out_dir(out_dir)
    with open_writer(out_dir / trace_name(scenario), start_time_s=0.0) as writer:   # simulated s from 0
        outcome = run_lockstep(scenario, db, codec, writer, progress=progress, dbc_name=str(dbc_path),
                               setup=setup)
    return finish_run(scenario, outcome, out_dir, db, codec, interactive_report=interactive_report)
