"""`railhil trace diff A B --dbc DBC` — signal-by-signal comparison of two traces (the golden-trace check).

Frames are paired per message by order of occurrence: the k-th frame of a message in A with the k-th
frame of the same message (same id, same 11/29-bit kind, same data/remote/error kind) in B.  For
every pair:

- timestamps: |t_B − t_A| > --time-tolerance counts as a timing difference, each time on its trace's
  time base (hil.cli.trace.timebase: a run's trace from the run's start, any other from its first
  frame, as recorded with --absolute), or each relative to its first frame in the window with
  ``--align start``;
- a message the DBC knows: each signal is decoded on both sides; |Δ| = |value_B − value_A| in the
  signal's DBC unit, > its tolerance counts as a difference (NaN equals NaN; NaN against a number is
  |Δ| = inf).  A pair in which only one side carries a signal (another multiplexer value) counts as
  unpaired.  A pair in which either side does not decode is compared raw;
- ids the DBC does not know, remote frames (DLC) and error frames: raw payload (DLC and data bytes).

Also reported: frame counts per message that differ, and messages present in one trace only.  Times
reported (first_over_s ...) are trace A's, on its time base, in seconds; --start/--end select the
frames of both traces, each on its own time base.

Exit 0 when the traces are equal within tolerance, 1 when they differ (a verdict, not an error), 2
for bad input.  The traces are read once, side by side in time order, so memory stays small when
they are alike.
"""

from __future__ import annotations

import argparse
import heapq
import json
import math
import sys
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can

from hil.can.codec import Codec, FrameCodec
from hil.can.dbc import load_dbc
from hil.cli.trace.common import (
    Output,
    TraceArgError,
    id_text,
    jsonable,
    kind_of,
    lookup,
    notice_skipped,
    num,
    resolve_signal,
)
from hil.cli.trace.timebase import TimeBase, add_time_arguments
from hil.trace.readers import open_trace

FORMAT_CHOICES = ("table", "json")


def add_parser(tsub: argparse._SubParsersAction) -> None:
    p = tsub.add_parser(
        "diff",
        help="compare two traces signal by signal (exit 0 equal within tolerance, 1 differ)",
        description="Compare trace B against trace A. Per message, the k-th frame in A is paired with "
                    "the k-th in B. Per signal: pairs compared, max |Δ| (DBC unit), pairs over "
                    "tolerance and the first time (A's timestamp) where |Δ| > tolerance. Also: frame "
                    "counts that differ, timestamps that differ by more than --time-tolerance, ids "
                    "in one trace only, raw payload differences for ids the DBC does not know. Exit 0 "
                    "if equal within tolerance, 1 if they differ, 2 for bad input. Golden traces: "
                    "--signal-tolerance CHECKSUM=inf ignores a signal.",
    )
    p.add_argument("a", metavar="A",
                   help="reference trace (the golden one), or '-' for candump text on stdin")
    p.add_argument("b", metavar="B", help="trace compared against A")
    p.add_argument("--dbc", type=Path, default=None,
                   help="DBC file; without it every frame is compared raw (DLC and data bytes)")
    p.add_argument("--tolerance", type=float, default=0.0, metavar="ABS",
                   help="allowed |Δ| of every signal, in its DBC unit (default 0: exactly equal)")
    p.add_argument("--signal-tolerance", action="append", default=[], metavar="NAME=ABS",
                   help="allowed |Δ| of one signal (NAME: every message carrying it; MESSAGE.NAME: that "
                        "one); 'inf' ignores the signal; repeatable")
    p.add_argument("--time-tolerance", type=float, default=0.0, metavar="S",
                   help="allowed |t_B − t_A| of paired frames, seconds (default 0; 'inf' ignores timing)")
    p.add_argument("--align", choices=("none", "start"), default="none",
                   help="none: compare the times on each trace's time base (default: a run's trace from "
                        "the run's start, any other from its first frame; --absolute: as recorded); "
                        "start: each relative to its first frame in the window")
    add_time_arguments(p)
    p.add_argument("--format", choices=FORMAT_CHOICES, default="table",
                   help="table: the messages and signals that differ and a summary line (default); "
                        "json: every message and signal")
    p.add_argument("--all", action="store_true",
                   help="table: list every message and signal, not only those that differ")
    p.set_defaults(func=run)


