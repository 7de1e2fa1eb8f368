"""`railhil timing TRACE --dbc DBC` — do the cyclic frames of a trace keep their DBC cycle times?

One row per cyclic DBC message (GenMsgCycleTime > 0): count, period mean / σ / p99 / max [ms], late,
missed and burst periods, and a verdict PASS / FAIL / MISSING (defined in hil.trace.timing); then the
bus load the trace put on the bus.  Exit 0 when every message PASSes, 1 when any is FAIL or
MISSING (a verdict, not an error), 2 for bad input; a trace damaged part-way (a corrupt line, a BLF
file cut short) gives the report of the frames before the damage, then the error, exit 2.
``--periods-only`` needs no DBC: the periods of every id of the trace, no verdict.

``--rta``: the worst-case response time of every cyclic message from the DBC alone (hil.can.rta, Davis
et al. 2007) — with no trace, the analysis only (exit 0 when every message is schedulable); with a
trace, also the response each message shows in it (FAIL when above its bound).  ``--chain``:
cause -> effect latencies (hil.trace.timing.analyse_chains), with a verdict under ``--chain-max-ms``.
``--histogram NAME``: the periods of NAME as text bars (the JSON output has every histogram).

A run's trace (trace.blf beside its run.json, or ``--run FOLDER``) is judged as that run: only the cyclic
messages its nodes send (run.json's messages_sent: its cars, its studies' frames) are judged, one line says
what was left out and why, and ``--all-messages`` judges every one.  Times (--start/--end, the report's)
are on the trace's time base (hil.cli.trace.timebase): from the run's start, or the first frame of a
trace of no run; --absolute as recorded.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np
from cantools.database.can import Database

from hil.can.busload import declared_bitrate, optional_function, with_functions
from hil.can.dbc import closest, load_dbc
from hil.can.rta import RtaReport, messages_from_dbc
from hil.can.rta import analyse as rta_analyse
from hil.cli.aliases import function_names
from hil.cli.trace import Output, id_text, notice_skipped, num
from hil.cli.trace.timebase import RunOfTrace, TimeBase, add_time_arguments
from hil.trace.columns import read_trace_columns
from hil.trace.readers import Salvage, TraceError, open_trace
from hil.trace.timing import (
    MEASURE_SLACK_US,
    BusLoadMeasured,
    Chain,
    ChainResult,
    LatencyStats,
    MessageTiming,
    PeriodHistogram,
    PeriodStats,
    RtaCheck,
    TimingArgError,
    TimingReport,
    analyse,
    analyse_chains,
    bus_load,
    chain_frame_keys,
    check_tolerance,
    frame_arrays,
    measure_periods,
    parse_chain,
    period_histogram,
    rta_against_trace,
    rta_check,
)

FORMAT_CHOICES = ("table", "json", "junit")
SUITE = "railhil.timing"
BAR_WIDTH = 40  # characters of the longest histogram bar


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "timing",
        help="cycle-time conformance of a trace against the DBC, bus load, response-time analysis, "
             "latency chains",
        description="For each DBC message with GenMsgCycleTime > 0: the periods between its data "
                    "frames in the trace (11- and 29-bit ids apart), late / missed / burst periods "
                    "and a verdict. PASS: at least 2 frames, mean period within ±tolerance of the "
                    "cycle time, no missed frame (a gap of 1.5 cycles or more that the sender does "
                    "not make up within 10 periods; the last 0.2 s, a run's teardown, not judged) "
                    "and no silence of 1.5 cycles + 0.2 s before the end of the trace; else FAIL; "
                    "MISSING when no "
                    "frame is in the trace. Exit 0 if all PASS, 1 if any FAIL/MISSING, 2 for bad "
                    "input. Bus load: worst-case-stuffed frame lengths (Davis et al. 2007), average "
                    "over the trace and peak over a sliding window. --rta adds the worst-case "
                    "response time of every cyclic message from the DBC (Davis et al. 2007, revised "
                    "analysis; without a trace: the analysis alone, exit 0 when all are schedulable); "
                    "--chain adds cause -> effect latencies. A run's trace (run.json beside it, or --run "
                    "FOLDER) is judged on the cyclic messages that run sends (one line says what was left "
                    "out; --all-messages judges every one); times are seconds from the run's start (a trace "
                    "of no run: from its first frame; --absolute: as recorded).",
    )
    p.add_argument("trace", nargs="?", default=None,
                   help="trace file python-can reads, or '-' for candump -L text on stdin "
                        "(optional with --rta: then the DBC alone is analysed)")
    p.add_argument("--dbc", type=Path, default=None, help="DBC file (required unless --periods-only)")
    p.add_argument("--tolerance", type=float, default=0.10, metavar="FRACTION",
                   help="allowed deviation of the mean period from the cycle time (default 0.10)")
    p.add_argument("--override", action="append", default=[], metavar="NAME=FRACTION",
                   help="tolerance for one message; repeatable")
    p.add_argument("--ignore", action="append", default=[], metavar="PATTERN",
                   help="do not judge messages matching this shell pattern, e.g. 'RADIO_*' (frames a run "
                        "does not send by design; --rta leaves them off the bus too); repeatable")
    p.add_argument("--bitrate", type=int, default=None, metavar="BPS",
                   help="bus bitrate in bit/s (default: the DBC's Baudrate attribute)")
    p.add_argument("--window", type=float, default=0.1, metavar="S",
                   help="length of the sliding window of the peak bus load, seconds (default 0.1)")
    p.add_argument("--periods-only", action="store_true",
                   help="no DBC, no verdict: period statistics of every id of the trace")
    p.add_argument("--rta", action="store_true",
                   help="worst-case response time of every cyclic DBC message (Davis et al. 2007: "
                        "blocking, busy period, queued instances, jitter; D = cycle time) and the bus "
                        "utilisation; with a trace also the measured response, FAIL when above the bound")
    p.add_argument("--function", action="append", default=[], metavar="NAME",
                   help="also check the frames of this optional function of the DBC (its messages' "
                        "RailhilFunction attribute, e.g. consensus; 'all' for every frame); by "
                        "default only the train's base frames are in scope; repeatable (railhil 0.1's "
                        "function names still work, until 0.3)")
    p.add_argument("--jitter", action="append", default=[], metavar="NAME=US",
                   help="queuing jitter of one message for --rta, in µs (default: from the sender's "
                        "CANoeJitterMin/Max node attributes, in %% of the cycle time, else 0); repeatable")
    p.add_argument("--chain", action="append", default=[], metavar="'A.SIG -> B.SIG -> C.SIG'",
                   help="cause -> effect latency chain: an event of a link is a frame of its message in "
                        "which the signal changed (a bare MESSAGE: every frame); each event of the first "
                        "link is followed to the next link's first event after it; repeatable")
    p.add_argument("--chain-max-ms", type=float, default=None, metavar="MS",
                   help="verdict of every --chain: FAIL when an instance took longer than MS from first "
                        "to last link (or never completed though MS passed before the end of the trace)")
    p.add_argument("--histogram", action="append", default=[], metavar="NAME",
                   help="print the period histogram of this message as text bars (table format; the "
                        "JSON output has every message's); repeatable")
    p.add_argument("--all-messages", action="store_true",
                   help="a run's trace: judge every cyclic message in scope, also those the run's scenario "
                        "does not send (by default a run's trace is judged on the messages its nodes send: "
                        "run.json beside the trace, or --run)")
    add_time_arguments(p, run=True)
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


def parse_jitters(items: list[str]) -> dict[str, int]:
    """--jitter NAME=US items; the names are checked against the DBC by hil.can.rta.messages_from_dbc."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep or not name:
                raise ValueError
            us = int(value)
            if us < 0:
                raise ValueError
        except ValueError:
            raise TimingArgError(f"--jitter {item!r}: expected NAME=US, a whole number of µs >= 0, "
                                 f"e.g. BCU_DEMAND=500") from None
        out[name] = us
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


