"""`railhil trace plot TRACE --dbc DBC SIGNAL... -o FILE.png|FILE.html` — signals of a trace over time.

SIGNAL is ``NAME`` or ``MESSAGE.NAME``; a bare name that several messages carry is an error that lists
them.  Only the frames of the messages named are decoded (a large trace costs one integer compare
per other frame).  Multiplexed signals have a sample only in the frames whose multiplexer selects
them, as cantools decodes them.  Values are drawn as steps (a CAN signal holds its value until the
next frame).  PNG: matplotlib (Agg), one subplot per unit (``--subplots signal``: per signal), the
unit from the DBC on the y axis.  HTML: plotly, one self-contained file with plotly.js embedded, so
it opens offline.

Time axis in seconds on the trace's time base (hil.cli.trace.timebase), as --start/--end: from the run's
start for a run's trace, from the first frame for any other (the axis label gives that origin's
timestamp), as recorded with --absolute.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np

from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.cli.trace.common import SignalRef, TraceArgError, notice_skipped, resolve_signal
from hil.cli.trace.timebase import TimeBase, add_time_arguments
from hil.trace.readers import open_trace

SUFFIXES = (".png", ".html")
WEBGL_POINTS = 20_000   # an HTML series longer than this is drawn with WebGL (plotly's Scattergl)
MAX_CHOICE_TICKS = 16   # a lone signal with at most this many value-table entries gets them as y ticks


def add_parser(tsub: argparse._SubParsersAction) -> None:
    p = tsub.add_parser(
        "plot",
        help="plot DBC signals of a trace over time to a PNG (matplotlib) or HTML (plotly) file",
        description="Decode the named signals with the DBC and plot them over time. SIGNAL is NAME or "
                    "MESSAGE.NAME (a NAME that several messages carry must be qualified). -o FILE.png: "
                    "matplotlib, one subplot per unit; -o FILE.html: plotly, interactive, one "
                    "self-contained file that works offline. Time in seconds from the trace's start "
                    "(a run's trace: the run's start; any other: its first frame; --absolute: as "
                    "recorded).",
    )
    p.add_argument("trace", help="trace file, or '-' for candump -L text on stdin")
    p.add_argument("signals", nargs="+", metavar="SIGNAL", help="signal to plot: NAME or MESSAGE.NAME")
    p.add_argument("--dbc", type=Path, required=True, help="DBC file that defines the signals")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FILE",
                   help="output file: FILE.png (static image) or FILE.html (interactive, self-contained)")
    add_time_arguments(p)
    p.add_argument("--subplots", choices=("unit", "signal"), default="unit",
                   help="one subplot per unit (signals of one unit share axes; default) or per signal")
    p.add_argument("--title", default=None, help="figure title (default: the trace file name)")
    p.set_defaults(func=run)


@dataclass
class Series:
    """The samples of one signal: trace time [s] and physical value (DBC unit) per frame carrying it."""

    ref: SignalRef
    t: list[float] = field(default_factory=list)
    v: list[float] = field(default_factory=list)


@dataclass
class Collected:
    series: list[Series]
    first_t: float | None     # timestamp of the trace's first frame (any id), seconds
    frames: int               # frames read
    decoded: int              # frames of the wanted messages decoded
    failed: int               # frames of the wanted messages that did not decode (too short, bad mux)


def resolve(codec: Codec, names: list[str], dbc: Path) -> list[SignalRef]:
    """The SignalRefs of the command line's SIGNAL arguments, duplicates removed, in order."""
    refs: list[SignalRef] = []
    problems = []
    for text in names:
        try:
            for ref in resolve_signal(codec, text):
                if ref not in refs:
                    refs.append(ref)
        except TraceArgError as exc:
            problems.append(str(exc))
    if problems:
        raise TraceArgError(f"{dbc}: " + "; ".join(problems))
    return refs


def collect(frames: Iterable[can.Message], refs: list[SignalRef], start: float | None = None,
            end: float | None = None) -> Collected:
    """Decode only the frames of the messages that carry ``refs``, within [start, end]."""
    series = [Series(ref) for ref in refs]
    wanted: dict[tuple[int, bool], tuple] = {}
    for s in series:
        fc, entries = wanted.setdefault(s.ref.key, (s.ref.fc, []))
        entries.append((s.ref.name, s.t.append, s.v.append))
    first_t = None
    n = decoded = failed = 0
    for msg in frames:
        n += 1
        if first_t is None:
            first_t = msg.timestamp
        if msg.is_error_frame or msg.is_remote_frame:
            continue
        entry = wanted.get((msg.arbitration_id, bool(msg.is_extended_id)))
        if entry is None:
            continue
        t = msg.timestamp
        if (start is not None and t < start) or (end is not None and t > end):
            continue
        fc, entries = entry
        try:
            values = fc.decode(bytes(msg.data))
        except Exception:  # FrameError, or what cantools raises on a multiplexed message: counted
            failed += 1
            continue
        decoded += 1
        for name, add_t, add_v in entries:
            value = values.get(name)
            if value is not None:     # a multiplexed signal that this frame's multiplexer does not select
                add_t(t)
                add_v(value)
    return Collected(series, first_t, n, decoded, failed)


def groups(series: list[Series], per: str) -> list[tuple[str, list[Series]]]:
    """(unit, series) per subplot: by unit in order of first appearance, or one per signal."""
    if per == "signal":
        return [(s.ref.unit, [s]) for s in series]
    by_unit: dict[str, list[Series]] = {}
    for s in series:
        by_unit.setdefault(s.ref.unit, []).append(s)
    return list(by_unit.items())


