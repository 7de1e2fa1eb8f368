"""One time base for every trace command: `railhil trace stats|decode|export|plot|diff|replay` and
`railhil timing` read --start/--end and print times in seconds from the same origin.

The origin of a trace:

* a run's trace (a trace file in a run folder, beside its run.json, or any trace with ``--run FOLDER``):
  the run's start, run.json's ``trace_t0_s`` -- 0 in lockstep (the timestamps are simulated seconds),
  the wall clock at the run's start in real time (the timestamps are epoch seconds);
* any other trace: its first frame (in file order);
* with ``--absolute``: none, the timestamps as recorded.

So ``railhil trace decode RUN/trace.blf --start 1.0 --end 1.03`` selects the same 30 ms of a lockstep run
and of its real-time twin.  A window that holds none of the trace's frames is one ``warning:`` line on
stderr (the command still runs, and says what it found).  The run of a trace is read here too
(`RunOfTrace`): `railhil timing` judges only the frames that run's scenario sends.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import can
import numpy as np

from hil.cli.trace.common import TraceArgError, check_window
from hil.runtime.clock import RunClock
from hil.trace.columns import FrameBlock
from hil.trace.readers import STDIN

if TYPE_CHECKING:
    from hil.trace.timing import FrameArrays

__all__ = ["RUN_FILE", "RunOfTrace", "TimeBase", "add_time_arguments", "run_of_trace"]

RUN_FILE = "run.json"     # what makes a folder a run folder (hil.runtime.run.write_run_folder writes it)
#: shifted times are rounded to the ns: an epoch timestamp in float64 is only good to ~0.2 µs, and what the
#: subtraction leaves below the ns is that rounding's noise, not the trace's (0.0023326873779296875 s)
NS_DIGITS = 9


@dataclass(frozen=True)
class RunOfTrace:
    """The run a trace belongs to: its folder and its run.json."""

    folder: Path
    meta: dict

    @property
    def clock(self) -> RunClock:
        """The run's clock: its trace's time base (run.json, hil.runtime.clock.RunClock.of_run)."""
        return RunClock.of_run(self.meta)

    @property
    def t0_s(self) -> float:
        """The trace's timestamp at the run's start (run.json trace_t0_s; 0 in lockstep)."""
        return self.clock.t0_s

    @property
    def scenario(self) -> dict:
        return self.meta.get("scenario") or {}

    @property
    def mode(self) -> str:
        return str(self.meta.get("mode") or "lockstep")

    @property
    def trace(self) -> Path:
        return self.folder / str(self.meta.get("trace") or "trace.blf")

    def describe(self) -> str:
        """The run in a few words: its folder, scenario, mode and train."""
        sc = self.scenario
        cars = (sc.get("train") or {}).get("cars")
        return (f"{self.folder} (scenario {sc.get('name', '?')}, {self.mode}"
                + (f", {cars} cars" if cars else "") + ")")

    def messages_sent(self) -> set[str] | None:
        """The DBC messages the run's nodes send: run.json's messages_sent (hil.runtime.run), else the
        messages its bit-timed lockstep bus carried (bus_timing), else those of the nodes its resolved
        scenario builds (a run folder of an earlier release); None when none of these can be had."""
        sent = self.meta.get("messages_sent")
        if isinstance(sent, dict) and sent:
            return {str(m) for names in sent.values() for m in names}
        carried = (self.meta.get("bus_timing") or {}).get("messages")
        if isinstance(carried, dict) and carried:
            return set(carried)
        return self._built()

    def _built(self) -> set[str] | None:
        """The messages the nodes of run.json's resolved scenario send, built as the run built them."""
        # lazy: trace commands load no scenario, nodes or numba: 190 ms to start, not 465 ms
        from hil.can.codec import loaded_dbc
        from hil.can.dbc import DEFAULT_DBC
        from hil.runtime.assembly import build_node, node_names
        from hil.scenario import scenario_model

        try:
            scenario = scenario_model().model_validate(self.scenario)
            db, codec = loaded_dbc(Path(scenario.dbc) if scenario.dbc else DEFAULT_DBC)
            return {msg for name in node_names(scenario)
                    for msg, _ in build_node(name, scenario, db, codec).binding.tx}
        except Exception:        # a scenario of another release, a device file gone: not known
            return None