# --- comparison --------------------------------------------------------------------------------


def abs_delta(a: float, b: float) -> float:
    """|b − a|; NaN equals NaN, NaN against a number is inf, inf equals inf of the same sign."""
    if a == b:
        return 0.0
    d = abs(b - a)
    if math.isnan(d):
        return 0.0 if math.isnan(a) and math.isnan(b) else math.inf
    return d


@dataclass
class SignalDiff:
    """One signal of one message, compared over the frame pairs (values in the signal's DBC unit)."""

    name: str
    unit: str
    tolerance: float
    compared: int = 0                  # pairs in which both frames carry the signal
    max_abs_delta: float = 0.0
    over: int = 0                      # pairs with |Δ| > tolerance
    first_over_s: float | None = None  # A's timestamp of the first of them
    first_over_a: float | None = None  # the values there
    first_over_b: float | None = None
    unpaired: int = 0                  # pairs in which only one frame carries it (multiplexing)

    @property
    def differs(self) -> bool:
        return self.over > 0 or self.unpaired > 0

    def add(self, a: float | None, b: float | None, t: float) -> None:
        if a is None or b is None:
            if a is not None or b is not None:
                self.unpaired += 1
            return
        self.compared += 1
        d = abs_delta(a, b)
        if d > self.max_abs_delta:
            self.max_abs_delta = d
        if d > self.tolerance:
            self.over += 1
            if self.first_over_s is None:
                self.first_over_s, self.first_over_a, self.first_over_b = t, a, b

    def as_dict(self) -> dict:
        return {"signal": self.name, "unit": self.unit, "tolerance": jsonable(self.tolerance),
                "compared": self.compared, "max_abs_delta": jsonable(self.max_abs_delta), "over": self.over,
                "first_over_s": self.first_over_s,
                "first_over_a": None if self.first_over_a is None else jsonable(self.first_over_a),
                "first_over_b": None if self.first_over_b is None else jsonable(self.first_over_b),
                "unpaired": self.unpaired}


@dataclass
class MessageDiff:
    """One message (id, 11/29-bit, data/remote/error) compared between the traces."""

    kind: str
    arbitration_id: int
    extended: bool
    fc: FrameCodec | None
    frames_a: int = 0
    frames_b: int = 0
    pairs: int = 0
    time_over: int = 0                     # pairs with |t_B − t_A| > time tolerance
    max_abs_dt: float = 0.0                # seconds
    first_time_over_s: float | None = None
    raw_differ: int = 0                    # pairs with different DLC/data, where compared raw
    first_raw_differ_s: float | None = None
    failed_a: int = 0                      # frames of a DBC message that did not decode
    failed_b: int = 0
    signals: dict[str, SignalDiff] = field(default_factory=dict)

    @property
    def id(self) -> str:
        return "" if self.kind == "error" else id_text(self.arbitration_id, self.extended)

    @property
    def name(self) -> str:
        if self.fc is not None:
            return self.fc.name
        return "" if self.kind == "data" else f"({self.kind})"

    @property
    def only_in(self) -> str | None:
        if self.frames_b == 0:
            return "A"
        if self.frames_a == 0:
            return "B"
        return None

    def sort_key(self) -> tuple:
        return (self.kind == "error", self.extended, self.arbitration_id, self.kind)

    @property
    def signals_differ(self) -> int:
        return sum(s.differs for s in self.signals.values())

    @property
    def differs(self) -> bool:
        return (self.frames_a != self.frames_b or self.time_over > 0 or self.raw_differ > 0
                or self.signals_differ > 0)

    def as_dict(self) -> dict:
        return {"id": self.id, "name": self.fc.name if self.fc is not None else None, "kind": self.kind,
                "frames_a": self.frames_a, "frames_b": self.frames_b, "pairs": self.pairs,
                "only_in": self.only_in, "time_over": self.time_over, "max_abs_dt_s": self.max_abs_dt,
                "first_time_over_s": self.first_time_over_s, "raw_differ": self.raw_differ,
                "first_raw_differ_s": self.first_raw_differ_s, "decode_failed_a": self.failed_a,
                "decode_failed_b": self.failed_b,
                "signals": [s.as_dict() for s in self.signals.values()]}


