"""SocketCAN: railhil on the Linux kernel's virtual CAN buses vcan0 and vcan1, and beside a peer no one here
wrote (can-utils: candump records a run, cansend forges a frame).

The tests marked `socketcan` need vcan0 (and vcan1); `make test` leaves them out, since the kernel of the
development VM has no CAN at all (AF_CAN: Errno 97), and `make test-vcan` runs them: on the machine itself
where its kernel has SocketCAN, else inside a Debian kernel booted under qemu (tools/vcan_suite.py).  Where
vcan0 is missing they skip, saying so, and `make test-vcan` counts such a skip as a failure.

As python-can's test/back2back_test.py does, one class of tests runs on two buses of one channel, and a
subclass per interface names it (two class attributes): the python-can `virtual` bus, `udp_multicast`, and
`socketcan` on vcan0.  There, railhil's FrameIO (hil.can.frame_io: what a real-time host and the recorder
send and take the frames with) goes through python-can's own recv and send, as it does on every interface
but udp_multicast, whose fast path bypasses can.Message.

The emulated guest of `make test-vcan` (qemu's software emulation) runs Python about 30x slower than the
host: the real-time runs here run at RUN_SPEED (slower than real time) from a low speed, they are judged on
their behaviour (the train stopped, every frame recorded, the forged frame rejected), never on the
real-time verdict (`railhil run` exits 1 when real time was not held: accepted when that is its only failed
verdict), and railhil's commands run in forked children of this test process (`Forked`), which the guest
would otherwise take a minute each to start.  Every wait is on a frame, a line or a process, with a timeout.
"""

from __future__ import annotations

import fcntl
import json
import logging
import multiprocessing as mp
import os
import re
import select
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import ROOT, railhil

from hil.can.dbc import load_dbc
from hil.can.frame_io import FrameIO
from hil.can.secoc import AUTH_BYTES
from hil.runtime.realtime import enlarge_receive_buffer

SOCKETCAN = pytest.mark.socketcan
CHANNEL = "vcan0"
OTHER = "vcan1"                 # a second bus: nothing sent on one reaches the other
WAIT_S = 10.0                   # a frame sent on a vcan bus arrives within this, even in the emulated guest
START_S = 300.0                 # a railhil command's first frame, from its start (the guest: minutes)
RUN_TIMEOUT_S = 600.0           # a whole real-time run below, in the emulated guest
RUN_SPEED = 0.25                # simulated seconds per wall second of the runs below ([realtime] speed)
RUN_SETS = ("--set", "train.initial_speed_kmh=20", "--set", f"realtime.speed={RUN_SPEED}")
MARKER_ID = 0x7FF               # candump's start and end markers: an id the DBC does not define
ERROR_FRAME = "20000004#0004000000000000"   # cansend: CAN_ERR_FLAG | CAN_ERR_CRTL, "rx error warning"
DB = load_dbc()
BCU_DEMAND = DB.get_message_by_name("BCU_DEMAND")
DBC = ROOT / "dbc" / "train_brake.dbc"


def socketcan_bus(channel: str = CHANNEL, **kwargs) -> can.BusABC:
    """python-can's SocketCAN bus on `channel`, its receive buffer enlarged as railhil's hosts enlarge theirs
    (a test reads its frames after the fact), or a skip that says there is no such bus here."""
    try:
        bus = can.Bus(interface="socketcan", channel=channel, **kwargs)
    except Exception as exc:  # noqa: BLE001 - any failure means: no such device here
        why = " ".join(str(exc).split())
        pytest.skip(f"no SocketCAN {channel} on this machine ({why}); `make test-vcan` runs these tests, "
                    "in a VM where the kernel has no CAN")
    enlarge_receive_buffer(bus)
    return bus


def need_can_utils() -> None:
    missing = [tool for tool in ("candump", "cansend", "stdbuf") if shutil.which(tool) is None]
    if missing:
        pytest.skip(f"no can-utils here ({', '.join(missing)} missing): apt-get install can-utils")


def received(bus: can.BusABC, n: int, timeout_s: float = WAIT_S) -> list[can.Message]:
    """The next `n` frames `bus` receives, each within `timeout_s`."""
    out = []
    while len(out) < n:
        msg = bus.recv(timeout_s)
        assert msg is not None, f"{len(out)} of {n} frames, then none for {timeout_s} s on {bus.channel_info}"
        out.append(msg)
    return out


