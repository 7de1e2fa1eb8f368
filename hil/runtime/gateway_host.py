"""The real-time host of a device's gateway: the bench's python-can bus and the device's, in one process.

The gateway (hil.devices.gateway) translates a frame the moment it arrives: the host waits on both buses'
sockets at once (select(2) on python-can's `fileno()`; a bus without one is polled every POLL_NS) and
takes every frame each holds as soon as one comes, so that a routed frame leaves within the time the
machine takes to wake the process and translate it — a real rig's gateway forwards on reception, it does
not wait for a cycle.  Between frames it keeps the two sides' cyclic schedules on absolute deadlines of
the run's clock (t0, as every host: hil.runtime.host): the bench side's at the replaced node's cycle and
phase (its frames sent at their own cycle, its E2E checks of frames that did not come), the device side's
at the greatest common divisor of the device's cycle times.  The bench side's cycles are judged as any
node's (`CycleTiming`: the real-time verdict), and each routed frame's time from its reception (the
kernel's timestamp of the frame on its bus) to its send is kept, by the bus it went to.

Frames are taken and sent through hil.can.frame_io (on udp_multicast without a can.Message per frame,
python-can's wire format; the host's own frames filtered out of its sockets); a frame of the bench's
bus that the gateway reads nothing of is dropped by the socket's filter, as a CAN controller's
acceptance filter would.
"""

from __future__ import annotations

import selectors
import time
from array import array
from collections.abc import Callable

import can
import numpy as np

from hil.can.frame_io import FrameIO
from hil.devices.device import TRUTH_FIELDS
from hil.devices.opcua import OpcUaLink
from hil.runtime.clock import RunClock
from hil.runtime.host import PARENT_CHECK_US, TIMESTAMP_TRUST_US, CycleTiming
from hil.runtime.release import NodeRelease

POLL_NS = 500_000              # a bus without a file descriptor is polled this often [ns]


class SharedTruth:
    """The plant's truth quantities a device's map reads (hil.devices.device.TRUTH_QUANTITIES), shared between
    processes: the plant's host writes them after each wake's steps (`write`), the gateway reads the
    latest (`read`, a hil.devices.gateway.TruthReader); NaN until the plant's first step.  One double per
    field and car in a multiprocessing array (aligned 8-byte stores: a reader sees a whole value)."""

    def __init__(self, array, n_cars: int) -> None:
        self.array, self.n = array, n_cars
        self.index = {f: k * n_cars for k, f in enumerate(TRUTH_FIELDS)}

    def write(self, plant_controller) -> None:
        snap = plant_controller.plant.snapshot()
        a, n = self.array, self.n
        for field_name, base in self.index.items():
            a[base:base + n] = getattr(snap, field_name)

    def read(self, field_name: str, car: int) -> float:
        return self.array[self.index[field_name] + car]


def latency_figures(us) -> dict:
    """p50 / p99 / max [µs] of routed frames' latencies, and their number."""
    a = np.asarray(us, dtype=np.int64)
    if not a.size:
        return {"frames": 0, "p50_us": None, "p99_us": None, "max_us": None}
    return {"frames": int(a.size), "p50_us": round(float(np.percentile(a, 50)), 1),
            "p99_us": round(float(np.percentile(a, 99)), 1), "max_us": int(a.max())}


