"""`railhil trace ACTION` — inspect, plot, compare and replay recorded CAN traces.

One module per action (cantools' ``subparsers/``): ``stats``, ``decode``, ``export``, ``plot``,
``diff``, ``replay``; what they share is in ``common``.  Every action reads any trace python-can reads
(.asc .blf .csv .db .log .mf4 .trc, also .gz compressed; '-' = candump -L text on stdin) through
``hil.trace.readers.open_trace``.  Times are seconds on the trace's time base everywhere, in the output
and in --start/--end (``timebase``: a run's trace from the run's start, any other from its first frame,
--absolute as recorded; ``trace stats`` shows the first and last).  Ids print as candump does:
3 hex digits for an 11-bit id, 8 for a 29-bit one, so the two never mix.
"""

from __future__ import annotations

import argparse

from hil.cli.trace import decode, diff, export, plot, replay, stats
from hil.cli.trace.common import (
    Output,
    SignalRef,
    TraceArgError,
    check_window,
    id_text,
    jsonable,
    kind_of,
    lookup,
    notice_skipped,
    num,
    parse_id,
    resolve_signal,
)

__all__ = [
    "ACTIONS", "Output", "SignalRef", "TraceArgError", "add_subparser", "check_window", "id_text",
    "jsonable", "kind_of", "lookup", "notice_skipped", "num", "parse_id", "resolve_signal",
]

ACTIONS = (stats, decode, export, plot, diff, replay)


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "trace",
        help="inspect a recorded CAN trace: statistics, decoding, export, plots, comparison, replay",
        description="Inspect a CAN trace that python-can reads (.asc .blf .csv .db .log .mf4 .trc, "
                    "also .gz compressed; '-' reads candump -L text from stdin): per-id statistics, "
                    "DBC decoding, signal plots, a signal-by-signal comparison of two traces, and "
                    "replay onto a python-can bus.",
    )
    tsub = p.add_subparsers(dest="trace_command", metavar="ACTION")
    tsub.required = True
    for action in ACTIONS:
        action.add_parser(tsub)