def cansend(channel: str, frame: str) -> None:
    subprocess.run(["cansend", channel, frame], check=True, timeout=60)


# -- two buses on one channel: python-can's bus and railhil's FrameIO -------------------------------------
class Back2Back:
    """python-can's bus and railhil's FrameIO over a second bus of the same channel, frames both ways
    (python-can's test/back2back_test.py: the subclasses name the interface and the channel)."""

    INTERFACE = "virtual"
    CHANNEL = "railhil-back2back"
    FAST = False                  # FrameIO takes and sends without can.Message (udp_multicast's fast path)
    KWARGS: dict = {}

    @pytest.fixture
    def buses(self):
        a = self.open()
        b = self.open()
        yield a, b
        a.shutdown()
        b.shutdown()

    def open(self) -> can.BusABC:
        return can.Bus(interface=self.INTERFACE, channel=self.CHANNEL, **self.KWARGS)

    def take(self, io: FrameIO, n: int) -> list[tuple]:
        """`n` frames taken by FrameIO, as a host takes them: each time its socket has some, all it has."""
        got: list[tuple] = []
        io.take(lambda *frame: got.append(frame))        # the virtual bus delivers as it sends: all there
        while len(got) < n:
            ready, _, _ = select.select([io.bus.fileno()], [], [], WAIT_S)
            assert ready, f"FrameIO took {len(got)} of {n} frames, then none came for {WAIT_S} s"
            io.take(lambda *frame: got.append(frame))
        return got

    def test_data_frames_go_both_ways(self, buses):
        a, b = buses
        io = FrameIO(b, drop_own=True)
        assert io.fast == self.FAST
        frames = [(0x7FF if k == 0 else 0x100 + k, k % 2 == 1, bytes(range(7, 7 + k % 9))) for k in range(18)]
        frames += [(0x1FFF_FFFF, True, b"\xff" * 8), (0, False, b"")]
        for arbitration_id, extended, data in frames:
            a.send(can.Message(arbitration_id=arbitration_id, is_extended_id=extended, data=data))
        got = self.take(io, len(frames))
        assert [f[1:4] for f in got] == frames
        stamps = [f[0] for f in got]
        assert stamps == sorted(stamps) and abs(stamps[-1] - time.time()) < 60      # absolute, in order
        for arbitration_id, extended, data in frames:                                # and the other way
            io.send(arbitration_id, extended, data)
        back = received(a, len(frames))
        assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in back] == frames
        assert io.take(lambda *frame: pytest.fail(f"its own frame came back: {frame}")) == 0
        io.close()

    def test_remote_and_error_frames_come_as_python_cans_messages(self, buses):
        a, b = buses
        io = FrameIO(b)
        a.send(can.Message(arbitration_id=0x123, is_remote_frame=True, dlc=3, is_extended_id=False))
        a.send(can.Message(arbitration_id=0x4, is_error_frame=True, data=bytes([0, 4, 0, 0, 0, 0, 0, 0])))
        a.send(can.Message(arbitration_id=0x11, is_extended_id=False, data=b"\x01"))
        got = self.take(io, 3)
        assert got[0][4].is_remote_frame and got[0][4].dlc == 3 and got[0][1] == 0x123
        assert got[1][4].is_error_frame
        assert got[2][1:4] == (0x11, False, b"\x01")


class TestBack2BackVirtual(Back2Back):
    pass


class TestBack2BackUdpMulticast(Back2Back):
    INTERFACE = "udp_multicast"
    CHANNEL = f"239.255.{os.getpid() % 250 + 1}.{(os.getpid() >> 8) % 250 + 1}"
    FAST = True
    KWARGS = {"port": 40_000 + os.getpid() % 20_000, "hop_limit": 0}


@SOCKETCAN
class TestBack2BackSocketCan(Back2Back):
    INTERFACE = "socketcan"
    CHANNEL = CHANNEL

    def open(self) -> can.BusABC:
        return socketcan_bus(self.CHANNEL)

    def test_two_vcan_buses_do_not_hear_each_other(self, buses):
        a, _ = buses
        other = socketcan_bus(OTHER)
        try:
            other.send(can.Message(arbitration_id=0x55, is_extended_id=False, data=b"\x05"))
            assert a.recv(0.5) is None
            a.send(can.Message(arbitration_id=0x56, is_extended_id=False, data=b"\x06"))
            assert other.recv(0.5) is None
        finally:
            other.shutdown()


