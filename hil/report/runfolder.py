"""Run folders and traces in Python, for notebooks: `hil.open_run(PATH)` and `hil.open_trace(PATH, dbc=...)`.

    import hil
    run = hil.open_run("runs/default-lockstep-20261201-120000")
    run.kpis["stopping_distance_m"]
    run.truth[["v_mps_1", "p_Pa_1"]].plot()                  # the plant's ground truth, by time
    run.signal("BCU_DEMAND.TargetDecel").plot(drawstyle="steps-post")
    run.signals("TargetDecel", "PLANT_CAR1_SENSORS.CylPressure")   # one DataFrame, by time
    run.message("BCU_STATUS")                                # every signal of one message
    run.frames                                               # the raw frames

Times: a run's are simulated seconds (a real-time trace's wall-clock timestamps are taken back to the
run's start with the run's clock from run.json, hil.runtime.clock.RunClock.of_run), so truth and signals
share one axis; a trace opened on its own keeps its own timestamps.  The trace is read once, through the
fast column readers (hil.trace.columns), and each message decoded once, on first use (hil.trace.decoded).
A signal is named `MESSAGE.Signal`, or `Signal` alone where one message of the DBC has it.
"""

from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path

import numpy as np

from hil.can.codec import Codec
from hil.can.dbc import DEFAULT_DBC, closest, load_dbc
from hil.errors import RailhilError
from hil.report.kpis import run_trace
from hil.runtime.clock import LOCKSTEP_CLOCK, RunClock
from hil.runtime.truth import read_truth_csv
from hil.scenario import scenario_model
from hil.trace.decoded import DecodedTrace


class RunFolderError(RailhilError, ValueError):
    """A folder that is not a run folder, or a signal name the DBC does not have."""


class TraceView:
    """A trace with its DBC: `.frames`, `.signal()`, `.signals()`, `.message()` (module docstring)."""

    def __init__(self, path: str | Path, dbc: str | Path | None = None,
                 clock: RunClock = LOCKSTEP_CLOCK) -> None:
        self.path = Path(path)
        self.dbc_path = Path(dbc) if dbc is not None else DEFAULT_DBC
        self.db = load_dbc(self.dbc_path)
        self._clock = clock

    @cached_property
    def decoded(self) -> DecodedTrace:
        return DecodedTrace.read(self.path, self.db, Codec(self.db))

    def _time(self, t: np.ndarray) -> np.ndarray:
        return self._clock.simulated_s(t)

    @cached_property
    def frames(self):
        """Every frame: t [s], id, extended, remote, error, dlc, data (bytes), message (the DBC's name or
        "")."""
        import pandas as pd

        f = self.decoded.frames
        names = {(m.frame_id, bool(m.is_extended_frame)): m.name for m in self.db.messages}
        ids, ext = f.arbitration_id.tolist(), f.extended.tolist()
        return pd.DataFrame({
            "t": self._time(f.t), "id": f.arbitration_id, "extended": f.extended, "remote": f.remote,
            "error": f.error, "dlc": f.dlc,
            "data": [f.payload[i, : f.length[i]].tobytes() for i in range(len(f))],
            "message": [names.get(k, "") for k in zip(ids, ext, strict=True)],
        })

    def _resolve(self, ref: str) -> tuple[str, str]:
        """(message, signal) of "MESSAGE.Signal" or a bare "Signal" that one message has."""
        message, _, signal = ref.rpartition(".")
        if message:
            try:
                msg = self.db.get_message_by_name(message)
            except KeyError:
                raise RunFolderError(f"{ref!r}: no message {message!r} in {self.dbc_path} (closest: "
                                     f"{closest(message, [m.name for m in self.db.messages])})") from None
            if signal not in [s.name for s in msg.signals]:
                raise RunFolderError(f"{ref!r}: {message} has no signal {signal!r} (closest: "
                                     f"{closest(signal, [s.name for s in msg.signals])})")
            return message, signal
        owners = [m.name for m in self.db.messages if any(s.name == signal for s in m.signals)]
        if len(owners) == 1:
            return owners[0], signal
        if owners:
            raise RunFolderError(f"{ref!r}: {len(owners)} messages have it ({', '.join(owners[:4])}"
                                 f"{', ...' if len(owners) > 4 else ''}); name it MESSAGE.{signal}")
        every = sorted({s.name for m in self.db.messages for s in m.signals})
        raise RunFolderError(f"{ref!r}: no signal of that name in {self.dbc_path} (closest: "
                             f"{closest(signal, every)})")

    def message(self, name: str):
        """Every signal of one message: a DataFrame indexed by time [s], one column per signal (physical
        values; NaN where a multiplexed frame does not carry the signal)."""
        import pandas as pd

        try:
            table = self.decoded.table(name)
        except KeyError:
            raise RunFolderError(f"{name!r}: no message of that name in {self.dbc_path} (closest: "
                                 f"{closest(name, [m.name for m in self.db.messages])})") from None
        frame = pd.DataFrame(table.columns, index=pd.Index(self._time(table.t), name="t"))
        frame.attrs["units"] = dict(table.units)
        frame.attrs["choices"] = {k: dict(v) for k, v in table.choices.items()}
        return frame

    def signal(self, ref: str):
        """One signal as a Series indexed by time [s], named "MESSAGE.Signal", its unit in .attrs."""
        message, signal = self._resolve(ref)
        frame = self.message(message)
        series = frame[signal].dropna().rename(f"{message}.{signal}")
        series.attrs = {"unit": frame.attrs["units"].get(signal, ""),
                        "choices": frame.attrs["choices"].get(signal, {})}
        return series

    def signals(self, *refs: str):
        """Several signals in one DataFrame indexed by time [s], a column "MESSAGE.Signal" each, joined
        on time (NaN where a signal's message has no frame at that instant)."""
        import pandas as pd

        if not refs:
            raise RunFolderError("signals(): name at least one signal, e.g. "
                                 "signals('BCU_DEMAND.TargetDecel')")
        series = [self.signal(r) for r in refs]
        frame = pd.concat(series, axis=1).sort_index()
        frame.attrs["units"] = {s.name: s.attrs.get("unit", "") for s in series}
        return frame


