"""`railhil trace decode TRACE --dbc DBC` — the frames of a trace decoded with a DBC, with filters.

Two paths write the same bytes: the per-frame path (``decoded_rows`` and ``row_texts``: one Row per
python-can Message), the reference; and the fast path that ``run`` takes, a block of frames at a time
(``hil.trace.columns.BlockReader`` reads them, ``hil.trace.fastdecode.BlockDecoder`` decodes and writes
them, and hands the frames it does not take -- remote, error, multiplexed, too short -- to the
per-frame path, in their place).  tests/trace/test_fastdecode.py holds the two to the same output.

Values are shown as cantools shows them (``cantools decode``): a signal whose raw value is in its value
table by the table's name (``Enable=Enabled``), every other one by its number and the DBC unit
(``AverageRadius=1.8 m``); ``--raw`` shows every signal by its number (``Enable=1 -``), as
``cantools decode --no-decode-choices``.  csv and jsonl carry the number, the unit and the name.  The
names are cantools' own (``decode_choices=True``, ``hil.trace.fastdecode.choice_names``), the numbers
``hil.can.codec``'s, which equal cantools' (tests/cli/test_decode_choices.py).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import can

from hil.can.codec import Codec
from hil.can.dbc import closest, load_dbc
from hil.cli.trace.common import (
    Output,
    TraceArgError,
    id_text,
    jsonable,
    kind_of,
    lookup,
    notice_skipped,
    parse_id,
)
from hil.cli.trace.timebase import TimeBase, add_time_arguments
from hil.trace.columns import BLOCK_FRAMES, BlockReader
from hil.trace.fastdecode import BlockDecoder, choice_names, table_word
from hil.trace.readers import open_trace

FORMAT_CHOICES = ("table", "csv", "jsonl")
CSV_HEADER = "t,id,name,signal,value,error,unit,choice\n"


def add_parser(tsub: argparse._SubParsersAction) -> None:
    d = tsub.add_parser(
        "decode",
        help="decode the frames of a trace with a DBC",
        description="Decode each frame with the DBC, as cantools decode does: a signal whose value is in "
                    "its value table (VAL_) by the table's name, any other by its number and its DBC "
                    "unit. table: one line per frame, signals as name=value (Enable=Enabled "
                    "AverageRadius=1.8 m; a name or unit that is not one plain word is written as a "
                    "JSON string, \"Signal error\"); csv: one row per (frame, signal) with columns "
                    "t,id,name,signal,value,error,unit,choice (choice: the value-table name, empty when "
                    "none); jsonl: one object per frame {t, id, name, signals, choices, units} (signals: "
                    "the numbers; choices: the names of the signals whose value is in their table; "
                    "units: the units the DBC gives). --raw: numbers only, no names (units kept). "
                    "Frames of ids the DBC does not know, remote and error frames are shown raw (hex "
                    "data) unless a filter excludes them; a frame that does not decode is shown raw "
                    "with the reason, counted, and decoding goes on. A summary goes to stderr.",
    )
    d.add_argument("trace", help="trace file, or '-' for candump -L text on stdin")
    d.add_argument("--dbc", type=Path, required=True, help="DBC file")
    d.add_argument("--id", dest="ids", action="append", default=[], metavar="ID",
                   help="only frames with this arbitration id, hex (0x123) or decimal; repeatable")
    d.add_argument("--message", dest="messages", action="append", default=[], metavar="NAME",
                   help="only frames of this DBC message; repeatable")
    d.add_argument("--signal", dest="signals", action="append", default=[], metavar="NAME",
                   help="only these signals (and only frames that carry one); repeatable")
    add_time_arguments(d)
    d.add_argument("--format", choices=FORMAT_CHOICES, default="table", help="output format (default table)")
    d.add_argument("--raw", action="store_true",
                   help="value-table signals as their numbers, not their names (as cantools decode "
                        "--no-decode-choices; the scaled values, not the raw bits): no choice in csv, no "
                        "choices in jsonl; units are still shown")
    d.set_defaults(func=run)


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
    choices: dict[str, str] | None = None  # the names of the values in their value tables; None: --raw
    units: dict[str, str] | None = None  # the units of the signals the DBC gives one


def decoded_rows(frames: Iterable[can.Message], codec: Codec, sel: Selection, start: float | None,
                 end: float | None, counts: dict[str, int], raw: bool = False) -> Iterator[Row]:
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
        choices = None
        if not raw:
            names = choice_names(fc, bytes(msg.data))
            choices = {k: names[k] for k in values if k in names}
        signal = fc.message.get_signal_by_name
        units = {k: unit for k in values if (unit := signal(k).unit)}
        counts["decoded"] += 1
        yield Row(t, ident, fc.name, values, choices=choices, units=units)


def row_texts(fmt: str, width: int) -> Callable[[Iterable[Row]], str]:
    """The per-frame path's text of rows in `fmt`: table (`width` = the name column's width), csv, jsonl."""
    if fmt == "csv":
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")

        def csv_text(rows: Iterable[Row]) -> str:
            for r in rows:
                if r.signals is None:
                    writer.writerow((f"{r.t:.6f}", r.id, r.name or ("" if r.kind == "data" else r.kind), "",
                                     r.data, r.error or "", "", ""))
                else:
                    choices, units = r.choices or {}, r.units or {}
                    for sig, value in r.signals.items():
                        writer.writerow((f"{r.t:.6f}", r.id, r.name, sig, repr(value), "", units.get(sig, ""),
                                         choices.get(sig, "")))
            text = buffer.getvalue()
            buffer.seek(0)
            buffer.truncate()
            return text

        return csv_text

    def one(r: Row) -> str:
        if fmt == "jsonl":
            obj: dict = {"t": r.t, "id": r.id, "name": r.name}
            if r.signals is not None:
                obj["signals"] = {k: jsonable(v) for k, v in r.signals.items()}
                if r.choices is not None:
                    obj["choices"] = r.choices
                obj["units"] = r.units or {}
            else:
                obj["data"] = r.data
                if r.kind != "data":
                    obj["kind"] = r.kind
                if r.kind == "remote":
                    obj["dlc"] = r.dlc
                if r.error:
                    obj["error"] = r.error
            return json.dumps(obj) + "\n"
        if r.signals is not None:
            body = " ".join(signal_text(k, v, r.choices, r.units or {}) for k, v in r.signals.items())
            name = r.name
        else:
            body = {"remote": f"remote frame dlc={r.dlc}", "error": "error frame"}.get(
                r.kind, f"data={r.data}" + (f"  ({r.error})" if r.error else ""))
            name = r.name or ("?" if r.kind == "data" else r.kind.upper())
        return f"{r.t:17.6f}  {r.id:<10}  {name:<{width}}  {body}\n"

    return lambda rows: "".join(map(one, rows))


def signal_text(name: str, value: float, choices: dict[str, str] | None, units: dict[str, str]) -> str:
    """One signal in the table: ``name=choice`` where it has a name, else ``name=value`` and the unit."""
    if choices and name in choices:
        return f"{name}={table_word(choices[name], choice=True)}"
    unit = units.get(name)
    return f"{name}={value:.10g} {table_word(unit)}" if unit else f"{name}={value:.10g}"


def run(args: argparse.Namespace) -> int:
    codec = Codec(load_dbc(args.dbc))
    sel = select(args, codec)
    timebase = TimeBase.of(args, args.trace)
    return decode(args.trace, codec, sel, args.format, args.start, args.end, dbc_name=str(args.dbc),
                  raw=args.raw, timebase=timebase)


def decode(trace: str | Path, codec: Codec, sel: Selection, fmt: str, start: float | None, end: float | None,
           dbc_name: str, fast: bool = True, block_frames: int = BLOCK_FRAMES, raw: bool = False,
           timebase: TimeBase | None = None) -> int:
    """Write the decoded frames of `trace` to stdout in `fmt`, the summary to stderr; `raw` (--raw):
    numbers only, no value-table names.  Times and `start`/`end` are on `timebase`
    (hil.cli.trace.timebase; default: the timestamps as recorded).

    `fast` (the default): a block of up to `block_frames` frames at a time (hil.trace.columns reads
    them, hil.trace.fastdecode decodes and writes them, the per-frame path below takes the frames it does
    not); `fast` False: the per-frame path for every frame -- the reference that
    tests/trace/test_fastdecode.py holds the fast path to, byte for byte.
    """
    timebase = timebase or TimeBase(start, end, absolute=True)
    counts = {"decoded": 0, "unknown": 0, "remote": 0, "error": 0, "failed": 0}
    width = max([len(fc.name) for fc in codec] + [6])
    texts = row_texts(fmt, width)
    if fast:
        reader = BlockReader(trace, block_frames)
        frames = reader.trace
    else:
        frames = open_trace(trace)
    out = Output()
    if fmt == "csv":
        out.write(CSV_HEADER)
    elif fmt == "table":
        out.write(f"{'t_s':>17}  {'id':<10}  {'name':<{width}}  signals\n")
    if fast:
        def slow(msg: can.Message) -> str:
            return texts(decoded_rows((msg,), codec, sel, start, end, counts, raw))

        decoder = BlockDecoder(codec, fmt, width=width, ids=sel.ids, names=sel.names, signals=sel.signals,
                               start=start, end=end, slow=slow, counts=counts, raw=raw)
        for block in reader:
            out.write(decoder.text(timebase.block(block)))
            if out.closed:
                break
        frames = reader.trace  # a new one if the BLF reader gave the file to python-can's
    else:
        for row in decoded_rows(timebase.messages(frames, window=False), codec, sel, start, end, counts, raw):
            out.write(texts((row,)))
            if out.closed:
                break
    out.flush()
    notice_skipped(frames)
    if not out.closed:
        summary = (f"{counts['decoded']} frames decoded, {counts['unknown']} with ids not in {dbc_name}, "
                   f"{counts['remote']} remote, {counts['error']} error frames, "
                   f"{counts['failed']} failed to decode")
        if timebase.shifted:
            summary += f"; {timebase.describe()}"
        print(summary, file=sys.stderr)
        timebase.warn_outside("<stdin>" if str(trace) == "-" else str(trace))
    return 0