# -- railhil's commands in forked children of this test process -------------------------------------------
class Forked:
    """`railhil ARGS` (hil.cli.main.main, as the console script calls it) in a forked child of this process,
    in a session of its own; its stdout and stderr, merged, come as `lines`.  The child has railhil imported
    already: the emulated guest takes a minute to import it anew for each command."""

    def __init__(self, *args) -> None:
        self.args = [str(a) for a in args]
        self.lines: list[str] = []
        self._changed = threading.Condition()
        read_fd, write_fd = os.pipe()
        self.proc = mp.get_context("fork").Process(target=_railhil_child, args=(self.args, write_fd))
        self.proc.start()
        os.close(write_fd)
        self._reader = threading.Thread(target=self._read, args=(read_fd,), daemon=True)
        self._reader.start()

    def _read(self, fd: int) -> None:
        with open(fd, encoding="utf-8", errors="replace") as stream:
            for line in stream:
                with self._changed:
                    self.lines.append(line.rstrip("\n"))
                    self._changed.notify_all()
        with self._changed:                    # the output ended: a waiter stops waiting
            self._changed.notify_all()

    def wait_for(self, pattern: str, timeout_s: float = START_S) -> str:
        """The first line matching `pattern` (a regular expression), waiting up to `timeout_s`."""
        found = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while True:
                line = next((x for x in self.lines if found.search(x)), None)
                if line is not None:
                    return line
                left = deadline - time.monotonic()
                assert left > 0 and self._reader.is_alive(), \
                    f"railhil {' '.join(self.args)}: no line {pattern!r} in {timeout_s:.0f} s:\n{self.tail()}"
                self._changed.wait(left)

    def join(self, timeout_s: float = RUN_TIMEOUT_S) -> int:
        """Its exit code, once it ended (and its output was read)."""
        self.proc.join(timeout_s)
        assert self.proc.exitcode is not None, \
            f"railhil {' '.join(self.args)} still running after {timeout_s:.0f} s:\n{self.tail()}"
        self._reader.join(WAIT_S)
        return self.proc.exitcode

    def kill(self) -> None:
        """It and every process it started (its session): a failed test leaves none."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:         # all ended
            pass
        self.proc.join(WAIT_S)

    def tail(self, n: int = 30) -> str:
        return "\n".join(self.lines[-n:])


def _railhil_child(args: list[str], write_fd: int) -> None:
    from hil.cli.main import main

    os.setsid()
    for handler in logging.root.handlers[:]:                   # pytest's: python-can logs as in a new process
        logging.root.removeHandler(handler)
    os.dup2(write_fd, 1)
    os.dup2(write_fd, 2)
    os.close(write_fd)
    sys.stdout = open(1, "w", buffering=1, closefd=False)     # noqa: SIM115 - this process's own stdout
    sys.stderr = open(2, "w", buffering=1, closefd=False)     # noqa: SIM115
    sys.exit(main(args))


# -- a run on vcan0, candump beside it, cansend forging a frame -------------------------------------------
class Candump:
    """can-utils' `candump -L CHANNEL` into `path`, line by line; known to listen before the run (a start
    marker it printed) and stopped once it printed an end marker sent after the run, so that the file holds
    every frame in between.  The markers (id MARKER_ID, not in the DBC) stay out of the file."""

    def __init__(self, channel: str, path: Path, bus: can.BusABC) -> None:
        self.path, self.bus = path, bus
        self.seen = {b"START": threading.Event(), b"END": threading.Event()}
        self.proc = subprocess.Popen(["stdbuf", "-oL", "candump", "-L", "-r", str(4 << 20), channel],
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self._writer = threading.Thread(target=self._write, daemon=True)
        self._writer.start()
        self._mark(b"START")

    def _write(self) -> None:
        marker = f" {MARKER_ID:03X}#"
        with self.path.open("w") as f:
            for line in self.proc.stdout:
                if marker in line:
                    self.seen[bytes.fromhex(line.split("#")[1].strip())].set()
                else:
                    f.write(line)

    def _mark(self, text: bytes) -> None:
        """Send the marker `text` until candump printed it (it listens some time after Popen returns)."""
        deadline = time.monotonic() + START_S
        while True:
            self.bus.send(can.Message(arbitration_id=MARKER_ID, is_extended_id=False, data=text))
            if self.seen[text].wait(1.0):
                return
            assert time.monotonic() < deadline, f"candump did not print the {text.decode()} marker"

    def stop(self) -> Path:
        self._mark(b"END")
        self.proc.terminate()
        self.proc.wait(WAIT_S)
        self._writer.join(WAIT_S)
        return self.path

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def forge(genuine: bytes) -> bytes:
    """A BCU_DEMAND as an attacker who recorded the bus would send it: the genuine payload, the next
    freshness value (the byte before the MAC), and a MAC that is not the key's (the genuine MAC inverted)."""
    end = len(genuine) - AUTH_BYTES
    return genuine[:end] + bytes([(genuine[end] + 1) & 0xFF]) + bytes(b ^ 0xFF for b in genuine[end + 1:])


