"""`railhil trace stats TRACE` — frames per arbitration id: count, rate, period, DLCs, first/last time.

Times (first_s, last_s, --start/--end) are on the trace's time base (hil.cli.trace.timebase): seconds from
the run's start for a run's trace, from the first frame for any other, as recorded with --absolute."""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import can

from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.cli.trace.common import Output, id_text, kind_of, notice_skipped, num
from hil.cli.trace.timebase import TimeBase, add_time_arguments
from hil.trace.readers import Salvage, open_trace

FORMAT_CHOICES = ("table", "csv", "jsonl")


def add_parser(tsub: argparse._SubParsersAction) -> None:
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
    add_time_arguments(s)
    s.set_defaults(func=run)


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


def run(args: argparse.Namespace) -> int:
    codec = Codec(load_dbc(args.dbc)) if args.dbc is not None else None
    timebase = TimeBase.of(args, args.trace)
    trace = open_trace(args.trace)
    frames = Salvage(trace)  # a corrupt or cut file: the table of the frames before it, then the error
    table, total, first, last = collect_stats(timebase.messages(frames))
    if total == 0:
        frames.raise_error()  # nothing read: the error alone
    notice_skipped(trace)
    duration = last - first if total else 0.0
    n_err = sum(r.count for r in table.values() if r.kind == "error")
    n_rtr = sum(r.count for r in table.values() if r.kind == "remote")
    name = "<stdin>" if args.trace == "-" else str(args.trace)
    header = (f"{name}: {total} frames ({n_err} error, {n_rtr} remote) over {duration:.6f} s, "
              f"{len({(r.arbitration_id, r.extended) for r in table.values() if r.kind != 'error'})} ids")
    if args.dbc is not None:
        header += f", names from {args.dbc}"
    if timebase.windowed:
        header += f", between {num(args.start, 'g') or '-inf'} and {num(args.end, 'g') or 'inf'} s"
    if timebase.shifted or timebase.windowed:
        header += f"; {timebase.describe()}"
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
    timebase.warn_outside(name)
    frames.raise_error()
    return 0
