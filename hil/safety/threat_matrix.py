"""The threat matrix: every EN 50159 threat on every protected frame of a scenario, plus a babbling node
and each sending node gone bus-off, run in lockstep, with what the receivers detected and what happened
to the train (plant truth).

Cells.  A protected frame is an E2E-protected DBC message that a node of the scenario sends and another
receives (`protected_frames`: derived from the DBC and the node bindings).  The cells of a scenario:

* one per (protected frame, message threat): repetition, deletion, insertion, resequencing, corruption,
  delay, masquerade (EN 50159 §5.1, hil.safety.injection);
* ``bus_off`` — one per node that sends a protected frame: the node falls silent; the cell hits every
  protected frame that node sends;
* ``babbling`` — one per bus (a lockstep run has one): a node floods identifier 0x000 back to back, so
  every frame of the bus loses arbitration, the babbler's own included; which node babbles changes
  nothing on the bus, the babbler is BABBLER (PLANT, the sensor gateway).  The cell hits every
  protected frame of the scenario.

A scenario without a protected frame has no cell; the table says so and why (`no_cells_reason`).

Window.  Every fault acts over [t_brake + WINDOW_START_S, + WINDOW_S) with probability 1 (`window_s`
of `plan` and `run_baseline`, the CLI's --window, makes it longer or shorter), where
t_brake is the time braking is established in the fault-free run: its first BCU_DEMAND frame with
TargetDecel > 0 (the BCU's demand, whether the driver, precise stopping or the ACD asked for it; the
desk's first brake command where the scenario has no BCU_DEMAND).  Delay and repetition shift by
DELAY_CYCLES cycles of the message (a delay shorter than the receiver's timeout is no fault E2E can
see).  Masquerade: a rogue frame of the message with the first signal of ROGUE_CLAIMS it carries set to
the claim that matters for that frame (a release, a moved stop point, φ at its limit, a false NONE
request, a false standstill), with a correct E2E counter and CRC and a guessed MAC.

Per cell:

* detected — for every protected frame the cell hits and every node that receives it: the time from
  the first frame of it released in the window (the first one the fault acted on) to the first non-OK
  E2E status or SecOC rejection of it at that node; detected when every one is within DETECT_CYCLES
  cycles of that frame.
* released — today's rule: a car's cylinder pressure (plant truth) below half of its fault-free value
  at the same instant, where that is above 20 kPa, for longer than RELEASE_S inside the window (a brake
  released by a spoofed or lost command).
* target moved — a receiving controller was handed spoofed content: a frame of a message the cell hits
  that the receiving node accepted (it passed SecOC and E2E and entered the node's latest-value table,
  which is what its controller steps on) and whose signals — every signal but the E2E counter and CRC
  and the SecOC trailer — equal none of the frames the legitimate sender released in the last
  STALE_CYCLES cycles of the message.  Forged, inserted and corrupted frames carry such content, and so
  does a replay older than STALE_CYCLES; a frame merely late by the delay threat's DELAY_CYCLES does
  not.  For DESK_TARGET that content is the stop point the BCU brakes to; for ACD_BRAKE_REQ, DESK_CMD,
  BCU_DEMAND and BCU_EMERGENCY the requested deceleration or emergency; for BCU_BRAKE_CORR the φ and
  feedback state that scale every car's cylinder pressure; for BECUn_PRESS_CMD the cylinder set-point
  and dump valve; for BECUn_STATUS the speed the BCU's odometer and vote take.  It is judged at the
  receiver against the legitimate sender of the same run, not against the fault-free run, so that a
  value held through a deletion (the sender's own, detected as lost) or a train that brakes
  differently after a detected fault is not taken for a spoof; what the spoof did to the train is
  judged on plant truth by `unsafe` and `released`.
* unsafe — the scenario family's criterion on plant truth against the fault-free run of the same
  scenario and seed (FAMILY_OF_STUDY picks it from the scenario's study sections):

  - stop distance (default, stop_30kmh, decel_feedback, rg_low_adhesion; every scenario without one
    of the sections below): the train did not stop, or its stopping distance from t_brake exceeds the
    fault-free one by more than UNSAFE_MARGIN (5 %) + UNSAFE_EXTRA_M (1 m).
  - stop error (precise_stop): the train did not stop, or its front stopped more than STOP_BAND_M
    (0.3 m) beyond the farther of the target and the fault-free stop point.  0.3 m is the project's
    platform-door goal for precise stopping (docs/studies/precise-stop.md, met by the PI baseline);
    seed 002 itself reports ±25–45 m for its adaptive search and ±2–7 m with the differentiation unit
    (§VII, Figs. 5–6).  Overshoot is the hazard (past the platform, towards what lies beyond); a
    fail-safe reaction to a detected fault that stops the train short is not.
  - gap to the train ahead (anticollision): a collision (minimum gap to the leader's last wagon ≤ 0,
    hil/studies/anticollision/kpis.py), or a minimum gap smaller than the fault-free one by more than
    the stop-distance margin on the fault-free braking distance (5 % of it + 1 m), or more red signals
    passed than fault-free, or no stop.
  - coupler displacement (consensus): max |Δl| over the run (hil/studies/consensus/kpis.py) beyond
    θ₂ = 10 mm, the bound seed 003's potential field keeps (eqs. 26–27, Table 2), or beyond 1.1 × the
    fault-free max |Δl| where that is already larger.

  A stop-distance, stop-error or gap scenario whose fault-free run does not stand still by its
  max_duration_s (rg_low_adhesion: seed 001's 30 s ends at 8.5 m/s) runs, fault-free and in every cell,
  with its horizon HORIZON_FACTOR times longer, so that its stop is judged.

Runs.  `run_matrices` runs the fault-free runs, then the cells, through a concurrent.futures executor
(hil.campaign.sweep.executor_for: in this process, local processes or a Dask cluster), the slowest
scenario's cells first.  `run_cell` runs one cell.  hil.safety.matrix_report writes the table.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Executor
from dataclasses import asdict, dataclass, field

import numpy as np
from cantools.database.can import Database

from firmware_py.decel_feedback import PhiParams
from hil.campaign.jobs import executor_map
from hil.can.attributes import authentic_length, e2e_config
from hil.can.codec import Codec, loaded_dbc
from hil.report.kpis import RunView
from hil.runtime.assembly import build_node, node_names
from hil.runtime.desk import DeskScript
from hil.runtime.lockstep import prepare_lockstep, run_lockstep
from hil.runtime.node import Node
from hil.safety.injection import FaultInjector, build_injector
from hil.scenario import Scenario, parse_scenario, registry
from hil.scenario.faults import MESSAGE_THREATS, NODE_FAULTS
from hil.scenario.params import run_params

__all__ = ["FAMILIES", "ROGUE_CLAIMS", "THREATS", "Baseline", "Cell", "CellSpec", "Frame", "ScenarioMatrix",
           "as_rows", "cells_of", "fault_for", "plan", "protected_frames", "run_baseline", "run_cell",
           "run_matrices", "safety_messages"]

THREATS = MESSAGE_THREATS + NODE_FAULTS
WINDOW_START_S = 2.0          # after braking is established (chosen: the brakes are applied by then)
WINDOW_S = 2.0
DETECT_CYCLES = 3             # acceptance of issue #9
DELAY_CYCLES = 2
STALE_CYCLES = 3              # target moved: content no legitimate frame of the last 3 cycles carried
UNSAFE_MARGIN = 0.05          # stop distance: 5 % ...
UNSAFE_EXTRA_M = 1.0          # ... + 1 m beyond the fault-free run
STOP_BAND_M = 0.3             # stop error: platform-door goal, docs/studies/precise-stop.md
COUPLER_BOUND_M = 0.01        # θ₂ = 1 cm, seed 003 Table 2
COUPLER_MARGIN = 0.10         # ... or 10 % beyond the fault-free max |Δl| where that is larger
RELEASE_S = 0.1
RELEASE_FLOOR_PA = 20e3       # a fault-free pressure below this is no applied brake to release
HORIZON_FACTOR = 2.0
BABBLER = "PLANT"
TARGET_SHIFT_M = 100.0        # a masquerading DESK_TARGET moves the stop point this far beyond the target
PROTECTION_SIGNALS = ("CHECKSUM", "COUNTER")


def _stop_point_beyond(scenario: Scenario) -> float:
    targets = [e.target_stop_m for e in scenario.desk if e.target_stop_m is not None]
    return (targets[-1] if targets else run_params(scenario).start_position_m) + TARGET_SHIFT_M


def _phi_limit(scenario: Scenario) -> float:
    """The largest correction φ a BECU applies (PhiParams.limits)."""
    return PhiParams().limits[1]


#: masquerade: what the rogue frame claims, by the first of these signals the message carries — the
#: claim that matters for that frame: (signal, value or value(scenario), what it does)
ROGUE_CLAIMS: tuple[tuple[str, float | Callable[[Scenario], float], str], ...] = (
    ("TargetDecel", 0.0, "BCU_DEMAND: no deceleration, a release"),
    ("WspValve", 2.0, "BECUn_PRESS_CMD: dump valve VENT, a release"),
    ("EmergencyActive", 0.0, "BCU_EMERGENCY: no emergency"),
    ("BrakeStep", 0.0, "DESK_CMD: brake step 0, a release"),
    ("Request", 0.0, "ACD_BRAKE_REQ: NONE, a false all-clear"),
    ("TargetStopPos", _stop_point_beyond, "DESK_TARGET: the stop point TARGET_SHIFT_M beyond the target"),
    ("FrictionPhi", _phi_limit, "BCU_BRAKE_CORR: φ at the BECUs' upper limit, the force part of every "
                                "cylinder pressure divided by it (1.6: −37 %)"),
    ("SpeedEst", 0.0, "BECUn_STATUS: the car stands, a false standstill for the BCU's odometer and vote"),
)


# ------------------------------------------------------------------------------------------ families
@dataclass(frozen=True)
class Family:
    """A scenario family's unsafe criterion: `measure` names the figure each cell reports."""

    name: str
    measure: str          # [m]
    rule: str


