"""A run reported: the KPIs, figures and report.html of a run folder the runtime left, and the entry points
that run a scenario and then report it.

The runtime runs a scenario into its folder — the trace, truth.csv and run.json (hil.runtime.run,
hil.runtime.realtime) — and hands back what it ran (`RunRecord`: the outcome, the truth at full precision,
the DBC, the run's clock).  `finish_run` reads the trace back once (hil.report.kpis.read_run_trace) for
everything the KPIs take from it and writes kpis.json, and, unless the caller turns them off
(`plots=False`: a campaign's points, `railhil campaign` without --plots), the figures (plot.png, each
study's <study>.png) and report.html; `write_figures` draws those later from the folder's own files.

`run_scenario_lockstep` and `run_scenario_realtime` do both: the runtime's run, then its report.  In
lockstep the scenario's [[faults]] are injected by an injector built here (hil.safety.injection) and
handed to the runtime, which names no fault.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hil.can.codec import Codec, loaded_dbc
from hil.errors import NodeDied
from hil.report.bus import trace_bus_kpis, worst_case_load
from hil.report.conduct import frames_sent_by, node_conduct, silence_reported
from hil.report.devices import device_kpis
from hil.report.html import REPORT_NAME, write_run_report
from hil.report.kpis import RunView, compute_kpis, read_run_trace, read_signal, study_kpis, write_kpis
from hil.report.plots import LATENESS_NAME, plot_lateness, plot_run, study_plots
from hil.report.summary import summary_lines
from hil.runtime.clock import LOCKSTEP_CLOCK, RunClock
from hil.runtime.desk import DeskScript
from hil.runtime.outcome import RunOutcome, realtime_verdict
from hil.runtime.realtime import run_realtime_folder
from hil.runtime.run import RunRecord, dbc_path_of, device_trace_of, run_lockstep_folder
from hil.safety.injection import build_injector
from hil.scenario import Scenario
from hil.trace.decoded import DecodedTrace

PLOT_NAME = "plot.png"         # the run's figure of the truth (hil.report.plots.plot_run)


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


def plausibility_events(trace: DecodedTrace | Path, db, codec: Codec, n_cars: int,
                        clock: RunClock = LOCKSTEP_CLOCK) -> dict[str, dict[str, float]]:
    """When the ECUs first flagged a sensor or a car (issue #9), from the trace (read once:
    hil.report.kpis.read_run_trace; a path is read here): simulated time [s] of the first BECUn_DIAG
    frame with SpeedSensorFault / AccelSensorFault / CylSensorFault = 1 and of the first BCU_STATUS frame
    with a car's CarsImplausible bit, by flag and car ("car2"), in the order the trace has them."""
    decoded = trace if isinstance(trace, DecodedTrace) else read_run_trace(trace, db, codec)
    hits: list[tuple[int, int, str, str, float]] = []    # (frame row, order in the frame, flag, car, t)

    def first(message: str, on: np.ndarray, order: int, kind: str, car: str) -> None:
        k = np.flatnonzero(on)
        if k.size:
            table = decoded.table(message)
            hits.append((int(_rows(decoded, message)[k[0]]), order, kind, car,
                         float(clock.simulated_s(table.t[k[0]]))))

    for i in range(1, n_cars + 1):
        name = f"BECU{i}_DIAG"
        columns = decoded.table(name).columns
        for order, sig in enumerate(("SpeedSensorFault", "AccelSensorFault", "CylSensorFault")):
            if sig in columns:
                first(name, columns[sig] >= 0.5, order, sig, f"car{i}")
    status = decoded.table("BCU_STATUS").columns
    if "CarsImplausible" in status:
        bits = status["CarsImplausible"].astype(np.int64)
        for k in range(n_cars):
            first("BCU_STATUS", bits >> k & 1 == 1, k, "CarsImplausible", f"car{k + 1}")
    flagged: dict[str, dict[str, float]] = {}
    for _, _, kind, car, t in sorted(hits):
        flagged.setdefault(kind, {}).setdefault(car, round(t, 4))
    return flagged