def run_of_trace(trace: str | Path, run: Path | None = None) -> RunOfTrace | None:
    """The run of `trace`: the folder `run` (``--run``), else the trace's own folder when it holds a run.json;
    None for a trace of no run (and for stdin).  A --run folder without a readable run.json is a
    TraceArgError."""
    if run is not None:
        folder = Path(run)
        if not (folder / RUN_FILE).is_file():
            raise TraceArgError(f"--run {folder}: not a run folder (no {RUN_FILE}; `railhil run` writes one)")
    elif str(trace) == STDIN:
        return None
    else:
        folder = Path(trace).parent
        if not (folder / RUN_FILE).is_file():
            return None
    try:
        meta = json.loads((folder / RUN_FILE).read_text())
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        if run is None:      # a stray run.json beside a trace: the trace is taken on its own
            why = " ".join(str(exc).split())[:120]
            print(f"notice: {folder / RUN_FILE}: not readable ({why}); the trace is taken on its own",
                  file=sys.stderr)
            return None
        raise TraceArgError(f"--run {folder}: cannot read {RUN_FILE}: {' '.join(str(exc).split())[:160]}"
                            ) from None
    if not isinstance(meta, dict):
        if run is not None:
            raise TraceArgError(f"--run {folder}: {RUN_FILE} is not a run's metadata (a JSON object)")
        return None
    return RunOfTrace(folder, meta)


WINDOW_HELP = ("seconds from the trace's start: a run's trace (run.json beside it) from the run's start, any "
               "other from its first frame; --absolute: the timestamps as recorded")


def add_time_arguments(p: argparse.ArgumentParser, run: bool = False) -> None:
    """--start/--end, --absolute and, with `run`, --run FOLDER: the time base's options."""
    p.add_argument("--start", type=float, default=None, metavar="S",
                   help=f"only frames at or after S ({WINDOW_HELP})")
    p.add_argument("--end", type=float, default=None, metavar="S",
                   help="only frames at or before S (the same time base as --start)")
    p.add_argument("--absolute", action="store_true",
                   help="times as recorded (epoch seconds in a real-time run or a candump capture), in "
                        "--start/--end and in the output, instead of seconds from the trace's start")
    if run:
        p.add_argument("--run", type=Path, default=None, metavar="FOLDER",
                       help="the run folder the trace belongs to (default: the trace's own folder when it "
                            "holds a run.json): times from the run's start, and what the run sends")