FAMILIES = {
    "stop_distance": Family("stop distance", "stopping_distance_m",
                            "no stop, or stopping distance > fault-free × 1.05 + 1 m"),
    "stop_error": Family("stop error", "stop_error_m",
                         "no stop, or stop error (+ = overshoot) > max(fault-free, 0) + 0.3 m"),
    "gap": Family("gap to the train ahead", "min_gap_m",
                  "collision, min gap < fault-free − (5 % of the fault-free braking distance + 1 m), a red "
                  "signal passed, or no stop"),
    "coupler": Family("coupler displacement", "max_abs_dl_m", "max |Δl| > max(10 mm, 1.1 × fault-free)"),
}
#: the study whose scenario section selects a family, first match wins; none: stop distance
FAMILY_OF_STUDY = (("consensus", "coupler"), ("anticollision", "gap"), ("precise_stop", "stop_error"))


def family_of(scenario: Scenario) -> str:
    names = {s.name for s in registry.active(scenario)}
    return next((fam for study, fam in FAMILY_OF_STUDY if study in names), "stop_distance")


def measures(scenario: Scenario, cols: dict, t_brake: float) -> dict:
    """The figures the criteria judge, from plant truth: stopped, stopping distance of car 1 from
    `t_brake`, and those of the family's study (its kpis part: stop error, min gap and red-signal
    overruns, max |Δl|)."""
    no_signal = (np.zeros(0), np.zeros(0))
    view = RunView.of(scenario, cols, no_signal, t_brake)
    t, x1 = cols["t_s"], cols["x_m_1"]
    out = {"stopped": view.stopped,
           "stopping_distance_m": float(x1[view.i_stop] - np.interp(t_brake, t, x1))}
    wanted = {study for study, _ in FAMILY_OF_STUDY}
    k = {s.name: s.part("kpis").kpis(view) for s in registry.active(scenario) if s.name in wanted}
    if "precise_stop" in k:
        out["stop_error_m"] = k["precise_stop"]["stop_error_m"]
    if "anticollision" in k:
        out["min_gap_m"] = k["anticollision"]["min_gap_m"]
        out["overruns"] = k["anticollision"]["overruns"]
    if "consensus" in k:
        out["max_abs_dl_m"] = k["consensus"]["max_abs_dl_mm"] / 1000.0
    return out