def _rows(decoded: DecodedTrace, message: str) -> np.ndarray:
    """The trace rows of a decoded message's frames, in the order of its table (its frames of the right
    kind and length), so that flags of different messages keep the trace's order."""
    msg = decoded.db.get_message_by_name(message)
    f = decoded.frames
    rows = np.flatnonzero((f.arbitration_id == msg.frame_id) & ~f.remote & ~f.error
                          & (f.extended == bool(msg.is_extended_frame)) & (f.length >= msg.length))
    if len(rows) != len(decoded.table(message).t):      # the codec's frame-by-frame path: order by time
        return np.searchsorted(f.t, decoded.table(message).t)
    return rows


def finish_run(run: RunRecord, interactive_report: bool = True, plots: bool = True) -> RunReport:
    """The report of a run the runtime finished into its folder (hil.runtime.run.RunRecord: the trace,
    truth.csv and run.json are there): kpis.json (the trace read back once, the truth at full precision
    from the run), and with `plots` plot.png, the studies' figures and report.html.  A real-time run's nodes
    are judged on the messages each sends (`run.sent_by`)."""
    scenario, outcome, out_dir, db, codec = run.scenario, run.outcome, run.out_dir, run.db, run.codec
    clock, sent_by, trace, cols = run.clock, run.sent_by, run.trace, run.cols
    decoded = read_run_trace(trace, db, codec)                  # the one read of the trace
    *target, recorded = read_signal(decoded, db, codec, "BCU_DEMAND", "TargetDecel", clock)
    brake_us = DeskScript(scenario.desk).first_brake_us()
    brake_s = None if brake_us is None else brake_us / 1e6
    external = list((outcome.realtime or {}).get("external") or [])
    for name in external:                      # a device under test sent what the trace holds of its frames
        outcome.frames_by_node[name] = frames_sent_by(decoded, db, name)
    for name, record in (outcome.devices or {}).items():
        if record.get("bus_mode") == "bench" and record.get("mode") == "device":    # real time, one bus:
            ddb, _ = loaded_dbc(record["dbc"])     # the device's frames and the gateway's to it are the run's
            outcome.frames_by_node[f"{name}.device"] = frames_sent_by(decoded, ddb, record["node"])
            outcome.frames_by_node[f"{name}.gateway"] = record["gateway"]["device_side"]["frames_sent"]
    kpis = compute_kpis(scenario, cols, target, brake_s, outcome.frames_by_node, recorded,
                        outcome.frames_in_flight, outcome.frames_overwritten, outcome.frames_faulted)
    view = RunView.of(scenario, cols, tuple(target), brake_s, out_dir=out_dir, trace=trace, db=db,
                      codec=codec, clock=clock, mode=outcome.mode, decoded=decoded)
    kpis.update(study_kpis(view))                    # each study's own, under its name
    run_end_s = clock.trace_s(outcome.end_us)        # the run's end in the trace's time
    if outcome.bus is not None:
        worst = max(outcome.bus["messages"].items(), key=lambda kv: kv[1]["response_max_us"],
                    default=(None, {"response_max_us": 0.0}))
        kpis["bus"] = {
            "bitrate_bps": outcome.bus["bitrate_bps"],
            "load": round(outcome.bus["load"], 5) if outcome.bus["load"] is not None else None,
            "worst_response_us": worst[1]["response_max_us"],
            "worst_response_message": worst[0],
            "deadline_misses": sum(m["deadline_misses"] for m in outcome.bus["messages"].values()),
            "load_worst_case": worst_case_load(decoded, clock.t0_s, run_end_s, outcome.bus["bitrate_bps"]),
            "source": "bus model",
        }
    elif outcome.mode == "realtime":           # no bus model: the figures the trace shows (hil.report.bus)
        bus = trace_bus_kpis(decoded, db, clock.t0_s, run_end_s, scenario.bus.bitrate)
        if bus is not None:
            kpis["bus"] = bus
    detected: dict[str, int] = {}              # what the receivers' E2E / SecOC checks reported
    for stats in outcome.node_stats.values():
        for _, _, status in stats.get("e2e_events") or ():
            if status != "INITIAL":
                detected[status] = detected.get(status, 0) + 1
    kpis["protection_events"] = dict(sorted(detected.items()))
    if outcome.faults is not None:
        kpis["faults_injected"] = dict(sorted(outcome.faults["counts"].items()))
    flagged = plausibility_events(decoded, db, codec, scenario.train.cars, clock)
    if flagged or outcome.faults is not None:
        kpis["plausibility_flags"] = flagged       # first time [s] each sensor / car was flagged
    if outcome.mode == "realtime":
        kpis["realtime"] = realtime_verdict(outcome)
        conduct = node_conduct(decoded, db, list(outcome.frames_by_node), outcome.node_stats, external,
                               clock, run_end_s, sent_by)
        for name in external:
            conduct[name]["reported_silent_s"] = silence_reported(decoded, db, name, conduct[name]["last_s"],
                                                                  clock)
        kpis["realtime"]["conduct"] = conduct
    if outcome.devices:                         # each device on its own terms (hil.report.devices)
        kpis["devices"] = {name: device_kpis(record, decoded, db, outcome.node_stats,
                                             out_dir / device_trace_of(scenario, name, record), clock,
                                             run_end_s)
                           for name, record in outcome.devices.items()}
    kpis["mode"] = outcome.mode
    kpis["seed"] = scenario.seed
    kpis["simulated_s"] = outcome.end_us / 1e6
    kpis["end_reason"] = outcome.reason
    kpis_json = out_dir / "kpis.json"
    write_kpis(kpis, kpis_json)
    figures = _draw(view, outcome.mode) if plots else []
    if plots and "realtime" in kpis:
        figures.append(plot_lateness(kpis["realtime"], out_dir / LATENESS_NAME))
    report = [write_run_report(out_dir, interactive_report)] if plots else []   # one self-contained page
    return RunReport(out_dir, outcome, kpis, [trace, *run.device_traces, run.truth_csv, kpis_json, *figures,
                                              run.run_json, *report])