@dataclass
class VcanRun:
    out: Path                 # the run folder
    lines: list[str]          # what railhil run printed
    code: int                 # its exit code
    candump: Path             # candump -L's log of the same bus
    forged: bytes             # the forged BCU_DEMAND cansend sent

    def kpis(self) -> dict:
        return json.loads((self.out / "kpis.json").read_text())

    def run_json(self) -> dict:
        return json.loads((self.out / "run.json").read_text())


@pytest.fixture(scope="module")
def vcan_run(tmp_path_factory) -> VcanRun:
    """The default scenario's train from 20 km/h to standstill, in real time on vcan0 at RUN_SPEED, with
    candump -L recording vcan0 beside railhil's recorder; 50 BCU_DEMAND frames in, cansend sends a forged
    BCU_DEMAND and an error frame."""
    need_can_utils()
    watch = socketcan_bus(CHANNEL, can_filters=[{"can_id": BCU_DEMAND.frame_id, "can_mask": 0x7FF,
                                                 "extended": False}])
    folder = tmp_path_factory.mktemp("vcan-run")
    dump = run = None
    try:
        dump = Candump(CHANNEL, folder / "candump.log", watch)
        run = Forked("run", "default", "--realtime", "-i", "socketcan", "-c", CHANNEL, *RUN_SETS,
                     "--out", folder / "run", "-q")
        demands = received(watch, 50, START_S)
        forged = forge(bytes(demands[-1].data))
        cansend(CHANNEL, f"{BCU_DEMAND.frame_id:03X}#{forged.hex().upper()}")
        cansend(CHANNEL, ERROR_FRAME)
        code = run.join()
        dump.stop()
    finally:
        for process in (run, dump):
            if process is not None:
                process.kill()
        watch.shutdown()
    return VcanRun(folder / "run", run.lines, code, folder / "candump.log", forged)


@SOCKETCAN
def test_socketcan_vcan0_when_the_kernel_has_it(vcan_run):
    assert vcan_run.code in (0, 1), "\n".join(vcan_run.lines[-30:])   # 1: a verdict that failed, not an error
    with can.LogReader(str(vcan_run.out / "trace.blf")) as reader:
        assert len({m.arbitration_id for m in reader}) > 10
    assert np.isfinite(vcan_run.kpis()["stopping_distance_m"])


@SOCKETCAN
def test_a_run_on_vcan0_stops_the_train_and_records_every_frame(vcan_run):
    from hil.report.gate import gates

    kpis, lines = vcan_run.kpis(), vcan_run.lines
    failed = [g for g in gates(kpis) if not g.passed]
    # exit 1 only for the real-time verdict: an emulated guest is no real-time host
    assert vcan_run.code == (1 if failed else 0) and all(g.kind == "real time" for g in failed), \
        "\n".join(lines[-30:])
    assert any(re.match(r"realtime: \d+ processes on interface=socketcan channel=vcan0", x) for x in lines)
    assert any(x.startswith("realtime run:") and x.endswith("ended by standstill") for x in lines), lines
    assert vcan_run.run_json()["bus"] == {"interface": "socketcan", "channel": "vcan0"}
    # every frame the nodes sent is in the trace, and the two cansend sent (the forged one, the error frame)
    assert kpis["frames_recorded"] == kpis["frames_sent"] + 2, kpis
    with can.LogReader(str(vcan_run.out / "trace.blf")) as reader:
        frames = list(reader)
    senders = {s for m in frames if not m.is_error_frame for s in DB.get_message_by_frame_id(
        m.arbitration_id).senders}
    assert senders == {"PLANT", "DESK", "BCU"} | {f"BECU{i}" for i in range(1, 7)}
    assert 0 < kpis["stopping_distance_m"] < 40 and kpis["time_to_stop_s"] > 0, kpis
    print("\n".join(x for x in lines if x.startswith(("realtime", "stopping", "frames sent", "real time",
                                                      "verdict"))))


