"""An external brake ECU (BECU) for car N of railhil's train, on any python-can bus.

It is not railhil: it reads the train's DBC with cantools, talks on the bus with python-can, protects
and checks frames with its own E2E and SecOC (protection.py, AES-CMAC from `cryptography`) and runs its
own brake control (brake_control.py).  railhil's BCU and PLANT accept its frames, and it theirs, because
all keep the wire contract of docs/external-ecu.md.

    python examples/external_becu/becu.py --car 3 --interface udp_multicast \\
        --channel 239.74.163.2 --bus-kwargs port=43113

Receives PLANT_CARn_SENSORS, BCU_DEMAND, BCU_EMERGENCY and BCU_BRAKE_CORR (which only a train with
deceleration feedback sends); sends BECUn_PRESS_CMD (10 ms), BECUn_STATUS and BECUn_DIAG (50 ms) and
BECUn_EST (100 ms), at the cycle times of the DBC.  The cycle runs on absolute 10 ms deadlines of
time.monotonic_ns(); between deadlines it waits in bus.recv(timeout=remaining).

The authenticated frames it sends (those with a SecOCDataID in the DBC, which carry SecOCFreshness and
SecOCMAC: BECUn_PRESS_CMD and BECUn_STATUS) start with the first frame heard from the train: railhil's
receivers start their SecOC freshness at 0 and accept at most `window` frames ahead, so an authenticated
frame sent long before the train starts would be locked out for the whole run.  The others (BECUn_DIAG,
BECUn_EST) go out from the start.

Ctrl-C or SIGTERM end it with a one-line summary; a bus that cannot be opened is `error: ...` and exit 2.
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

# isort: split
# this program's own modules, beside it (its folder is on sys.path when it runs)
from brake_control import BrakeControl, CarParams, Inputs
from protection import DEV_SECOC_KEY_HEX, Receiver, Sender, key_from_hex

DEFAULT_DBC = Path(__file__).resolve().parents[2] / "dbc" / "train_brake.dbc"
KEY_ENV = "RAILHIL_SECOC_KEY"
DEFAULT_WINDOW = 255          # frames: the SecOC acceptance window of railhil's scenarios ([secoc] window)
CATCH_UP_CYCLES = 5           # up to this many cycles late: run them back to back; further: skip


def becu_frames(car: int) -> tuple[list[str], list[str]]:
    """(frames received, frames sent) by the BECU of car `car`."""
    return ([f"PLANT_CAR{car}_SENSORS", "BCU_DEMAND", "BCU_EMERGENCY", "BCU_BRAKE_CORR"],
            [f"BECU{car}_PRESS_CMD", f"BECU{car}_STATUS", f"BECU{car}_DIAG", f"BECU{car}_EST"])


# the control's inputs: (message, signal) -> Inputs field
_INPUTS = {
    ("SENSORS", "AxleSpeed"): "axle_speed_rad_s",
    ("SENSORS", "CylPressure"): "cyl_pressure_Pa",
    ("SENSORS", "AccelLong"): "accel_mps2",
    ("BCU_DEMAND", "TargetDecel"): "target_decel_mps2",
    ("BCU_EMERGENCY", "EmergencyActive"): "emergency",
    ("BCU_BRAKE_CORR", "FrictionPhi"): "friction_phi",
    ("BCU_BRAKE_CORR", "FbState"): "fb_state",
}


@dataclass
class _Due:
    sender: Sender
    cycle_us: int
    next_us: int
    needs_train: bool        # an authenticated frame: not before the train is heard


@dataclass
class Stats:
    cycles: int = 0
    late_cycles: int = 0
    skipped_cycles: int = 0
    frames_sent: int = 0          # frames the ECU built (those the bus refused are send_errors)
    frames_received: int = 0      # frames of the messages this ECU receives
    send_errors: int = 0
    step_errors: int = 0          # control steps that raised: the fail-safe command went out instead


class BecuNode:
    """The ECU without a bus or a clock: `receive(frame_id, data, t_us)`, `cycle(now_us)` -> frames."""

    def __init__(self, db, car: int, keys: dict[str, bytes] | None = None, window: int = DEFAULT_WINDOW,
                 start_us: int = 0, params: CarParams | None = None) -> None:
        keys = keys or {}
        default = keys.get("*", key_from_hex(DEV_SECOC_KEY_HEX))
        rx_names, tx_names = becu_frames(car)
        self.name = f"BECU{car}"
        self.tx_names = tx_names
        self.control = BrakeControl(params or CarParams())
        self.receivers: dict[int, tuple[str, Receiver]] = {}
        for name in rx_names:
            msg = db.get_message_by_name(name)
            kind = "SENSORS" if name.endswith("_SENSORS") else name
            self.receivers[msg.frame_id] = (kind, Receiver(msg, keys.get(name, default), window, start_us))
        self.due: list[_Due] = []
        for name in tx_names:
            msg = db.get_message_by_name(name)
            sender = Sender(msg, keys.get(name, default))     # authenticates when the DBC gives a SecOCDataID
            self.due.append(_Due(sender, int(msg.cycle_time) * 1000, start_us,
                                 needs_train=sender.data_id is not None))
        self.values: dict[str, float] = {}
        self.taken_us: dict[str, int] = {}       # message kind -> reception time of its last usable frame
        self.train_heard = False
        self.stats = Stats()

    def receive(self, frame_id: int, data: bytes, t_us: int) -> bool:
        """A frame from the bus; True when its values were taken (known, authentic, E2E usable)."""
        entry = self.receivers.get(frame_id)
        if entry is None:
            return False
        kind, rx = entry
        self.stats.frames_received += 1
        self.train_heard = True
        values = rx.receive(data, t_us)
        if values is None:
            return False
        for (k, sig), key in _INPUTS.items():
            if k == kind and sig in values:
                self.values[key] = values[sig]
        self.taken_us[kind] = t_us
        return True

    def inputs(self, now_us: int) -> Inputs:
        def age(kind: str) -> int | None:
            t_us = self.taken_us.get(kind)
            return None if t_us is None else now_us - t_us

        return Inputs(**self.values, demand_age_us=age("BCU_DEMAND"), phi_age_us=age("BCU_BRAKE_CORR"),
                      sensors_age_us=age("SENSORS"))

    def cycle(self, now_us: int) -> list[tuple[int, bytes]]:
        """One control cycle at `now_us`: E2E checks of missed frames, the control step, the frames due."""
        self.stats.cycles += 1
        for _, rx in self.receivers.values():
            rx.tick(now_us)
        try:
            outputs = self.control.step(now_us, self.inputs(now_us))
        except Exception:                  # a bug must not stop the ECU: it brakes
            self.stats.step_errors += 1
            outputs = self.control.safe_outputs()
        frames = []
        for d in self.due:
            if now_us < d.next_us:
                continue
            while d.next_us <= now_us:
                d.next_us += d.cycle_us
            if d.needs_train and not self.train_heard:
                continue
            frames.append((d.sender.message.frame_id, d.sender.frame(outputs)))
        self.stats.frames_sent += len(frames)
        return frames

    def rejects(self) -> tuple[int, int]:
        """(E2E rejects, SecOC rejects) over every message received."""
        rxs = [rx for _, rx in self.receivers.values()]
        return sum(rx.e2e_rejects for rx in rxs), sum(rx.secoc_rejects for rx in rxs)


# --- the process -------------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="becu.py", description="An external brake ECU (BECU) of car N on a python-can bus.")
    parser.add_argument("--car", type=int, required=True, help="the car, 1..8")
    parser.add_argument("--dbc", type=Path, default=DEFAULT_DBC,
                        help=f"the train's DBC (default {DEFAULT_DBC})")
    parser.add_argument("--key", help=f"SecOC AES-128 key, 32 hex digits (default ${KEY_ENV}, else railhil's "
                                      f"development key {DEV_SECOC_KEY_HEX})")
    parser.add_argument("--key-for", action="append", default=[], metavar="MESSAGE=HEX",
                        help="the key of one message, as a scenario's [secoc] keys.MESSAGE (repeatable)")
    parser.add_argument("--secoc-window", type=int, default=DEFAULT_WINDOW, metavar="FRAMES",
                        help=f"SecOC freshness acceptance window, 1..255 (default {DEFAULT_WINDOW}, "
                             "a scenario's [secoc] window)")
    parser.add_argument("--duration", type=float, help="stop after this many seconds")
    can.cli.add_bus_arguments(parser)
    return parser


def _keys(args) -> dict[str, bytes]:
    keys = {"*": key_from_hex(args.key or os.environ.get(KEY_ENV) or DEV_SECOC_KEY_HEX)}
    for item in args.key_for:
        name, sep, text = item.partition("=")
        if not sep:
            raise ValueError(f"--key-for {item!r}: expected MESSAGE=HEX")
        keys[name.strip()] = key_from_hex(text)
    return keys


def _fail(text: str) -> int:
    print(f"error: {text}", file=sys.stderr, flush=True)
    return 2


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not 1 <= args.car <= 8:
        return _fail(f"--car {args.car}: the DBC has cars 1..8")
    if not 1 <= args.secoc_window <= 255:
        return _fail(f"--secoc-window {args.secoc_window}: expected 1..255 frames")
    try:
        keys = _keys(args)
    except ValueError as exc:
        return _fail(f"SecOC key: {exc}")
    try:
        db = cantools.database.load_file(str(args.dbc))
        node = BecuNode(db, args.car, keys, args.secoc_window)
    except KeyError as exc:
        return _fail(f"the DBC {args.dbc} has no message {exc}: not the train's DBC?")
    except Exception as exc:            # a file that is not there, not a DBC, or protection it cannot use
        return _fail(f"cannot use the DBC {args.dbc}: {' '.join(str(exc).split())}")
    try:
        bus = can.cli.create_bus_from_namespace(args)
    except Exception as exc:            # python-can wraps the cause in an ArgumentError
        cause = exc.__cause__ or exc
        where = " ".join(str(getattr(args, k)) for k in ("interface", "channel") if getattr(args, k, None))
        return _fail(f"cannot open the bus ({where or 'python-can configuration'}): "
                     f"{type(cause).__name__}: {cause}")
    try:
        return run(bus, node, args)
    finally:
        bus.shutdown()


def run(bus: can.BusABC, node: BecuNode, args) -> int:
    """The cycle on absolute deadlines until SIGINT, SIGTERM or --duration; the summary line."""
    stop = False

    def on_signal(signum, frame) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    given = {"interface": getattr(args, "interface", None), "channel": getattr(args, "channel", None)}
    try:                                # as python-can resolved them: arguments, environment, config file
        where = can.util.load_config(config={k: v for k, v in given.items() if v is not None})
    except Exception:                   # a bus that opened has a configuration; only the print needs it
        where = given
    period_ns = node.control.p.cycle_us * 1000
    name = node.name
    print(f"external {name}: on {where.get('interface')} {where.get('channel')}, sending "
          f"{', '.join(node.tx_names)}", flush=True)

    t0 = time.monotonic_ns()
    end_ns = t0 + round(args.duration * 1e9) if args.duration else None
    deadline = t0
    stats = node.stats
    while not stop:
        now = time.monotonic_ns()
        if end_ns is not None and now >= end_ns:
            break
        if now < deadline:
            msg = bus.recv(timeout=(deadline - now) / 1e9)
            if msg is not None and not msg.is_error_frame and not msg.is_remote_frame:
                node.receive(msg.arbitration_id, bytes(msg.data), (time.monotonic_ns() - t0) // 1000)
            continue
        late = now - deadline
        if late > CATCH_UP_CYCLES * period_ns:          # far behind: skip to the next slot
            missed = late // period_ns
            deadline += missed * period_ns
            stats.skipped_cycles += missed
            continue
        stats.late_cycles += late > period_ns // 2
        for frame_id, data in node.cycle((deadline - t0) // 1000):
            try:
                bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
            except can.CanError:
                stats.send_errors += 1
        deadline += period_ns
    e2e, secoc = node.rejects()
    errors = "".join(f", {n} {what}" for n, what in ((stats.send_errors, "send errors"),
                                                      (stats.step_errors, "step errors")) if n)
    print(f"external {name}: {stats.cycles} cycles, {stats.frames_sent - stats.send_errors} frames sent, "
          f"{stats.frames_received} received, {e2e} E2E rejects, {secoc} SecOC rejects, "
          f"{stats.late_cycles} late, {stats.skipped_cycles} skipped{errors}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