# --- period histograms -------------------------------------------------------------------------------


def histogram_of(m: MessageTiming) -> PeriodHistogram | None:
    if m.stats is None or m.stats.count < 2:
        return None
    return period_histogram(m.stats.periods_ms, m.cycle_ms, m.tolerance)


def histogram_obj(h: PeriodHistogram | None) -> dict | None:
    if h is None:
        return None
    return {"cycle_ms": h.cycle_ms, "bin_ms": jnum(h.bin_ms), "edges_ms": [jnum(e) for e in h.edges_ms],
            "counts": [int(c) for c in h.counts], "below": h.below, "above": h.above}


def histogram_text(m: MessageTiming, h: PeriodHistogram | None) -> str:
    """Text bars from the first to the last occupied bin, plus the periods outside the bins."""
    title = f"periods of {m.name} ({id_text(m.arbitration_id, m.extended)}), cycle {m.cycle_ms:g} ms"
    if h is None:
        return f"{title}: fewer than 2 frames, no period\n"
    rows = []
    occupied = np.flatnonzero(h.counts)
    peak = max([int(h.counts.max()) if len(h.counts) else 0, h.below, h.above, 1])

    def bar(count: int) -> str:
        return "#" * (max(1, round(BAR_WIDTH * count / peak)) if count else 0)

    if h.below:
        rows.append((f"< {h.edges_ms[0]:.3f}", h.below))
    if len(occupied):
        for i in range(occupied[0], occupied[-1] + 1):
            rows.append((f"{h.edges_ms[i]:.3f} - {h.edges_ms[i + 1]:.3f}", int(h.counts[i])))
    if h.above:
        rows.append((f">= {h.edges_ms[-1]:.3f}", h.above))
    width = max(len(label) for label, _ in rows)
    digits = max(len(str(count)) for _, count in rows)
    lines = [f"{title}, bin {h.bin_ms:.3f} ms, {h.total} periods"]
    lines += [f"  {label.rjust(width)} ms  {str(count).rjust(digits)}  {bar(count)}".rstrip()
              for label, count in rows]
    return "\n".join(lines) + "\n"


