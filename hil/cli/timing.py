"""`railhil timing TRACE --dbc DBC` — do the cyclic frames of a trace keep their DBC cycle times?

One row per cyclic DBC message (GenMsgCycleTime > 0): count, period mean / σ / p99 / max [ms], late,
missed and burst periods, and a verdict PASS / FAIL / MISSING (defined in hil.timing); then the
bus load the trace put on the bus.  Exit 0 when every message PASSes, 1 when any is FAIL or
MISSING (a verdict, not an error), 2 for bad input.  ``--periods-only`` needs no DBC: the periods
of every id of the trace, no verdict.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

from hil.busload import declared_bitrate
from hil.cli.trace import Output, id_text, notice_skipped, num
from hil.dbc import closest, load_dbc
from hil.timing import (
    BusLoadMeasured,
    MessageTiming,
    PeriodStats,
    TimingArgError,
    TimingReport,
    analyse,
    bus_load,
    check_tolerance,
    frame_arrays,
    measure_periods,
)
from hil.traceio import open_trace

FORMAT_CHOICES = ("table", "json", "junit")
SUITE = "railhil.timing"


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "timing",
        help="cycle-time conformance of a trace's cyclic frames against the DBC, and bus load",
        description="For each DBC message with GenMsgCycleTime > 0: the periods between its data "
                    "frames in the trace (11- and 29-bit ids apart), late / missed / burst periods "
                    "and a verdict. PASS: at least 2 frames, mean period within ±tolerance of the "
                    "cycle time, no missed frame (a gap of 1.5 cycles or more that the sender does "
                    "not make up within 10 periods; the last 0.2 s, a run's teardown, not judged) "
                    "and no silence of 1.5 cycles + 0.2 s before the end of the trace; else FAIL; "
                    "MISSING when no "
                    "frame is in the trace. Exit 0 if all PASS, 1 if any FAIL/MISSING, 2 for bad "
                    "input. Bus load: worst-case-stuffed frame lengths (Davis et al. 2007), average "
                    "over the trace and peak over a sliding window.",
    )
    p.add_argument("trace", help="trace file python-can reads, or '-' for candump -L text on stdin")
    p.add_argument("--dbc", type=Path, default=None, help="DBC file (required unless --periods-only)")
    p.add_argument("--tolerance", type=float, default=0.10, metavar="FRACTION",
                   help="allowed deviation of the mean period from the cycle time (default 0.10)")
    p.add_argument("--override", action="append", default=[], metavar="NAME=FRACTION",
                   help="tolerance for one message; repeatable")
    p.add_argument("--ignore", action="append", default=[], metavar="PATTERN",
                   help="do not judge messages matching this shell pattern, e.g. 'RADIO_*' (frames a run "
                        "does not send by design); repeatable")
    p.add_argument("--bitrate", type=int, default=None, metavar="BPS",
                   help="bus bitrate in bit/s (default: the DBC's Baudrate attribute)")
    p.add_argument("--window", type=float, default=0.1, metavar="S",
                   help="length of the sliding window of the peak bus load, seconds (default 0.1)")
    p.add_argument("--periods-only", action="store_true",
                   help="no DBC, no verdict: period statistics of every id of the trace")
    p.add_argument("--format", choices=FORMAT_CHOICES, default="table", help="output format (default table)")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="FILE",
                   help="write the report to FILE instead of stdout")
    p.set_defaults(func=timing)


def parse_overrides(items: list[str], names: list[str]) -> dict[str, float]:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError
            fraction = float(value)
        except ValueError:
            raise TimingArgError(f"--override {item!r}: expected NAME=FRACTION, e.g. BCU_STATUS=0.2"
                                 ) from None
        if name not in names:
            raise TimingArgError(f"--override {item!r}: no message named {name!r} "
                                 f"(closest: {closest(name, names)})")
        out[name] = fraction
    return out


def jnum(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else round(value, 6)


STAT_FIELDS = ("mean_ms", "sigma_ms", "p50_ms", "p99_ms", "min_ms", "max_ms")


def stats_obj(s: PeriodStats | None) -> dict:
    if s is None:
        return {"count": 0}
    return {"count": s.count, "first_s": s.first_s, "last_s": s.last_s,
            **{k: jnum(getattr(s, k)) for k in STAT_FIELDS}}


def load_obj(load: BusLoadMeasured | None) -> dict | None:
    if load is None:
        return None
    return {"bitrate_bps": load.bitrate_bps, "frames": load.frames, "bits": load.bits,
            "duration_s": jnum(load.duration_s), "average": jnum(load.average), "window_s": load.window_s,
            "peak": jnum(load.peak), "peak_at_s": jnum(load.peak_at_s), "error_frames": load.error_frames,
            "fd_frames": load.fd_frames, "worst_case_stuffing": True}


def load_line(load: BusLoadMeasured | None) -> str:
    if load is None:
        return "bus load: not computed (no bitrate: pass --bitrate)"
    line = (f"bus load: average {100 * load.average:.2f} %, peak {100 * load.peak:.2f} % "
            f"({load.window_s:g} s window at {load.peak_at_s:.3f} s) of {load.bitrate_bps} bit/s; "
            f"{load.frames} frames, worst-case stuffing")
    if load.error_frames:
        line += f", {load.error_frames} error frames not counted"
    if load.fd_frames:
        line += f", {load.fd_frames} CAN FD frames counted as classic (≤ 8 bytes)"
    return line


def render_table(columns: tuple[str, ...], rows: list[dict], left: set[str]) -> str:
    widths = {c: max([len(c), *(len(str(r[c])) for r in rows)]) for c in columns}

    def line(values: dict) -> str:
        return "  ".join(str(values[c]).ljust(widths[c]) if c in left else str(values[c]).rjust(widths[c])
                         for c in columns).rstrip() + "\n"

    return line({c: c for c in columns}) + "".join(line(r) for r in rows)


TIMING_COLUMNS = ("name", "id", "cycle_ms", "count", "mean_ms", "sigma_ms", "p99_ms", "max_ms",
                  "late", "missed", "bursts", "verdict")


def timing_row(m: MessageTiming) -> dict:
    s = m.stats
    return {"name": m.name, "id": id_text(m.arbitration_id, m.extended), "cycle_ms": f"{m.cycle_ms:g}",
            "count": 0 if s is None else s.count,
            "mean_ms": num(s and s.mean_ms, ".3f"), "sigma_ms": num(s and s.sigma_ms, ".3f"),
            "p99_ms": num(s and s.p99_ms, ".3f"), "max_ms": num(s and s.max_ms, ".3f"),
            "late": m.late, "missed": m.missed, "bursts": m.bursts, "verdict": m.verdict}


def timing_obj(m: MessageTiming) -> dict:
    return {"name": m.name, "id": id_text(m.arbitration_id, m.extended), "extended": m.extended,
            "cycle_ms": m.cycle_ms, "tolerance": m.tolerance, **stats_obj(m.stats), "late": m.late,
            "missed": m.missed, "bursts": m.bursts, "jitter_max_ms": jnum(m.jitter_max_ms),
            "tail_ms": jnum(m.tail_ms), "stopped": m.stopped, "verdict": m.verdict, "reason": m.reason}


def summary_line(report: TimingReport) -> str:
    c = report.counts()
    unknown = sum(report.unknown.values())
    return (f"{len(report.messages)} cyclic messages: {c['PASS']} PASS, {c['FAIL']} FAIL, "
            f"{c['MISSING']} MISSING; {unknown} frames of {len(report.unknown)} ids not in the DBC "
            f"(no verdict); {report.non_cyclic} frames of non-cyclic DBC messages")


def junit(report: TimingReport, trace_name: str) -> str:
    c = report.counts()
    suite = ET.Element("testsuite", name=SUITE, tests=str(len(report.messages)),
                       failures=str(c["FAIL"] + c["MISSING"]), errors="0", skipped="0")
    props = ET.SubElement(suite, "properties")
    ET.SubElement(props, "property", name="trace", value=trace_name)
    if report.load is not None:
        ET.SubElement(props, "property", name="bus_load_average", value=f"{report.load.average:.6f}")
        ET.SubElement(props, "property", name="bus_load_peak", value=f"{report.load.peak:.6f}")
    for m in report.messages:
        case = ET.SubElement(suite, "testcase", classname=SUITE,
                             name=f"{m.name} ({id_text(m.arbitration_id, m.extended)})")
        if m.verdict != "PASS":
            failure = ET.SubElement(case, "failure", message=f"{m.verdict}: {m.reason}", type=m.verdict)
            failure.text = json.dumps(timing_obj(m))
    ET.indent(suite)
    return ET.tostring(suite, encoding="unicode", xml_declaration=True) + "\n"


PERIOD_COLUMNS = ("id", "frame", "count", "mean_ms", "sigma_ms", "p50_ms", "p99_ms", "min_ms", "max_ms")


def periods_report(periods: dict[tuple[int, bool], PeriodStats], fmt: str, trace_name: str,
                   load: BusLoadMeasured | None) -> str:
    if fmt == "junit":
        raise TimingArgError("--periods-only gives no verdict: use --format table or json")
    if fmt == "json":
        return json.dumps({"trace": trace_name, "ids": [
            {"id": id_text(i, e), "extended": e, **stats_obj(s)} for (i, e), s in periods.items()],
            "bus_load": load_obj(load)}, indent=2) + "\n"
    rows = [{"id": id_text(i, e), "frame": "ext" if e else "std", "count": s.count,
             **{c: num(getattr(s, c), ".3f") for c in PERIOD_COLUMNS[3:]}} for (i, e), s in periods.items()]
    return render_table(PERIOD_COLUMNS, rows, {"id", "frame"}) + (load_line(load) + "\n" if load else "")


def timing(args: argparse.Namespace) -> int:
    if not args.window > 0 or not math.isfinite(args.window):
        raise TimingArgError(f"--window {args.window}: expected a positive number of seconds")
    if args.bitrate is not None and args.bitrate <= 0:
        raise TimingArgError(f"--bitrate {args.bitrate}: expected a positive bitrate in bit/s")
    trace_name = "<stdin>" if args.trace == "-" else str(args.trace)
    if args.periods_only:
        if args.override:
            raise TimingArgError("--override needs a DBC verdict, not --periods-only")
        trace = open_trace(args.trace)
        arrays = frame_arrays(trace)
        notice_skipped(trace)
        load = bus_load(arrays, args.bitrate, args.window) if args.bitrate is not None else None
        text, code = periods_report(measure_periods(arrays), args.format, trace_name, load), 0
    else:
        if args.dbc is None:
            raise TimingArgError("--dbc DBC is required (or --periods-only for periods without a DBC)")
        check_tolerance(args.tolerance, "--tolerance")
        db = load_dbc(args.dbc)
        overrides = parse_overrides(args.override, [m.name for m in db.messages])
        bitrate = args.bitrate if args.bitrate is not None else declared_bitrate(db)
        if bitrate is None:
            raise TimingArgError(f"{args.dbc}: no 'Baudrate' attribute: pass --bitrate BPS for the bus load")
        trace = open_trace(args.trace)
        arrays = frame_arrays(trace)
        notice_skipped(trace)
        report = analyse(arrays, db, args.tolerance, overrides, bitrate, args.window, ignore=args.ignore)
        code = 0 if report.ok else 1
        if args.format == "json":
            text = json.dumps({"trace": trace_name, "dbc": str(args.dbc), "tolerance": args.tolerance,
                               "frames": report.frames, "duration_s": report.duration_s,
                               "messages": [timing_obj(m) for m in report.messages],
                               "unknown_ids": {id_text(i, e): n for (i, e), n in report.unknown.items()},
                               "non_cyclic_frames": report.non_cyclic, "bus_load": load_obj(report.load),
                               "summary": report.counts(), "ok": report.ok}, indent=2) + "\n"
        elif args.format == "junit":
            text = junit(report, trace_name)
        else:
            rows = [timing_row(m) for m in report.messages]
            text = (f"{trace_name}: {report.frames} frames over {report.duration_s:.6f} s "
                    f"against {args.dbc}, tolerance ±{100 * args.tolerance:g} %\n"
                    + render_table(TIMING_COLUMNS, rows, {"name", "id", "verdict"})
                    + "".join(f"  {m.name}: {m.verdict}: {m.reason}\n" for m in report.messages if m.reason)
                    + summary_line(report) + "\n" + load_line(report.load) + "\n")
    if args.output is not None:
        try:
            args.output.write_text(text)
        except OSError as exc:
            raise TimingArgError(f"{args.output}: cannot write the report: {exc.strerror or exc}") from exc
        print(f"wrote {args.output}", file=sys.stderr)
    else:
        out = Output()
        out.write(text)
        out.flush()
    return code
