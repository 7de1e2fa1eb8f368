"""Lockstep runner: one process, integer-microsecond simulated time, a discrete-event schedule of node
cycles and plant steps, and an in-process bus that delivers every frame, in order, to its receivers
and to the trace.  Same scenario and seed -> byte-identical trace.

Event order at equal times is fixed by the node order of `assembly.node_names` (PLANT first, so the
plant integrates with the commands received up to that instant).  A frame sent at t is delivered at
t; a receiver that runs later at the same t sees it (no bus timing model yet: frame durations and
arbitration come with the bit-timed bus).
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import can
from cantools.database.can import Database

from hil.assembly import build_node, node_names
from hil.codec import Codec, FrameCodec
from hil.gctune import loop_gc
from hil.node import Node
from hil.plant_node import PlantController, TruthLog
from hil.scenario import Scenario


@dataclass
class RunOutcome:
    """What a run produced, in either mode; the results module turns it into files and KPIs."""

    mode: str
    end_us: int
    reason: str                               # "standstill" | "max_duration" | "interrupted"
    truth: TruthLog
    frames_by_node: dict[str, int]
    node_stats: dict[str, dict] = field(default_factory=dict)
    wall_s: float = 0.0


class LockstepBus:
    """In-process bus: decodes each frame once and hands the values to every subscribed node."""

    def __init__(self, nodes: list[Node], writer: can.Listener | None) -> None:
        self.writer = writer
        self.subscribers: dict[int, list[Node]] = {}
        for node in nodes:
            for fid in node.rx_ids:
                self.subscribers.setdefault(fid, []).append(node)
        self.frames = 0

    def send(self, t_us: int, fc: FrameCodec, data: bytes) -> None:
        self.frames += 1
        if self.writer is not None:
            self.writer.on_message_received(can.Message(
                timestamp=t_us / 1e6, arbitration_id=fc.frame_id, is_extended_id=fc.is_extended_id,
                data=data, dlc=len(data), channel=0, check=False))
        subs = self.subscribers.get(fc.frame_id)
        if subs:
            values = fc.decode(data)
            for node in subs:
                node.receive_values(fc.frame_id, values, t_us)


def run_lockstep(scenario: Scenario, db: Database, codec: Codec, writer: can.Listener | None,
                 progress: Callable[[int, dict], None] | None = None, dbc_name: str = "DBC") -> RunOutcome:
    wall0 = time.perf_counter()
    nodes = [build_node(name, scenario, db, codec, dbc_name) for name in node_names(scenario)]
    plant_node = nodes[0]
    plant: PlantController = plant_node.controller
    bus = LockstepBus(nodes, writer)

    max_us = round(scenario.max_duration_s * 1e6)
    linger_us = round(scenario.end_after_standstill_s * 1e6)
    heap = [(n.offset_us, k) for k, n in enumerate(nodes)]
    heapq.heapify(heap)
    stopped_since: int | None = None
    reason = "max_duration"
    next_progress = 0
    now = 0
    with loop_gc():
        while heap:
            now, k = heapq.heappop(heap)
            if now > max_us:
                break
            node = nodes[k]
            frames = node.cycle(now)
            for fc, data in frames:
                bus.send(now, fc, data)
            heapq.heappush(heap, (now + node.period_us, k))
            if node is plant_node:
                if plant.standstill:
                    stopped_since = now if stopped_since is None else stopped_since
                    if now - stopped_since >= linger_us:
                        reason = "standstill"
                        break
                else:
                    stopped_since = None
                if progress is not None and now >= next_progress:
                    progress(now, plant.glance())
                    next_progress += 500_000
    return RunOutcome(mode="lockstep", end_us=now, reason=reason, truth=plant.truth,
                      frames_by_node={n.name: n.stats.frames_sent for n in nodes},
                      node_stats={n.name: vars(n.stats).copy() for n in nodes},
                      wall_s=time.perf_counter() - wall0)