class RunFolder(TraceView):
    """A run folder of `railhil run`: `.scenario`, `.kpis`, `.meta` (run.json), `.truth`, and the trace's
    `.frames`, `.signal()`, `.signals()`, `.message()` in simulated time (module docstring)."""

    def __init__(self, path: str | Path) -> None:
        folder = Path(path)
        try:
            meta = json.loads((folder / "run.json").read_text())
            kpis = json.loads((folder / "kpis.json").read_text())
        except FileNotFoundError as exc:
            raise RunFolderError(f"{folder}: not a run folder of `railhil run` (no {Path(exc.filename).name})"
                                 ) from None
        except (OSError, ValueError) as exc:
            raise RunFolderError(f"{folder}: cannot read the run folder: "
                                 f"{' '.join(str(exc).split())}") from None

        self.folder, self.meta, self.kpis = folder, meta, kpis
        self.scenario = scenario_model().model_validate(meta["scenario"])
        trace, clock = run_trace(folder, meta)
        super().__init__(trace, meta.get("dbc") or None, clock=clock)

    @cached_property
    def truth(self):
        """The plant's ground truth (truth.csv): a DataFrame indexed by simulated time t_s [s], the columns
        `<quantity>_<car>` in SI units (v_mps_1, p_Pa_1, slip_speed_mps_1, ...)."""
        import pandas as pd

        cols = read_truth_csv(self.folder / "truth.csv")
        t = cols.pop("t_s")
        return pd.DataFrame(cols, index=pd.Index(t, name="t_s"))

    def __repr__(self) -> str:
        return (f"RunFolder({str(self.folder)!r}: {self.scenario.name}, {self.meta.get('mode')}, seed "
                f"{self.scenario.seed}, {self.kpis.get('simulated_s')} s simulated)")


def open_run(path: str | Path) -> RunFolder:
    """A run folder of `railhil run` (lockstep or real time) in Python."""
    return RunFolder(path)


def open_trace(path: str | Path, dbc: str | Path | None = None) -> TraceView:
    """Any trace python-can reads (BLF, MF4, ASC, candump .log, ...) with a DBC (default: railhil's
    train_brake.dbc), in its own timestamps."""
    return TraceView(path, dbc)