# --- response-time analysis --------------------------------------------------------------------------


def ms3(us: float) -> str:
    return "inf" if math.isinf(us) else f"{us / 1e3:.3f}"


RTA_COLUMNS = ("name", "id", "dlc", "period_ms", "jitter_ms", "c_ms", "b_ms", "busy_ms", "q", "r_ms", "d_ms")


def rta_row(c: RtaCheck, with_trace: bool) -> dict:
    r, m = c.result, c.result.message
    row = {"name": m.name, "id": id_text(m.frame_id, m.extended), "dlc": m.dlc,
           "period_ms": f"{m.period_us / 1e3:g}", "jitter_ms": f"{m.jitter_us / 1e3:g}", "c_ms": ms3(r.c_us),
           "b_ms": ms3(r.blocking_us), "busy_ms": ms3(r.busy_period_us), "q": r.instances or "-",
           "r_ms": ms3(r.response_us), "d_ms": f"{m.deadline_us / 1e3:g}", "verdict": c.verdict}
    if with_trace:
        row["measured_ms"] = "" if c.measured is None else ms3(c.measured.max_us)
    return row


def rta_obj(c: RtaCheck) -> dict:
    r, m = c.result, c.result.message
    obj = {"name": m.name, "id": id_text(m.frame_id, m.extended), "extended": m.extended, "dlc": m.dlc,
           "sender": m.sender, "period_us": m.period_us, "deadline_us": m.deadline_us,
           "jitter_us": m.jitter_us, "c_us": jnum(r.c_us), "blocking_us": jnum(r.blocking_us),
           "busy_period_us": jnum(r.busy_period_us),
           "instances": r.instances, "response_us": jnum(r.response_us), "unbounded": r.unbounded,
           "schedulable": r.schedulable}
    if c.measured is not None:
        mr = c.measured
        obj["measured"] = {"frames": mr.frames, "cycles": mr.cycles, "missed": mr.missed,
                           "period_us": jnum(mr.period_us), "drift_ppm": jnum(mr.drift_ppm),
                           "p50_us": jnum(mr.p50_us), "p99_us": jnum(mr.p99_us), "max_us": jnum(mr.max_us)}
    return {**obj, "verdict": c.verdict, "reason": c.reason}


