"""The threat matrix: every EN 50159 threat on every safety frame of a scenario, run in lockstep, with
what the receivers detected and what happened to the train (plant truth).

One cell = one lockstep run of the scenario with one `[[faults]]` entry: `threat` on `message` over
the window [t_brake + WINDOW_START_S, + WINDOW_S) with probability 1, where t_brake is the desk's
first brake command.  Per cell:

* detection — for each node that receives the message: the time from the first injected event to
  the first non-OK E2E status or SecOC rejection of that message at that node; ``detected`` when
  every receiver saw one within DETECT_CYCLES cycles of the message.
* outcome on plant truth, against the fault-free run of the same scenario and seed:
  ``unsafe`` when the train did not stop, or stopped more than UNSAFE_MARGIN (fraction) + 1 m beyond
  the fault-free stopping distance; ``released`` when any car's cylinder pressure fell below half of
  its fault-free value at the same instant, for longer than RELEASE_S inside the window (a brake
  released by a spoofed or lost command).

Parameters of a threat: delay and repetition shift by DELAY_CYCLES cycles of the message (a delay
shorter than the receiver's timeout is no fault E2E can see); masquerade sets the first signal of
RELEASE_CLAIMS the message carries to its release value (no deceleration, dump valve VENT, no
emergency, brake step 0, no request).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass

import numpy as np
from cantools.database.can import Database

from hil.can.codec import Codec, loaded_dbc
from hil.report.kpis import compute_kpis
from hil.runtime.desk import DeskScript
from hil.runtime.node import e2e_config
from hil.safety.injection import MESSAGE_THREATS
from hil.scenario import Scenario, parse_scenario

__all__ = ["Cell", "run_cell", "run_matrix", "safety_messages"]

WINDOW_START_S = 2.0          # after the first brake command (chosen: braking is established)
WINDOW_S = 2.0
DETECT_CYCLES = 3             # acceptance of issue #9
DELAY_CYCLES = 2
UNSAFE_MARGIN = 0.05
RELEASE_S = 0.1
# what a rogue frame claims, by the first of these signals the message carries: a brake release
RELEASE_CLAIMS = (("TargetDecel", 0.0), ("WspValve", 2.0), ("EmergencyActive", 0.0), ("BrakeStep", 0.0),
                  ("Request", 0.0))


@dataclass(frozen=True)
class Cell:
    message: str
    threat: str
    injected: int
    receivers: tuple[str, ...]
    detected: bool
    worst_detection_ms: float | None      # slowest receiver; None when one never detected it
    first_status: str                     # what the slowest receiver reported first
    stopped: bool
    stopping_distance_m: float | None
    distance_change_m: float | None       # against the fault-free run
    released: bool
    unsafe: bool
    error: str = ""


def _codec(scenario: Scenario, db: Database) -> Codec:
    """The codec of `db`: the one loaded once per process when `db` is the scenario's DBC."""
    cached_db, codec = loaded_dbc(scenario.dbc)
    return codec if db is cached_db else Codec(db)


def safety_messages(scenario: Scenario, db: Database) -> list[str]:
    """E2E-protected messages that some node of the scenario sends and another receives."""
    from hil.runtime.assembly import build_node, node_names

    codec = _codec(scenario, db)
    nodes = [build_node(n, scenario, db, codec) for n in node_names(scenario)]
    sent = {fc.name for node in nodes for fc in (tx.codec for tx in node.tx)}
    received = {db.get_message_by_frame_id(fid).name for node in nodes for fid in node.rx_ids}
    return [m.name for m in db.messages if e2e_config(m) is not None and m.name in sent & received]


def _receivers(scenario: Scenario, db: Database, message: str) -> tuple[str, ...]:
    from hil.runtime.assembly import build_node, node_names

    codec = _codec(scenario, db)
    fid = db.get_message_by_name(message).frame_id
    return tuple(n for n in node_names(scenario) if fid in build_node(n, scenario, db, codec).rx_ids)


def fault_for(scenario: Scenario, db: Database, message: str, threat: str) -> dict:
    msg = db.get_message_by_name(message)
    brake_us = DeskScript(scenario.desk).first_brake_us() or 0
    start = brake_us / 1e6 + WINDOW_START_S
    fault: dict = {"kind": threat, "message": message, "from_s": start, "to_s": start + WINDOW_S}
    if threat in ("delay", "repetition"):
        fault["delay_ms"] = DELAY_CYCLES * float(msg.cycle_time or 10)
    if threat == "masquerade":
        names = {s.name for s in msg.signals}
        fault["signal"], fault["value"] = next(((s, v) for s, v in RELEASE_CLAIMS if s in names),
                                               (msg.signals[-1].name, 0.0))
    return fault


