"""`railhil trace replay` onto python-can's udp_multicast: every frame arrives with its id and data, in
order (checked by --verify and by a receiver of the test's own), filters, send errors counted not
raised, Ctrl-C reports what was sent, and bad input or a bus that cannot be opened is one line.

Each test uses a multicast group and port of its own, so parallel runs do not hear each other.  No
timing figure is asserted (a loaded 2-core machine makes them what it makes them); bench/ measures.
The corpus lives outside the repository; RAILHIL_CORPUS points to it (default ../shared/corpus).
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest
from conftest import CORPUS

from hil.cli.main import main
from hil.cli.trace.replay import identity, match_in_order

ROOT = Path(__file__).resolve().parents[2]
ISSUE_1256 = CORPUS / "python-can" / "test" / "data" / "issue_1256.asc"
NO_CORPUS = pytest.mark.skipif(not CORPUS.is_dir(),
                               reason=f"no trace corpus at {CORPUS} (set RAILHIL_CORPUS)")
RECEIVE_TIMEOUT_S = 10.0     # generous: a loaded 2-core machine


def railhil(capsys, *args) -> tuple[int, str, str]:
    """main() in-process: (exit code, stdout, stderr)."""
    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, err: str, expected_code: int, *needles: str) -> None:
    assert code == expected_code, (code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for needle in needles:
        assert needle in lines[0], lines[0]


@pytest.fixture
def group() -> tuple[str, int]:
    """A multicast group and port of this test's own."""
    rnd = random.Random(os.getpid() ^ time.monotonic_ns())
    return f"239.255.{rnd.randrange(1, 255)}.{rnd.randrange(1, 255)}", rnd.randrange(20000, 60000)


def bus_args(group: tuple[str, int], *extra: str) -> list[str]:
    channel, port = group
    return ["-i", "udp_multicast", "-c", channel, "--bus-kwarg", f"port={port}", *extra]   # = --bus-kwargs


def listen(group: tuple[str, int], **kwargs) -> can.BusABC:
    channel, port = group
    return can.Bus(interface="udp_multicast", channel=channel, port=port, **kwargs)


def receive(bus: can.BusABC, count: int) -> list[can.Message]:
    """Up to ``count`` frames; stops early only when none has come for RECEIVE_TIMEOUT_S."""
    frames = []
    while len(frames) < count:
        msg = bus.recv(timeout=RECEIVE_TIMEOUT_S)
        if msg is None:
            break
        frames.append(msg)
    return frames


@pytest.fixture(scope="module")
def small_trace(tmp_path_factory) -> Path:
    """49 sendable frames over 0.12 s, written with python-can's BLF writer: 11-bit data frames of
    every length 0..8, a 29-bit frame, a remote frame, a 64-byte CAN FD frame; and one error frame."""
    frames = [can.Message(timestamp=k * 0.003, arbitration_id=0x100 + k % 4, is_extended_id=False,
                          data=bytes(range(k, k + k % 9))) for k in range(40)]
    frames += [
        can.Message(timestamp=0.0405, arbitration_id=0x300, is_extended_id=False, is_remote_frame=True,
                    dlc=4),
        can.Message(timestamp=0.0505, arbitration_id=0x18FF0001, is_extended_id=True, data=b"\x11\x22"),
        can.Message(timestamp=0.0605, arbitration_id=0x400, is_extended_id=False, is_fd=True,
                    bitrate_switch=True, data=bytes(range(64))),
        can.Message(timestamp=0.0705, is_error_frame=True),
    ]
    frames += [can.Message(timestamp=0.121 + k * 0.0001, arbitration_id=0x7FF, is_extended_id=False,
                           data=bytes([k])) for k in range(6)]      # a burst, 100 µs apart
    path = tmp_path_factory.mktemp("replay") / "small.blf"
    with can.Logger(str(path)) as writer:
        for msg in sorted(frames, key=lambda m: m.timestamp):
            writer(msg)
    return path


def expected(trace: Path, keep=lambda m: True) -> list[tuple]:
    return [identity(m) for m in can.LogReader(str(trace)) if not m.is_error_frame and keep(m)]


def test_every_frame_arrives_in_order_with_its_id_and_data(capsys, small_trace, group):
    sent = expected(small_trace)
    assert len(sent) == 49
    with listen(group) as own:
        code, out, err = railhil(capsys, "trace", "replay", small_trace, "--verify", "--format", "json",
                                 *bus_args(group))
        got = receive(own, len(sent))
    assert code == 0, err
    assert [identity(m) for m in got] == sent                  # the test's own receiver
    report = json.loads(out)
    assert (report["frames_sent"], report["frames_dropped"], report["error_frames_not_sent"]) == (49, 0, 1)
    verify = report["verify"]                                  # the replay's own --verify receiver
    assert (verify["frames_received"], verify["frames_matched"], verify["frames_missing"],
            verify["frames_foreign"]) == (49, 49, 0, 0)
    for figures in (report["send_dt_error"], verify["receive_dt_error"]):
        assert 0 <= figures["p50_us"] <= figures["p99_us"] <= figures["max_us"]
    assert report["trace_span_s"] == pytest.approx(0.1215)
    assert report["bus"] == f"interface=udp_multicast channel={group[0]} port={group[1]}"
    assert "replay: 49 frames sent, 0 dropped; verify: 49 received in order, 0 missing, 0 foreign" in err