def judge(family: str, m: dict, m0: dict) -> tuple[float | None, float | None, bool]:
    """(the family's measure, its bound, unsafe) of a run's measures `m` against the fault-free `m0`."""
    if family == "stop_distance":
        d, d0 = m["stopping_distance_m"], m0["stopping_distance_m"]
        bound = d0 * (1 + UNSAFE_MARGIN) + UNSAFE_EXTRA_M
        return d, bound, (not m["stopped"]) or d > bound
    if family == "stop_error":
        e, e0 = m.get("stop_error_m"), m0["stop_error_m"]
        if e0 is None:                                   # the fault-free run did not stop: only the stop
            return e, None, not m["stopped"]
        bound = max(e0, 0.0) + STOP_BAND_M
        return e, bound, (not m["stopped"]) or e is None or e > bound
    if family == "gap":
        g, g0 = m.get("min_gap_m"), m0["min_gap_m"]
        if g0 is None:                                   # no train ahead: only the stop is judged
            return g, None, not m["stopped"]
        bound = g0 - (UNSAFE_MARGIN * m0["stopping_distance_m"] + UNSAFE_EXTRA_M)
        unsafe = (not m["stopped"]) or g is None or g <= 0.0 or g < bound or m["overruns"] > m0["overruns"]
        return g, bound, unsafe
    dl, dl0 = m["max_abs_dl_m"], m0["max_abs_dl_m"]
    bound = max(COUPLER_BOUND_M, (1 + COUPLER_MARGIN) * dl0)
    return dl, bound, dl > bound