def _run(scenario: Scenario) -> tuple:
    from hil.runtime.lockstep import run_lockstep

    db, codec = loaded_dbc(scenario.dbc)
    outcome = run_lockstep(scenario, db, codec, writer=None)
    cols = outcome.truth.columns()
    brake_us = DeskScript(scenario.desk).first_brake_us()
    kpis = compute_kpis(scenario, cols, (np.array([]), np.array([])),
                        None if brake_us is None else brake_us / 1e6, outcome.frames_by_node, 0)
    return outcome, cols, kpis


def _pressures(cols: dict, cars: int) -> tuple[np.ndarray, np.ndarray]:
    return cols["t_s"], np.column_stack([cols[f"p_Pa_{i}"] for i in range(1, cars + 1)])


def run_cell(scenario: Scenario, message: str, threat: str, baseline: tuple | None = None) -> Cell:
    """One cell of the matrix (module docstring); `baseline` = the fault-free (kpis, t, p) if known."""
    db, _ = loaded_dbc(scenario.dbc)
    fault = fault_for(scenario, db, message, threat)
    receivers = _receivers(scenario, db, message)
    if baseline is None:
        _, cols0, kpis0 = _run(scenario)
        baseline = (kpis0, *_pressures(cols0, scenario.train.cars))
    kpis0, t0, p0 = baseline
    faulty = parse_scenario({**scenario.model_dump(), "faults": [fault]}, f"{scenario.name} + {threat}")
    outcome, cols, kpis = _run(faulty)
    events = outcome.faults["events"] if outcome.faults else []
    injected = sum(outcome.faults["counts"].values()) if outcome.faults else 0
    cycle_us = float(db.get_message_by_name(message).cycle_time or 10) * 1000
    worst, first_status, detected = 0.0, "", bool(events)
    if events:
        t_inj_us = events[0][0] * 1e6
        for node in receivers:
            seen = [(t, st) for t, m, st in outcome.node_stats[node]["e2e_events"]
                    if m == message and t >= t_inj_us and st != "INITIAL"]
            if not seen or seen[0][0] - t_inj_us > DETECT_CYCLES * cycle_us:
                detected = False
            latency = (seen[0][0] - t_inj_us) / 1e3 if seen else math.inf
            if latency >= worst:
                worst, first_status = latency, seen[0][1] if seen else "never"
    t, p = _pressures(cols, scenario.train.cars)
    ref = np.column_stack([np.interp(t, t0, p0[:, i]) for i in range(p0.shape[1])])
    in_window = (t >= fault["from_s"]) & (t < fault["to_s"])
    low = np.any((p < 0.5 * ref) & (ref > 20e3), axis=1) & in_window
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    released = bool(low.sum() * dt > RELEASE_S)
    d0, d = kpis0["stopping_distance_m"], kpis["stopping_distance_m"]
    change = d - d0 if (kpis["stopped"] and kpis0["stopped"]) else None
    unsafe = (not kpis["stopped"]) or (change is not None and change > UNSAFE_MARGIN * d0 + 1.0)
    return Cell(message, threat, injected, receivers, detected,
                None if math.isinf(worst) else round(worst, 3), first_status, bool(kpis["stopped"]),
                d if kpis["stopped"] else None, None if change is None else round(change, 3),
                released, unsafe)


def _cell_job(args: tuple) -> Cell:
    scenario_json, message, threat, baseline = args
    scenario = Scenario.model_validate_json(scenario_json)
    try:
        return run_cell(scenario, message, threat, baseline)
    except Exception as exc:          # one failing cell is recorded, the others go on
        return Cell(message, threat, 0, (), False, None, "", False, None, None, False, True,
                    error=f"{type(exc).__name__}: {exc}")


def run_matrix(scenario: Scenario, messages: Iterable[str] | None = None,
               threats: Iterable[str] = MESSAGE_THREATS, jobs: int = 1,
               progress: Callable[[Cell], None] | None = None) -> tuple[list[Cell], dict]:
    """Every (message, threat) cell, in parallel processes when jobs > 1; returns cells and baseline."""
    db, _ = loaded_dbc(scenario.dbc)
    messages = list(messages) if messages is not None else safety_messages(scenario, db)
    _, cols0, kpis0 = _run(scenario)
    baseline = (kpis0, *_pressures(cols0, scenario.train.cars))
    work = [(scenario.model_dump_json(), m, th, baseline) for m in messages for th in threats]
    cells: list[Cell] = []
    if jobs <= 1:
        for job in work:
            cells.append(_cell_job(job))
            if progress:
                progress(cells[-1])
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            for cell in pool.map(_cell_job, work):
                cells.append(cell)
                if progress:
                    progress(cell)
    return cells, {"stopping_distance_m": kpis0["stopping_distance_m"], "stopped": kpis0["stopped"]}


def as_rows(cells: list[Cell]) -> list[dict]:
    return [asdict(c) | {"receivers": ",".join(c.receivers)} for c in cells]
