"""`railhil trace stats|decode TRACE` — what is on a recorded CAN trace, and what it means per the DBC.

Any trace python-can reads (.asc .blf .csv .db .log .mf4 .trc, also .gz compressed; '-' = candump -L
text on stdin).  Times are the trace's own timestamps, in seconds, everywhere: in the output and in
--start/--end (``trace stats`` shows the first and last).  Ids print as candump does: 3 hex digits
for an 11-bit id, 8 for a 29-bit one, so the two never mix.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can

from hil.codec import Codec, FrameCodec
from hil.dbc import closest, load_dbc
from hil.errors import RailhilError
from hil.traceio import Trace, open_trace

FORMAT_CHOICES = ("table", "csv", "jsonl")


class TraceArgError(RailhilError, ValueError):
    """A trace command option that names something the DBC or the syntax does not have."""


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "trace",
        help="inspect a recorded CAN trace: per-id statistics, DBC decoding",
        description="Inspect a CAN trace that python-can reads (.asc .blf .csv .db .log .mf4 .trc, "
                    "also .gz compressed; '-' reads candump -L text from stdin).",
    )
    tsub = p.add_subparsers(dest="trace_command", metavar="ACTION")
    tsub.required = True

    s = tsub.add_parser(
        "stats",
        help="frames per arbitration id: count, rate, period, DLCs, first/last time",
        description="One row per arbitration id (11-bit and 29-bit apart; remote frames and error "
                    "frames on rows of their own), sorted by id. rate_hz = count / trace duration; "
                    "period_ms = mean time between this id's frames. The header line (total frames, "
                    "duration, file) goes to stdout with --format table, to stderr with csv/jsonl.",
    )
    s.add_argument("trace", help="trace file, or '-' for candump -L text on stdin")
    s.add_argument("--dbc", type=Path, default=None, help="DBC file: adds the message names")
    s.add_argument("--format", choices=FORMAT_CHOICES, default="table", help="output format (default table)")
    s.set_defaults(func=stats)

    d = tsub.add_parser(
        "decode",
        help="decode the frames of a trace with a DBC",
        description="Decode each frame with the DBC. table: one line per frame, signals as name=value; "
                    "csv: one row per (frame, signal) with columns t,id,name,signal,value,error; "
                    "jsonl: one object per frame {t, id, name, signals}. Frames of ids the DBC does "
                    "not know, remote and error frames are shown raw (hex data) unless a filter "
                    "excludes them; a frame that does not decode is shown raw with the reason, "
                    "counted, and decoding goes on. A summary goes to stderr.",
    )
    d.add_argument("trace", help="trace file, or '-' for candump -L text on stdin")
    d.add_argument("--dbc", type=Path, required=True, help="DBC file")
    d.add_argument("--id", dest="ids", action="append", default=[], metavar="ID",
                   help="only frames with this arbitration id, hex (0x123) or decimal; repeatable")
    d.add_argument("--message", dest="messages", action="append", default=[], metavar="NAME",
                   help="only frames of this DBC message; repeatable")
    d.add_argument("--signal", dest="signals", action="append", default=[], metavar="NAME",
                   help="only these signals (and only frames that carry one); repeatable")
    d.add_argument("--start", type=float, default=None, metavar="S",
                   help="only frames with timestamp >= S (the trace's own time, seconds)")
    d.add_argument("--end", type=float, default=None, metavar="S",
                   help="only frames with timestamp <= S (the trace's own time, seconds)")
    d.add_argument("--format", choices=FORMAT_CHOICES, default="table", help="output format (default table)")
    d.set_defaults(func=decode)


# --- helpers ----------------------------------------------------------------------------------


def id_text(arbitration_id: int, extended: bool) -> str:
    return f"0x{arbitration_id:08X}" if extended else f"0x{arbitration_id:03X}"


def parse_id(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise TraceArgError(f"--id {text!r}: expected a CAN id, hex (0x123) or decimal (291)") from None
    if not 0 <= value <= 0x1FFFFFFF:
        raise TraceArgError(f"--id {text!r}: expected a CAN id between 0 and 0x1FFFFFFF")
    return value


def lookup(codec: Codec | None, msg: can.Message) -> FrameCodec | None:
    """The DBC message of a data frame (its id and its 11/29-bit kind must both match)."""
    if codec is None or msg.is_error_frame or msg.is_remote_frame:
        return None
    fc = codec.get(msg.arbitration_id)
    if fc is None or bool(fc.message.is_extended_frame) != bool(msg.is_extended_id):
        return None
    return fc


def kind_of(msg: can.Message) -> str:
    return "error" if msg.is_error_frame else "remote" if msg.is_remote_frame else "data"


def num(value: float | None, fmt: str) -> str:
    return "" if value is None or not math.isfinite(value) else format(value, fmt)


class Output:
    """stdout that stops quietly when the reader goes away (``railhil trace ... | head``)."""

    def __init__(self) -> None:
        self.closed = False

    def write(self, text: str) -> None:
        if not self.closed:
            try:
                sys.stdout.write(text)
            except BrokenPipeError:
                self.pipe_closed()

    def flush(self) -> None:
        if not self.closed:
            try:
                sys.stdout.flush()
            except BrokenPipeError:
                self.pipe_closed()

    def pipe_closed(self) -> None:
        self.closed = True
        # Python flushes stdout at exit; point it at devnull so that flush cannot fail again
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)
        except (OSError, ValueError):  # stdout without a file descriptor (captured in tests)
            pass


def notice_skipped(trace: Trace) -> None:
    if trace.skipped:
        print(f"notice: {trace.name}: python-can skipped {trace.skipped} unreadable lines "
              f"(first: {trace.first_skipped})", file=sys.stderr)


# --- stats ------------------------------------------------------------------------------------


@dataclass
class IdStats:
    arbitration_id: int
    extended: bool
    kind: str
    count: int = 0
    first: float = math.inf
    last: float = -math.inf
    dlcs: set[int] = field(default_factory=set)
    fd: bool = False

    def add(self, msg: can.Message) -> None:
        self.count += 1
        self.first = min(self.first, msg.timestamp)
        self.last = max(self.last, msg.timestamp)
        self.dlcs.add(msg.dlc)
        self.fd = self.fd or msg.is_fd

    def sort_key(self) -> tuple:
        return (self.kind == "error", self.extended, self.arbitration_id, self.kind)

    def period_ms(self) -> float | None:
        return (self.last - self.first) / (self.count - 1) * 1e3 if self.count > 1 else None


STATS_COLUMNS = ("id", "frame", "kind", "name", "count", "rate_hz", "period_ms", "dlc", "first_s", "last_s")


def collect_stats(frames: Iterable[can.Message]) -> tuple[dict[tuple, IdStats], int, float, float]:
    table: dict[tuple, IdStats] = {}
    total, first, last = 0, math.inf, -math.inf
    for msg in frames:
        total += 1
        first = min(first, msg.timestamp)
        last = max(last, msg.timestamp)
        kind = kind_of(msg)
        if kind == "error":  # error frames carry no meaningful id: one row for them all
            key = (0, False, kind)
        else:
            key = (msg.arbitration_id, bool(msg.is_extended_id), kind)
        row = table.get(key)
        if row is None:
            row = table[key] = IdStats(*key)
        row.add(msg)
    return table, total, first, last


def stats(args: argparse.Namespace) -> int:
    codec = Codec(load_dbc(args.dbc)) if args.dbc is not None else None
    trace = open_trace(args.trace)
    table, total, first, last = collect_stats(trace)
    notice_skipped(trace)
    duration = last - first if total else 0.0
    n_err = sum(r.count for r in table.values() if r.kind == "error")
    n_rtr = sum(r.count for r in table.values() if r.kind == "remote")
    name = "<stdin>" if args.trace == "-" else str(args.trace)
    header = (f"{name}: {total} frames ({n_err} error, {n_rtr} remote) over {duration:.6f} s, "
              f"{len({(r.arbitration_id, r.extended) for r in table.values() if r.kind != 'error'})} ids")
    if args.dbc is not None:
        header += f", names from {args.dbc}"
    rows = []
    for r in sorted(table.values(), key=IdStats.sort_key):
        fc = None
        if codec is not None and r.kind != "error":
            fc = codec.get(r.arbitration_id)
            if fc is not None and bool(fc.message.is_extended_frame) != r.extended:
                fc = None
        rate = r.count / duration if duration > 0 else None
        rows.append({
            "id": "" if r.kind == "error" else id_text(r.arbitration_id, r.extended),
            "frame": "" if r.kind == "error" else ("ext" if r.extended else "std") + ("+fd" if r.fd else ""),
            "kind": r.kind,
            "name": fc.name if fc is not None else "",
            "count": r.count,
            "rate_hz": num(rate, ".3f"),
            "period_ms": num(r.period_ms(), ".3f"),
            "dlc": ",".join(str(d) for d in sorted(r.dlcs)),
            "first_s": f"{r.first:.6f}",
            "last_s": f"{r.last:.6f}",
        })
    out = Output()
    if args.format == "table":
        out.write(header + "\n")
        widths = {c: max([len(c), *(len(str(row[c])) for row in rows)]) for c in STATS_COLUMNS}
        left = {"id", "frame", "kind", "name", "dlc"}

        def line(values: dict) -> str:
            cells = [str(values[c]).ljust(widths[c]) if c in left else str(values[c]).rjust(widths[c])
                     for c in STATS_COLUMNS]
            return "  ".join(cells).rstrip() + "\n"

        out.write(line({c: c for c in STATS_COLUMNS}))
        for row in rows:
            out.write(line(row))
    else:
        print(header, file=sys.stderr)
        if args.format == "csv":
            writer = csv.DictWriter(out, fieldnames=STATS_COLUMNS, lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows)
        else:
            for row in rows:
                out.write(json.dumps(row) + "\n")
    out.flush()
    return 0


# --- decode -----------------------------------------------------------------------------------


@dataclass
class Selection:
    ids: set[int] | None
    names: set[str] | None  # message names, from --message and --signal
    signals: set[str] | None

    @property
    def by_dbc(self) -> bool:
        return self.names is not None


def select(args: argparse.Namespace, codec: Codec) -> Selection:
    ids = {parse_id(t) for t in args.ids} or None
    all_names = [fc.name for fc in codec]
    carriers: dict[str, set[str]] = {}  # signal name -> the messages that carry it
    for fc in codec:
        for s in fc.signal_names:
            carriers.setdefault(s, set()).add(fc.name)
    problems = [f"no message named {n!r} (closest: {closest(n, all_names)})"
                for n in args.messages if n not in all_names]
    problems += [f"no signal named {s!r} (closest: {closest(s, list(carriers))})"
                 for s in args.signals if s not in carriers]
    if problems:
        raise TraceArgError(f"{args.dbc}: " + "; ".join(problems))
    names = set(args.messages) or None
    signals = None
    if args.signals:
        signals = set(args.signals)
        with_signal = set().union(*(carriers[s] for s in signals))
        names = with_signal if names is None else names & with_signal
    return Selection(ids, names, signals)


@dataclass
class Row:
    t: float
    id: str
    name: str | None
    signals: dict[str, float] | None
    data: str | None = None
    kind: str = "data"
    error: str | None = None
    dlc: int = 0


def decoded_rows(frames: Iterable[can.Message], codec: Codec, sel: Selection, start: float | None,
                 end: float | None, counts: dict[str, int]) -> Iterator[Row]:
    for msg in frames:
        t = msg.timestamp
        if start is not None and t < start:
            continue
        if end is not None and t > end:
            continue
        if sel.ids is not None and (msg.is_error_frame or msg.arbitration_id not in sel.ids):
            continue
        fc = lookup(codec, msg)
        if sel.by_dbc and (fc is None or fc.name not in sel.names):
            continue
        kind = kind_of(msg)
        ident = "" if msg.is_error_frame else id_text(msg.arbitration_id, msg.is_extended_id)
        data = bytes(msg.data).hex().upper()
        if fc is None:
            counts[kind if kind != "data" else "unknown"] += 1
            yield Row(t, ident, None, None, data, kind, dlc=msg.dlc)
            continue
        try:
            values = fc.decode(bytes(msg.data))
        except Exception as exc:  # FrameError, or whatever cantools raises on a multiplexed message
            counts["failed"] += 1
            yield Row(t, ident, fc.name, None, data, kind, " ".join(str(exc).split()) or type(exc).__name__)
            continue
        if sel.signals is not None:
            values = {k: v for k, v in values.items() if k in sel.signals}
        counts["decoded"] += 1
        yield Row(t, ident, fc.name, values)


def jsonable(value: float) -> float | str:
    return value if math.isfinite(value) else repr(value)  # JSON has no NaN/inf


def decode(args: argparse.Namespace) -> int:
    codec = Codec(load_dbc(args.dbc))
    sel = select(args, codec)
    if args.start is not None and args.end is not None and args.end < args.start:
        raise TraceArgError(f"--end {args.end} is before --start {args.start}")
    frames = open_trace(args.trace)
    counts = {"decoded": 0, "unknown": 0, "remote": 0, "error": 0, "failed": 0}
    out = Output()
    rows = decoded_rows(frames, codec, sel, args.start, args.end, counts)
    if args.format == "csv":
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(("t", "id", "name", "signal", "value", "error"))
        for r in rows:
            if r.signals is None:
                writer.writerow((f"{r.t:.6f}", r.id, r.name or ("" if r.kind == "data" else r.kind), "",
                                 r.data, r.error or ""))
            else:
                for sig, value in r.signals.items():
                    writer.writerow((f"{r.t:.6f}", r.id, r.name, sig, repr(value), ""))
            if out.closed:
                break
    elif args.format == "jsonl":
        for r in rows:
            obj: dict = {"t": r.t, "id": r.id, "name": r.name}
            if r.signals is not None:
                obj["signals"] = {k: jsonable(v) for k, v in r.signals.items()}
            else:
                obj["data"] = r.data
                if r.kind != "data":
                    obj["kind"] = r.kind
                if r.kind == "remote":
                    obj["dlc"] = r.dlc
                if r.error:
                    obj["error"] = r.error
            out.write(json.dumps(obj) + "\n")
            if out.closed:
                break
    else:
        width = max([len(fc.name) for fc in codec] + [6])
        out.write(f"{'t_s':>17}  {'id':<10}  {'name':<{width}}  signals\n")
        for r in rows:
            if r.signals is not None:
                body = " ".join(f"{k}={v:.10g}" for k, v in r.signals.items())
                name = r.name
            else:
                body = {"remote": f"remote frame dlc={r.dlc}", "error": "error frame"}.get(
                    r.kind, f"data={r.data}" + (f"  ({r.error})" if r.error else ""))
                name = r.name or ("?" if r.kind == "data" else r.kind.upper())
            out.write(f"{r.t:17.6f}  {r.id:<10}  {name:<{width}}  {body}\n")
            if out.closed:
                break
    out.flush()
    notice_skipped(frames)
    if not out.closed:
        summary = (f"{counts['decoded']} frames decoded, {counts['unknown']} with ids not in {args.dbc}, "
                   f"{counts['remote']} remote, {counts['error']} error frames, "
                   f"{counts['failed']} failed to decode")
        print(summary, file=sys.stderr)
    return 0