def needs_stop(family: str) -> bool:
    return family != "coupler"


# ---------------------------------------------------------------------------------- frames and cells
@dataclass(frozen=True)
class Frame:
    """A protected frame of a scenario: its sender, the nodes that receive it, its cycle [ms]."""

    name: str
    sender: str
    receivers: tuple[str, ...]
    cycle_ms: float


def _codec(scenario: Scenario, db: Database) -> Codec:
    """The codec of `db`: the one loaded once per process when `db` is the scenario's DBC."""
    cached_db, codec = loaded_dbc(scenario.dbc)
    return codec if db is cached_db else Codec(db)


def protected_frames(scenario: Scenario, db: Database) -> dict[str, Frame]:
    """E2E-protected messages that a node of the scenario sends cyclically and another receives, in DBC
    order, from the DBC and the node bindings."""

    codec = _codec(scenario, db)
    nodes = [build_node(n, scenario, db, codec) for n in node_names(scenario)]
    senders = {tx.codec.name: node.name for node in nodes for tx in node.tx}
    out = {}
    for m in db.messages:
        if e2e_config(m) is None or m.name not in senders:
            continue
        receivers = tuple(n.name for n in nodes if m.frame_id in n.rx_ids and n.name != senders[m.name])
        if receivers:
            out[m.name] = Frame(m.name, senders[m.name], receivers, float(m.cycle_time or 10))
    return out


def safety_messages(scenario: Scenario, db: Database) -> list[str]:
    """The names of `protected_frames`."""
    return list(protected_frames(scenario, db))


def no_cells_reason(scenario: Scenario, db: Database) -> str:
    """Why a scenario has no protected frame: the frames its nodes exchange carry no E2E protection."""

    codec = _codec(scenario, db)
    nodes = [build_node(n, scenario, db, codec) for n in node_names(scenario)]
    sent = {tx.codec.name for node in nodes for tx in node.tx}
    received = {db.get_message_by_frame_id(fid).name for node in nodes for fid in node.rx_ids}
    exchanged = [m.name for m in db.messages if m.name in sent & received]
    shown = ", ".join(exchanged[:6]) + (", ..." if len(exchanged) > 6 else "")
    return (f"no E2E-protected frame: none of the {len(exchanged)} frames its nodes "
            f"({', '.join(n.name for n in nodes)}) exchange ({shown}) has an E2EProfile in the DBC")


@dataclass(frozen=True)
class CellSpec:
    """What one cell injects: `threat` on `target` (a frame, or a node for babbling and bus_off), hitting
    the protected `frames`."""

    scenario: str
    threat: str
    target: str
    frames: tuple[str, ...]


def cells_of(scenario: Scenario, db: Database, threats: Iterable[str] = THREATS,
             messages: Iterable[str] | None = None,
             frames: dict[str, Frame] | None = None) -> list[CellSpec]:
    """The cells of a scenario (module docstring), frames first in DBC order, threats in `threats` order.
    `messages`: only the cells hitting these frames (their threats, their senders' bus-off, babbling)."""
    frames = protected_frames(scenario, db) if frames is None else frames
    threats = list(threats)
    chosen = [m for m in frames if messages is None or m in set(messages)]
    cells = [CellSpec(scenario.name, th, m, (m,)) for m in chosen for th in threats if th in MESSAGE_THREATS]
    if "bus_off" in threats:
        senders = list(dict.fromkeys(frames[m].sender for m in chosen))
        for node in senders:
            sent = tuple(m for m, f in frames.items() if f.sender == node)
            cells.append(CellSpec(scenario.name, "bus_off", node, sent))
    if "babbling" in threats and chosen:
        cells.append(CellSpec(scenario.name, "babbling", BABBLER, tuple(frames)))
    return cells