def rta_section_obj(report: RtaReport, checks: tuple[RtaCheck, ...]) -> dict:
    return {"bitrate_bps": report.bitrate_bps, "utilisation": jnum(report.utilisation),
            "worst_case_stuffing": True, "messages": [rta_obj(c) for c in checks],
            "schedulable": sum(c.result.schedulable for c in checks),
            "ok": all(c.verdict == "PASS" for c in checks)}


def rta_text(report: RtaReport, checks: tuple[RtaCheck, ...], with_trace: bool) -> str:
    columns = RTA_COLUMNS + (("measured_ms",) if with_trace else ()) + ("verdict",)
    schedulable = sum(c.result.schedulable for c in checks)
    failed = [c for c in checks if c.verdict != "PASS"]
    head = (f"response-time analysis (Davis et al. 2007, revised): {len(checks)} cyclic messages at "
            f"{report.bitrate_bps} bit/s, worst-case stuffing, D = cycle time; "
            f"utilisation {100 * report.utilisation:.2f} %\n")
    tail = f"{schedulable} of {len(checks)} schedulable"
    if with_trace:
        measured = [c for c in checks if c.measured is not None]
        within = sum(c.measured.max_us <= c.result.response_us + MEASURE_SLACK_US for c in measured)
        tail += f"; measured response within the bound for {within} of {len(measured)} messages in the trace"
    return (head + render_table(columns, [rta_row(c, with_trace) for c in checks], {"name", "id", "verdict"})
            + "".join(f"  {c.result.message.name}: FAIL: {c.reason}\n" for c in failed) + tail + "\n")


def rta_messages(db: Database, args: argparse.Namespace, bitrate: int, ignore: list[str] | None = None
                 ) -> RtaReport:
    from fnmatch import fnmatchcase

    ignore = args.ignore if ignore is None else ignore
    messages = [m for m in messages_from_dbc(db, parse_jitters(args.jitter))
                if not any(fnmatchcase(m.name, g) for g in ignore)]
    return rta_analyse(messages, bitrate)


# --- latency chains ----------------------------------------------------------------------------------


def latency_obj(s: LatencyStats) -> dict:
    return {"count": s.count, "p50_ms": jnum(s.p50_ms), "p99_ms": jnum(s.p99_ms), "max_ms": jnum(s.max_ms)}


def chain_obj(r: ChainResult) -> dict:
    links = r.chain.links
    return {"chain": str(r.chain), "links": [str(x) for x in links], "instances": r.instances,
            "completed": r.completed, "incomplete": r.incomplete, "overdue": r.overdue,
            "undecodable_frames": r.undecodable,
            "link_latency": [{"from": str(a), "to": str(b), **latency_obj(s)}
                             for a, b, s in zip(links[:-1], links[1:], r.links, strict=True)],
            "end_to_end": latency_obj(r.end_to_end), "max_ms": r.max_ms, "verdict": r.verdict,
            "reason": r.reason}


CHAIN_COLUMNS = ("link", "count", "p50_ms", "p99_ms", "max_ms")