@SOCKETCAN
def test_candumps_log_reads_as_railhils_trace_of_the_same_run(vcan_run, capsys):
    """railhil's trace tools read candump -L's log of the run (python-can's .log reader): per identifier, as
    many frames as railhil's own trace.blf, in stats, decode and timing alike (the error frame aside:
    candump without -e takes none)."""
    blf, log = vcan_run.out / "trace.blf", vcan_run.candump

    def per_id(trace, *extra) -> dict:
        code, out, err = railhil(capsys, "trace", "stats", trace, "--format", "jsonl", *extra)
        assert code == 0, err
        rows = [json.loads(x) for x in out.splitlines()]
        return {(r["id"], r["frame"]): r["count"] for r in rows if r["kind"] == "data"}

    counts = per_id(blf)
    assert per_id(log) == counts and sum(counts.values()) > 1000
    assert counts[(f"0x{BCU_DEMAND.frame_id:03x}", "std")] > 50

    def decoded(trace) -> Counter:
        code, out, err = railhil(capsys, "trace", "decode", trace, "--dbc", DBC, "--format", "jsonl")
        assert code == 0, err
        return Counter(json.loads(x)["name"] for x in out.splitlines())

    by_name = decoded(blf)
    assert by_name.pop(None) == 1              # the error frame, shown raw
    assert decoded(log) == by_name

    def timing(trace) -> dict:
        code, out, err = railhil(capsys, "timing", trace, "--dbc", DBC, "--run", vcan_run.out, "--format",
                                 "json")
        assert code in (0, 1), err            # 1: a verdict FAIL (a real-time run at RUN_SPEED's periods)
        return {m["name"]: m["count"] for m in json.loads(out)["messages"]}

    assert timing(log) == timing(blf)
    print(f"candump -L's log and trace.blf: {sum(counts.values())} data frames each, {len(counts)} ids, "
          f"equal per id in trace stats, trace decode and timing")


@SOCKETCAN
def test_a_forged_bcu_demand_is_rejected_by_every_becu_and_counted(vcan_run):
    """cansend's BCU_DEMAND with the next freshness value and a wrong MAC: every BECU drops it (SecOC before
    E2E: hil.runtime.node), and run.json counts it per node."""
    stats = vcan_run.run_json()["node_stats"]
    becus = [f"BECU{i}" for i in range(1, 7)]
    for name in becus:
        events = [e for e in stats[name]["e2e_events"] if e[1] == "BCU_DEMAND" and e[2].startswith("SECOC_")]
        assert len(events) == 1, (name, events)
        assert sum(stats[name]["secoc_rejected"].values()) >= 1, stats[name]["secoc_rejected"]
    with can.LogReader(str(vcan_run.out / "trace.blf")) as reader:
        assert sum(1 for m in reader if m.arbitration_id == BCU_DEMAND.frame_id
                   and bytes(m.data) == vcan_run.forged) == 1          # and the trace has it
    print(f"forged BCU_DEMAND {vcan_run.forged.hex().upper()}: run.json secoc_rejected "
          + ", ".join(f"{n} {stats[n]['secoc_rejected']}" for n in becus))


@SOCKETCAN
def test_an_error_frame_is_recorded_and_no_node_takes_it(vcan_run):
    with can.LogReader(str(vcan_run.out / "trace.blf")) as reader:
        errors = [m for m in reader if m.is_error_frame]
    assert len(errors) == 1 and errors[0].arbitration_id == 0x4, errors
    stats = vcan_run.run_json()["node_stats"]
    assert all(s["bad_frames"] == 0 and s["unknown_frames"] == 0 for s in stats.values()), stats