# -------------------------------------------------------------------------------------- the fault-free
@dataclass(frozen=True)
class Baseline:
    """The fault-free run of a scenario as the cells need it."""

    scenario: str
    family: str
    horizon_s: float               # max_duration_s of every run of the matrix
    t_brake_s: float               # braking established (module docstring)
    window: tuple[float, float]    # [from, to) of every fault [s]
    measures: dict
    t_s: np.ndarray = field(repr=False)       # truth sample times inside the window
    p_Pa: np.ndarray = field(repr=False)      # cylinder pressures there, one column per car
    wall_s: float = 0.0
    extended: bool = False         # the horizon was extended for the stop (HORIZON_FACTOR)


class _DemandLog:
    """Times [s] and TargetDecel of every BCU_DEMAND frame on the bus (a writer for run_lockstep)."""

    def __init__(self, codec: Codec) -> None:
        self.fc = next((fc for fc in codec if fc.name == "BCU_DEMAND"), None)
        self.t: list[float] = []
        self.v: list[float] = []

    def write_frame(self, t_s: float, frame_id: int, extended: bool, data: bytes) -> None:
        if self.fc is not None and frame_id == self.fc.frame_id:
            self.t.append(t_s)
            self.v.append(float(self.fc.decode(data)["TargetDecel"]))

    def on_message_received(self, msg) -> None:          # can.Listener's interface, unused
        pass


def _pressures(cols: dict, cars: int) -> np.ndarray:
    return np.column_stack([cols[f"p_Pa_{i}"] for i in range(1, cars + 1)])


def run_baseline(scenario: Scenario, window_s: float = WINDOW_S) -> Baseline:
    """The fault-free run: its measures, t_brake, the window (`window_s` long) and the pressures in it; a
    scenario whose family needs a stop and that does not stop runs again with its horizon HORIZON_FACTOR
    times longer."""

    t0 = time.perf_counter()
    db, codec = loaded_dbc(scenario.dbc)
    family = family_of(scenario)
    for attempt in range(2):
        log = _DemandLog(codec)
        outcome = run_lockstep(scenario, db, codec, writer=log, injector=build_injector(scenario, db, codec))
        cols = outcome.truth.columns()
        on = [t for t, v in zip(log.t, log.v, strict=True) if v > 0.0]
        desk_us = DeskScript(scenario.desk).first_brake_us()
        t_brake = on[0] if on else (desk_us / 1e6 if desk_us is not None else 0.0)
        m0 = measures(scenario, cols, t_brake)
        if m0["stopped"] or not needs_stop(family) or attempt:
            break
        scenario = parse_scenario({**scenario.model_dump(),
                                   "max_duration_s": scenario.max_duration_s * HORIZON_FACTOR}, scenario.name)
    window = (t_brake + WINDOW_START_S, t_brake + WINDOW_START_S + window_s)
    t = cols["t_s"]
    inside = (t >= window[0] - 0.05) & (t < window[1] + 0.05)
    return Baseline(scenario.name, family, scenario.max_duration_s, t_brake, window, m0, t[inside],
                    _pressures(cols, scenario.train.cars)[inside], time.perf_counter() - t0, attempt > 0)


# ------------------------------------------------------------------------------------------- one cell
@dataclass(frozen=True)
class Cell:
    scenario: str
    target: str                          # the frame (message threats) or the node (babbling, bus_off)
    threat: str
    frames: tuple[str, ...]              # the protected frames the fault hits
    receivers: tuple[str, ...]
    injected: int
    detected: bool
    worst_detection_ms: float | None     # slowest (frame, receiver); None when one never detected it
    first_status: str                    # what the slowest receiver reported first
    stopped: bool
    measure: float | None                # the family's measure (Family.measure), plant truth
    change: float | None                 # against the fault-free run
    bound: float | None                  # unsafe beyond this (below it for the gap)
    released: bool
    target_moved: bool
    unsafe: bool
    error: str = ""

    @property
    def ok(self) -> bool:
        return self.detected and not (self.unsafe or self.released or self.target_moved or self.error)


