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

Faults ([[faults]] in the scenario) are the caller's: it builds an injector (hil.safety.injection
build_injector) and hands it in (`injector`, a `FaultHook`); the runner asks it what becomes of each frame
a node releases and when a node babbles, and knows no fault kinds itself.

A device in a node's place (hil.devices: [devices.NAME]) has a bus of its own (`DeviceBus`): the
gateway's device side and the device's model on a bit-timed bus at the device's bit rate, whose events
share the run's schedule after the bench's at equal times, its frames in a trace of their own.  A frame
that a gateway translates at once (a routed one) enters the other bus's transmit queue the instant the
frame it translates is delivered.
"""

from __future__ import annotations

import heapq
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import can
from cantools.database.can import Database

from hil.can.busload import declared_bitrate
from hil.can.bustiming import BitTimedBus, Pending
from hil.can.codec import Codec, FrameCodec
from hil.devices.model import VariableModel, build_model_node
from hil.devices.opcua import LinkMeter
from hil.errors import DeviceError, ScenarioError
from hil.runtime.assembly import build_node, check_devices, node_names
from hil.runtime.gctune import loop_gc
from hil.runtime.node import Node
from hil.runtime.outcome import RunOutcome
from hil.runtime.plant_node import PlantController
from hil.runtime.release import NodeRelease, message_delays, node_releases
from hil.scenario import Scenario
from hil.scenario.params import secoc_keys

Message = can.Message
DEFAULT_BITRATE = 500_000   # bit/s, when neither the scenario nor the DBC gives one
DELIVER, CYCLE, RELEASE, ARBITRATE, BABBLE = 0, 1, 2, 3, 4   # event phases: their order at equal times
DEVICE_DELIVER, DEVICE_CYCLE, DEVICE_ARBITRATE = 5, 6, 7      # ... then a device bus's (DeviceBus)
NEVER = 1 << 63             # ns: no such event scheduled
ROGUE = -1                  # FaultHook.on_release's sender of an attacker's frames: a transmit queue apart


class FaultHook(Protocol):
    """What the runner asks of a fault injector (hil.safety.injection.FaultInjector, which the caller builds
    from the scenario's [[faults]]): install the faults that live in the nodes, what becomes of each frame a
    node releases, when nodes babble, and what it did (`log`: `add(t_ns, kind, what)`, `counts`,
    `events`, for RunOutcome.faults)."""

    log: Any
    babble_rng: Any               # random.Random: a babbling node's payloads

    def attach(self, nodes: list[Node]) -> None:
        """Install the faults that live in the nodes (stuck signals, failed sensors)."""

    def on_release(self, t_ns: int, node: int, frame_id: int, data: bytes) -> list[tuple[int, bytes, int]]:
        """The frames (time [ns], payload, sender index; ROGUE: the attacker's) that enter the transmit
        queues for one frame node `node` released at `t_ns`."""

    def babble_windows(self) -> list[tuple[int, int, int, int]]:
        """(start ns, end ns, node index, frame id) of each babbling node."""


class RawFrame(NamedTuple):
    """A frame the DBC does not define (a babbling node's): enough for the bus and the trace."""

    frame_id: int
    is_extended_id: bool
    name: str


class LockstepBus:
    """In-process delivery: hands each frame to every subscribed node (Node.receive)."""

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
                node.receive(fc.frame_id, data, t_us)


def bus_bitrate(scenario: Scenario, db: Database) -> int:
    return scenario.bus.bitrate or declared_bitrate(db) or DEFAULT_BITRATE


def bus_report(bus: BitTimedBus, db: Database, end_ns: int, more: tuple[Database, ...] = ()) -> dict:
    """The bit-timed bus's figures for the run folder: load and per-message response times [µs]; `more`:
    the DBCs of other frames on it (a device on the bench's bus)."""
    names = {m.frame_id: m.name for d in (*more, db) for m in d.messages}
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


class DeviceBus:
    """A device's own bus in a lockstep run: the gateway's device side (sender 0) and the device's model
    (sender 1) on a bit-timed bus of their own (the bench's `[bus]` timing and stuffing, the device's bit
    rate), on exact 1 ms-grid releases of their own cycles; its frames go to `writer` (the run folder's
    device-NAME trace).  Its events live in the run's heap (phases DEVICE_*); `bench_index` is the gateway's
    bench side among the run's nodes, the sender of what it routes onto the bench's bus."""

    def __init__(self, bench_index: int, gateway, model: Node, scenario: Scenario,
                 bench_bitrate: int) -> None:
        self.bench_index, self.gateway, self.model = bench_index, gateway, model
        self.name = gateway.bench.name
        self.nodes = [gateway.device_side, model]
        self.releases = [NodeRelease(n.name, n.period_us, n.offset_us, seed=scenario.seed)
                         for n in self.nodes]
        device = gateway.device
        self.bus: BitTimedBus | None = None
        if scenario.bus.timing == "bit":
            deadlines = {m.frame_id: int(m.cycle_time) * 1_000_000
                         for m in device.db.messages if m.cycle_time}
            self.bus = BitTimedBus(device.bitrate() or bench_bitrate, len(self.nodes), scenario.bus.stuffing,
                                   deadlines)
        self.delivery = LockstepBus(self.nodes, None)
        self.arbitrating = False            # an arbitration is scheduled
        self.bus_mode = "own"
        self.end_ns = 0

    def open(self, writer: can.Listener | None) -> None:
        """Its frames go to `writer` (None: nowhere)."""
        self.delivery = LockstepBus(self.nodes, writer)

    def start(self, push: Callable[[int, int, tuple], None]) -> None:
        for j, release in enumerate(self.releases):
            t_ns, nominal, _ = release.next()
            push(t_ns, DEVICE_CYCLE, (self, j, nominal))

    def send(self, now: int, j: int, fc: FrameCodec, data: bytes, push) -> None:
        """Node `j`'s frame into its transmit queue at `now` (the ideal bus: delivered at once)."""
        if self.bus is None:
            self.delivery.send(now, fc, data)
            return
        self.bus.enqueue(Pending(j, fc.frame_id, fc.is_extended_id, data, now, now, fc))
        if not self.arbitrating:
            self.arbitrating = True
            push(max(now, self.bus.idle_at_ns), DEVICE_ARBITRATE, (self,))

    def handle(self, now: int, phase: int, item: tuple, push) -> None:
        """One of its events, at `now`."""
        self.end_ns = now
        if phase == DEVICE_DELIVER:
            pending = item[1]
            self.delivery.send(now, pending.item, pending.data)
        elif phase == DEVICE_CYCLE:
            _, j, nominal = item
            for fc, data in self.nodes[j].cycle(now // 1000, nominal):
                self.send(now, j, fc, data, push)
            t_ns, nominal, _ = self.releases[j].next()
            push(t_ns, DEVICE_CYCLE, (self, j, nominal))
        else:                                           # DEVICE_ARBITRATE
            self.arbitrating = False
            started = self.bus.arbitrate(now)
            if started is not None:
                pending, deliver_ns, idle_ns = started
                push(deliver_ns, DEVICE_DELIVER, (self, pending))
                if self.bus.pending():
                    self.arbitrating = True
                    push(idle_ns, DEVICE_ARBITRATE, (self,))

    def report(self) -> dict:
        """What the device bus carried and what the gateway and the model did (RunOutcome.devices)."""
        return {**self.gateway.describe(), "mode": "model", "bus_mode": "own",
                "bus": None if self.bus is None else bus_report(self.bus, self.gateway.device.db,
                                                                self.end_ns),
                "gateway": self.gateway.stats(),
                "model": self.model.stats.as_dict()}


class DeviceOnBench:
    """A device on the bench's own bus ([bus] = "bench" in its device file): the gateway's device side and
    the device's model are nodes of the run (`device_index` and the one after it), their frames arbitrate
    with the bench's and go into the bench's trace."""

    bus_mode = "bench"

    def __init__(self, bench_index: int, device_index: int, gateway, model: Node) -> None:
        self.bench_index, self.device_index = bench_index, device_index
        self.gateway, self.model = gateway, model
        self.name = gateway.bench.name

    def report(self) -> dict:
        return {**self.gateway.describe(), "mode": "model", "bus_mode": "bench", "bus": None,
                "gateway": self.gateway.stats(), "model": self.model.stats.as_dict()}


class DeviceLink:
    """A device on OPC UA in a lockstep run (transport = "opcua"): the gateway's variable side (0) and the
    device's model (1, hil.devices.model.VariableModel), each on exact releases of its own cycle; what one
    writes reaches the other at once (no bus: the link's own delays are measured in real time).  The stamp
    and echo are counted as the real-time link counts them (hil.devices.opcua.LinkMeter)."""

    bus_mode = "opcua"

    def __init__(self, bench_index: int, gateway, model, scenario: Scenario) -> None:
        self.bench_index, self.gateway, self.model = bench_index, gateway, model
        self.name = gateway.bench.name
        self.nodes = [gateway.device_side, model]
        self.releases = [NodeRelease(n.name, n.period_us, n.offset_us, seed=scenario.seed)
                         for n in self.nodes]
        objects = {m.frame_id: m for m in gateway.device.db.messages}
        self.meter = LinkMeter(gateway.device.spec.opcua, objects)
        self.end_ns = 0

    def open(self, writer) -> None:
        """No trace: the link carries variables, not frames."""

    def start(self, push: Callable[[int, int, tuple], None]) -> None:
        for j, release in enumerate(self.releases):
            t_ns, nominal, _ = release.next()
            push(t_ns, DEVICE_CYCLE, (self, j, nominal))

    def send(self, now: int, j: int, ref, values: dict, push) -> None:
        """What side `j` wrote at `now`, to the other at once."""
        if j == 0:
            values = dict(values)
            self.meter.bench_wrote(ref.frame_id, values, now / 1e9)
            self.model.deliver(ref.frame_id, values)
        else:
            clean = self.meter.plc_wrote(ref.frame_id, values, now / 1e9)
            self.gateway.device_side.receive(ref.frame_id, clean, now // 1000)

    def handle(self, now: int, phase: int, item: tuple, push) -> None:
        self.end_ns = now
        _, j, nominal = item
        for ref, values in self.nodes[j].cycle(now // 1000, nominal):
            self.send(now, j, ref, values, push)
        t_ns, nominal, _ = self.releases[j].next()
        push(t_ns, DEVICE_CYCLE, (self, j, nominal))

    def report(self) -> dict:
        return {**self.gateway.describe(), "mode": "model", "bus_mode": "opcua", "bus": None,
                "gateway": self.gateway.stats(), "model": self.model.stats.as_dict(),
                "opcua": self.meter.record("none: lockstep, the model without a link", 0.0,
                                           self.end_ns / 1e9)}


@dataclass
class LockstepSetup:
    """The nodes of a lockstep run, built and checked against the DBC before anything is written."""

    nodes: list[Node]
    injector: FaultHook | None
    releases: list
    delays: dict
    devices: list[DeviceBus | DeviceOnBench | DeviceLink] = field(default_factory=list)


def prepare_lockstep(scenario: Scenario, db: Database, codec: Codec, dbc_name: str = "DBC",
                     injector: FaultHook | None = None) -> LockstepSetup:
    """Build every node, the release schedules and the message delays, and attach the fault `injector` (the
    scenario's [[faults]], built by the caller: hil.safety.injection.build_injector): a scenario the DBC
    cannot carry fails here, with one line (RailhilError), before a run folder or trace exists.  A scenario
    with faults and no injector is a ValueError: its faults are not silently left out."""
    if scenario.faults and injector is None:
        raise ValueError(f"scenario {scenario.name!r} has [[faults]] and the lockstep run no injector: build "
                         "it with hil.safety.injection.build_injector and pass it as injector=")
    check_devices(scenario)
    nodes = [build_node(name, scenario, db, codec, dbc_name) for name in node_names(scenario)]
    keys = secoc_keys(scenario)
    for node in nodes:
        node.use_keys(keys, scenario.secoc.window)
    if injector is not None:
        injector.attach(nodes)              # stuck signals and failed sensors live in the nodes
    releases = node_releases(scenario, db, nodes)
    devices = []
    for k, node in enumerate(list(nodes)):
        gateway = getattr(node, "gateway", None)
        if gateway is None:
            continue
        device = gateway.device
        if device.spec.model is None:
            raise DeviceError(f"{device.path}: no key 'model': a lockstep run needs the device's model "
                              f"(model = \"module:Class\"), or run --realtime with the device on its bus")
        plant = nodes[0].controller.plant
        gateway.to_device.truth = lambda field, car, plant=plant: getattr(plant.snapshot(), field)[car]
        if device.codec is None:                  # OPC UA: its variables, no bus
            model = VariableModel(device, f"{node.name}.device", node.offset_us)
            devices.append(DeviceLink(k, gateway, model, scenario))
            continue
        model = build_model_node(device, f"{node.name}.device", node.offset_us)
        if device.spec.bus == "bench":           # on the bench's bus: two more nodes of the run
            own, bench = declared_bitrate(device.db), bus_bitrate(scenario, db)
            if own and own != bench:
                print(f"notice: {device.dbc_path.name} declares {own // 1000} kbit/s; on the bench's bus "
                      f"(bus = 'bench' in {device.path.name}) the device runs at the bench's "
                      f"{bench // 1000} kbit/s", file=sys.stderr)
            devices.append(DeviceOnBench(k, len(nodes), gateway, model))
            for extra in (gateway.device_side, model):
                nodes.append(extra)
                releases.append(NodeRelease(extra.name, extra.period_us, extra.offset_us, seed=scenario.seed))
        else:
            devices.append(DeviceBus(k, gateway, model, scenario, bus_bitrate(scenario, db)))
    return LockstepSetup(nodes, injector, releases, message_delays(scenario, db), devices)


def run_lockstep(scenario: Scenario, db: Database, codec: Codec, writer: can.Listener | None,
                 progress: Callable[[int, dict], None] | None = None, dbc_name: str = "DBC",
                 setup: LockstepSetup | None = None,
                 device_writers: dict[str, can.Listener] | None = None,
                 injector: FaultHook | None = None) -> RunOutcome:
    """Run `scenario` to its end in simulated time; `setup` from prepare_lockstep (built here if None, with
    the fault `injector`); `device_writers`: the trace of each device's own bus, by the node it replaces."""
    wall0 = time.perf_counter()
    setup = setup or prepare_lockstep(scenario, db, codec, dbc_name, injector)
    nodes, injector, releases, delays = setup.nodes, setup.injector, setup.releases, setup.delays
    devices = setup.devices
    plant_node = nodes[0]
    plant: PlantController = plant_node.controller
    delivery = LockstepBus(nodes, writer)
    deliver = delivery.send
    timed = scenario.bus.timing == "bit"
    rogue = len(nodes)                   # the transmit queue of an attacker's frames (FaultHook, ROGUE)
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
            deliver(t_ns, fc, data)
            return
        bus.enqueue(Pending(k, fc.frame_id, fc.is_extended_id, data, t_ns, window_ns, fc))
        if arbitration_at == NEVER:
            arbitration_at = max(t_ns, bus.idle_at_ns)

    fast_release = timed and injector is None      # a frame goes straight into its transmit queue
    heappop, heappush = heapq.heappop, heapq.heappush

    def push(t_ns: int, phase: int, item: tuple) -> None:    # a device bus's event
        nonlocal seq
        seq += 1
        heappush(heap, (t_ns, phase, seq, item))

    def route(now: int) -> None:
        """What the gateways translated at once, onto the bus each frame goes to."""
        for dev in devices:
            if dev.gateway.outbox:
                for side, fc, data in dev.gateway.take():
                    if side == "bench":
                        release(now, dev.bench_index, fc, data, now)
                    elif dev.bus_mode != "bench":
                        dev.send(now, 0, fc, data, push)
                    else:                                       # the device on the bench's bus
                        release(now, dev.device_index, fc, data, now)

    if devices:
        def deliver(t_ns: int, fc: FrameCodec, data: bytes) -> None:    # noqa: F811 - the bench bus, routed
            delivery.send(t_ns, fc, data)
            route(t_ns)

        for dev in devices:
            if dev.bus_mode != "bench":
                dev.open((device_writers or {}).get(dev.name))
                dev.start(push)
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
                deliver(now, frame.item, frame.data)
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
                if phase > BABBLE:                     # a device bus's event
                    item[0].handle(now, phase, item, push)
                    if phase == DEVICE_DELIVER:
                        route(now)
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
    release = route = deliver = push = None   # they call each other: freed at once, not at a GC
    in_flight = (sum(1 for e in heap if e[1] == RELEASE) + (on_wire is not None)
                 + (bus.waiting() if bus else 0))
    overwritten = sum(s.overwritten for s in bus.stats.values()) if bus else 0
    return RunOutcome(mode="lockstep", end_us=now // 1000, reason=reason, truth=plant.truth,
                      frames_by_node={n.name: n.stats.frames_sent for n in nodes},
                      node_stats={n.name: n.stats.as_dict() for n in nodes},
                      wall_s=time.perf_counter() - wall0,
                      bus=None if bus is None else bus_report(
                          bus, db, now, tuple(d.gateway.device.db for d in devices if d.bus_mode == "bench")),
                      frames_in_flight=in_flight, frames_overwritten=overwritten,
                      frames_faulted=faulted,
                      faults=None if injector is None else {"counts": injector.log.counts,
                                                            "events": injector.log.events},
                      devices={dev.name: dev.report() for dev in devices})