@dataclass
class Tolerances:
    default: float
    by_signal: dict[str, float]            # bare NAME=ABS
    by_message_signal: dict[str, float]    # MESSAGE.NAME=ABS

    def of(self, message: str, signal: str) -> float:
        return self.by_message_signal.get(f"{message}.{signal}", self.by_signal.get(signal, self.default))


def parse_signal_tolerance(item: str) -> tuple[str, float]:
    """``NAME=ABS`` or ``MESSAGE.NAME=ABS`` -> (name, ABS), ABS >= 0 or inf."""
    name, sep, text = item.partition("=")
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not sep or not name or math.isnan(value) or value < 0:
        raise TraceArgError(f"--signal-tolerance {item!r}: expected NAME=ABS or MESSAGE.NAME=ABS with ABS "
                            f"an absolute tolerance >= 0 in the signal's unit (a number, or inf)")
    return name, value


def tolerances(args: argparse.Namespace, codec: Codec | None) -> Tolerances:
    if not (args.tolerance >= 0):  # also NaN
        raise TraceArgError(f"--tolerance {args.tolerance}: expected an absolute tolerance >= 0")
    if not (args.time_tolerance >= 0):
        raise TraceArgError(f"--time-tolerance {args.time_tolerance}: expected seconds >= 0")
    if args.signal_tolerance and codec is None:
        raise TraceArgError("--signal-tolerance needs --dbc (the signals are the DBC's)")
    tol = Tolerances(args.tolerance, {}, {})
    problems = []
    for item in args.signal_tolerance:
        name, abs_tol = parse_signal_tolerance(item)
        try:
            resolve_signal(codec, name, allow_ambiguous=True)
        except TraceArgError as exc:
            problems.append(str(exc))
            continue
        (tol.by_message_signal if "." in name else tol.by_signal)[name] = abs_tol
    if problems:
        raise TraceArgError(f"{args.dbc}: --signal-tolerance: " + "; ".join(problems))
    return tol


def _timed(frames: Iterable[can.Message], side: int, offset: float | None) -> Iterator[tuple]:
    """(aligned time, side, frame); offset None: subtract the first frame's time."""
    for msg in frames:
        if offset is None:
            offset = msg.timestamp
        yield msg.timestamp - offset, side, msg