def chain_text(n: int, r: ChainResult) -> str:
    links = r.chain.links

    def row(label: str, s: LatencyStats) -> dict:
        return {"link": label, "count": s.count, "p50_ms": num(s.p50_ms, ".3f"),
                "p99_ms": num(s.p99_ms, ".3f"), "max_ms": num(s.max_ms, ".3f")}

    rows = [row(f"{a} -> {b}", s) for a, b, s in zip(links[:-1], links[1:], r.links, strict=True)]
    rows.append(row("end to end", r.end_to_end))
    verdict = (f"{r.verdict} (limit {r.max_ms:g} ms)" + (f": {r.reason}" if r.reason else "")
               if r.verdict else "no verdict (no --chain-max-ms)")
    extra = f", {r.undecodable} frames did not decode" if r.undecodable else ""
    return (f"chain {n}: {r.chain}\n" + render_table(CHAIN_COLUMNS, rows, {"link"})
            + f"  {plural(r.instances, 'instance')}, {r.completed} completed, {r.incomplete} incomplete"
              f"{extra}; {verdict}\n")


def plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def tap(frames: Iterable[can.Message], keys: set[tuple[int, bool]], sink: list) -> Iterator[can.Message]:
    """Pass every frame on, keeping those of `keys` in `sink` (one read of the trace for both)."""
    for msg in frames:
        if (msg.arbitration_id, bool(msg.is_extended_id)) in keys:
            sink.append(msg)
        yield msg


# --- JUnit ---------------------------------------------------------------------------------------------


def junit(report: TimingReport | None, trace_name: str | None, rta: tuple[RtaCheck, ...] = (),
          chains: tuple[ChainResult, ...] = (), rta_report: RtaReport | None = None,
          dbc_name: str | None = None) -> str:
    """One <testsuite>: a testcase per cyclic message (classname railhil.timing), per --rta message
    (railhil.timing.rta) and per --chain (railhil.timing.chain)."""
    cases: list[tuple[str, str, str | None, str, str]] = []  # classname, name, failure type, message, detail
    if report is not None:
        for m in report.messages:
            cases.append((SUITE, f"{m.name} ({id_text(m.arbitration_id, m.extended)})",
                          None if m.verdict == "PASS" else m.verdict, f"{m.verdict}: {m.reason}",
                          json.dumps(timing_obj(m))))
    for c in rta:
        m = c.result.message
        cases.append((f"{SUITE}.rta", f"{m.name} ({id_text(m.frame_id, m.extended)})",
                      None if c.verdict == "PASS" else c.verdict, f"{c.verdict}: {c.reason}",
                      json.dumps(rta_obj(c))))
    for r in chains:
        cases.append((f"{SUITE}.chain", str(r.chain), "FAIL" if r.verdict == "FAIL" else None,
                      f"FAIL: {r.reason}", json.dumps(chain_obj(r))))
    failures = sum(1 for c in cases if c[2] is not None)
    suite = ET.Element("testsuite", name=SUITE, tests=str(len(cases)), failures=str(failures), errors="0",
                       skipped="0")
    props = ET.SubElement(suite, "properties")
    if trace_name is not None:
        ET.SubElement(props, "property", name="trace", value=trace_name)
    if dbc_name is not None:
        ET.SubElement(props, "property", name="dbc", value=dbc_name)
    if report is not None and report.load is not None:
        ET.SubElement(props, "property", name="bus_load_average", value=f"{report.load.average:.6f}")
        ET.SubElement(props, "property", name="bus_load_peak", value=f"{report.load.peak:.6f}")
    if rta_report is not None:
        ET.SubElement(props, "property", name="bitrate_bps", value=str(rta_report.bitrate_bps))
        ET.SubElement(props, "property", name="utilisation", value=f"{rta_report.utilisation:.6f}")
    for classname, name, failure_type, message, detail in cases:
        case = ET.SubElement(suite, "testcase", classname=classname, name=name)
        if failure_type is not None:
            failure = ET.SubElement(case, "failure", message=message, type=failure_type)
            failure.text = detail
        elif classname != SUITE:
            ET.SubElement(case, "system-out").text = detail
    ET.indent(suite)
    return ET.tostring(suite, encoding="unicode", xml_declaration=True) + "\n"


# --- the command ---------------------------------------------------------------------------------------


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


