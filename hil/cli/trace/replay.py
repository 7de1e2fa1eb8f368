"""`railhil trace replay TRACE` — send a trace's frames onto a python-can bus at their recorded times.

Frame k is due at ``(t_k − t_first) / speed`` seconds after the replay starts (t = the timestamps of
the frames selected by --start/--end/--id, on the trace's time base: hil.cli.trace.timebase); the
sender sleeps on the monotonic clock until then (absolute deadlines, so errors do not accumulate) and
hands the frame to ``bus.send``.
``--speed 0`` or ``--max-speed`` sends back to back.  Error frames cannot be sent and are counted.

Report (stdout; ``--format json`` for a machine):

- frames sent, and frames dropped: ``bus.send`` raised (a send error, or the bus's transmit buffer
  stayed full for --send-timeout) -- counted and reported, never raised;
- send Δt error: the instant ``bus.send`` was called minus the frame's due time, in µs, p50 / p99 /
  max over the frames sent (positive = late);
- with ``--verify``: a second bus instance on the same channel, in a process of its own
  (udp_multicast delivers to every other bus instance on the group and port; socketcan loops frames
  back to the other sockets on the device) records what arrives;
  received frames are matched in order to the frames sent (same id, 11/29-bit, remote, FD, DLC and
  data): received, missing, and foreign (received but not sent, or out of order); receive Δt error =
  the receiver's timestamp minus the due time, in µs (for interfaces that stamp frames with
  time.time()'s clock, as udp_multicast and socketcan do).

Exit 0 when every frame was sent (and, with --verify, received), 1 when some were dropped or
missing, 130 after Ctrl-C (the report covers what was sent until then), 2 for bad input, 3 when the
bus cannot be opened.

Bus: python-can's flags (-i/--interface, -c/--channel, -b/--bitrate, --fd, --bus-kwargs KEY=VALUE
...), then python-can's own configuration (CAN_* environment variables, ~/.canrc), else
udp_multicast on python-can's default group and port, where ``python -m can.viewer -i udp_multicast``
and other tools listen by default.  (A real-time ``railhil run`` picks a group of its own: replay
into it with the channel and port it prints.)
"""

from __future__ import annotations

import argparse
import gc
import inspect
import json
import logging
import math
import multiprocessing as mp
import signal
import sys
import time
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import can
import can.cli
import numpy as np

from hil.cli.bus_args import bus_config_from_args
from hil.cli.trace.common import Output, TraceArgError, notice_skipped, parse_id
from hil.cli.trace.timebase import TimeBase, add_time_arguments
from hil.errors import BusError
from hil.progress import progress_bar
from hil.trace.readers import Salvage, open_trace

DEFAULT_INTERFACE = "udp_multicast"
SEND_TIMEOUT_S = 0.01      # bus.send waits at most this long for room in the transmit buffer
VERIFY_QUIET_S = 1.0       # --verify stops waiting for missing frames after this long without one
INTERRUPT_QUIET_S = 0.2    # ... and after Ctrl-C, this long
RECEIVER_READY_S = 60.0    # the --verify receiver process must have opened its bus within this time
PROGRESS_DELAY_S = 1.0     # the progress bar appears once a replay has run this long
SLEEP_SLICE_S = 0.05       # a long wait for the next frame wakes this often to honour Ctrl-C
READ_AHEAD = 20_000        # frames read ahead of the sender (before the start, then in the slack)
READ_SLACK_NS = 300_000    # reading ahead stops this long before the next frame is due
MATCH_LOOKAHEAD = 100_000  # a received frame is searched this far ahead among the frames sent
FORMAT_CHOICES = ("table", "json")