class TraceDiff:
    """The comparison of trace B against trace A (see the module docstring)."""

    def __init__(self, codec: Codec | None, tol: Tolerances, time_tolerance: float) -> None:
        self.codec = codec
        self.tol = tol
        self.time_tolerance = time_tolerance
        self.messages: dict[tuple, MessageDiff] = {}

    def run(self, a: Iterable[can.Message], b: Iterable[can.Message], align_start: bool) -> TraceDiff:
        offset = None if align_start else 0.0
        pending: dict[tuple, tuple[deque, deque]] = {}
        merged = heapq.merge(_timed(a, 0, offset), _timed(b, 1, offset), key=lambda item: item[0])
        for t_aligned, side, msg in merged:
            kind = kind_of(msg)
            if kind == "error":  # error frames carry no meaningful id: one row for them all
                key = (kind, 0, False)
            else:
                key = (kind, msg.arbitration_id, bool(msg.is_extended_id))
            md = self.messages.get(key)
            if md is None:
                md = self.messages[key] = MessageDiff(*key, lookup(self.codec, msg))
                pending[key] = (deque(), deque())
            queues = pending[key]
            if side == 0:
                md.frames_a += 1
            else:
                md.frames_b += 1
            other = queues[1 - side]
            if other:
                t_other, msg_other = other.popleft()
                if side == 0:
                    self.compare(md, t_aligned, msg, t_other, msg_other)
                else:
                    self.compare(md, t_other, msg_other, t_aligned, msg)
            else:
                queues[side].append((t_aligned, msg))
        return self

    def compare(self, md: MessageDiff, ta: float, ma: can.Message, tb: float, mb: can.Message) -> None:
        md.pairs += 1
        t = ma.timestamp
        dt = abs(tb - ta)
        if dt > md.max_abs_dt:
            md.max_abs_dt = dt
        if dt > self.time_tolerance:
            md.time_over += 1
            if md.first_time_over_s is None:
                md.first_time_over_s = t
        fc = md.fc
        if fc is not None:
            va = vb = None
            try:
                va = fc.decode(bytes(ma.data))
            except Exception:  # FrameError, or what cantools raises on a multiplexed message
                md.failed_a += 1
            try:
                vb = fc.decode(bytes(mb.data))
            except Exception:
                md.failed_b += 1
            if va is not None and vb is not None:
                signals = md.signals
                for name in fc.signal_names:
                    sd = signals.get(name)
                    if sd is None:
                        unit = fc.message.get_signal_by_name(name).unit or ""
                        sd = signals[name] = SignalDiff(name, unit, self.tol.of(fc.name, name))
                    sd.add(va.get(name), vb.get(name), t)
                return
        if md.kind == "error":  # nothing to compare but the timestamps
            return
        if ma.dlc != mb.dlc or (md.kind == "data" and bytes(ma.data) != bytes(mb.data)):
            md.raw_differ += 1
            if md.first_raw_differ_s is None:
                md.first_raw_differ_s = t

    # --- verdict ---

    def rows(self) -> list[MessageDiff]:
        return sorted(self.messages.values(), key=MessageDiff.sort_key)

    @property
    def equal(self) -> bool:
        return not any(md.differs for md in self.messages.values())

    def summary(self) -> str:
        rows = self.rows()
        signals = [s for md in rows for s in md.signals.values()]
        pairs = sum(md.pairs for md in rows)
        if self.equal:
            return (f"trace diff: equal within tolerance: {len(rows)} messages, {len(signals)} signals, "
                    f"{pairs} frame pairs compared")
        parts = []
        over = [f"{md.name}.{s.name}" for md in rows for s in md.signals.values() if s.differs]
        if over:
            shown = ", ".join(over[:6]) + (f", ... ({len(over) - 6} more)" if len(over) > 6 else "")
            parts.append(f"{len(over)} of {len(signals)} signals over tolerance ({shown})")
        only = [md for md in rows if md.only_in]
        for side in ("A", "B"):
            ids = [md.id or "error frames" for md in only if md.only_in == side]
            if ids:
                more = ", ..." if len(ids) > 6 else ""
                parts.append(f"{len(ids)} ids only in {side} ({', '.join(ids[:6])}{more})")
        counts = [md for md in rows if md.frames_a != md.frames_b and not md.only_in]
        if counts:
            shown = ", ".join(f"{md.id or md.kind} {md.frames_a}/{md.frames_b}" for md in counts[:6])
            parts.append(f"{len(counts)} ids with different frame counts, A/B ({shown})")
        timed = sum(md.time_over for md in rows)
        if timed:
            parts.append(f"{timed} frame pairs with timestamps more than {self.time_tolerance:g} s apart")
        raw = sum(md.raw_differ for md in rows)
        if raw:
            parts.append(f"{raw} frame pairs with different raw payloads")
        return f"trace diff: DIFFER: {'; '.join(parts)}; {pairs} frame pairs compared"


# --- output ------------------------------------------------------------------------------------


def table(columns: tuple[str, ...], rows: list[dict], left: set[str]) -> list[str]:
    widths = {c: max([len(c), *(len(str(r[c])) for r in rows)]) for c in columns}

    def line(values: dict) -> str:
        return "  ".join(str(values[c]).ljust(widths[c]) if c in left else str(values[c]).rjust(widths[c])
                         for c in columns).rstrip()

    return [line({c: c for c in columns}), *(line(r) for r in rows)]


MESSAGE_COLUMNS = ("id", "name", "frames_a", "frames_b", "pairs", "time_over", "max_dt_ms", "raw_differ",
                   "signals_differ", "note")