class TimeBase:
    """The time base of one trace (module docstring): ``origin`` is subtracted from every timestamp
    (None until the first frame is seen, for a trace of no run), ``start``/``end`` select frames on the
    shifted times.  ``messages``, ``block`` and ``arrays`` shift (and window) frames; ``warn_outside``
    says, once the trace is read, when the window held none of its frames."""

    def __init__(self, start: float | None = None, end: float | None = None, absolute: bool = False,
                 run: RunOfTrace | None = None) -> None:
        check_window(start, end)
        self.start, self.end = start, end
        self.absolute = absolute
        self.run = run
        self.origin: float | None = 0.0 if absolute else (run.t0_s if run is not None else None)
        self.first: float | None = None         # the first and last frame on the base (every frame read)
        self.last: float | None = None
        self.selected = 0                       # frames within the window

    @classmethod
    def of(cls, args: argparse.Namespace, trace: str | Path) -> TimeBase:
        """The time base of `trace` from a command's options (--start, --end, --absolute, --run)."""
        run = run_of_trace(trace, getattr(args, "run", None))
        return cls(getattr(args, "start", None), getattr(args, "end", None), args.absolute, run)

    @property
    def windowed(self) -> bool:
        return self.start is not None or self.end is not None

    @property
    def shifted(self) -> bool:
        return bool(self.origin)

    def bind(self, first_t: float) -> float:
        """The origin, taken from the first frame's timestamp `first_t` when the trace has no run."""
        if self.origin is None:
            self.origin = float(first_t)
        return self.origin

    def describe(self) -> str:
        """What the times are, for a header or a summary line."""
        if self.absolute:
            return "times as recorded"
        if self.run is not None:
            return (f"times from the run's start: t0 = {self.run.t0_s:.6f} s in {self.run.folder / RUN_FILE}"
                    if self.run.t0_s else f"times from the run's start, as recorded ({self.run.mode})")
        if self.origin:
            return f"times from the first frame: t0 = {self.origin:.6f} s"
        return "times from the first frame"

    def axis_label(self) -> str:
        """A plot's time axis label."""
        if self.absolute:
            return "time [s] (as recorded)"
        where = "the run's start" if self.run is not None else "the first frame"
        return f"time [s] from {where}" + (f" (t0 = {self.origin:.6f} s)" if self.origin else "")

    def _see(self, t_first: float, t_last: float) -> None:
        self.first = t_first if self.first is None else min(self.first, t_first)
        self.last = t_last if self.last is None else max(self.last, t_last)

    def _inside(self, t: float) -> bool:
        return not ((self.start is not None and t < self.start) or (self.end is not None and t > self.end))

    # --- the frames, shifted ----------------------------------------------------------------------------

    def messages(self, frames: Iterable[can.Message], window: bool = True) -> Iterator[can.Message]:
        """The frames with their timestamps on the base (changed in place: the reader made them), those
        outside the window left out (`window` False: every one)."""
        for msg in frames:
            if self.origin is None:
                self.bind(msg.timestamp)
            if self.origin:
                msg.timestamp = round(float(msg.timestamp) - self.origin, NS_DIGITS)
            t = msg.timestamp
            self._see(t, t)
            if self._inside(t):
                self.selected += 1
            elif window:
                continue
            yield msg

    def block(self, block: FrameBlock, window: bool = False) -> FrameBlock:
        """`block` with its times on the base (a candump block's own texts of its timestamps dropped when
        they shift); `window`: only its rows within the window."""
        if not len(block):
            return block
        if self.origin is None:
            self.bind(block.message(0).timestamp if block.special is not None and block.special[0]
                      else float(block.t[0]))
        if self.origin:
            t = block.t.copy()
            if block.special is not None:           # timestamps that are not floats: the Messages have them
                for i in np.flatnonzero(block.special).tolist():
                    t[i] = float(block.messages[i].timestamp)
            if block.messages is not None:          # python-can's Messages, read for this block only
                for msg in block.messages:
                    if msg is not None:
                        msg.timestamp = round(float(msg.timestamp) - self.origin, NS_DIGITS)
            block = replace(block, t=np.round(t - self.origin, NS_DIGITS), stamps=None, special=None)
        t = block.t
        keep = self._window(t)
        if window and not keep.all():
            block = block.take(np.flatnonzero(keep))
        return block

    def _window(self, t: np.ndarray) -> np.ndarray:
        """Which of the times `t` (on the base) lie in the window; counted, and the span seen noted."""
        self._see(float(t.min()), float(t.max()))
        keep = np.ones(len(t), dtype=bool)
        if self.start is not None:
            keep &= t >= self.start
        if self.end is not None:
            keep &= t <= self.end
        self.selected += int(keep.sum())
        return keep

    def arrays(self, arrays: FrameArrays) -> FrameArrays:
        """The frames of `arrays` within the window, their times on the base."""
        if not len(arrays):
            return arrays
        self.bind(float(arrays.t[0]))
        t = np.round(arrays.t - self.origin, NS_DIGITS) if self.origin else arrays.t
        keep = self._window(t)
        if keep.all() and not self.origin:
            return arrays
        return replace(arrays, t=t[keep], arbitration_id=arrays.arbitration_id[keep],
                       extended=arrays.extended[keep], dlc=arrays.dlc[keep], kind=arrays.kind[keep],
                       fd=arrays.fd[keep])

    # --- the window against the trace ----------------------------------------------------------------------

    def outside(self) -> bool:
        """Whether a window was given and none of the trace's frames fell in it (known once it is read)."""
        return self.windowed and self.first is not None and self.selected == 0

    def warn_outside(self, name: str) -> None:
        """One warning line on stderr when the window held none of the trace's frames."""
        if not self.outside():
            return
        lo = "-inf" if self.start is None else f"{self.start:.15g}"
        hi = "inf" if self.end is None else f"{self.end:.15g}"
        span = f"{self.first:.6f} to {self.last:.6f} s"
        hint = ""
        if not self.absolute and self.origin and min(abs(x) for x in (self.start, self.end)
                                                     if x is not None) > 1e8:
            hint = "; those look like recorded timestamps: add --absolute"
        elif self.absolute and self.first is not None and abs(self.first) > 1e8:
            hint = "; without --absolute, times are seconds from the trace's start"
        print(f"warning: {name}: no frame between {lo} and {hi} s: the trace runs from {span}, "
              f"{self.describe()}{hint}", file=sys.stderr)
