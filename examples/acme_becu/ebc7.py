"""ACME EBC-7: the brake ECU of one car, as a program on its own CAN bus — not railhil.

It reads its own matrix (acme_becu.dbc) with cantools, talks on the bus with python-can, protects and
checks its frames as that matrix's interface specification says (AUTOSAR E2E profiles 5 and 11 through
the autosar-e2e package; a plain 4-bit counter with an XOR or a sum checksum by hand) and runs its control
law (ebc7_control.py) every 10 ms on absolute deadlines:

    python examples/acme_becu/ebc7.py                        # its default bus: acme_becu.toml's [bus]
    python examples/acme_becu/ebc7.py -i socketcan -c can1   # any python-can bus

Receives VCU_BRAKE_DEMAND (E2E P05) and VCU_WHEEL_DATA (counter + XOR); a frame that fails its check is
dropped and counted.  Sends EBC7_VALVE_CMD (E2E P11) every 10 ms and EBC7_STATUS (counter + sum) every
20 ms, its pages in turn (0: brake, 1: diagnosis).  railhil puts it in BECU3's place with
`railhil run default --realtime --device examples/acme_becu/acme_becu.toml`; the gateway bridges the two
buses.  Ctrl-C or SIGTERM end it with a one-line summary; a bus that cannot be opened is `error: ...` and
exit code 2.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import can
import can.cli
import cantools
import e2e

# isort: split
# this program's own module, beside it (its folder is on sys.path when it runs)
from ebc7_control import Ebc7Control

DBC = Path(__file__).resolve().with_name("acme_becu.dbc")
DEFAULT_BUS = {"interface": "udp_multicast", "channel": "239.74.163.7", "port": 43117, "hop_limit": 0}
CYCLE_NS = 10_000_000          # the control cycle and EBC7_VALVE_CMD's GenMsgCycleTime [ns]
STATUS_EVERY = 2               # EBC7_STATUS every 2 cycles (its GenMsgCycleTime, 20 ms)
CATCH_UP_CYCLES = 5            # up to this many cycles late: run them back to back; further: skip
DEMAND_DATA_ID, VALVE_DATA_ID = 0x1027, 0x0A3      # E2E data ids (acme_becu.dbc's comments)
# a real ECU has a CPU of its own; beside a bench on one machine it asks for real-time scheduling, one step
# below the bench's processes (railhil's nodes run at SCHED_FIFO 50, its gateway 49), where the OS permits
FIFO_PRIORITY = 45
MAX_DELTA = 1                  # counter steps allowed between two frames


class Received:
    """The latest value of each received signal ("MESSAGE.Signal") and when it came [µs]."""

    def __init__(self) -> None:
        self.values: dict[str, float] = {}
        self.times: dict[str, int] = {}

    def __getitem__(self, name: str) -> float:
        return self.values.get(name, float("nan"))

    def age_us(self, name: str, now_us: int) -> int | None:
        t = self.times.get(name)
        return None if t is None else now_us - t

    def take(self, message: str, values: dict, t_us: int) -> None:
        for signal_name, value in values.items():
            key = f"{message}.{signal_name}"
            self.values[key] = float(value)
            self.times[key] = t_us


@dataclass
class Sequence:
    """A receiver's counter check: each frame's counter one more than the last (at most MAX_DELTA more)."""

    modulo: int
    last: int | None = None

    def ok(self, counter: int) -> bool:
        good = self.last is None or 1 <= (counter - self.last) % self.modulo <= MAX_DELTA
        self.last = counter
        return good


def xor_of(data: bytes) -> int:
    out = 0
    for b in data:
        out ^= b
    return out


def check_demand(data: bytes, seq: Sequence) -> bool:
    """VCU_BRAKE_DEMAND: E2E profile 5 (CRC-16 in bytes 0-1, counter in byte 2)."""
    return len(data) == 8 and e2e.p05.e2e_p05_check(data, DEMAND_DATA_ID, length=8) and seq.ok(data[2])


def check_wheel(data: bytes, seq: Sequence) -> bool:
    """VCU_WHEEL_DATA: XOR of bytes 0-6 in byte 7, 4-bit counter in the low nibble of byte 6."""
    return len(data) == 8 and xor_of(data[:7]) == data[7] and seq.ok(data[6] & 0x0F)


def protect_valve(data: bytes, counter: int) -> bytes:
    """EBC7_VALVE_CMD: E2E profile 11, mode BOTH (CRC byte 0, counter in the low nibble of byte 1)."""
    out = bytearray(data)
    out[1] = (out[1] & 0xF0) | counter
    e2e.p11.e2e_p11_protect(out, VALVE_DATA_ID, length=8, increment_counter=False)
    return bytes(out)


def protect_status(data: bytes, counter: int) -> bytes:
    """EBC7_STATUS: 4-bit counter in the low nibble of byte 0, sum of bytes 0-6 (mod 256) in byte 7."""
    out = bytearray(data)
    out[0] = (out[0] & 0xF0) | counter
    out[7] = sum(out[:7]) & 0xFF
    return bytes(out)


@dataclass
class Stats:
    cycles: int = 0
    late_cycles: int = 0
    skipped_cycles: int = 0
    frames_sent: int = 0
    frames_received: int = 0
    rejected: int = 0             # received frames whose protection failed (dropped)
    send_errors: int = 0
    step_errors: int = 0


class Ebc7:
    """The ECU without a bus or a clock: `receive(frame_id, data, t_us)`, `cycle(now_us)` -> frames."""

    def __init__(self, db) -> None:
        self.control = Ebc7Control()
        self.rx = Received()
        message = db.get_message_by_name
        self.demand, self.wheel = message("VCU_BRAKE_DEMAND"), message("VCU_WHEEL_DATA")
        self.valve, self.status = message("EBC7_VALVE_CMD"), message("EBC7_STATUS")
        self.checks = {self.demand.frame_id: (self.demand, check_demand, Sequence(256)),
                       self.wheel.frame_id: (self.wheel, check_wheel, Sequence(16))}
        self.valve_counter = self.status_counter = self.page = 0
        self.stats = Stats()

    def receive(self, frame_id: int, data: bytes, t_us: int) -> None:
        entry = self.checks.get(frame_id)
        if entry is None:
            return
        message, check, seq = entry
        self.stats.frames_received += 1
        if not check(data, seq):
            self.stats.rejected += 1
            return
        self.rx.take(message.name, message.decode(data, decode_choices=False), t_us)

    def cycle(self, now_us: int) -> list[tuple[int, bool, bytes]]:
        self.stats.cycles += 1
        try:
            out = self.control.step(now_us, self.rx)
        except Exception:                      # a bug must not stop the ECU: it brakes
            self.stats.step_errors += 1
            out = self.control.safe_outputs()
        valve = {k.split(".")[1]: v for k, v in out.items() if k.startswith("EBC7_VALVE_CMD.")}
        data = self.valve.encode({"ValveCRC": 0, "ValveCounter": 0, **valve}, strict=False)
        frames = [(self.valve.frame_id, False, protect_valve(data, self.valve_counter))]
        self.valve_counter = (self.valve_counter + 1) % 15
        if self.stats.cycles % STATUS_EVERY == 1:
            page = {k.split(".")[1]: v for k, v in out.items() if k.startswith("EBC7_STATUS.")}
            page.update(StatusCounter=0, StatusChecksum=0, StatusPage=self.page)
            data = self.status.encode(page, strict=False)
            frames.append((self.status.frame_id, False, protect_status(data, self.status_counter)))
            self.status_counter = (self.status_counter + 1) % 16
            self.page ^= 1
        self.stats.frames_sent += len(frames)
        return frames


def build_parser() -> argparse.ArgumentParser:
    default = " ".join(f"{k}={v}" for k, v in DEFAULT_BUS.items())
    parser = argparse.ArgumentParser(
        prog="ebc7.py", description=f"ACME EBC-7 brake ECU on a python-can bus (default: {default})")
    parser.add_argument("--duration", type=float,
                        help="stop this many seconds after the first frame it receives (the bench's)")
    can.cli.add_bus_arguments(parser)
    return parser


def realtime_scheduling() -> str:
    """SCHED_FIFO at FIFO_PRIORITY where the OS permits it (root, or CAP_SYS_NICE); what it got."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
    except (AttributeError, OSError):         # not Linux, or not permitted: the default scheduling
        return "normal scheduling (SCHED_FIFO not permitted)"
    return f"SCHED_FIFO priority {FIFO_PRIORITY}"


