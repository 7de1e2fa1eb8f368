"""Multi-process bus at 100 % load of a 1 Mbit/s CAN bus: every frame logged by railhil's recorder?

BENCH_FRAMES frames (default 10⁶) are sent by SENDERS processes on a udp_multicast bus and logged by
railhil's recorder process (goal of issue #10: 0 lost, all logged).

The frames are classic 8-byte data frames, identifiers 0x100-0x13F; byte 0 is the sending process,
bytes 1-4 its sequence number (little endian), bytes 5-7 vary with it.  Each frame's length in bit
times is exact (hil.can.bustiming.FrameBits: its real stuff bits and the interframe space), and frame i is
due at t0 + (bits of frames 0..i-1) / 1 Mbit/s: the frames follow each other as they would on a
1 Mbit/s bus kept 100 % busy (about 8,000 frames/s at these lengths).  Frame i is sent by process
i mod SENDERS at its due time (absolute deadlines, `time.sleep` until the next one is due; frames
already due go out back to back).  The recorder is the real-time runner's own (hil.runtime.realtime: a
python-can Notifier feeding a BLF Logger).  Afterwards the BLF trace is read back: every (process,
sequence number) must be there exactly once.

    BENCH_FRAMES=100000 python bench/bench_bus.py      # a shorter run
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ISSUE = "#10"                 # the issue that set the goals printed here (bench/run_all.py)
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import hil.runtime.realtime as realtime  # noqa: E402
from hil.progress import progress_bar  # noqa: E402
from hil.runtime.rtos import NODE_PRIORITY, make_realtime  # noqa: E402

N_FRAMES = int(os.environ.get("BENCH_FRAMES", "1000000"))
SENDERS = 4                    # sender processes, like nodes
BITRATE_BPS = 1_000_000        # the CAN bus whose 100 % load the senders reproduce
FIRST_ID = 0x100
N_IDS = 64
START_MARGIN_S = 0.5           # t0 lies this far after the senders are started


def payload(sender: int, seq: int) -> bytes:
    return bytes([sender]) + seq.to_bytes(4, "little") + bytes([seq & 0xFF, (seq >> 3) & 0xFF, 0x55])


def frame_of(i: int) -> tuple[int, int, int, bytes]:
    """(sender, its sequence number, identifier, data) of frame i."""
    sender, seq = i % SENDERS, i // SENDERS
    return sender, seq, FIRST_ID + i % N_IDS, payload(sender, seq)


def schedule_ns(n: int) -> tuple[np.ndarray, int]:
    """Due times [ns after t0] of frames 0..n-1 back to back at BITRATE_BPS, and their total bits."""
    from hil.can.bustiming import FrameBits

    shapes = {fid: FrameBits(fid, False, 8, 8, False) for fid in range(FIRST_ID, FIRST_ID + N_IDS)}
    bits = np.empty(n, dtype=np.int64)
    for i in range(n):
        _, _, fid, data = frame_of(i)
        bits[i] = shapes[fid].bits(data)
    starts = np.concatenate([[0], np.cumsum(bits)[:-1]])
    return starts * (1_000_000_000 // BITRATE_BPS), int(bits.sum())


def _sender(s: int, cfg: dict, due_ns: np.ndarray, t0_value, go, counter, out) -> None:
    import can

    bus = realtime.open_bus(cfg)
    make_realtime(NODE_PRIORITY)                        # SCHED_FIFO as the nodes, where the OS permits
    out.put(("ready", s))
    go.wait(realtime.READY_TIMEOUT_S)
    t0_ns = t0_value.value
    sent = errors = 0
    worst_late_ns = 0
    try:
        for i in range(s, due_ns.size, SENDERS):
            due = t0_ns + int(due_ns[i])
            delay = due - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay / 1e9)
            else:
                worst_late_ns = max(worst_late_ns, -delay)
            _, _, fid, data = frame_of(i)
            try:
                bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False, check=False))
                sent += 1
            except can.CanError:
                errors += 1
            if sent % 1000 == 0:
                with counter.get_lock():
                    counter.value += 1000
    finally:
        bus.shutdown()
    out.put(("done", (s, sent, errors, worst_late_ns, time.monotonic_ns())))


def measure(n: int = N_FRAMES, progress: bool = True) -> dict:
    """Send n frames at 100 % of a 1 Mbit/s bus from SENDERS processes, record them, read them back."""
    import can

    from hil.scenario import Scenario

    due, total_bits = schedule_ns(n)
    cfg = realtime.resolve_bus_config({}, Scenario())          # a udp_multicast group of its own
    ctx = mp.get_context("fork")
    go, stop, results, out = ctx.Event(), ctx.Event(), ctx.Queue(), ctx.Queue()
    counter = ctx.Value("q", 0)
    with tempfile.TemporaryDirectory(prefix="railhil-bench-bus-") as tmp:
        trace = Path(tmp) / "trace.blf"
        recorder = ctx.Process(target=realtime._recorder_process, args=(str(trace), cfg, go, stop, results),
                               daemon=True)
        recorder.start()
        kind, name, detail = results.get(timeout=realtime.READY_TIMEOUT_S)
        if kind != "ready":
            raise RuntimeError(f"the recorder did not start: {detail}")
        senders_go = ctx.Event()
        t0_value = ctx.Value("q", 0)
        senders = [ctx.Process(target=_sender, daemon=True,
                               args=(s, cfg, due, t0_value, senders_go, counter, out))
                   for s in range(SENDERS)]
        for p in senders:
            p.start()
        for _ in senders:                                    # every sender has its bus open
            kind, _s = out.get(timeout=realtime.READY_TIMEOUT_S)
        t0 = t0_value.value = time.monotonic_ns() + int(START_MARGIN_S * 1e9)
        senders_go.set()
        bar = progress_bar(n, enabled=progress, unit="frame", desc="bus at 100 % of 1 Mbit/s", leave=False)
        reports = []
        while len(reports) < SENDERS:
            try:
                reports.append(out.get(timeout=0.5)[1])
            except queue.Empty:
                if all(p.exitcode is not None for p in senders) and out.empty():
                    break
            bar.n = counter.value
            bar.refresh()
        bar.close()
        for p in senders:
            p.join(10)
        stop.set()
        try:
            results.get(timeout=60)
        except queue.Empty:
            pass
        recorder.join(30)
        end_ns = max((r[4] for r in reports), default=time.monotonic_ns())
        seen = np.zeros(n, dtype=np.int32)
        unknown = 0
        with can.LogReader(str(trace)) as reader:
            for msg in reader:
                d = msg.data
                if len(d) != 8 or d[0] >= SENDERS:
                    unknown += 1
                    continue
                i = int.from_bytes(d[1:5], "little") * SENDERS + d[0]
                if i < n:
                    seen[i] += 1
                else:
                    unknown += 1
    sent = sum(r[1] for r in reports)
    return {"frames": n, "sent": sent, "send_errors": sum(r[2] for r in reports),
            "logged": int(seen.sum()), "lost": int(np.count_nonzero(seen == 0)),
            "duplicated": int(np.count_nonzero(seen > 1)), "unknown": unknown,
            "wall_s": (end_ns - t0) / 1e9, "bus_s": total_bits / BITRATE_BPS,
            "worst_send_late_us": max((r[3] for r in reports), default=0) / 1e3}


def run() -> list[tuple[str, str]]:
    m = measure()
    rate = m["frames"] / m["bus_s"]
    return [
        (f"frames at 100 % of a 1 Mbit/s bus ({SENDERS} sender processes)",
         f"{m['frames']:,} in {m['bus_s']:.1f} s of bus time ({rate:,.0f} frames/s)"),
        ("sent in wall time (achieved load of 1 Mbit/s)",
         f"{m['sent']:,} in {m['wall_s']:.1f} s ({100 * m['bus_s'] / max(m['wall_s'], 1e-9):.1f} %)"),
        ("logged by the recorder (BLF), read back",
         f"{m['logged']:,}, {m['duplicated']} duplicated, {m['unknown']} foreign"),
        ("lost (goal 0 lost, all logged)",
         f"{m['lost']:,}: {'met' if m['lost'] == 0 and m['logged'] == m['frames'] else 'NOT met'}"),
        ("  send errors / worst lateness of a send",
         f"{m['send_errors']} / {m['worst_send_late_us']:,.0f} us"),
        ("  machine: CPUs, 1-min load average after", f"{os.cpu_count()}, {os.getloadavg()[0]:.1f}"),
    ]


if __name__ == "__main__":
    for label, figure in run():
        print(f"  {label:<62} {figure}")