# -- railhil node, trace replay, a bus that goes away, a bus that is not there -----------------------------
@SOCKETCAN
def test_railhil_node_bcu_brakes_on_the_demand_of_railhil_node_desk(tmp_path):
    """Two `railhil node` processes on vcan0, each with its own bus connection: the BCU takes the desk's
    frames off SocketCAN (SecOC, E2E: hil.runtime.node) and answers the desk's brake step 7 (at 0.5 s) with
    BCU_DEMAND frames that say so."""
    watch = socketcan_bus(CHANNEL, can_filters=[{"can_id": BCU_DEMAND.frame_id, "can_mask": 0x7FF,
                                                 "extended": False}])
    bcu = desk = None
    try:
        bcu = Forked("node", "BCU", "default", "-i", "socketcan", "-c", CHANNEL, "--until-idle", "2",
                     "--stats", tmp_path / "bcu.json")
        bcu.wait_for("waiting for the first frame")
        desk = Forked("node", "DESK", "default", "-i", "socketcan", "-c", CHANNEL, "--start", "now",
                      "--duration", "3")
        steps = []
        while 7 not in steps:
            msg = watch.recv(START_S if not steps else WAIT_S)
            assert msg is not None, f"BCU_DEMAND brake steps {steps}:\n{bcu.tail()}\n{desk.tail()}"
            steps.append(BCU_DEMAND.decode(bytes(msg.data))["BrakeStep"])
        assert desk.join() == 0, desk.tail()
        assert bcu.join() == 0, bcu.tail()
    finally:
        for node in (bcu, desk):
            if node is not None:
                node.kill()
        watch.shutdown()
    assert steps[0] == 0 and steps[-1] == 7
    report = json.loads((tmp_path / "bcu.json").read_text())["BCU"]
    assert report["frames_received"] >= 10 and report["bad_frames"] == 0, report
    assert not [k for k in report["reported"] if k.startswith("SECOC_") or k in ("ERROR", "WRONGSEQUENCE")], \
        report["reported"]


def small_trace(path: Path, n: int = 300) -> list[tuple]:
    """A BLF of `n` frames of the DBC's ids, 2 ms apart, and an error frame among them; the data frames
    as (id, extended, data)."""
    ids = [m.frame_id for m in DB.messages if not m.is_extended_frame][:20]
    frames = [(ids[k % len(ids)], False, bytes([k & 0xFF, k >> 8, 1, 2, 3, 4, 5, 6])) for k in range(n)]
    with can.BLFWriter(str(path)) as writer:
        for k, (fid, extended, data) in enumerate(frames):
            writer.on_message_received(can.Message(timestamp=1000.0 + 0.002 * k, arbitration_id=fid,
                                                   is_extended_id=extended, data=data))
            if k == n // 2:
                writer.on_message_received(can.Message(timestamp=1000.0 + 0.002 * k + 0.001,
                                                       is_error_frame=True, arbitration_id=0x4))
    return frames


@SOCKETCAN
def test_trace_replay_onto_vcan1_reaches_vcan1_and_not_vcan0(tmp_path, capsys):
    frames = small_trace(tmp_path / "small.blf")
    here, there = socketcan_bus(OTHER), socketcan_bus(CHANNEL)
    try:
        code, out, err = railhil(capsys, "trace", "replay", tmp_path / "small.blf", "-i", "socketcan", "-c",
                                 OTHER, "--verify", "--format", "json")
        assert code == 0, err
        got = received(here, len(frames))
        assert there.recv(0.5) is None                       # vcan0 heard none of it
    finally:
        here.shutdown()
        there.shutdown()
    report = json.loads(out)
    assert report["frames_sent"] == len(frames) and report["frames_dropped"] == 0, report
    assert report["error_frames_not_sent"] == 1                 # railhil trace replay sends no error frame
    assert report["verify"]["frames_matched"] == len(frames) and report["verify"]["frames_missing"] == 0
    assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in got] == frames


def set_down(name: str) -> None:
    """`ip link set NAME down`, at once: an ioctl (SIOCSIFFLAGS) from this process, not a process started."""
    siocgifflags, siocsifflags, iff_up = 0x8913, 0x8914, 0x1          # <linux/sockios.h>, <net/if.h>
    ifreq = struct.Struct("16sH22x")                                   # struct ifreq: name, ifr_flags
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        _, flags = ifreq.unpack(fcntl.ioctl(sock, siocgifflags, ifreq.pack(name.encode(), 0)))
        fcntl.ioctl(sock, siocsifflags, ifreq.pack(name.encode(), flags & ~iff_up))


def still_queued(bus: can.BusABC) -> list[can.Message]:
    """The frames waiting in `bus`'s socket; the error of a device set down (ENETDOWN), which the kernel
    reports before them, passed over once."""
    out, errors = [], 0
    while errors < 2:
        try:
            msg = bus.recv(0.0)
        except can.CanOperationError:
            errors += 1
            continue
        if msg is None:
            break
        out.append(msg)
    return out