def _fail(text: str) -> int:
    print(f"error: {text}", file=sys.stderr, flush=True)
    return 2


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    db = cantools.database.load_file(str(DBC))
    try:
        if getattr(args, "interface", None) or getattr(args, "channel", None):
            bus = can.cli.create_bus_from_namespace(args)
        else:
            bus = can.Bus(**DEFAULT_BUS)
    except Exception as exc:               # python-can wraps the cause in an ArgumentError
        cause = exc.__cause__ or exc
        return _fail(f"cannot open the bus: {type(cause).__name__}: {cause}")
    try:
        return run(bus, Ebc7(db), args)
    finally:
        bus.shutdown()


def run(bus: can.BusABC, ecu: Ebc7, args) -> int:
    """The cycle on absolute deadlines until SIGINT, SIGTERM or --duration after the first frame received;
    the summary line."""
    stop = False

    def on_signal(signum, frame) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    print(f"EBC-7: on {bus.__class__.__name__} {bus.channel_info}, sending EBC7_VALVE_CMD, EBC7_STATUS; "
          f"{realtime_scheduling()}", flush=True)
    t0 = time.monotonic_ns()
    end_ns = None                                       # --duration: counted from the first frame received
    deadline = t0
    stats = ecu.stats
    while not stop:
        now = time.monotonic_ns()
        if end_ns is not None and now >= end_ns:
            break
        if now < deadline:
            msg = bus.recv(timeout=(deadline - now) / 1e9)
            if msg is not None and not msg.is_error_frame and not msg.is_remote_frame:
                ecu.receive(msg.arbitration_id, bytes(msg.data), (time.monotonic_ns() - t0) // 1000)
                if end_ns is None and args.duration and stats.frames_received:   # the bench's, not its own
                    end_ns = time.monotonic_ns() + round(args.duration * 1e9)      # (udp_multicast echoes)
            continue
        late = now - deadline
        if late > CATCH_UP_CYCLES * CYCLE_NS:           # far behind: skip to the next slot
            missed = late // CYCLE_NS
            deadline += missed * CYCLE_NS
            stats.skipped_cycles += missed
            continue
        stats.late_cycles += late > CYCLE_NS // 2
        for frame_id, extended, data in ecu.cycle((deadline - t0) // 1000):
            try:
                bus.send(can.Message(arbitration_id=frame_id, is_extended_id=extended, data=data))
            except can.CanError:
                stats.send_errors += 1
        deadline += CYCLE_NS
    print(f"EBC-7: {stats.cycles} cycles, {stats.frames_sent - stats.send_errors} frames sent, "
          f"{stats.frames_received} received, {stats.rejected} rejected by their protection, "
          f"{stats.late_cycles} late, {stats.skipped_cycles} skipped"
          + (f", {stats.step_errors} step errors" if stats.step_errors else ""), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