def fault_for(scenario: Scenario, db: Database, spec: CellSpec, window: tuple[float, float]) -> dict:
    """The `[[faults]]` entry of a cell."""
    fault: dict = {"kind": spec.threat, "from_s": window[0], "to_s": window[1]}
    if spec.threat in NODE_FAULTS:
        return {**fault, "node": spec.target}
    msg = db.get_message_by_name(spec.target)
    fault["message"] = spec.target
    if spec.threat in ("delay", "repetition"):
        fault["delay_ms"] = DELAY_CYCLES * float(msg.cycle_time or 10)
    if spec.threat == "masquerade":
        names = {s.name for s in msg.signals}
        signal, value = next(((s, v) for s, v, _ in ROGUE_CLAIMS if s in names), (msg.signals[-1].name, 0.0))
        fault["signal"], fault["value"] = signal, float(value(scenario) if callable(value) else value)
    return fault


def content_signals(msg) -> tuple[str, ...]:
    """The signals of a message its sender's software writes: not the E2E counter and CRC, not the SecOC
    trailer."""
    authentic = authentic_length(msg)
    return tuple(s.name for s in msg.signals if s.name not in PROTECTION_SIGNALS and s.start < 8 * authentic)


class _Watch:
    """What one cell's run does to the frames it watches: their legitimate releases, before the injector acts
    on them (`released`, told by `_WatchedInjector`), and what each receiving node accepted of them
    (`accepted`: the node's receive watch, hil.runtime.node.ReceiveWatch, set by `attach`)."""

    def __init__(self, db: Database, codec: Codec, frames: Sequence[str], from_s: float) -> None:
        self.from_ns = round(from_s * 1e9)
        self.msgs = {db.get_message_by_name(m).frame_id: db.get_message_by_name(m) for m in frames}
        self.sigs = {fid: content_signals(msg) for fid, msg in self.msgs.items()}
        self.stale_ns = {fid: STALE_CYCLES * int(msg.cycle_time or 10) * 1_000_000
                         for fid, msg in self.msgs.items()}
        self.codec = codec
        self.first_ns: dict[str, int] = {}                 # message -> first release in the window
        self.legit: dict[int, deque] = {fid: deque() for fid in self.msgs}
        self.moved: list[tuple[float, str, str]] = []      # (t [s], node, message) of spoofed content

    def attach(self, nodes: Iterable[Node]) -> None:
        """Watch what each node that receives a watched message accepts."""
        for node in nodes:
            if node.rx_ids & self.msgs.keys():
                node.receive_watch = self

    def released(self, t_ns: int, frame_id: int, data: bytes) -> None:
        """A node released this frame at `t_ns` (before the injector acts on it)."""
        if frame_id in self.msgs:
            name = self.msgs[frame_id].name
            if t_ns >= self.from_ns and name not in self.first_ns:
                self.first_ns[name] = t_ns
            values = self.codec[frame_id].decode(data)
            self.legit[frame_id].append((t_ns, tuple(values[s] for s in self.sigs[frame_id])))

    def accepted(self, node: Node, frame_id: int, data: bytes, t_us: int) -> None:
        """`node` took this frame's signals into its table (hil.runtime.node.ReceiveWatch)."""
        if frame_id not in self.msgs:
            return
        t_ns = t_us * 1000
        legit = self.legit[frame_id]
        while len(legit) > 1 and legit[1][0] <= t_ns - self.stale_ns[frame_id]:
            legit.popleft()             # keep the last release at or before the stale limit, and after it
        values = self.codec[frame_id].decode(data)
        content = tuple(values[s] for s in self.sigs[frame_id])
        if not any(c == content for t, c in legit if t_ns - self.stale_ns[frame_id] <= t <= t_ns):
            self.moved.append((t_us / 1e6, node.name, self.msgs[frame_id].name))


class _WatchedInjector:
    """A cell's fault injector as the lockstep runner asks it (hil.runtime.lockstep.FaultHook), which first
    tells the watch of each frame a node releases."""

    def __init__(self, injector: FaultInjector, watch: _Watch) -> None:
        self.injector, self.watch = injector, watch
        self.log, self.babble_rng = injector.log, injector.babble_rng

    def attach(self, nodes: list[Node]) -> None:
        self.injector.attach(nodes)

    def on_release(self, t_ns: int, node: int, frame_id: int, data: bytes) -> list[tuple[int, bytes, int]]:
        self.watch.released(t_ns, frame_id, data)
        return self.injector.on_release(t_ns, node, frame_id, data)

    def babble_windows(self) -> list[tuple[int, int, int, int]]:
        return self.injector.babble_windows()


