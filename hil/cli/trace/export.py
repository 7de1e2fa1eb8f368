"""`railhil trace export TRACE --dbc DBC -o FILE.mf4|FILE.parquet|FILE.csv` — the trace's signals,
decoded with the DBC, with their names, units and value tables: MF4 one channel group per message,
Parquet/CSV one row per (frame, signal).  Definitions in hil.trace.export.  Times (and --start/--end) are
on the trace's time base (hil.cli.trace.timebase)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hil.can.codec import Codec
from hil.can.dbc import closest, load_dbc
from hil.cli.trace.common import TraceArgError
from hil.cli.trace.timebase import TimeBase, add_time_arguments
from hil.trace.decoded import DecodedTrace
from hil.trace.export import FORMATS, export_format, write_export


def add_parser(tsub: argparse._SubParsersAction) -> None:
    p = tsub.add_parser(
        "export",
        help="write the decoded signals as MF4, Parquet or CSV (names, units, value tables)",
        description="Decode every frame of TRACE with the DBC and write the signals to FILE, the format by "
                    "its suffix: .mf4 (ASAM MDF 4.10: one channel group per message, one channel per "
                    "signal with its unit, comment and value table as a value-to-text conversion, the "
                    "way asammdf's bus-logging extraction writes it), .parquet or .csv (one row per "
                    "frame and signal: t, id, message, signal, value, unit, choice). Frames the DBC "
                    "does not know are counted, not written. The file is written under a temporary "
                    "name and renamed when complete.",
    )
    p.add_argument("trace", help="trace file (any python-can format, also MF4)")
    p.add_argument("--dbc", type=Path, required=True, help="DBC file")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FILE",
                   help="the file to write: " + ", ".join(FORMATS))
    p.add_argument("--message", action="append", default=[], metavar="NAME",
                   help="only this DBC message (repeatable; default: every message with frames)")
    add_time_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    export_format(args.output)                   # a bad suffix fails before the trace is read
    db = load_dbc(args.dbc)
    names = [m.name for m in db.messages]
    for name in args.message:
        if name not in names:
            raise TraceArgError(f"--message {name!r}: no such message in {args.dbc} (closest: "
                                f"{closest(name, names)})")
    timebase = TimeBase.of(args, args.trace)
    decoded = DecodedTrace.read(args.trace, db, Codec(db))
    decoded.frames = timebase.block(decoded.frames, window=True)    # on the time base, in the window
    present = decoded.message_names()
    wanted = [n for n in present if not args.message or n in args.message]
    counts = write_export(decoded, args.output, wanted)
    unknown = decoded.count_unknown()
    print(f"{args.trace}: {len(decoded.frames)} frames, {counts['frames']} decoded in {counts['messages']} "
          f"messages ({counts['signals']} signals)"
          + (f", {unknown} not in the DBC (or remote/error)" if unknown else "")
          + (f", {decoded.undecodable} that do not decode" if decoded.undecodable else "")
          + (f"; {timebase.describe()}" if timebase.shifted else ""), file=sys.stderr)
    timebase.warn_outside(str(args.trace))
    print(f"wrote {args.output}")
    return 0
