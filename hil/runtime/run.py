"""One run of a scenario and the run folder it leaves: the trace(s), truth.csv and run.json.

The runtime runs a scenario — in lockstep here (`run_lockstep_folder`), in real time in hil.runtime.realtime
(`run_realtime_folder`) — and writes what it ran into the run folder (`write_run_folder`): the plant's
ground truth (truth.csv, hil.runtime.truth), and run.json (the resolved scenario, the DBC, the node
statistics, the bus, the faults, the devices, the real-time set-up, the run's clock and what reproduces
it).  It hands back a `RunRecord`, which the report reads (hil.report.run.finish_run: kpis.json, the
figures, report.html).
"""

from __future__ import annotations

import contextlib
import json
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np
from cantools.database.can import Database

from hil.can.codec import Codec, loaded_dbc
from hil.can.dbc import DEFAULT_DBC
from hil.errors import RailhilError
from hil.fmi.fmu import describe as describe_fmu
from hil.fmi.fmu import scenario_fmus
from hil.runtime.assembly import build_plant
from hil.runtime.clock import LOCKSTEP_CLOCK, RunClock
from hil.runtime.lockstep import FaultHook, prepare_lockstep, run_lockstep
from hil.runtime.outcome import RunOutcome
from hil.runtime.provenance import run_metadata
from hil.runtime.truth import write_truth_csv
from hil.scenario import Scenario
from hil.trace.writers import open_writer

TRACE_NAME = "trace.blf"       # the default trace's name; [trace] format chooses another (trace_name)
TRUTH_NAME = "truth.csv"       # the plant's ground truth (hil.runtime.truth)
RUN_NAME = "run.json"          # what ran: what makes a folder a run folder


def trace_name(scenario: Scenario) -> str:
    """The trace file of a run folder: trace.<format> ([trace] format; python-can picks its writer by
    the suffix)."""
    return f"trace.{scenario.trace.format}"


def device_trace_name(scenario: Scenario, node: str) -> str:
    """The trace of the own bus of the device in `node`'s place: device-<node>.<format>."""
    return f"device-{node}.{scenario.trace.format}"


def device_trace_of(scenario: Scenario, node: str, record: dict) -> str:
    """Where the frames of the device in `node`'s place are: its own bus's trace, or, on the bench's bus,
    the run's trace."""
    return trace_name(scenario) if record.get("bus_mode") == "bench" else device_trace_name(scenario, node)


@dataclass
class RunRecord:
    """A run the runtime finished, and its folder: the trace(s), truth.csv and run.json are there.  What the
    report needs beside the folder is kept here: the outcome, the truth's columns at full precision
    (truth.csv keeps 6 significant digits), the DBC and codec it ran with, its clock and the messages each
    node sends."""

    scenario: Scenario
    outcome: RunOutcome
    out_dir: Path
    db: Database
    codec: Codec
    cols: dict[str, np.ndarray]                  # the truth's columns (outcome.truth.columns())
    clock: RunClock = LOCKSTEP_CLOCK             # the trace's time base
    sent_by: dict[str, list[str]] | None = None  # the messages each node sends (messages_sent)
    failure: str | None = None                   # real time: why the run ended early (run.json "failure")

    @property
    def trace(self) -> Path:
        return self.out_dir / trace_name(self.scenario)

    @property
    def device_traces(self) -> list[Path]:
        """The traces of the devices' own buses (none for a device on the bench's bus or on OPC UA)."""
        return [self.out_dir / device_trace_name(self.scenario, name)
                for name, record in self.outcome.devices.items()
                if record.get("bus_mode") not in ("bench", "opcua")]

    @property
    def truth_csv(self) -> Path:
        return self.out_dir / TRUTH_NAME

    @property
    def run_json(self) -> Path:
        return self.out_dir / RUN_NAME