@NO_CORPUS
def test_a_real_trace_window_at_double_speed(capsys, group):
    def keep(m):
        return 1.0 <= m.timestamp <= 2.0

    sent = expected(ISSUE_1256, keep)
    assert len(sent) > 150
    with listen(group) as own:
        # --absolute: the window on the timestamps as recorded (by default: from the trace's first frame)
        code, out, err = railhil(capsys, "trace", "replay", ISSUE_1256, "--start", "1", "--end", "2",
                                 "--absolute", "--speed", "2", "--verify", *bus_args(group))
        got = receive(own, len(sent))
    assert code == 0, out + err
    assert [identity(m) for m in got] == sent
    lines = out.splitlines()
    assert lines[0].startswith(f"replay {ISSUE_1256} -> interface=udp_multicast") and "speed 2x" in lines[0]
    assert f"frames sent        {len(sent)}" in lines
    n = len(sent)
    assert f"frames received    {n} ({n} in order as sent, 0 missing, 0 foreign or out of order)" in lines
    assert any(line.startswith("send Δt error      p50 ") for line in lines)
    assert lines[-1] == f"replay: {n} frames sent, 0 dropped; verify: {n} received in order, 0 missing, " \
                        f"0 foreign"


def test_id_filter_at_max_speed(capsys, small_trace, group):
    sent = expected(small_trace, lambda m: m.arbitration_id in (0x101, 0x18FF0001))
    assert len(sent) == 11
    with listen(group) as own:
        code, out, err = railhil(capsys, "trace", "replay", small_trace, "--id", "0x101",
                                 "--id", "0x18FF0001", "--max-speed", "--format", "json", *bus_args(group))
        got = receive(own, len(sent))
    assert code == 0, err
    assert [identity(m) for m in got] == sent
    report = json.loads(out)
    assert report["speed"] == 0 and report["frames_sent"] == 11 and report["send_dt_error"] is None


def test_send_errors_are_counted_not_raised(capsys, small_trace, group):
    # a real bus that refuses CAN FD frames: python-can's udp_multicast with fd=False
    code, out, err = railhil(capsys, "trace", "replay", small_trace, "--max-speed", "--format", "json",
                             *bus_args(group, "fd=False"))
    assert code == 1, err
    report = json.loads(out)
    assert (report["frames_sent"], report["frames_dropped"]) == (48, 1)
    assert "CanOperationError" in report["first_drop_error"] and "FD" in report["first_drop_error"]


def test_ctrl_c_stops_with_the_report_so_far(small_trace, group, tmp_path):
    # 2000 frames 10 ms apart: 20 s at speed 1, interrupted as soon as the first frame arrived
    long_trace = tmp_path / "long.blf"
    with can.Logger(str(long_trace)) as writer:
        for k in range(2000):
            writer(can.Message(timestamp=k * 0.01, arbitration_id=0x123, is_extended_id=False,
                               data=k.to_bytes(2, "little")))
    with listen(group) as own:
        proc = subprocess.Popen([sys.executable, "-m", "hil", "trace", "replay", str(long_trace), "--verify",
                                 "--format", "json", *bus_args(group)], cwd=ROOT, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            first = own.recv(timeout=60.0)
            assert first is not None and first.arbitration_id == 0x123
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    assert proc.returncode == 130, err
    report = json.loads(out)
    assert report["interrupted"] is True and 1 <= report["frames_sent"] < 2000
    assert report["verify"]["frames_received"] <= report["frames_sent"]
    assert "Traceback" not in err and err.strip().splitlines()[-1].endswith("; interrupted")


def test_match_in_order():
    sent = [(1,), (2,), (3,), (4,), (5,)]
    assert match_in_order(sent, sent) == ([(0, 0), (1, 1), (2, 2), (3, 3), (4, 4)], 0, 0)
    # 2 and 4 lost, a foreign frame in between
    assert match_in_order(sent, [(1,), (3,), (9,), (5,)]) == ([(0, 0), (2, 1), (4, 3)], 2, 1)
    # out of order: 3 before 2 -> 2 counts as missing (passed over), the late 2 as foreign
    assert match_in_order(sent[:3], [(1,), (3,), (2,)]) == ([(0, 0), (2, 1)], 1, 1)


# --- bad input ------------------------------------------------------------------------------------


@pytest.mark.parametrize("args, exit_code, needles", [
    (["-i", "nosuch"], 2, ["--interface 'nosuch'", "udp_multicast"]),
    (["-i", "udp_multicast", "-c", "not-a-group"], 3, ["cannot open the python-can bus", "not-a-group"]),
    (["-i", "udp_multicast", "-c", "not-a-group", "--verify"], 3, ["cannot open the python-can bus"]),
    (["-i", "udp_multicast", "-c", "239.255.1.1", "--bus-kwargs", "port=99999"], 3, ["port=99999"]),
    (["-i", "socketcan", "-c", "nosuchcan0"], 3, ["interface=socketcan channel=nosuchcan0"]),
    (["-i", "virtual", "--verify"], 2, ["--verify -i virtual"]),
    (["--speed", "-1"], 2, ["--speed -1"]),
    (["--speed", "nan"], 2, ["--speed nan"]),
    (["--id", "0xZZ"], 2, ["--id '0xZZ'"]),
    (["--start", "2", "--end", "1"], 2, ["--end 1.0 is before --start 2.0"]),
])
def test_bad_options_and_buses_are_one_line_errors(capsys, small_trace, args, exit_code, needles):
    code, out, err = railhil(capsys, "trace", "replay", small_trace, *args)
    assert_one_line_error(code, err, exit_code, *needles)
    assert out == ""


def test_missing_trace_is_a_one_line_error(capsys, tmp_path):
    missing = tmp_path / "missing.blf"
    code, _, err = railhil(capsys, "trace", "replay", missing)
    assert_one_line_error(code, err, 2, str(missing), "no such trace file")