def bitrate_of(args: argparse.Namespace, db: Database, why: str) -> int:
    bitrate = args.bitrate if args.bitrate is not None else declared_bitrate(db)
    if bitrate is None:
        raise TimingArgError(f"{args.dbc}: no 'Baudrate' attribute: pass --bitrate BPS for {why}")
    return bitrate


def check_histogram_names(names: list[str], db: Database, ignore: list[str]) -> None:
    from fnmatch import fnmatchcase

    cyclic = [m.name for m in db.messages if m.cycle_time and m.cycle_time > 0]
    for name in names:
        if name not in cyclic:
            raise TimingArgError(f"--histogram {name!r}: no cyclic message named {name!r} in the DBC "
                                 f"(closest: {closest(name, cyclic)})")
        if any(fnmatchcase(name, g) for g in ignore):
            raise TimingArgError(f"--histogram {name!r}: the message is left out by --ignore")


def rta_only(args: argparse.Namespace) -> tuple[str, int]:
    """`railhil timing --rta --dbc DBC`: the analysis of the DBC alone."""
    if args.dbc is None:
        raise TimingArgError("--rta needs --dbc DBC")
    for option, given in (("--chain", args.chain), ("--histogram", args.histogram),
                          ("--periods-only", args.periods_only), ("--chain-max-ms", args.chain_max_ms)):
        if given:
            raise TimingArgError(f"{option} needs a trace: railhil timing TRACE --dbc DBC {option} ...")
    db = with_functions(load_dbc(args.dbc), function_names(args.function))
    report = rta_messages(db, args, bitrate_of(args, db, "the response-time analysis"))
    checks = tuple(rta_check(r) for r in report.results)
    code = 0 if all(c.verdict == "PASS" for c in checks) else 1
    if args.format == "json":
        text = json.dumps({"dbc": str(args.dbc), "rta": rta_section_obj(report, checks), "ok": code == 0},
                          indent=2) + "\n"
    elif args.format == "junit":
        text = junit(None, None, checks, rta_report=report, dbc_name=str(args.dbc))
    else:
        text = f"{args.dbc}:\n" + rta_text(report, checks, with_trace=False)
    return text, code


@dataclass(frozen=True)
class RunScope:
    """What a run's trace is judged on: the run, the cyclic messages of the DBC left out because its nodes
    do not send them (`left_out`), and the line that says so."""

    run: RunOfTrace
    left_out: tuple[str, ...]
    line: str


def run_scope(args: argparse.Namespace, timebase: TimeBase, db: Database) -> RunScope | None:
    """The scope of a run's trace (the module docstring): None for a trace of no run, with --all-messages,
    for a trace of the run's folder other than the run's own (a device's bus) without --run, or when
    run.json does not say what the run sends."""
    run = timebase.run
    if run is None or args.all_messages or args.trace == "-":
        return None
    if args.run is None and Path(args.trace).name != run.trace.name:
        return None
    sent = run.messages_sent()
    if not sent or not sent & {m.name for m in db.messages}:
        print(f"notice: {run.folder / 'run.json'}: does not say which messages the run sends (or none is in "
              f"{args.dbc}): every cyclic message in scope is judged", file=sys.stderr)
        return None
    asked = set(function_names(args.function))
    left = tuple(m.name for m in db.messages if m.cycle_time and m.cycle_time > 0 and m.name not in sent
                 and not ({"all", optional_function(m)} & asked))
    if not left:
        return RunScope(run, (), f"run {run.describe()}: every cyclic message of the DBC is one it sends")
    line = (f"run {run.describe()}: left out {len(left)} cyclic messages of the DBC that its nodes do not "
            f"send ({why_left_out(left, db, run)}); --all-messages judges them too")
    return RunScope(run, left, line)