def _draw(view: RunView, mode: str) -> list[Path]:
    """plot.png and each study's figures of a run, into its folder; the files written."""
    s = view.scenario
    plot = plot_run(s, view.cols, view.out_dir / PLOT_NAME, f"{s.name} ({mode}, seed {s.seed})")
    return [plot, *study_plots(view)]


def has_figures(folder: Path) -> bool:
    """Whether a run folder has its figures and report.html (a campaign point run without --plots has
    not)."""
    return (Path(folder) / PLOT_NAME).is_file() and (Path(folder) / REPORT_NAME).is_file()


def write_figures(folder: Path, interactive_report: bool = False) -> list[Path]:
    """plot.png, the studies' figures and report.html of a run folder that has none (a campaign point run
    without plots), drawn from its own files: run.json, truth.csv (6 significant digits) and the trace;
    the files written."""
    view = RunView.from_folder(folder)
    return [*_draw(view, view.mode), write_run_report(Path(folder), interactive_report)]


def run_scenario_lockstep(scenario: Scenario, out_dir: Path,
                          progress: Callable[[int, dict], None] | None = None,
                          interactive_report: bool = True, plots: bool = True) -> RunReport:
    """Run `scenario` in lockstep into the run folder `out_dir`, its [[faults]] injected, and report it
    (finish_run: `plots` False leaves out the figures and report.html)."""
    db, codec = loaded_dbc(dbc_path_of(scenario))                # bad DBC or faults: no run folder is left
    run = run_lockstep_folder(scenario, out_dir, progress, injector=build_injector(scenario, db, codec))
    return finish_run(run, interactive_report, plots)


def run_scenario_realtime(scenario: Scenario, out_dir: Path, cli_bus_config: dict,
                          progress: Callable[[int, dict], None] | None = None,
                          external: tuple[str, ...] = ()) -> RunReport:
    """Run `scenario` in real time into the run folder `out_dir` (hil.runtime.realtime.run_realtime_folder:
    the bus from `cli_bus_config`, python-can's configuration and the scenario; `external`: nodes another
    process or host runs) and report it; a run that failed (a node died) raises NodeDied once its folder is
    written: nothing recorded is lost."""
    run = run_realtime_folder(scenario, out_dir, cli_bus_config, progress=progress, external=external)
    report = finish_run(run)
    if run.failure is not None:
        raise NodeDied(f"{run.failure}; what was recorded is in {out_dir}")
    return report