def write_run_folder(run: RunRecord, extra: dict | None = None) -> RunRecord:
    """truth.csv and run.json of a finished run into its folder, beside its trace; `extra`: more of run.json
    (a real-time run's bus and failure).  Returns `run`."""
    scenario, outcome = run.scenario, run.outcome
    write_truth_csv(run.cols, run.truth_csv)
    fmus = scenario_fmus(scenario)            # the FMUs in nodes' places (hil.fmi), kept with their SHA-256
    meta = {
        "scenario": scenario.model_dump(mode="json"),
        "mode": outcome.mode,
        "dbc": str(dbc_path_of(scenario)),
        "python": sys.version.split()[0],
        "python_can": can.__version__,
        "platform": platform.platform(),
        "trace": run.trace.name,
        "trace_t0_s": run.clock.t0_s,
        **({"messages_sent": run.sent_by} if run.sent_by else {}),
        "node_stats": outcome.node_stats,
        "bus_timing": outcome.bus,
        "faults": outcome.faults,
        **({"devices": outcome.devices} if outcome.devices else {}),
        **({"fmus": {node: describe_fmu(path) for node, path in fmus.items()}} if fmus else {}),
        "wall_s": round(outcome.wall_s, 3),
        **({"realtime": realtime_meta(outcome.realtime)} if outcome.realtime else {}),
        **run_metadata(dbc_path_of(scenario), scenario.seed),   # versions, DBC SHA-256, git commit
        **(extra or {}),
    }
    run.run_json.write_text(json.dumps(meta, indent=2, default=str) + "\n")
    return run


def dbc_path_of(scenario: Scenario) -> Path:
    return Path(scenario.dbc) if scenario.dbc else DEFAULT_DBC


def messages_sent(nodes) -> dict[str, list[str]]:
    """The DBC messages each node of a run sends (its binding's tx), by node: run.json's `messages_sent`,
    from which `railhil timing` and the report know the frames a run sends by design."""
    return {node.name: [msg for msg, _ in node.binding.tx] for node in nodes}


def realtime_meta(rt: dict) -> dict:
    """run.json's record of a real-time run: hosting, what the OS granted each process, the sleep
    calibration and the precise wait's margin, the external nodes (the per-cycle figures are in kpis.json's
    verdict, not here)."""
    skip = ("cycles", "probes", "host_stalls")
    return {k: v for k, v in rt.items() if k not in skip}


def check_out_dir(out: Path) -> Path:
    """`out`, made where it is not (a run's folder, a campaign's, a report's): one line where it cannot be."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RailhilError(f"{out}: cannot create the run folder: {exc.strerror}") from None
    return out


def prepare_worker(scenario: Scenario) -> float:
    """Load once per process what every lockstep run of `scenario`'s kind needs before its first step:
    its DBC and codec (loaded_dbc) and the compiled plant step for its train (plant_sim.kernel, loaded
    as the plant is built). The seconds it took: ~0.35 s the first time in a process, ~1 ms after.  A
    campaign worker calls it before timing a point, as it imports the runtime: a one-time cost, reported
    apart (run_point's `startup_s`).  Never raises: a scenario that cannot be built fails in its run."""

    t0 = time.perf_counter()
    try:
        loaded_dbc(dbc_path_of(scenario))
        build_plant(scenario)
    except Exception:            # the run itself reports what is wrong, with its one-line error
        pass
    return time.perf_counter() - t0


def run_lockstep_folder(scenario: Scenario, out_dir: Path,
                        progress: Callable[[int, dict], None] | None = None,
                        injector: FaultHook | None = None) -> RunRecord:
    """Run `scenario` in lockstep into the run folder `out_dir`: its trace (and each device's own bus's),
    truth.csv and run.json.  `injector`: the scenario's [[faults]] (hil.safety.injection.build_injector);
    a scenario with faults needs it."""
    dbc_path = dbc_path_of(scenario)
    db, codec = loaded_dbc(dbc_path)
    setup = prepare_lockstep(scenario, db, codec, str(dbc_path), injector)   # bad input: no run folder
    out_dir = check_out_dir(out_dir)
    with contextlib.ExitStack() as open_traces:                    # simulated s from 0
        writer = open_traces.enter_context(open_writer(out_dir / trace_name(scenario), start_time_s=0.0))
        device_writers = {dev.name: open_traces.enter_context(
            open_writer(out_dir / device_trace_name(scenario, dev.name), start_time_s=0.0))
            for dev in setup.devices if dev.bus_mode == "own"}
        outcome = run_lockstep(scenario, db, codec, writer, progress=progress, dbc_name=str(dbc_path),
                               setup=setup, device_writers=device_writers)
    return write_run_folder(RunRecord(scenario, outcome, out_dir, db, codec, outcome.truth.columns(),
                                      sent_by=messages_sent(setup.nodes)))