def why_left_out(left: tuple[str, ...], db: Database, run: RunOfTrace) -> str:
    """The messages a run does not send, in kinds: the frames of cars its train does not have, of the
    optional functions (DBC RailhilFunction) it has not, and any other by name."""
    import re

    cars = (run.scenario.get("train") or {}).get("cars")
    by_name = {m.name: m for m in db.messages}
    per_car, functions, other = [], {}, []
    for name in left:
        car = re.match(r"^(?:BECU|PLANT_CAR)(\d+)_", name)
        function = optional_function(by_name[name])
        if car and cars and int(car.group(1)) > int(cars):
            per_car.append(int(car.group(1)))
        elif function:
            functions[function] = functions.get(function, 0) + 1
        else:
            other.append(name)
    parts = []
    if per_car:
        lo, hi = min(per_car), max(per_car)
        parts.append(f"{len(per_car)} of car{'s' if hi > lo else ''} {lo}{f'–{hi}' if hi > lo else ''}, "
                     f"beyond its {cars}-car train")
    if functions:
        parts.append(f"{sum(functions.values())} of functions it does not have: "
                     + ", ".join(f"{f} {n}" for f, n in sorted(functions.items())))
    if other:
        parts.append(", ".join(other[:6]) + (f" and {len(other) - 6} more" if len(other) > 6 else ""))
    return "; ".join(parts)


def trace_report(args: argparse.Namespace, trace_name: str) -> tuple[str, int, TraceError | None]:
    """`railhil timing TRACE --dbc DBC [--rta] [--chain ...] [--histogram ...]`: the report, its exit
    code, and the error of a damaged trace (the report is of the frames read before it)."""
    if args.dbc is None:
        raise TimingArgError("--dbc DBC is required (or --periods-only for periods without a DBC)")
    check_tolerance(args.tolerance, "--tolerance")
    timebase = TimeBase.of(args, args.trace)
    full = load_dbc(args.dbc)
    scope = run_scope(args, timebase, with_functions(full, ["all"]))
    db = with_functions(full, ["all"] if scope is not None else function_names(args.function))
    ignore = [*args.ignore, *(scope.left_out if scope is not None else ())]
    overrides = parse_overrides(args.override, [m.name for m in db.messages])
    bitrate = bitrate_of(args, db, "the bus load")
    chains: list[Chain] = [parse_chain(text, db) for text in args.chain]
    check_histogram_names(args.histogram, db, ignore)
    rta_report = rta_messages(db, args, bitrate, ignore) if args.rta else None
    kept: list[can.Message] = []
    if chains:                      # chains need the frames themselves: one pass through python-can
        trace = open_trace(args.trace)
        frames = Salvage(trace)
        arrays = frame_arrays(tap(timebase.messages(frames), chain_frame_keys(chains), kept))
        damage = frames.error
    else:                           # columns only: BLF read without a can.Message per frame
        arrays, trace = read_trace_columns(args.trace, salvage=True)
        damage = trace.error
        arrays = timebase.arrays(arrays)
    if damage is not None and timebase.first is None:  # nothing read: the error alone
        raise damage
    notice_skipped(trace)
    timebase.warn_outside(trace_name)
    report = analyse(arrays, db, args.tolerance, overrides, bitrate, args.window, ignore=ignore)
    rta = rta_against_trace(arrays, rta_report) if rta_report is not None else ()
    end_s = float(arrays.t.max()) if len(arrays) else 0.0  # the end of the trace, as hil.trace.timing.analyse
    chain_results = analyse_chains(kept, chains, end_s, args.chain_max_ms) if chains else ()
    ok = (report.ok and all(c.verdict == "PASS" for c in rta)
          and all(r.verdict != "FAIL" for r in chain_results))
    code = 0 if ok else 1
    by_name = {m.name: m for m in report.messages}
    if args.format == "json":
        obj = {"trace": trace_name, "dbc": str(args.dbc), "tolerance": args.tolerance,
               "times": timebase.describe(), "start_s": args.start, "end_s": args.end,
               "run": None if scope is None else {
                   "folder": str(scope.run.folder), "left_out": list(scope.left_out),
                   "why": "not sent by the run's nodes (run.json messages_sent)"},
               "frames": report.frames, "duration_s": report.duration_s,
               "messages": [{**timing_obj(m), "histogram": histogram_obj(histogram_of(m))}
                            for m in report.messages],
               "unknown_ids": {id_text(i, e): n for (i, e), n in report.unknown.items()},
               "non_cyclic_frames": report.non_cyclic, "bus_load": load_obj(report.load),
               "summary": report.counts()}
        if rta_report is not None:
            obj["rta"] = rta_section_obj(rta_report, rta)
        if chains:
            obj["chains"] = [chain_obj(r) for r in chain_results]
        obj["ok"] = ok
        text = json.dumps(obj, indent=2) + "\n"
    elif args.format == "junit":
        text = junit(report, trace_name, rta, chain_results, rta_report, str(args.dbc))
    else:
        rows = [timing_row(m) for m in report.messages]
        window = (f", frames between {num(args.start, 'g') or '-inf'} and {num(args.end, 'g') or 'inf'} s"
                  if timebase.windowed else "")
        text = (f"{trace_name}: {report.frames} frames over {report.duration_s:.6f} s{window} "
                f"against {args.dbc}, tolerance ±{100 * args.tolerance:g} %"
                + (f"; {timebase.describe()}" if timebase.windowed or timebase.shifted else "") + "\n"
                + (scope.line + "\n" if scope is not None else "")
                + render_table(TIMING_COLUMNS, rows, {"name", "id", "verdict"})
                + "".join(f"  {m.name}: {m.verdict}: {m.reason}\n" for m in report.messages if m.reason)
                + summary_line(report) + "\n" + load_line(report.load) + "\n")
        for name in args.histogram:
            text += "\n" + histogram_text(by_name[name], histogram_of(by_name[name]))
        if rta_report is not None:
            text += "\n" + rta_text(rta_report, rta, with_trace=True)
        for n, r in enumerate(chain_results, 1):
            text += "\n" + chain_text(n, r)
    return text, code, damage