SIGNAL_COLUMNS = ("signal", "unit", "compared", "max_abs_delta", "tolerance", "over", "first_over_s",
                  "unpaired")


def table_lines(diff: TraceDiff, show_all: bool) -> list[str]:
    lines = []
    messages = [md for md in diff.rows() if show_all or md.differs]
    if messages:
        rows = [{"id": md.id, "name": md.name, "frames_a": md.frames_a, "frames_b": md.frames_b,
                 "pairs": md.pairs, "time_over": md.time_over, "max_dt_ms": f"{md.max_abs_dt * 1e3:.3f}",
                 "raw_differ": md.raw_differ, "signals_differ": md.signals_differ,
                 "note": f"only in {md.only_in}" if md.only_in else ""} for md in messages]
        lines += ["", "messages" + ("" if show_all else " that differ") + ":"]
        lines += table(MESSAGE_COLUMNS, rows, {"id", "name", "note"})
    signals = [(md, s) for md in diff.rows() for s in md.signals.values() if show_all or s.differs]
    if signals:
        rows = [{"signal": f"{md.name}.{s.name}", "unit": s.unit, "compared": s.compared,
                 "max_abs_delta": f"{s.max_abs_delta:.6g}", "tolerance": f"{s.tolerance:g}", "over": s.over,
                 "first_over_s": num(s.first_over_s, ".6f"), "unpaired": s.unpaired} for md, s in signals]
        lines += ["", "signals" + ("" if show_all else " that differ") + ":"]
        lines += table(SIGNAL_COLUMNS, rows, {"signal", "unit"})
    return lines


def run(args: argparse.Namespace) -> int:
    codec = Codec(load_dbc(args.dbc)) if args.dbc is not None else None
    tol = tolerances(args, codec)
    if args.a == "-" and args.b == "-":
        raise TraceArgError("A and B cannot both be '-' (stdin)")
    base_a, base_b = TimeBase.of(args, args.a), TimeBase.of(args, args.b)
    trace_a, trace_b = open_trace(args.a), open_trace(args.b)
    diff = TraceDiff(codec, tol, args.time_tolerance).run(base_a.messages(trace_a), base_b.messages(trace_b),
                                                           args.align == "start")
    notice_skipped(trace_a)
    notice_skipped(trace_b)
    base_a.warn_outside(trace_a.name)
    base_b.warn_outside(trace_b.name)
    summary = diff.summary()
    out = Output()
    overrides = {**tol.by_signal, **tol.by_message_signal}
    if args.format == "json":
        doc = {"a": trace_a.name, "b": trace_b.name, "frames_a": trace_a.count, "frames_b": trace_b.count,
               "dbc": None if args.dbc is None else str(args.dbc), "tolerance": jsonable(tol.default),
               "signal_tolerances": {k: jsonable(v) for k, v in overrides.items()},
               "time_tolerance_s": jsonable(args.time_tolerance), "align": args.align, "equal": diff.equal,
               "messages": [md.as_dict() for md in diff.rows()], "summary": summary}
        out.write(json.dumps(doc, indent=1) + "\n")
        print(summary, file=sys.stderr)
    else:
        shown = ", ".join(f"{k}={v:g}" for k, v in overrides.items())
        same = base_a.describe() == base_b.describe()
        times = ((f"{base_a.describe()}, both" if same else f"A: {base_a.describe()}; B: {base_b.describe()}")
                 if args.align == "none" else "times from each trace's first frame in the window")
        if base_a.windowed:
            times += f"; frames between {num(args.start, 'g') or '-inf'} and {num(args.end, 'g') or 'inf'} s"
        head = [f"A: {trace_a.name} ({trace_a.count} frames)", f"B: {trace_b.name} ({trace_b.count} frames)",
                f"tolerance {tol.default:g}{f' ({shown})' if shown else ''}, time tolerance "
                f"{args.time_tolerance:g} s; {times}"
                + ("" if codec is not None else ", no DBC: every frame compared raw")]
        for line in [*head, *table_lines(diff, args.all), "", summary]:
            out.write(line + "\n")
    out.flush()
    return 0 if diff.equal else 1
