"""Lockstep runner: one process, a discrete-event schedule of node cycles, plant steps and bus events
in integer nanoseconds (node times are integer microseconds), and an in-process bus.  Same scenario
and seed -> byte-identical trace.

The bus (scenario ``[bus] timing``):

* ``bit`` (default) — hil.can.bustiming: each node's frames enter its transmit queue when released
  (hil.runtime.release: cycle phase, drift, jitter, extra delay); when the bus is idle the lowest pending
  identifier wins arbitration and occupies the bus for its frame length at the scenario's bitrate;
  receivers and the trace get the frame at the end of its EOF.
* ``ideal`` — a frame sent at t is delivered at t (no frame durations, no arbitration).

Event order at equal times: frame deliveries first (a node running at that instant sees the frame),
then node cycles in the node order of `assembly.node_names` (PLANT first, so the plant integrates
with the commands received up to that instant), then delayed releases, then arbitration (so every
frame released at an instant competes in the arbitration that starts then).
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import can
from cantools.database.can import Database

from hil.can.busload import declared_bitrate
from hil.can.bustiming import BitTimedBus, Pending
from hil.can.codec import Codec, FrameCodec
from hil.errors import ScenarioError
from hil.runtime.assembly import build_node, node_names
from hil.runtime.gctune import loop_gc
from hil.runtime.node import Node
from hil.runtime.outcome import RunOutcome
from hil.runtime.plant_node import PlantController
from hil.runtime.release import message_delays, node_releases
from hil.safety.injection import ROGUE, build_injector
from hil.scenario import Scenario
from hil.scenario.params import secoc_keys

Message = can.Message
DEFAULT_BITRATE = 500_000   # bit/s, when neither the scenario nor the DBC gives one
DELIVER, CYCLE, RELEASE, ARBITRATE, BABBLE = 0, 1, 2, 3, 4   # event phases: their order at equal times
NEVER = 1 << 63             # ns: no such event scheduled


class RawFrame(NamedTuple):
    """A frame the DBC does not define (a babbling node's): enough for the bus and the trace."""

    frame_id: int
    is_extended_id: bool
    name: str


class LockstepBus:
    """In-process delivery: hands each frame to every subscribed node (Node.receive_frame)."""

    def __init__(self, nodes: list[Node], writer: can.Listener | None) -> None:
        self.writer = writer
        # hil.trace.writers.BlfWriter takes a frame's fields as they are (no can.Message a frame)
        self._write_frame = getattr(writer, "write_frame", None)
        self.subscribers: dict[int, list[Node]] = {}
        for node in nodes:
            for fid in node.rx_ids:
                self.subscribers.setdefault(fid, []).append(node)
        self.frames = 0

    def send(self, t_ns: int, fc: FrameCodec, data: bytes) -> None:
        self.frames += 1
        if self._write_frame is not None:
            self._write_frame(t_ns / 1e9, fc.frame_id, fc.is_extended_id, data)
        elif self.writer is not None:
            self.writer.on_message_received(Message(
                timestamp=t_ns / 1e9, arbitration_id=fc.frame_id, is_extended_id=fc.is_extended_id,
                data=data, dlc=len(data), channel=0, check=False))
        subs = self.subscribers.get(fc.frame_id)
        if subs:
            t_us = t_ns // 1000
            for node in subs:                    # each decodes the signals it reads, once its checks pass
                node.receive_frame(fc.frame_id, data, t_us)


def bus_bitrate(scenario: Scenario, db: Database) -> int:
    return scenario.bus.bitrate or declared_bitrate(db) or DEFAULT_BITRATE


def bus_report(bus: BitTimedBus, db: Database, end_ns: int) -> dict:
    """The bit-timed bus's figures for the run folder: load and per-message response times [µs]."""
    names = {m.frame_id: m.name for m in db.messages}
    messages = {}
    for fid, s in sorted(bus.stats.items()):
        messages[names.get(fid, hex(fid))] = {
            "frame_id": fid,
            "frames": s.frames,
            "response_max_us": s.response_max_ns / 1e3,
            "response_mean_us": s.response_sum_ns / s.frames / 1e3 if s.frames else None,
            "queued_max_us": s.queued_max_ns / 1e3,
            "deadline_misses": s.deadline_misses,
            "overwritten": s.overwritten,
        }
    return {"bitrate_bps": bus.bitrate_bps, "stuffing": bus.stuffing,
            "load": bus.busy_ns / max(end_ns, bus.idle_at_ns) if end_ns > 0 else None,
            "messages": messages}


@dataclass
class LockstepSetup:
    """The nodes of a lockstep run, built and checked against the DBC before anything is written."""

    nodes: list[Node]
    injector: object | None
    releases: list
    delays: dict


def prepare_lockstep(scenario: Scenario, db: Database, codec: Codec, dbc_name: str = "DBC") -> LockstepSetup:
    """Build every node, the fault injector, the release schedules and the message delays: a scenario the
    DBC cannot carry fails here, with one line (RailhilError), before a run folder or trace exists."""
    nodes = [build_node(name, scenario, db, codec, dbc_name) for name in node_names(scenario)]
    keys = secoc_keys(scenario)
    for node in nodes:
        node.use_keys(keys, scenario.secoc.window)
    injector = build_injector(scenario, db, codec, [n.name for n in nodes])
    if injector is not None:
        injector.attach(nodes)              # stuck signals and failed sensors live in the nodes
    return LockstepSetup(nodes, injector, node_releases(scenario, db, nodes), message_delays(scenario, db))


def run_lockstep(scenario: Scenario, db: Database, codec: Codec, writer: can.Listener | None,
                 progress: Callable[[int, dict], None] | None = None, dbc_name: str = "DBC",
                 setup: LockstepSetup | None = None) -> RunOutcome:
    """Run `scenario` to its end in simulated time; `setup` from prepare_lockstep (built here if None)."""
    wall0 = time.perf_counter()
    setup = setup or prepare_lockstep(scenario, db, codec, dbc_name)
    nodes, injector, releases, delays = setup.nodes, setup.injector, setup.releases, setup.delays
    plant_node = nodes[0]
    plant: PlantController = plant_node.controller
    delivery = LockstepBus(nodes, writer)
    timed = scenario.bus.timing == "bit"
    rogue = len(nodes)                   # the transmit queue of an attacker's frames (hil.safety.injection)
    bus = None
    if timed:
        deadlines = {m.frame_id: int(m.cycle_time) * 1_000_000 for m in db.messages if m.cycle_time}
        bus = BitTimedBus(bus_bitrate(scenario, db), len(nodes) + 1, scenario.bus.stuffing, deadlines)

    max_ns = round(scenario.max_duration_s * 1e9)
    linger_ns = round(scenario.end_after_standstill_s * 1e9)
    heap: list[tuple] = []
    nominal = [0] * len(nodes)
    window = [0] * len(nodes)
    # The plant's 1 ms cycles (a fixed clock: no jitter, drift or delay) live outside the heap too, at
    # `plant_at`: a third of a run's events, each then without a heap push and pop or a release draw.
    # At equal times the plant (CYCLE, node 0) comes after a delivery and before everything in the heap.
    lane = plant_node is nodes[0] and releases[0].exact
    plant_at = NEVER
    plant_period_ns, plant_period_us = releases[0].period_us * 1000, releases[0].period_us
    for k, rel in enumerate(releases):
        t_ns, nominal[k], window[k] = rel.next()
        if lane and k == 0:
            plant_at = t_ns
        else:
            heap.append((t_ns, CYCLE, k, None))
    heapq.heapify(heap)
    seq = len(nodes)                     # tie-breaker of heap events after every node index
    # The bus's own two events live outside the heap: at most one frame is on the wire (delivered at
    # `deliver_at`) and at most one arbitration is scheduled (`arbitration_at`); NEVER: none.  The loop
    # takes them in the heap's order (phases DELIVER < CYCLE < RELEASE < ARBITRATE < BABBLE at equal
    # times), which saves two heap pushes and pops per frame.
    deliver_at = arbitration_at = NEVER
    on_wire: Pending | None = None
    stopped_since: int | None = None
    reason = "max_duration"
    next_progress = 0
    now = 0

    faulted = 0
    babble_step_ns = bus.duration_ns(47) if bus is not None else 0    # a babbler re-queues this often
    if injector is not None:
        for start_ns, end_ns, node_k, frame_id in injector.babble_windows():
            if not timed:
                raise ScenarioError("a babbling fault needs the bit-timed bus ([bus] timing = \"bit\")")
            fc = codec[frame_id] if frame_id in codec else RawFrame(frame_id, False, f"0x{frame_id:03X}")
            seq += 1
            heap.append((start_ns, BABBLE, seq, (end_ns, node_k, fc)))
        heapq.heapify(heap)

    def release(t_ns: int, k: int, fc: FrameCodec, data: bytes, window_ns: int, inject: bool = True) -> None:
        nonlocal seq, arbitration_at, faulted
        if inject and injector is not None:
            out = injector.on_release(t_ns, k, fc.frame_id, data)
            faulted += len(out) - 1
            for t_out, d_out, sender in out:
                sender = rogue if sender == ROGUE else sender
                if t_out == t_ns:
                    release(t_ns, sender, fc, d_out, window_ns, inject=False)
                else:
                    seq += 1
                    heapq.heappush(heap, (t_out, RELEASE, seq, (sender, fc, d_out, window_ns, False)))
            return
        if not timed:
            delivery.send(t_ns, fc, data)
            return
        bus.enqueue(Pending(k, fc.frame_id, fc.is_extended_id, data, t_ns, window_ns, fc))
        if arbitration_at == NEVER:
            arbitration_at = max(t_ns, bus.idle_at_ns)

    fast_release = timed and injector is None      # a frame goes straight into its transmit queue
    heappop, heappush = heapq.heappop, heapq.heappush
    with loop_gc():
        while True:
            if heap:
                top = heap[0]
                t_top = top[0]
            elif deliver_at == NEVER and arbitration_at == NEVER and plant_at == NEVER:
                break
            else:
                top, t_top = None, NEVER
            if deliver_at <= t_top and deliver_at <= plant_at and deliver_at != NEVER:   # DELIVER: first
                now = deliver_at
                if now > max_ns:
                    break                                              # not run: still in flight
                frame, on_wire, deliver_at = on_wire, None, NEVER
                delivery.send(now, frame.item, frame.data)
                continue
            if plant_at <= t_top and plant_at <= arbitration_at and plant_at != NEVER:   # the plant's cycle
                now, k = plant_at, 0
                if now > max_ns:
                    break
            else:
                if arbitration_at < t_top or (arbitration_at == t_top != NEVER and top[1] > ARBITRATE):
                    now = arbitration_at
                    if now > max_ns:
                        break
                    arbitration_at = NEVER
                    started = bus.arbitrate(now)
                    if started is not None:
                        on_wire, deliver_at, idle_ns = started
                        if bus.pending():
                            arbitration_at = idle_ns
                    continue
                now, phase, k, item = heappop(heap)
                if now > max_ns:
                    heappush(heap, (now, phase, k, item))     # not run: still in flight
                    break
                if phase == RELEASE:
                    release(now, *item)
                    continue
                if phase == BABBLE:
                    end_ns, node_k, fc = item
                    if not bus.is_waiting(node_k, fc.frame_id, fc.is_extended_id):
                        release(now, node_k, fc, bytes(injector.babble_rng.getrandbits(8) for _ in range(8)),
                                now, inject=False)
                        injector.log.add(now, "babbling", nodes[node_k].name)
                        faulted += 1
                    if now + babble_step_ns < end_ns:
                        seq += 1
                        heappush(heap, (now + babble_step_ns, BABBLE, seq, item))
                    continue
            node = nodes[k]
            frames = node.cycle(now // 1000, nominal[k])
            for fc, data in frames:
                delay = delays.get(fc.frame_id) if delays else None
                if delay is not None:
                    seq += 1
                    heappush(heap, (now + delay.next_ns(), RELEASE, seq,
                                    (k, fc, data, window[k] + delay.delay_min_us * 1000, True)))
                elif fast_release:
                    bus.enqueue(Pending(k, fc.frame_id, fc.is_extended_id, data, now, window[k], fc))
                    if arbitration_at == NEVER:
                        arbitration_at = max(now, bus.idle_at_ns)
                else:
                    release(now, k, fc, data, window[k])
            if k == 0 and lane:                        # the next cycle on the plant's fixed clock
                plant_at = window[0] = plant_at + plant_period_ns
                nominal[0] += plant_period_us
            else:
                t_next, nominal[k], window[k] = releases[k].next()
                heappush(heap, (t_next, CYCLE, k, None))
            if node is plant_node:
                if plant.standstill:
                    stopped_since = now if stopped_since is None else stopped_since
                    if now - stopped_since >= linger_ns:
                        reason = "standstill"
                        break
                else:
                    stopped_since = None
                if progress is not None and now >= next_progress:
                    progress(now // 1000, plant.glance())
                    next_progress += 500_000_000
    release = None     # it calls itself: drop the cycle, so a finished run is freed at once, not at a GC
    in_flight = (sum(1 for e in heap if e[1] == RELEASE) + (on_wire is not None)
                 + (bus.waiting() if bus else 0))
    overwritten = sum(s.overwritten for s in bus.stats.values()) if bus else 0
    return RunOutcome(mode="lockstep", end_us=now // 1000, reason=reason, truth=plant.truth,
                      frames_by_node={n.name: n.stats.frames_sent for n in nodes},
                      node_stats={n.name: vars(n.stats).copy() for n in nodes},
                      wall_s=time.perf_counter() - wall0,
                      bus=bus_report(bus, db, now) if bus is not None else None,
                      frames_in_flight=in_flight, frames_overwritten=overwritten,
                      frames_faulted=faulted,
                      faults=None if injector is None else {"counts": injector.log.counts,
                                                            "events": injector.log.events})