@pytest.fixture
def vanishing_vcan():
    """A vcan device of this test's own, which the test may set down: needs root (CAP_NET_ADMIN)."""
    name = "vcangone"
    socketcan_bus(CHANNEL).shutdown()                     # SocketCAN here at all (else: skip, saying so)
    if os.geteuid() != 0:
        pytest.skip("needs root to create a vcan device and set it down (`make test-vcan` runs as root)")
    subprocess.run(["ip", "link", "add", "dev", name, "type", "vcan"], check=True, timeout=60)
    subprocess.run(["ip", "link", "set", "up", name], check=True, timeout=60)
    yield name
    subprocess.run(["ip", "link", "del", "dev", name], timeout=60)


@SOCKETCAN
def test_a_bus_that_goes_away_mid_run_is_one_line_and_nothing_recorded_is_lost(tmp_path, vanishing_vcan):
    """The run's vcan device set down after 600 frames, the last 100 of them still in the recorder's socket
    (the recorder stopped meanwhile: the kernel reports the device's error before them): railhil run ends
    with one line `error: ...`, and the trace holds, readable, every frame the bus carried until then."""
    watch = socketcan_bus(vanishing_vcan)
    run = None
    try:
        run = Forked("run", "default", "--realtime", "-i", "socketcan", "-c", vanishing_vcan, *RUN_SETS,
                     "--out", tmp_path / "run", "-q")
        pids = run.wait_for(r"^realtime: .* pids ")
        recorder = int(re.search(r"\bRECORDER=(\d+)", pids).group(1))
        seen = received(watch, 500, START_S)
        os.kill(recorder, signal.SIGSTOP)          # the frames from here on wait in the recorder's socket
        try:
            seen += received(watch, 100)
            set_down(vanishing_vcan)
        finally:
            os.kill(recorder, signal.SIGCONT)
        code = run.join()
        on_bus = seen + still_queued(watch)       # every frame the bus carried before it went down
    finally:
        if run is not None:
            run.kill()
        watch.shutdown()
    errors = [x for x in run.lines if x.startswith("error:")]
    assert code not in (0, 1) and len(errors) == 1, run.tail()
    assert [x for x in run.lines if not x.startswith("realtime:")] == errors, run.tail()
    assert vanishing_vcan in errors[0] or "Network is down" in errors[0], errors
    assert not any("Traceback" in x for x in run.lines), run.tail()
    with can.LogReader(str(tmp_path / "run" / "trace.blf")) as reader:
        recorded = [(m.arbitration_id, bytes(m.data)) for m in reader if not m.is_error_frame]
    assert Counter(recorded) >= Counter((m.arbitration_id, bytes(m.data)) for m in on_bus), \
        f"{len(recorded)} frames in the trace of the {len(on_bus)} the bus carried"
    print(f"exit {code}: {errors[0]}\ntrace.blf: {len(recorded)} frames; the bus carried {len(on_bus)} "
          f"before it went down, {len(seen)} of them seen by the test")


@pytest.mark.parametrize("command, exit_code", [(("run", "default", "--realtime"), 3),
                                               (("node", "DESK", "default"), 2)], ids=["run", "node"])
@pytest.mark.parametrize("kernel", ["any", pytest.param("socketcan", marks=SOCKETCAN)])
def test_no_such_socketcan_interface_is_one_line(kernel, command, exit_code, tmp_path):
    """Bad input: a SocketCAN interface that is not there, one line and exit 3 (`railhil node`: 2, a bad
    command line), nothing written.  On any kernel (make test: this one has no CAN), and on one with SocketCAN
    (make test-vcan: vcan0 and vcan1 exist, vcan9 does not), where python-can logs a line of its own first
    (`Could not access SocketCAN device vcan9`): a forked child logs as a new process would."""
    if kernel == "socketcan":
        socketcan_bus(CHANNEL).shutdown()
    out = ("--out", tmp_path / "o", "-q") if command[0] == "run" else ()
    proc = Forked(*command, "-i", "socketcan", "-c", "vcan9", *out)
    assert proc.join(START_S) == exit_code, proc.tail()
    assert len(proc.lines) == 1, proc.tail()
    assert proc.lines[0].startswith("error: cannot open the python-can bus interface=socketcan "
                                    "channel=vcan9: "), proc.lines
    assert not (tmp_path / "o").exists()
    print(proc.lines[0])