def _detection(outcome, frames: dict[str, Frame], hit: Sequence[str], first_ns: dict[str, int]):
    """(detected, worst latency [ms] or inf, first status of the slowest) over every (frame, receiver)."""
    worst, first_status, detected = 0.0, "", True
    for message in hit:
        f = frames[message]
        t_inj = first_ns.get(message)
        if t_inj is None:                        # no frame of it in the window: nothing to detect
            continue
        t_inj_us = t_inj / 1000
        for node in f.receivers:
            seen = [(t, st) for t, m, st in outcome.node_stats[node]["e2e_events"]
                    if m == message and t >= t_inj_us and st != "INITIAL"]
            latency = (seen[0][0] - t_inj_us) / 1e3 if seen else math.inf
            if latency > DETECT_CYCLES * f.cycle_ms:
                detected = False
            if latency >= worst:
                worst, first_status = latency, seen[0][1] if seen else "never"
    return detected, worst, first_status


def run_cell(scenario: Scenario, spec: CellSpec, baseline: Baseline,
             frames: dict[str, Frame] | None = None) -> Cell:
    """One cell of the matrix (module docstring) against the fault-free `baseline`."""

    db, codec = loaded_dbc(scenario.dbc)
    frames = protected_frames(scenario, db) if frames is None else frames
    fault = fault_for(scenario, db, spec, baseline.window)
    data = {**scenario.model_dump(), "max_duration_s": baseline.horizon_s, "faults": [fault]}
    faulty = parse_scenario(data, f"{scenario.name} + {spec.threat} on {spec.target}")
    watch = _Watch(db, codec, spec.frames, fault["from_s"])
    injector = build_injector(faulty, db, codec)          # never None: the cell's scenario has its fault
    setup = prepare_lockstep(faulty, db, codec, injector=_WatchedInjector(injector, watch))
    watch.attach(setup.nodes)
    outcome = run_lockstep(faulty, db, codec, writer=None, setup=setup)
    injected = sum(outcome.faults["counts"].values()) if outcome.faults else 0
    detected, worst, first_status = _detection(outcome, frames, spec.frames, watch.first_ns)
    detected = detected and injected > 0 and bool(watch.first_ns)
    cols = outcome.truth.columns()
    t, p = cols["t_s"], _pressures(cols, scenario.train.cars)
    in_window = (t >= fault["from_s"]) & (t < fault["to_s"])
    ref = np.column_stack([np.interp(t[in_window], baseline.t_s, baseline.p_Pa[:, i])
                           for i in range(baseline.p_Pa.shape[1])])
    low = np.any((p[in_window] < 0.5 * ref) & (ref > RELEASE_FLOOR_PA), axis=1)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    released = bool(low.sum() * dt > RELEASE_S)
    m = measures(faulty, cols, baseline.t_brake_s)
    value, bound, unsafe = judge(baseline.family, m, baseline.measures)
    value0 = baseline.measures.get(FAMILIES[baseline.family].measure)
    change = None if value is None or value0 is None else value - value0
    receivers = tuple(dict.fromkeys(r for f in spec.frames for r in frames[f].receivers))
    return Cell(spec.scenario, spec.target, spec.threat, spec.frames, receivers, injected, detected,
                None if math.isinf(worst) else round(worst, 3), first_status, bool(m["stopped"]),
                _round(value), _round(change), _round(bound), released, bool(watch.moved), bool(unsafe))


def _round(x: float | None, nd: int = 4) -> float | None:
    return None if x is None else round(float(x), nd) + 0.0


# ------------------------------------------------------------------------------------- the campaign
def baseline_job(scenario_json: str, window_s: float = WINDOW_S) -> Baseline | str:
    """A worker's job: the fault-free run, or its error as one line (never raises)."""
    try:
        return run_baseline(Scenario.model_validate_json(scenario_json), window_s)
    except Exception as exc:
        return f"{type(exc).__name__}: {' '.join(str(exc).split())}"