def y_label(unit: str, members: list[Series]) -> str:
    if len(members) == 1:
        return f"{members[0].ref.name} [{unit}]" if unit else members[0].ref.name
    return f"[{unit}]" if unit else "value"


def choice_ticks(members: list[Series]) -> list[tuple[float, str]] | None:
    """Value-table entries of a lone signal with few of them, as (value, 'value name') y ticks."""
    if len(members) != 1:
        return None
    choices = members[0].ref.signal.choices
    if not choices or len(choices) > MAX_CHOICE_TICKS:
        return None
    return [(float(k), f"{k} {v}") for k, v in sorted(choices.items())]


def plot_png(path: Path, layout: list[tuple[str, list[Series]]], t0: float, x_label: str, title: str) -> None:
    from matplotlib.figure import Figure  # no pyplot: no GUI backend, no global figure state

    rows = len(layout)
    fig = Figure(figsize=(11, 1.0 + 2.6 * rows), layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    for ax, (unit, members) in zip(axes, layout, strict=True):
        for s in members:
            ax.step(np.asarray(s.t) - t0, s.v, where="post", lw=1, label=s.ref.label)
        ax.set_ylabel(y_label(unit, members))
        ticks = choice_ticks(members)
        if ticks:
            ax.set_yticks([v for v, _ in ticks], [text for _, text in ticks], fontsize=7)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    axes[-1].set_xlabel(x_label)
    fig.suptitle(title)
    fig.savefig(path, dpi=100)


def plotly_figure(layout: list[tuple[str, list[Series]]], t0: float, x_label: str, title: str):
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    rows = len(layout)
    fig = make_subplots(rows=rows, cols=1, shared_xaxes=True, vertical_spacing=min(0.08, 0.3 / rows))
    for row, (unit, members) in enumerate(layout, start=1):
        for s in members:
            kind = go.Scattergl if len(s.t) > WEBGL_POINTS else go.Scatter
            fig.add_trace(kind(x=np.asarray(s.t) - t0, y=np.asarray(s.v), name=s.ref.label, mode="lines",
                               line={"shape": "hv", "width": 1}), row=row, col=1)
        fig.update_yaxes(title_text=y_label(unit, members), row=row, col=1)
        ticks = choice_ticks(members)
        if ticks:
            fig.update_yaxes(tickvals=[v for v, _ in ticks], ticktext=[text for _, text in ticks],
                             row=row, col=1)
    fig.update_xaxes(title_text=x_label, row=rows, col=1)
    fig.update_layout(title=title, height=max(400, 120 + 260 * rows), hovermode="x unified")
    return fig


def check_output(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise TraceArgError(f"-o {path}: expected a file name ending in .png (matplotlib image) or .html "
                            f"(interactive plotly page)")
    if not path.parent.is_dir():
        raise TraceArgError(f"-o {path}: no such directory {path.parent}")
    return suffix


def run(args: argparse.Namespace) -> int:
    suffix = check_output(args.output)
    timebase = TimeBase.of(args, args.trace)
    codec = Codec(load_dbc(args.dbc))
    refs = resolve(codec, args.signals, args.dbc)
    trace = open_trace(args.trace)
    got = collect(timebase.messages(trace, window=False), refs, args.start, args.end)
    notice_skipped(trace)
    name = "<stdin>" if args.trace == "-" else str(args.trace)
    window = ""
    if args.start is not None or args.end is not None:
        lo = "-inf" if args.start is None else args.start
        hi = "inf" if args.end is None else args.end
        window = f" between {lo} and {hi} s"
    empty = [s.ref.label for s in got.series if not s.t]
    if len(empty) == len(got.series):
        span = (f"; the trace runs from {timebase.first:.6f} to {timebase.last:.6f} s, {timebase.describe()}"
                if timebase.outside() else "")
        raise TraceArgError(f"{name}: no frame carries {', '.join(empty)}{window} ({got.frames} frames "
                            f"read, {got.failed} of those messages did not decode{span})")
    timebase.warn_outside(name)
    for label in empty:
        print(f"notice: {name}: no frame carries {label}{window}; plotted empty", file=sys.stderr)
    if got.failed:
        print(f"notice: {name}: {got.failed} frames of the plotted messages did not decode "
              f"(too short, or a multiplexer value the DBC does not define); left out", file=sys.stderr)
    t0, x_label = 0.0, timebase.axis_label()       # the frames' times are on the time base already
    layout = groups(got.series, args.subplots)
    title = args.title or name
    try:
        if suffix == ".png":
            plot_png(args.output, layout, t0, x_label, title)
        else:
            plotly_figure(layout, t0, x_label, title).write_html(args.output, include_plotlyjs=True,
                                                                 full_html=True)
    except OSError as exc:
        raise TraceArgError(f"-o {args.output}: cannot write: {exc.strerror or exc}") from None
    samples = sum(len(s.t) for s in got.series)
    times = [t for s in got.series if s.t for t in (s.t[0], s.t[-1])]
    span = f"{min(times):.6f} to {max(times):.6f} s" if times else "no samples"
    print(f"wrote {args.output}: {len(got.series)} signals, {samples} samples, {span}"
          f"{f' ({timebase.describe()})' if timebase.shifted else ''}")
    return 0