def timing(args: argparse.Namespace) -> int:
    if not args.window > 0 or not math.isfinite(args.window):
        raise TimingArgError(f"--window {args.window}: expected a positive number of seconds")
    if args.bitrate is not None and args.bitrate <= 0:
        raise TimingArgError(f"--bitrate {args.bitrate}: expected a positive bitrate in bit/s")
    if args.chain_max_ms is not None:
        if not (math.isfinite(args.chain_max_ms) and args.chain_max_ms > 0):
            raise TimingArgError(f"--chain-max-ms {args.chain_max_ms}: expected a positive number of ms")
        if not args.chain:
            raise TimingArgError("--chain-max-ms is the limit of --chain: give at least one --chain")
    if args.jitter and not args.rta:
        raise TimingArgError("--jitter is an input of the response-time analysis: add --rta")
    if args.trace is None:
        if not args.rta:
            raise TimingArgError("a trace file is required (or --rta --dbc DBC for the response-time "
                                 "analysis of the DBC alone)")
        text, code = rta_only(args)
        damage = None
    elif args.periods_only:
        for option, given in (("--override", args.override), ("--rta", args.rta), ("--chain", args.chain),
                              ("--histogram", args.histogram)):
            if given:
                raise TimingArgError(f"{option} needs a DBC verdict, not --periods-only")
        trace_name = "<stdin>" if args.trace == "-" else str(args.trace)
        timebase = TimeBase.of(args, args.trace)
        arrays, trace = read_trace_columns(args.trace, salvage=True)
        damage = trace.error
        if damage is not None and not len(arrays):  # nothing read: the error alone
            raise damage
        arrays = timebase.arrays(arrays)
        notice_skipped(trace)
        timebase.warn_outside(trace_name)
        load = bus_load(arrays, args.bitrate, args.window) if args.bitrate is not None else None
        text, code = periods_report(measure_periods(arrays), args.format, trace_name, load), 0
    else:
        text, code, damage = trace_report(args, "<stdin>" if args.trace == "-" else str(args.trace))
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
    if damage is not None:  # the report above is of the frames read before the damage
        raise damage
    return code