def cell_job(scenario_json: str, spec: CellSpec, baseline: Baseline, frames: dict[str, Frame]) -> Cell:
    """A worker's job: one cell; an error is recorded in the cell, the others go on (never raises).
    (A finished lockstep run is freed at once: it holds no reference cycle, tests/runtime/test_lockstep_run;
    one once grew a worker by 25 MB per precise_stop cell, to 3.5 GB.)"""
    try:
        return run_cell(Scenario.model_validate_json(scenario_json), spec, baseline, frames)
    except Exception as exc:
        return failed_cell(spec, f"{type(exc).__name__}: {' '.join(str(exc).split())}")


def failed_cell(spec: CellSpec, error: str) -> Cell:
    return Cell(spec.scenario, spec.target, spec.threat, spec.frames, (), 0, False, None, "", False, None,
                None, None, False, False, True, error=error)


@dataclass
class ScenarioMatrix:
    """One scenario's part of the matrix: its fault-free run, its cells, and why it has none."""

    name: str
    source: str                          # the scenario file
    family: str
    specs: list[CellSpec]
    frames: dict[str, Frame] = field(default_factory=dict)
    baseline: Baseline | None = None
    cells: list[Cell] = field(default_factory=list)
    reason: str = ""                     # no cells (no protected frame), or the fault-free run's error
    window_s: float = WINDOW_S           # how long every fault of it acts [s]


def plan(scenarios: Sequence[tuple[str, Scenario]], threats: Iterable[str] = THREATS,
         messages: Iterable[str] | None = None, window_s: float = WINDOW_S) -> list[ScenarioMatrix]:
    """The cells of every scenario (`(source, scenario)` pairs), each fault acting `window_s`, nothing
    run yet."""
    out = []
    for source, scenario in scenarios:
        db, _ = loaded_dbc(scenario.dbc)
        frames = protected_frames(scenario, db)
        specs = cells_of(scenario, db, threats, messages, frames)
        reason = "" if frames else no_cells_reason(scenario, db)
        out.append(ScenarioMatrix(scenario.name, source, family_of(scenario), specs, frames, reason=reason,
                                  window_s=window_s))
    return out


def run_matrices(scenarios: Sequence[tuple[str, Scenario]], executor: Executor | None = None,
                 threats: Iterable[str] = THREATS, messages: Iterable[str] | None = None,
                 progress: Callable[[str, int, int], None] | None = None,
                 planned: list[ScenarioMatrix] | None = None) -> list[ScenarioMatrix]:
    """The fault-free runs, then every cell, through `executor` (None: in this process).  `progress(phase,
    done, total)` after each job, phase "fault-free" or "cells"."""

    matrices = planned if planned is not None else plan(scenarios, threats, messages)
    by_name = {s.name: s for _, s in scenarios}
    jobs = [(by_name[mx.name].model_dump_json(), mx.window_s) for mx in matrices]
    count = {"fault-free": 0, "cells": 0}

    def tick(phase: str, total: int) -> Callable[[object], None]:
        def done(_result) -> None:
            count[phase] += 1
            if progress is not None:
                progress(phase, count[phase], total)
        return done

    baselines = executor_map(baseline_job, jobs, executor, tick("fault-free", len(jobs)),
                             lambda job, exc: f"{type(exc).__name__}: {exc}")
    work = []
    for mx, b in zip(matrices, baselines, strict=True):
        if isinstance(b, str):
            mx.reason = f"the fault-free run failed: {b}"
            mx.cells = [failed_cell(s, mx.reason) for s in mx.specs]
            continue
        mx.baseline = b
        work += [(b.wall_s, mx, spec) for spec in mx.specs]
    work.sort(key=lambda w: -w[0])                       # the slowest scenario's cells first
    cell_jobs = [(by_name[mx.name].model_dump_json(), spec, mx.baseline, mx.frames) for _, mx, spec in work]
    cells = executor_map(cell_job, cell_jobs, executor, tick("cells", len(cell_jobs)),
                         lambda job, exc: failed_cell(job[1], f"{type(exc).__name__}: {exc}"))
    results: dict[tuple, Cell] = {(c.scenario, c.threat, c.target): c for c in cells}
    for mx in matrices:
        if mx.baseline is not None:
            mx.cells = [results[(s.scenario, s.threat, s.target)] for s in mx.specs]
    return matrices


def as_rows(cells: Iterable[Cell]) -> list[dict]:
    return [asdict(c) | {"frames": ",".join(c.frames), "receivers": ",".join(c.receivers)} for c in cells]