class GatewayHost:
    """A gateway between `bench_bus` and `device_bus` (None: the device is on the bench's bus, each frame
    goes to the side whose DBC has its identifier): `run(stop)` until `stop` is set or `orphaned()`."""

    def __init__(self, gateway, bench_bus: can.BusABC, device_bus, clock: RunClock, *,
                 orphaned: Callable[[], bool] | None = None,
                 first_device_frame: Callable[[float], None] | None = None) -> None:
        self.gateway = gateway
        self.clock, self.orphaned = clock, orphaned         # the run's (hil.runtime.clock.RunClock.starting)
        self.sides = {"bench": gateway.bench, "device": gateway.device_side}
        unread = [fc.frame_id for fc in gateway.bench.codec if fc.frame_id not in gateway.bench.rx_ids]
        bench_io = FrameIO(bench_bus, drop_own=True, drop_ids=unread)
        self.one_bus = device_bus is None
        # the device's port: its python-can bus, or an OPC UA link (hil.devices.opcua: its objects for frames)
        port = device_bus if isinstance(device_bus, OpcUaLink) else None
        self.io = {"bench": bench_io,
                   "device": bench_io if self.one_bus else port or FrameIO(device_bus, drop_own=True)}
        self.first_device_frame = first_device_frame
        self.stopped_epoch: float | None = None      # when run() ended [s, wall clock]
        self.buses = {"bench": bench_bus} if self.one_bus else {"bench": bench_bus, "device": device_bus}
        self.device_ids = frozenset(gateway.device_side.rx_ids)   # one bus: the frames of the device's
        self.releases = {side: NodeRelease(node.name, node.period_us, node.offset_us)
                         for side, node in self.sides.items()}
        self.timing = CycleTiming(gateway.bench.period_us)   # the bench side's cycles, judged as a node's
        self.latency = {"bench": array("q"), "device": array("q")}   # routed: received -> sent [µs], by bus
        self.frames_received = {"bench": 0, "device": 0}
        self.frames_before_start = {"bench": 0, "device": 0}   # dropped: on the buses before t0
        self.timestamps_untrusted = 0
        self.reason: str | None = None

    def now_us(self) -> int:
        return self.clock.now_us()

    def _take(self, side: str) -> None:
        """Every frame the bus of `side` holds, to that side of the gateway (one bus: to the side its
        identifier belongs to); what it routes, out at once."""
        now_us = self.now_us()
        device_ids = self.device_ids if self.one_bus else None

        def on_frame(timestamp: float, frame_id: int, _extended: bool, data: bytes, msg) -> None:
            if msg is not None and (msg.is_error_frame or msg.is_remote_frame):
                return
            t_us = self.clock.simulated_us(timestamp)
            if not (now_us - TIMESTAMP_TRUST_US < t_us <= now_us + 1000):   # not this run's clock
                t_us = now_us
                self.timestamps_untrusted += 1
            on = side if device_ids is None else "device" if frame_id in device_ids else "bench"
            if on == "device" and not self.frames_received["device"] and self.first_device_frame is not None:
                self.first_device_frame(timestamp)
            self.frames_received[on] += 1
            self.sides[on].receive(frame_id, data, t_us)
            if self.gateway.outbox:
                self._route(timestamp, "device" if on == "bench" else "bench")

        self.io[side].take(on_frame)

    def _route(self, received_s: float, to: str) -> None:
        """The frames the gateway translated from the frame received at `received_s`, onto their bus."""
        for side, fc, data in self.gateway.take():
            self.io[side].send(fc.frame_id, fc.is_extended_id, data)
            if side == to:
                self.latency[side].append(int((time.time() - received_s) * 1e6))

    def _send(self, side: str, frames) -> None:
        send = self.io[side].send
        for fc, data in frames:
            send(fc.frame_id, fc.is_extended_id, data)

    def run(self, stop) -> None:
        # what the buses held before the run's start is not the run's: a device running before the bench
        # (its frames piled up in the socket while the processes started) does not reach the bench late
        for side in self.buses:
            self.frames_before_start[side] = self.io[side].take(lambda *frame: None)
        # select(2): its timeout in µs (epoll's and poll's are whole ms: a cycle up to 1 ms late)
        selector = selectors.SelectSelector()
        polled = []
        for side, bus in self.buses.items():
            try:
                selector.register(bus.fileno(), selectors.EVENT_READ, side)
            except (NotImplementedError, OSError, ValueError):
                polled.append(side)              # no file descriptor (some adapters): polled
        try:
            self._loop(stop, selector, polled)
        finally:
            self.stopped_epoch = time.time()
            selector.close()
            for side in self.buses:
                self.io[side].close()

    def _loop(self, stop, selector, polled: list[str]) -> None:
        deadline_of, t0 = self.clock.deadline_ns, self.clock.t0_ns
        slot, nominal, deadline = {}, {}, {}
        for side, release in self.releases.items():
            slot[side], nominal[side], _ = release.next()
            deadline[side] = deadline_of(slot[side])
        next_check = time.monotonic_ns()
        while not stop.is_set():
            now = time.monotonic_ns()
            due = min(deadline.values())
            if now < due:
                wait = due - now if not polled else min(due - now, POLL_NS)
                for key, _ in selector.select(wait / 1e9):
                    self._take(key.data)
                for side in polled:
                    self._take(side)
                continue
            for side in ("bench", "device"):
                if deadline[side] > now:
                    continue
                node = self.sides[side]
                for side_taken in self.buses:           # what came before the deadline, first
                    self._take(side_taken)
                if side == "bench":
                    self.timing.released(deadline[side], t0, time.monotonic_ns())
                self._send(side, node.cycle(slot[side] // 1000, nominal[side]))
                if side == "bench":
                    self.timing.ended(t0)
                slot[side], nominal[side], _ = self.releases[side].next()
                deadline[side] = deadline_of(slot[side])
                if side == "bench":                    # far behind: skip to the next slot, counted
                    late_us = (time.monotonic_ns() - deadline[side]) // 1000
                    for _ in range(self.timing.cycles_to_skip(late_us, slot[side] // 1000)):
                        slot[side], nominal[side], _ = self.releases[side].next()
                        deadline[side] = deadline_of(slot[side])
            if now >= next_check:
                next_check = now + PARENT_CHECK_US * 1000
                if self.orphaned is not None and self.orphaned():
                    self.reason = "orphaned"
                    return

    def payload(self) -> dict:
        """The bench side's result as a node's (its stats and cycle timing) and the device's record."""
        bench = self.gateway.bench
        out = self.timing.payload(bench)
        out["stats"]["frames_received_by_bus"] = dict(self.frames_received)
        out["stats"]["frames_before_start"] = dict(self.frames_before_start)
        out["device"] = {**self.gateway.describe(), "mode": "device", "gateway": self.gateway.stats(),
                         "bus_mode": "bench" if self.one_bus else "own",
                         "processing": {"to_device": latency_figures(self.latency["device"]),
                                        "to_bench": latency_figures(self.latency["bench"])},
                         "timestamps_untrusted": self.timestamps_untrusted}
        return out