def add_parser(tsub: argparse._SubParsersAction) -> None:
    p = tsub.add_parser(
        "replay",
        help="send a trace's frames onto a python-can bus at their recorded times; report fidelity",
        description="Replay the frames of a trace onto a python-can bus at their recorded relative "
                    "times divided by --speed, paced on the monotonic clock. Reports frames sent and "
                    "dropped and the send-time error against the schedule (p50/p99/max, µs); --verify "
                    "also receives on a second bus instance and reports frames received/missing and "
                    "the receive-time error. Bus: the flags below, else python-can's configuration "
                    "(CAN_* environment variables, ~/.canrc), else udp_multicast on python-can's "
                    "default group and port. Exit 0 all sent (and received), 1 some dropped/missing, "
                    "130 interrupted, 2 bad input, 3 bus cannot be opened.",
    )
    p.add_argument("trace", help="trace file, or '-' for candump -L text on stdin")
    p.add_argument("--speed", type=float, default=1.0, metavar="FACTOR",
                   help="replay speed: 1 = as recorded (default), 2 = twice as fast, 0 = as fast as possible")
    p.add_argument("--max-speed", action="store_true", help="send back to back, ignoring the timestamps")
    add_time_arguments(p)
    p.add_argument("--id", dest="ids", action="append", default=[], metavar="ID",
                   help="only frames with this arbitration id, hex (0x123) or decimal; repeatable")
    p.add_argument("--verify", action="store_true",
                   help="receive on a second bus instance on the same channel and check that every frame "
                        "arrives, in order, with its id and data")
    p.add_argument("--send-timeout", type=float, default=SEND_TIMEOUT_S, metavar="S",
                   help=f"how long bus.send may wait for room in the transmit buffer before the frame "
                        f"counts as dropped, seconds (default {SEND_TIMEOUT_S})")
    p.add_argument("--verify-wait", type=float, default=VERIFY_QUIET_S, metavar="S",
                   help=f"--verify: stop waiting for missing frames after S seconds without a new one "
                        f"(default {VERIFY_QUIET_S})")
    p.add_argument("--format", choices=FORMAT_CHOICES, default="table", help="report format (default table)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    can.cli.add_bus_arguments(p, group_title="bus arguments (python-can's flags)")
    for action in p._actions:  # a bad --interface is our one-line error, not argparse's usage dump
        if action.dest == "channel":
            action.help = ("channel of the interface: vcan0 for socketcan; for udp_multicast a multicast "
                           "group, IPv6 or IPv4 such as 239.255.1.2 (default: python-can's group)")
        if action.dest == "bus_kwargs":
            action.help = ("further keyword arguments of the python-can bus, e.g. port=43113 for "
                           "udp_multicast (--bus-kwarg works too)")
        if action.dest == "interface":
            action.choices = None
            action.metavar = "INTERFACE"
            action.help = (f"python-can interface (default: python-can's configuration, else "
                           f"{DEFAULT_INTERFACE}); one of {', '.join(sorted(can.VALID_INTERFACES))}")
    p.set_defaults(func=run)


# --- the bus -----------------------------------------------------------------------------------


def bus_config(args: argparse.Namespace) -> dict:
    """python-can's precedence: flags, then python-can's configuration, else udp_multicast."""

    cfg = bus_config_from_args(args)
    interface = cfg.get("interface")
    if interface is not None and interface not in can.VALID_INTERFACES:
        raise TraceArgError(f"--interface {interface!r}: not a python-can interface; expected one of "
                            f"{', '.join(sorted(can.VALID_INTERFACES))}")
    if interface is None:
        try:
            configured = dict(can.util.load_config()).get("interface")
        except (can.CanError, ValueError):  # python-can has no (valid) configuration here
            configured = None
        if not configured:
            cfg["interface"] = DEFAULT_INTERFACE
    if cfg.get("interface") == "socketcan" and not cfg.get("channel"):
        cfg["channel"] = "vcan0"    # as hil.runtime.realtime: the virtual CAN device `make vcan` sets up
    return cfg


def describe(cfg: dict) -> str:
    interface = cfg.get("interface") or "python-can's configured interface"
    channel = cfg.get("channel")
    port = cfg.get("port")
    if interface == "udp_multicast":
        from can.interfaces.udp_multicast import UdpMulticastBus

        if channel is None:
            channel = f"{UdpMulticastBus.DEFAULT_GROUP_IPv6} (python-can's default group)"
        if port is None:
            port = inspect.signature(UdpMulticastBus.__init__).parameters["port"].default
    if channel is None:
        channel = "(the interface's default)"
    return f"interface={interface} channel={channel}" + ("" if port is None else f" port={port}")


class _CanLogs(logging.Handler):
    """python-can's log records while a bus opens: an interface module that warns at import, or a
    half-opened bus that complains when it is collected, must not add loose lines to a one-line error."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if "was not properly shut down" not in record.getMessage():
            self.lines.append(" ".join(record.getMessage().split()))

    def __enter__(self) -> _CanLogs:
        self.logger = logging.getLogger("can")
        self.propagate = self.logger.propagate
        self.logger.addHandler(self)
        self.logger.propagate = False
        return self

    def __exit__(self, *exc_info) -> None:
        self.logger.removeHandler(self)
        self.logger.propagate = self.propagate


def try_open(cfg: dict) -> tuple[can.BusABC | None, str, list[str]]:
    """(bus or None, why not, python-can's warnings) -- never raises."""
    with _CanLogs() as logs:
        try:
            return can.Bus(**cfg), "", logs.lines
        except Exception as exc:  # python-can raises many types; all mean "this bus cannot be opened here"
            detail = " ".join(str(exc).split()) or type(exc).__name__
        gc.collect()              # the half-opened bus object goes now, while its warning is caught
    return None, detail, logs.lines


def bus_error(cfg: dict, detail: str) -> BusError:
    hint = ""
    if cfg.get("interface") == "socketcan":
        hint = " (no SocketCAN here? `make vcan` sets up vcan0 where the kernel allows it)"
    return BusError(f"cannot open the python-can bus {describe(cfg)}: {detail}{hint}")


def open_bus(cfg: dict) -> can.BusABC:
    bus, detail, notices = try_open(cfg)
    if bus is None:
        raise bus_error(cfg, detail)
    for line in notices:
        print(f"notice: python-can: {line}", file=sys.stderr)
    return bus


# --- the replay ----------------------------------------------------------------------------------


def identity(msg: can.Message) -> tuple:
    """What must arrive unchanged: id, 11/29-bit, remote, FD, DLC, data."""
    return (msg.arbitration_id, bool(msg.is_extended_id), bool(msg.is_remote_frame), bool(msg.is_fd),
            msg.dlc, bytes(msg.data))


def outgoing(msg: can.Message) -> can.Message:
    """The frame to send: the trace's content, without its channel (which would route it elsewhere)."""
    return can.Message(arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                       is_remote_frame=msg.is_remote_frame, is_fd=msg.is_fd,
                       bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator,
                       dlc=msg.dlc if msg.is_remote_frame else None,
                       data=b"" if msg.is_remote_frame else bytes(msg.data), check=False)


def _receive(cfg: dict, ready, sent_count, quiet_s, conn) -> None:
    """The verifying receiver, in a process of its own (a thread would wait for the sender's GIL and
    delay it by up to the interpreter's 5 ms switch interval).  Records (identity, timestamp) of
    every frame until ``sent_count`` (set by the sender when it is done, -1 before) frames have come
    or none has come for ``quiet_s`` seconds after the sender was done; sends them through ``conn``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)          # the parent coordinates Ctrl-C
    bus, detail, _ = try_open(cfg)
    if bus is None:
        conn.send(("error", detail))
        return
    frames: list[tuple[tuple, float]] = []
    error = ""
    try:
        ready.set()
        last = time.monotonic()
        done_at = None
        while True:
            msg = bus.recv(timeout=0.05)
            now = time.monotonic()
            if msg is not None:
                frames.append((identity(msg), msg.timestamp))
                last = now
            n = sent_count.value
            if n < 0:
                continue
            if done_at is None:
                done_at = now
            if len(frames) >= n or now - max(last, done_at) > quiet_s.value:
                break
    except Exception as exc:  # a receive error ends the recording; what came until then is reported
        error = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    finally:
        bus.shutdown()
    conn.send(("frames", frames, error))


class Receiver:
    """The verifying bus instance, in its own process (see ``_receive``)."""

    def __init__(self, cfg: dict) -> None:
        ctx = mp.get_context("fork" if sys.platform.startswith("linux") else "spawn")
        self.conn, child = ctx.Pipe(duplex=False)
        self.ready = ctx.Event()
        self.sent_count = ctx.RawValue("q", -1)
        self.quiet_s = ctx.RawValue("d", VERIFY_QUIET_S)
        self.cfg = cfg
        self.proc = ctx.Process(target=_receive, args=(cfg, self.ready, self.sent_count, self.quiet_s, child),
                                name="railhil-replay-verify", daemon=True)
        self.proc.start()
        child.close()

    def wait_ready(self, timeout_s: float = RECEIVER_READY_S) -> None:
        deadline = time.monotonic() + timeout_s
        while not self.ready.wait(0.05):
            if self.conn.poll():
                raise bus_error(self.cfg, self.conn.recv()[1])
            if not self.proc.is_alive() or time.monotonic() > deadline:
                raise BusError(f"the --verify receiver on {describe(self.cfg)} did not start "
                               f"within {timeout_s:.0f} s")

    def finish(self, sent: int, quiet_s: float) -> tuple[list[tuple[tuple, float]], str]:
        """Tell the receiver how many frames were sent; its frames and receive error, once it is done."""
        self.quiet_s.value = quiet_s
        self.sent_count.value = sent
        while True:
            try:
                while not self.conn.poll(0.1):
                    if not self.proc.is_alive() and not self.conn.poll():
                        return [], f"the receiver process ended (exit code {self.proc.exitcode})"
                _, frames, error = self.conn.recv()
                return frames, error
            except KeyboardInterrupt:
                self.quiet_s.value = min(quiet_s, INTERRUPT_QUIET_S)   # a second Ctrl-C: stop sooner

    def close(self) -> None:
        self.proc.join(timeout=2.0)
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(timeout=2.0)
        self.conn.close()


def match_in_order(sent: list[tuple], received: list[tuple]) -> tuple[list[tuple[int, int]], int, int]:
    """Match received frames to sent ones in order: ([(sent index, received index)], missing, foreign).

    A received frame that is not the next one expected is searched for further ahead (the frames in
    between are missing); one not found at all is foreign (not sent by us, or out of order).
    """
    pairs = []
    foreign = 0
    j = 0
    for k, frame in enumerate(received):
        if j < len(sent) and sent[j] == frame:
            pairs.append((j, k))
            j += 1
            continue
        for i in range(j + 1, min(len(sent), j + MATCH_LOOKAHEAD)):
            if sent[i] == frame:
                pairs.append((i, k))
                j = i + 1
                break
        else:
            foreign += 1
    return pairs, len(sent) - len(pairs), foreign


def percentiles(values_us: list[float]) -> dict | None:
    if not values_us:
        return None
    a = np.asarray(values_us)
    return {"p50_us": round(float(np.percentile(a, 50)), 1), "p99_us": round(float(np.percentile(a, 99)), 1),
            "max_us": round(float(a.max()), 1)}


@dataclass
class Replay:
    """What a replay did; times in seconds unless the name says µs."""

    trace: str
    bus: str
    speed: float                          # 0 = as fast as possible
    sent: int = 0
    dropped: int = 0                      # bus.send raised: send error, or transmit buffer full
    first_drop: str = ""
    not_sendable: int = 0                 # error frames
    trace_span_s: float = 0.0             # first to last frame selected, trace time
    wall_s: float = 0.0                   # first send to last send
    interrupted: bool = False
    send_err_us: list[float] = field(default_factory=list)
    verify: bool = False
    received: int = 0
    matched: int = 0
    missing: int = 0
    foreign: int = 0
    rx_err_us: list[float] = field(default_factory=list)
    rx_error: str = ""
    # per frame sent: identity, due time after the start [s]
    log: list[tuple[tuple, float]] = field(default_factory=list, repr=False)

    @property
    def ok(self) -> bool:
        return self.dropped == 0 and (not self.verify or (self.missing == 0 and not self.rx_error))

    def as_dict(self) -> dict:
        doc = {"trace": self.trace, "bus": self.bus, "speed": self.speed, "frames_sent": self.sent,
               "frames_dropped": self.dropped, "first_drop_error": self.first_drop or None,
               "error_frames_not_sent": self.not_sendable, "trace_span_s": self.trace_span_s,
               "wall_s": self.wall_s, "interrupted": self.interrupted,
               "send_dt_error": percentiles(self.send_err_us)}
        if self.verify:
            doc["verify"] = {"frames_received": self.received, "frames_matched": self.matched,
                             "frames_missing": self.missing, "frames_foreign": self.foreign,
                             "receive_dt_error": percentiles(self.rx_err_us),
                             "receive_error": self.rx_error or None}
        return doc

    def summary(self) -> str:
        text = f"replay: {self.sent} frames sent, {self.dropped} dropped"
        if self.verify:
            text += (f"; verify: {self.matched} received in order, {self.missing} missing, "
                     f"{self.foreign} foreign")
        if self.interrupted:
            text += "; interrupted"
        return text

    def lines(self) -> list[str]:
        speed = "as fast as possible" if self.speed == 0 else f"{self.speed:g}x"
        rate = self.sent / self.wall_s if self.wall_s > 0 else math.nan
        first_drop = f" (first: {self.first_drop})" if self.first_drop else ""
        out = [f"replay {self.trace} -> {self.bus}, speed {speed}",
               f"frames sent        {self.sent}",
               f"frames dropped     {self.dropped}{first_drop}",
               f"error frames       {self.not_sendable} (not sendable, skipped)",
               f"duration           {self.trace_span_s:.6f} s of trace in {self.wall_s:.6f} s"
               + ("" if math.isnan(rate) else f" ({rate:.0f} frames/s)"),
               "send Δt error      " + dt_text(self.send_err_us, self.speed)]
        if self.verify:
            out += [f"frames received    {self.received} ({self.matched} in order as sent, {self.missing} "
                    f"missing, {self.foreign} foreign or out of order)",
                    "receive Δt error   " + dt_text(self.rx_err_us, self.speed)]
            if self.rx_error:
                out.append(f"receive error      {self.rx_error}")
        return out


def dt_text(values_us: list[float], speed: float) -> str:
    if speed == 0:
        return "n/a (as fast as possible: no schedule)"
    p = percentiles(values_us)
    if p is None:
        return "n/a (no frame)"
    return f"p50 {p['p50_us']:.0f} µs, p99 {p['p99_us']:.0f} µs, max {p['max_us']:.0f} µs (vs schedule)"


def selected(frames: Iterable[can.Message], report: Replay, start: float | None, end: float | None,
             ids: set[int] | None) -> Iterator[tuple[float, can.Message]]:
    """(trace time, frame to send) of the frames within the filters; error frames are counted."""
    for msg in frames:
        t = msg.timestamp
        if (start is not None and t < start) or (end is not None and t > end):
            continue
        if ids is not None and (msg.is_error_frame or msg.arbitration_id not in ids):
            continue
        if msg.is_error_frame:
            report.not_sendable += 1
            continue
        yield t, outgoing(msg)


class ReadAhead:
    """Frames read ahead of the sender, so reading the trace (a BLF container is decompressed at
    once) happens before the replay starts and in the slack before due times, not late."""

    def __init__(self, source: Iterator[tuple[float, can.Message]], size: int = READ_AHEAD) -> None:
        self.source = source
        self.size = size
        self.queue: deque[tuple[float, can.Message]] = deque()
        self.exhausted = False

    def fill(self, until_ns: int | None = None) -> None:
        """Read until the queue is full, the trace ends, or the monotonic clock reaches until_ns."""
        queue, size, source = self.queue, self.size, self.source
        while not self.exhausted and len(queue) < size:
            if until_ns is not None and time.monotonic_ns() >= until_ns:
                return
            try:
                queue.append(next(source))
            except StopIteration:
                self.exhausted = True

    def pop(self) -> tuple[float, can.Message] | None:
        if not self.queue and not self.exhausted:
            self._one()
        return self.queue.popleft() if self.queue else None

    def _one(self) -> None:
        try:
            self.queue.append(next(self.source))
        except StopIteration:
            self.exhausted = True


class Interrupt:
    """Ctrl-C as a flag the send loop checks between frames, so a frame is never half counted (sent
    but not in the report); outside the main thread (no signal handler possible) KeyboardInterrupt."""

    def __init__(self) -> None:
        self.set = False
        self.previous = None

    def __enter__(self) -> Interrupt:
        try:
            self.previous = signal.signal(signal.SIGINT, self.handler)
        except ValueError:  # not the main thread
            self.previous = None
        return self

    def handler(self, signum, frame) -> None:
        self.set = True

    def __exit__(self, *exc_info) -> None:
        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)


def sleep_until(due_ns: int, interrupt: Interrupt) -> None:
    """Sleep on the monotonic clock until due_ns, waking every SLEEP_SLICE_S to honour Ctrl-C."""
    while not interrupt.set:
        remaining = due_ns - time.monotonic_ns()
        if remaining <= 0:
            return
        time.sleep(min(remaining / 1e9, SLEEP_SLICE_S))


def drop_reason(exc: Exception, send_timeout: float) -> str:
    text = " ".join(str(exc).split())
    if not text and isinstance(exc, can.CanTimeoutError):
        text = f"no room in the transmit buffer within --send-timeout {send_timeout:g} s"
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def send_all(frames: Iterable[can.Message], bus: can.BusABC, report: Replay, start: float | None,
             end: float | None, ids: set[int] | None, send_timeout: float, progress) -> float:
    """Send the selected frames at their due times; fills ``report``; returns time.time() at start."""
    speed = report.speed
    t0_ns = 0
    wall0 = 0.0
    ts0 = None
    last_ts = 0.0
    last_send_ns = 0
    monotonic_ns = time.monotonic_ns
    ahead = ReadAhead(selected(frames, report, start, end, ids))
    with Interrupt() as interrupt:
        try:
            ahead.fill()
            while not interrupt.set and (item := ahead.pop()) is not None:
                t, frame = item
                if ts0 is None:
                    ts0 = t
                    t0_ns = monotonic_ns()
                    wall0 = time.time()
                due_s = (t - ts0) / speed if speed else 0.0
                due_ns = t0_ns + round(due_s * 1e9)
                if speed:
                    ahead.fill(until_ns=due_ns - READ_SLACK_NS)
                    sleep_until(due_ns, interrupt)
                    if interrupt.set:
                        break
                last_ts = t
                now = monotonic_ns()
                try:
                    bus.send(frame, timeout=send_timeout)
                except (can.CanError, OSError, ValueError, TypeError) as exc:  # counted, never raised
                    report.dropped += 1
                    if not report.first_drop:
                        report.first_drop = drop_reason(exc, send_timeout)
                    continue
                last_send_ns = now
                report.sent += 1
                if speed:
                    report.send_err_us.append((now - due_ns) / 1e3)
                report.log.append((identity(frame), due_s if speed else (now - t0_ns) / 1e9))
                if progress is not None:
                    progress.update()
        except KeyboardInterrupt:
            interrupt.set = True
    report.interrupted = interrupt.set
    report.trace_span_s = last_ts - ts0 if ts0 is not None else 0.0
    report.wall_s = (last_send_ns - t0_ns) / 1e9 if last_send_ns else 0.0
    return wall0


def verify(report: Replay, receiver: Receiver, wall0: float, quiet_s: float) -> None:
    """Match what the receiver recorded against what was sent (``report.log``)."""
    received, report.rx_error = receiver.finish(report.sent, INTERRUPT_QUIET_S if report.interrupted
                                                else quiet_s)
    report.received = len(received)
    sent = [ident for ident, _ in report.log]
    pairs, report.missing, report.foreign = match_in_order(sent, [ident for ident, _ in received])
    report.matched = len(pairs)
    if report.speed:
        report.rx_err_us = [(received[k][1] - (wall0 + report.log[i][1])) * 1e6 for i, k in pairs]


def run(args: argparse.Namespace) -> int:
    speed = 0.0 if args.max_speed else args.speed
    if not (math.isfinite(speed) and speed >= 0):
        raise TraceArgError(f"--speed {args.speed}: expected a factor > 0, or 0 for as fast as possible")
    if not (math.isfinite(args.send_timeout) and args.send_timeout >= 0):
        raise TraceArgError(f"--send-timeout {args.send_timeout}: expected seconds >= 0")
    if not (math.isfinite(args.verify_wait) and args.verify_wait >= 0):
        raise TraceArgError(f"--verify-wait {args.verify_wait}: expected seconds >= 0")
    timebase = TimeBase.of(args, args.trace)
    ids = {parse_id(t) for t in args.ids} or None
    cfg = bus_config(args)
    if args.verify and cfg.get("interface") == "virtual":
        raise TraceArgError("--verify -i virtual: python-can's virtual bus lives inside one process; the "
                            "verifying receiver runs in another (use udp_multicast or socketcan)")
    trace = open_trace(args.trace)
    report = Replay(trace.name, describe(cfg), speed, verify=args.verify)
    receiver = bus = progress = None
    try:
        if args.verify:  # started first: it must hear the first frame, and must not inherit our bus
            receiver = Receiver(cfg)
            receiver.wait_ready()
        bus = open_bus(cfg)
        progress = progress_bar(enabled=not args.quiet, desc="replay", unit=" frames", delay=PROGRESS_DELAY_S,
                                leave=False)
        frames = Salvage(trace)  # a corrupt or cut file: the frames before the damage are replayed
        wall0 = send_all(timebase.messages(frames), bus, report, None, None, ids, args.send_timeout,
                         None if progress.disable else progress)     # no call a frame for a bar not drawn
        if progress is not None:
            progress.close()
            progress = None
        if receiver is not None:
            verify(report, receiver, wall0, args.verify_wait)
    finally:
        if progress is not None:
            progress.close()
        if bus is not None:
            bus.shutdown()
        if receiver is not None:
            receiver.close()
    notice_skipped(trace)
    timebase.warn_outside(trace.name)
    out = Output()
    if args.format == "json":
        out.write(json.dumps(report.as_dict(), indent=1) + "\n")
        print(report.summary(), file=sys.stderr)
    else:
        for line in [*report.lines(), report.summary()]:
            out.write(line + "\n")
    out.flush()
    frames.raise_error()  # after the report of what was replayed
    if report.interrupted:
        return 130
    return 0 if report.ok else 1
