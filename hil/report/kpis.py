"""The foundation's KPIs of a run, from the plant's ground truth (not from what the controllers believe);
the demand the controllers were given is read back from the trace, decoded with the DBC.

`compute_kpis` gives the train's figures (stopping distance, time to stop, slip, WSP, deceleration
tracking, frames); `study_kpis` asks each study that is part of the run for its own
(hil/studies/<name>/kpis.py), each under the study's name in kpis.json.  A study's KPI function gets
the run as a `RunView`: the scenario, the truth columns, the demand, the braking window and the trace.

A finished run's trace is read once (`read_run_trace`: every frame as columns, hil.trace.decoded, each
message decoded on first use, with the values the codec and cantools give); the demand, the frame count
(`read_signal`), the plausibility flags and every study's signals (`RunView.signals`) are taken from that
one read.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import can
import numpy as np
from cantools.database.can import Database

from hil.can.codec import Codec
from hil.can.dbc import DEFAULT_DBC, load_dbc
from hil.errors import RailhilError
from hil.runtime.clock import LOCKSTEP_CLOCK, RunClock
from hil.runtime.truth import STANDSTILL_MPS, read_truth_csv
from hil.scenario import registry, scenario_model
from hil.scenario.params import run_params
from hil.trace.columns import BlockReader, FrameBlock
from hil.trace.decoded import DecodedTrace
from hil.trace.readers import TraceError

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

MOVING_MPS = 0.5        # a car below this speed is not judged for slip or deceleration tracking
NO_SIGNAL = (np.zeros(0), np.zeros(0))


def run_trace(folder: Path, meta: dict) -> tuple[Path, RunClock]:
    """The trace of a run folder and how its timestamps map to simulated time, from its run.json
    (`meta`): (path, the run's clock, hil.runtime.clock.RunClock.of_run)."""
    return Path(folder) / meta.get("trace", "trace.blf"), RunClock.of_run(meta)


def read_run_trace(trace: Path, db: Database, codec: Codec) -> DecodedTrace:
    """Every frame of a run's trace, read once as columns (hil.trace.columns: the fast BLF, MF4 and
    candump paths), each message decoded on first use.  As python-can's reader, which finish_run used
    before, a trace cut short or without a frame gives the frames before the end (nothing recorded is
    lost); a missing file or an unknown format is a TraceError."""
    reader = BlockReader(trace)
    blocks: list[FrameBlock] = []
    try:
        for block in reader:
            blocks.append(block)
    except TraceError:          # cut short (BLF), or no frame at all: the frames read before
        pass
    frames = (blocks[0] if len(blocks) == 1 else FrameBlock.join(blocks) if blocks
              else FrameBlock.from_messages([]))
    return DecodedTrace(Path(trace), db, frames, codec)


def _series(table, signal: str, clock: RunClock) -> tuple[np.ndarray, np.ndarray]:
    """Simulated times [s] and values of one signal of a decoded message (hil.trace.decoded)."""
    return clock.simulated_s(table.t), table.columns[signal]


def read_signal(trace: Path | DecodedTrace, db: Database, codec: Codec, message: str, signal: str,
                clock: RunClock = LOCKSTEP_CLOCK) -> tuple[np.ndarray, np.ndarray, int]:
    """Simulated times [s] (the run's `clock`) and values of one signal in a trace, and the number of
    frames in the whole trace: from a trace already read (`read_run_trace`), or in one pass over the file
    at `trace`."""
    if isinstance(trace, DecodedTrace):
        return (*_series(trace.table(message), signal, clock), len(trace.frames))
    fid = db.get_message_by_name(message).frame_id
    fc = codec[fid]
    ts, vs = [], []
    total = 0
    with can.LogReader(str(trace)) as reader:
        for msg in reader:
            total += 1
            if msg.arbitration_id == fid and not msg.is_error_frame and not msg.is_remote_frame:
                ts.append(clock.simulated_s(msg.timestamp))
                vs.append(fc.decode(bytes(msg.data))[signal])
    return np.asarray(ts), np.asarray(vs), total


def read_signals(trace: Path | DecodedTrace, db: Database, codec: Codec, wanted: dict[str, tuple[str, str]],
                 clock: RunClock = LOCKSTEP_CLOCK) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Several signals of a trace (already read, `read_run_trace`, or in one pass over the file):
    name -> (message, signal) in, name -> (simulated times [s], values) out (a message the DBC lacks
    gives empty arrays)."""
    if isinstance(trace, DecodedTrace):
        out = {}
        for name, (message, signal) in wanted.items():
            try:
                table = trace.table(message)
            except KeyError:
                out[name] = NO_SIGNAL
                continue
            out[name] = _series(table, signal, clock)
        return out
    by_id: dict[int, list[tuple[str, str]]] = {}
    for name, (message, signal) in wanted.items():
        try:
            fid = db.get_message_by_name(message).frame_id
        except KeyError:
            continue
        by_id.setdefault(fid, []).append((name, signal))
    series: dict[str, tuple[list, list]] = {name: ([], []) for name in wanted}
    with can.LogReader(str(trace)) as reader:
        for msg in reader:
            entries = by_id.get(msg.arbitration_id)
            if entries is None or msg.is_error_frame or msg.is_remote_frame:
                continue
            decoded = codec[msg.arbitration_id].decode(bytes(msg.data))
            for name, signal in entries:
                series[name][0].append(clock.simulated_s(msg.timestamp))
                series[name][1].append(decoded[signal])
    return {name: (np.asarray(ts), np.asarray(vs)) for name, (ts, vs) in series.items()}


def per_car(cols: dict[str, np.ndarray], key: str, n: int) -> np.ndarray:
    """The truth columns `<key>_1` .. `<key>_n` as one (samples, n) array."""
    return np.column_stack([cols[f"{key}_{i}"] for i in range(1, n + 1)])


def rounded(x: float | None, nd: int = 4) -> float | None:
    """`x` rounded to `nd` digits for kpis.json (None stays None; no "-0.0")."""
    return None if x is None else round(float(x), nd) + 0.0


def train_decel(scenario: Scenario, cols: dict[str, np.ndarray]) -> np.ndarray:
    """The train's deceleration −v̇ [m/s²], mass-weighted over the cars, per truth sample."""
    masses = np.asarray(run_params(scenario).plant.train.masses_kg)
    return -(per_car(cols, "a_mps2", scenario.train.cars) @ masses) / masses.sum()


def wsp_activations(cols: dict[str, np.ndarray], n: int) -> list[int]:
    """FILL→VENT transitions of each car's applied WSP valve (a vent at the first sample counts)."""
    vent = per_car(cols, "wsp_valve", n) == 2
    return [int(k) for k in np.sum(vent[1:] & ~vent[:-1], axis=0) + vent[0]]


@dataclass
class RunView:
    """A finished run as the KPI and plot functions see it.

    `cols`: the truth columns (t_s, then `<quantity>_<car>`); `target`: BCU_DEMAND.TargetDecel from the
    trace (times [s], values [m/s²]); `t_brake`: the first brake command [s] (the start of the run when
    there is none); `i_stop`: the truth sample of the standstill (the last one when the train did not
    stop).  `signals()` takes more signals from the trace, in simulated seconds; `decoded` is the trace
    read once (`read_run_trace`; read on the first `signals()` when not given)."""

    scenario: Scenario
    cols: dict[str, np.ndarray]
    target: tuple[np.ndarray, np.ndarray]
    t_brake: float
    i_stop: int
    stopped: bool
    out_dir: Path | None = None
    trace: Path | None = None
    db: Database | None = None
    codec: Codec | None = None
    clock: RunClock | None = LOCKSTEP_CLOCK   # the trace's time base (hil.runtime.clock; None: not known)
    mode: str = "lockstep"
    decoded: DecodedTrace | None = field(default=None, repr=False)
    _cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, scenario: Scenario, cols: dict[str, np.ndarray], target: tuple[np.ndarray, np.ndarray],
           brake_start_s: float | None, **kw) -> RunView:
        """The view of a run, its braking window found as compute_kpis finds it."""
        t = cols["t_s"]
        v = per_car(cols, "v_mps", scenario.train.cars)
        t_brake = brake_start_s if brake_start_s is not None else float(t[0])
        stop_idx = np.flatnonzero(np.all(v < STANDSTILL_MPS, axis=1) & (t >= t_brake))
        stopped = stop_idx.size > 0
        return cls(scenario, cols, target, t_brake, int(stop_idx[0]) if stopped else len(t) - 1, stopped,
                   **kw)

    @classmethod
    def from_folder(cls, folder: Path) -> RunView:
        """The view of a run folder of `railhil run` (run.json, truth.csv, the trace), read back."""

        folder = Path(folder)
        try:
            meta = json.loads((folder / "run.json").read_text())
            scenario = scenario_model().model_validate(meta["scenario"])
        except (OSError, ValueError, KeyError) as exc:
            raise RailhilError(f"{folder}: not a run folder of `railhil run` (run.json): "
                               f"{' '.join(str(exc).split())}") from None
        cols = read_truth_csv(folder / "truth.csv")
        db = load_dbc(Path(scenario.dbc) if scenario.dbc else DEFAULT_DBC)
        codec = Codec(db)
        trace, clock = run_trace(folder, meta)
        decoded = read_run_trace(trace, db, codec) if trace.exists() else None
        wanted = {"r0": ("BCU_DEMAND", "TargetDecel")}
        target = (read_signals(decoded, db, codec, wanted, clock)["r0"] if decoded is not None
                  else NO_SIGNAL)
        return cls.of(scenario, cols, target, None, out_dir=folder, trace=trace, db=db, codec=codec,
                      clock=clock, mode=meta.get("mode", "lockstep"), decoded=decoded)

    @property
    def t(self) -> np.ndarray:
        return self.cols["t_s"]

    def target_at(self, t: np.ndarray | None = None) -> np.ndarray:
        """The demanded deceleration r⁰ at the truth samples (0 before the first BCU_DEMAND frame)."""
        t = self.t if t is None else t
        tt, tv = self.target
        return np.interp(t, tt, tv, left=0.0) if tt.size else np.zeros_like(t)

    def signals(self, wanted: dict[str, tuple[str, str]]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """name -> (message, signal) in; name -> (simulated times [s], values) out, from the trace read
        once.  Empty arrays where there is no trace, the DBC lacks the message, or a real-time trace came
        without its t0 (wall-clock timestamps cannot be aligned with the truth)."""
        key = tuple(sorted(wanted.items()))
        if key in self._cache:
            return self._cache[key]
        empty = {name: NO_SIGNAL for name in wanted}
        if self.decoded is None:
            if self.trace is None or not self.trace.exists() or self.db is None or self.codec is None:
                return empty
            self.decoded = read_run_trace(self.trace, self.db, self.codec)
        sig = read_signals(self.decoded, self.db, self.codec, wanted,
                           LOCKSTEP_CLOCK if self.clock is None else self.clock)
        end = float(self.t[-1]) + 1.0 if len(self.t) else 0.0
        if self.clock is None and any(ts.size and ts[0] > end for ts, _ in sig.values()):
            sig = empty
        self._cache[key] = sig
        return sig


def compute_kpis(scenario: Scenario, cols: dict[str, np.ndarray], target: tuple[np.ndarray, np.ndarray],
                 brake_start_s: float | None, frames_sent: dict[str, int], frames_recorded: int,
                 in_flight: int = 0, overwritten: int = 0, faulted: int = 0) -> dict:
    """The train's KPIs from the truth columns, the demand (BCU_DEMAND.TargetDecel from the trace) and the
    frame counts; every figure is defined by the code below and listed in docs/reports.md."""
    n = scenario.train.cars
    t = cols["t_s"]
    x = per_car(cols, "x_m", n)
    v = per_car(cols, "v_mps", n)
    a = per_car(cols, "a_mps2", n)
    slip = per_car(cols, "slip_speed_mps", n)
    ratio = per_car(cols, "slip_ratio", n)
    wsp = per_car(cols, "wsp_valve", n)
    masses = np.asarray(run_params(scenario).plant.train.masses_kg)
    t_brake = brake_start_s if brake_start_s is not None else float(t[0])
    moving = v > MOVING_MPS

    stop_idx = np.flatnonzero(np.all(v < STANDSTILL_MPS, axis=1) & (t >= t_brake))
    stopped = stop_idx.size > 0
    i_stop = int(stop_idx[0]) if stopped else len(t) - 1
    x_brake = float(np.interp(t_brake, t, x[:, 0]))
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0

    # train deceleration (mass-weighted) against the BCU's target, while the train moves after braking
    train_decel = -(a @ masses) / masses.sum()
    tt, tv = target
    target_at = np.interp(t, tt, tv, left=0.0) if tt.size else np.zeros_like(t)
    judged = (t >= t_brake) & np.any(moving, axis=1)
    decel_err = np.abs(target_at - train_decel)[judged]

    vent = wsp == 2
    activations = np.sum(vent[1:] & ~vent[:-1], axis=0) + vent[0]
    kpis = {
        "stopped": bool(stopped),
        "brake_start_s": round(t_brake, 6),
        "stopping_distance_m": round(float(x[i_stop, 0]) - x_brake, 3),
        "time_to_stop_s": round(float(t[i_stop]) - t_brake, 3) if stopped else None,
        "max_slip_speed_mps": [round(float(s), 4) for s in np.max(np.where(moving, slip, 0.0), axis=0)],
        "max_slip_ratio": [round(float(s), 4) for s in np.max(np.where(moving, ratio, 0.0), axis=0)],
        "wsp_activations": [int(k) for k in activations],
        "wsp_time_s": [round(float(k) * dt, 3) for k in np.sum(vent | (wsp == 1), axis=0)],
        # no BCU_DEMAND in the trace (the preview study's paper mode has no BCU): no target to judge against
        "mean_abs_decel_error_mps2": (round(float(decel_err.mean()), 4) if decel_err.size and tt.size
                                      else None),
        "frames_sent": int(sum(frames_sent.values())),
        "frames_recorded": int(frames_recorded),          # in the trace
        "frames_in_flight": int(in_flight),               # queued or on the wire at the end
        "frames_overwritten": int(overwritten),           # replaced in a full transmit queue
        "frames_faulted": int(faulted),                   # added (+) / removed (-) by injected faults
        "frames_lost": int(sum(frames_sent.values())) + faulted - int(frames_recorded) - in_flight
        - overwritten,
        "frames_sent_by_node": dict(frames_sent),
    }
    if n > 1:
        dl = np.column_stack([cols[f"coupler_dl_m_{i}"] for i in range(1, n)])
        kpis["max_abs_coupler_dl_m"] = round(float(np.max(np.abs(dl))), 4)
    return kpis


def study_kpis(run: RunView) -> dict:
    """The KPIs of every study that is part of the run, by study name (hil/studies/<name>/kpis.py
    `kpis(run) -> dict | None`)."""
    out = {}
    for study in registry.active(run.scenario):
        k = study.part("kpis").kpis(run)
        if k is not None:
            out[study.name] = k
    return out


def write_kpis(kpis: dict, path: Path) -> None:
    path.write_text(json.dumps(kpis, indent=2, sort_keys=True) + "\n")
