"""Frames sent and taken on python-can's udp_multicast: hil.can.frame_io against the bus's own send/recv.

Two python-can udp_multicast buses on a group of their own (TTL 0: loopback only).  Each round sends
BATCH frames from one bus and then takes them all from the other, once with python-can's `bus.send` /
`bus.recv(0.0)` and once with FrameIO's `send` / `take`, alternately, ROUNDS times; the best round of each
gives µs per frame and the ratio.  Every frame sent is counted back (a lost one is printed).

    python bench/bench_frame_io.py
"""

from __future__ import annotations

import os
import random
import select
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import can  # noqa: E402

from hil.can.frame_io import FrameIO  # noqa: E402
from hil.runtime.realtime import enlarge_receive_buffer  # noqa: E402

BATCH = 2_000         # frames a round: ~1/15 of the receive buffer, none dropped
ROUNDS = 5


def _take_all(take, n: int) -> int:
    """Take frames until `n` came or none came for 1 s; the number taken."""
    got = 0
    while got < n:
        k = take()
        got += k
        if not k and not select.select([take.fileno], [], [], 1.0)[0]:
            break
    return got


def run() -> list[tuple[str, str]]:
    group = f"239.255.{random.randrange(1, 255)}.{random.randrange(1, 255)}"
    port = 30_000 + os.getpid() % 20_000
    with can.Bus(interface="udp_multicast", channel=group, port=port, hop_limit=0) as tx, \
            can.Bus(interface="udp_multicast", channel=group, port=port, hop_limit=0) as rx:
        enlarge_receive_buffer(rx)
        io_tx, io_rx = FrameIO(tx), FrameIO(rx)
        data = bytes(range(8))

        def python_can_send() -> None:
            for k in range(BATCH):
                tx.send(can.Message(arbitration_id=0x100 + k % 64, is_extended_id=False, data=data,
                                    check=False))

        def python_can_take() -> int:
            n = 0
            while rx.recv(0.0) is not None:
                n += 1
            return n

        def frame_io_send() -> None:
            for k in range(BATCH):
                io_tx.send(0x100 + k % 64, False, data)

        def frame_io_take() -> int:
            return io_rx.take(lambda *frame: None)

        python_can_take.fileno = frame_io_take.fileno = rx.fileno()
        best = {"python-can": [1e9, 1e9], "FrameIO": [1e9, 1e9]}
        lost = {"python-can": 0, "FrameIO": 0}
        for _ in range(ROUNDS):
            for name, send, take in (("python-can", python_can_send, python_can_take),
                                     ("FrameIO", frame_io_send, frame_io_take)):
                t0 = time.perf_counter()
                send()
                t1 = time.perf_counter()
                got = _take_all(take, BATCH)
                t2 = time.perf_counter()
                lost[name] += BATCH - got
                best[name][0] = min(best[name][0], (t1 - t0) / BATCH)
                best[name][1] = min(best[name][1], (t2 - t1) / max(got, 1))
    pc, fio = best["python-can"], best["FrameIO"]
    return [
        (f"udp_multicast send, python-can bus.send vs FrameIO ({BATCH} frames, best of {ROUNDS})",
         f"{pc[0] * 1e6:.1f} vs {fio[0] * 1e6:.1f} us a frame: {pc[0] / fio[0]:.1f}x"),
        ("udp_multicast take, python-can bus.recv(0) vs FrameIO.take",
         f"{pc[1] * 1e6:.1f} vs {fio[1] * 1e6:.1f} us a frame: {pc[1] / fio[1]:.1f}x"),
        ("frames lost (python-can / FrameIO)", f"{lost['python-can']} / {lost['FrameIO']}"),
    ]


if __name__ == "__main__":
    for label, figure in run():
        print(f"  {label:<62} {figure}")
