"""Lockstep runner: one process, a discrete-event schedule of node cycles, plant steps and bus events
in integer nanoseconds (node times are integer microseconds), and an in-process bus.  Same scenario
and seed -> byte-identical trace.

The bus (scenario ``[bus] timing``):

* ``bit`` (default) — hil.can.bustiming: each node's frames enter its transmit queue when released
  (hil.runtime.release: cycle phase, drift, jitter, extra delay); when the bus is idle the lowest pending
  identifier wins arbitration and occupies the bus for its frame length at the scenario's bitrate;
  receivers and the trace get the frame at the end of its EOF.
* ``ideal`` — a frame sent at t is delivered at t (no frame durations, no arbitration).

The schedule is a `LockstepLoop`; its docstring gives the order of the events (`EventKind`) at equal
times: frame deliveries first (a node running at that instant sees the frame), then node cycles in the
node order of `assembly.node_names` (PLANT first, so the plant integrates with the commands received up
to that instant), then delayed releases, then arbitration (so every frame released at an instant
competes in the arbitration that starts then).

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
import random
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, ClassVar, Protocol

import can
import numpy as np
from cantools.database.can import Database

from hil.can.busload import declared_bitrate
from hil.can.bustiming import BitTimedBus, Pending
from hil.can.codec import Codec, FrameCodec
from hil.devices.gateway import Gateway, ObjectRef, VariableSide
from hil.devices.model import VariableModel, build_model_node
from hil.devices.opcua import LinkMeter
from hil.errors import DeviceError, ScenarioError
from hil.runtime.assembly import build_node, check_devices, node_names
from hil.runtime.gctune import loop_gc
from hil.runtime.node import Node
from hil.runtime.outcome import RunOutcome
from hil.runtime.plant_node import SteppedPlant
from hil.runtime.release import MessageDelay, NodeRelease, message_delays, node_releases
from hil.runtime.truth import PlantView
from hil.scenario import Scenario
from hil.scenario.params import secoc_keys

Message = can.Message
DEFAULT_BITRATE = 500_000   # bit/s, when neither the scenario nor the DBC gives one
NEVER = 1 << 63             # ns: no such event scheduled
ROGUE = -1                  # FaultHook.on_release's sender of an attacker's frames: a transmit queue apart
PROGRESS_NS = 500_000_000   # a progress report every this much simulated time


class EventKind(IntEnum):
    """What a lockstep event does; at equal times the smaller kind runs first (LockstepLoop)."""

    DELIVER = 0            # the frame on the wire reaches the end of its EOF: trace and receivers get it
    CYCLE = 1              # a node's cycle (its controller's step, its frames released)
    RELEASE = 2            # a frame held back (a message delay, a fault) enters its transmit queue
    ARBITRATE = 3          # the bus is idle: the lowest pending identifier wins and goes on the wire
    BABBLE = 4             # a babbling node queues its next frame
    DEVICE_DELIVER = 5     # a device's own bus (DeviceBus): a frame delivered there
    DEVICE_CYCLE = 6       # ... a cycle of the gateway's device side or of the device's model
    DEVICE_ARBITRATE = 7   # ... an arbitration on it


class FaultRecord(Protocol):
    """What a fault injector did (hil.safety.injection.FaultLog)."""

    @property
    def counts(self) -> dict[str, int]: ...

    @property
    def events(self) -> list[tuple[float, str, str]]: ...

    def add(self, t_ns: int, kind: str, what: str) -> None: ...


class FaultHook(Protocol):
    """What the runner asks of a fault injector (hil.safety.injection.FaultInjector, which the caller builds
    from the scenario's [[faults]]): install the faults that live in the nodes, what becomes of each frame a
    node releases, when nodes babble, and what it did (`log`: `add(t_ns, kind, what)`, `counts`,
    `events`, for RunOutcome.faults)."""

    @property
    def log(self) -> FaultRecord: ...

    @property
    def babble_rng(self) -> random.Random: ...   # a babbling node's payloads

    def attach(self, nodes: list[Node]) -> None:
        """Install the faults that live in the nodes (stuck signals, failed sensors)."""

    def on_release(self, t_ns: int, node: int, frame_id: int, data: bytes) -> list[tuple[int, bytes, int]]:
        """The frames (time [ns], payload, sender index; ROGUE: the attacker's) that enter the transmit
        queues for one frame node `node` released at `t_ns`."""

    def babble_windows(self) -> list[tuple[int, int, int, int]]:
        """(start ns, end ns, node index, frame id) of each babbling node."""


class LockstepBus:
    """In-process delivery: hands each frame to every subscribed node (Node.receive)."""

    def __init__(self, nodes: list[Node], writer: can.Listener | None) -> None:
        self.writer = writer
        # hil.trace.writers.BlfWriter takes a frame's fields as they are (no can.Message a frame)
        self._write_frame: Callable[[float, int, bool, bytes], None] | None = getattr(writer, "write_frame",
                                                                                      None)
        self.subscribers: dict[int, list[Node]] = {}
        for node in nodes:
            for fid in node.rx_ids:
                self.subscribers.setdefault(fid, []).append(node)
        self.frames = 0

    def send(self, t_ns: int, frame_id: int, extended: bool, data: bytes) -> None:
        self.frames += 1
        if self._write_frame is not None:
            self._write_frame(t_ns / 1e9, frame_id, extended, data)
        elif self.writer is not None:
            self.writer.on_message_received(Message(
                timestamp=t_ns / 1e9, arbitration_id=frame_id, is_extended_id=extended,
                data=data, dlc=len(data), channel=0, check=False))
        subs = self.subscribers.get(frame_id)
        if subs:
            t_us = t_ns // 1000
            for node in subs:                    # each decodes the signals it reads, once its checks pass
                node.receive(frame_id, data, t_us)


def bus_bitrate(scenario: Scenario, db: Database) -> int:
    bitrate: int = scenario.bus.bitrate or declared_bitrate(db) or DEFAULT_BITRATE
    return bitrate


def bus_report(bus: BitTimedBus, db: Database, end_ns: int,
               more: tuple[Database, ...] = ()) -> dict[str, Any]:
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


# ------------------------------------------------------------------------------------ the heap's events
class Event:
    """What one event of the heap does when its time comes (`run`); its KIND orders it among the events of
    the same instant."""

    KIND: ClassVar[EventKind]

    def run(self, loop: LockstepLoop, now: int) -> None:
        raise NotImplementedError


class NodeCycle(Event):
    """CYCLE: node `index`'s next cycle (one event a node, pushed again after each cycle)."""

    KIND: ClassVar[EventKind] = EventKind.CYCLE

    def __init__(self, index: int) -> None:
        self.index = index

    def run(self, loop: LockstepLoop, now: int) -> None:
        loop.cycle(now, self.index)


class HeldFrame(Event):
    """RELEASE: a frame of node `sender` held back; it enters the transmit queues now, through the fault
    injector first when `inject` (a message delay's: the injector acts on it as it is released), straight
    when not (an injector's own output, a delayed or repeated copy)."""

    KIND: ClassVar[EventKind] = EventKind.RELEASE

    def __init__(self, sender: int, frame_id: int, extended: bool, data: bytes, window_ns: int,
                 inject: bool) -> None:
        self.sender, self.frame_id, self.extended, self.data = sender, frame_id, extended, data
        self.window_ns, self.inject = window_ns, inject

    def run(self, loop: LockstepLoop, now: int) -> None:
        if self.inject:
            loop.release(now, self.sender, self.frame_id, self.extended, self.data, self.window_ns)
        else:
            loop.enqueue(now, self.sender, self.frame_id, self.extended, self.data, self.window_ns)


class Babble(Event):
    """BABBLE: node `node` queues a frame of `frame_id` with random payload whenever it has none waiting,
    every `step_ns` until `end_ns` (hil.safety.injection `babbling`; the bit-timed bus only)."""

    KIND: ClassVar[EventKind] = EventKind.BABBLE

    def __init__(self, end_ns: int, node: int, frame_id: int, extended: bool, step_ns: int, bus: BitTimedBus,
                 injector: FaultHook) -> None:
        self.end_ns, self.node, self.frame_id, self.extended = end_ns, node, frame_id, extended
        self.step_ns, self.bus, self.injector = step_ns, bus, injector

    def run(self, loop: LockstepLoop, now: int) -> None:
        if not self.bus.is_waiting(self.node, self.frame_id, self.extended):
            payload = bytes([self.injector.babble_rng.getrandbits(8) for _ in range(8)])
            loop.enqueue(now, self.node, self.frame_id, self.extended, payload, now)
            self.injector.log.add(now, "babbling", loop.nodes[self.node].name)
            loop.faulted += 1
        if now + self.step_ns < self.end_ns:
            loop.schedule(now + self.step_ns, self)


class DeviceCycle(Event):
    """DEVICE_CYCLE: a cycle of a device's own side `side` (0: the gateway's device side, 1: the device's
    model)."""

    KIND: ClassVar[EventKind] = EventKind.DEVICE_CYCLE

    def __init__(self, device: DeviceBus | DeviceLink, side: int, nominal_us: int) -> None:
        self.device, self.side, self.nominal_us = device, side, nominal_us

    def run(self, loop: LockstepLoop, now: int) -> None:
        self.device.cycle(now, self.side, self.nominal_us, loop)


class DeviceDelivery(Event):
    """DEVICE_DELIVER: a frame on a device's own bus reaches the end of its EOF; what the gateway routes at
    once on it follows."""

    KIND: ClassVar[EventKind] = EventKind.DEVICE_DELIVER

    def __init__(self, device: DeviceBus, frame: Pending) -> None:
        self.device, self.frame = device, frame

    def run(self, loop: LockstepLoop, now: int) -> None:
        self.device.deliver(now, self.frame)
        loop.route(now)


class DeviceArbitration(Event):
    """DEVICE_ARBITRATE: a device's own bus is idle: its arbitration."""

    KIND: ClassVar[EventKind] = EventKind.DEVICE_ARBITRATE

    def __init__(self, device: DeviceBus) -> None:
        self.device = device

    def run(self, loop: LockstepLoop, now: int) -> None:
        self.device.arbitrate(now, loop)


# ------------------------------------------------------------------------------------------ devices
def _device_side(gateway: Gateway) -> Node:
    side = gateway.device_side
    if not isinstance(side, Node):
        raise DeviceError(f"{gateway.device.path}: the device's side of the gateway is not on a CAN bus")
    return side


class DeviceBus:
    """A device's own bus in a lockstep run: the gateway's device side (sender 0) and the device's model
    (sender 1) on a bit-timed bus of their own (the bench's `[bus]` timing and stuffing, the device's bit
    rate), on exact 1 ms-grid releases of their own cycles; its frames go to `writer` (the run folder's
    device-NAME trace).  Its events live in the run's heap (kinds DEVICE_*); `bench_index` is the gateway's
    bench side among the run's nodes, the sender of what it routes onto the bench's bus."""

    bus_mode: ClassVar[str] = "own"

    def __init__(self, bench_index: int, gateway: Gateway, model: Node, scenario: Scenario,
                 bench_bitrate: int) -> None:
        self.bench_index, self.gateway, self.model = bench_index, gateway, model
        self.name: str = gateway.bench.name
        self.nodes = [_device_side(gateway), model]
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
        self.end_ns = 0

    def open(self, writer: can.Listener | None) -> None:
        """Its frames go to `writer` (None: nowhere)."""
        self.delivery = LockstepBus(self.nodes, writer)

    def start(self, loop: LockstepLoop) -> None:
        for j, release in enumerate(self.releases):
            t_ns, nominal, _ = release.next()
            loop.schedule(t_ns, DeviceCycle(self, j, nominal))

    def send(self, now: int, j: int, fc: FrameCodec, data: bytes, loop: LockstepLoop) -> None:
        """Node `j`'s frame into its transmit queue at `now` (the ideal bus: delivered at once)."""
        if self.bus is None:
            self.delivery.send(now, fc.frame_id, fc.is_extended_id, data)
            return
        self.bus.enqueue(Pending(j, fc.frame_id, fc.is_extended_id, data, now, now))
        if not self.arbitrating:
            self.arbitrating = True
            loop.schedule(max(now, self.bus.idle_at_ns), DeviceArbitration(self))

    def routed(self, now: int, side: str, ref: FrameCodec | ObjectRef, payload: bytes | dict[str, float],
               loop: LockstepLoop) -> None:
        """A frame its gateway translated at once, onto the bus of `side`."""
        if not isinstance(ref, FrameCodec) or not isinstance(payload, bytes):
            raise DeviceError(f"{self.gateway.device.path}: a device on a CAN bus routed no frame")
        if side == "bench":
            loop.release(now, self.bench_index, ref.frame_id, ref.is_extended_id, payload, now)
        else:
            self.send(now, 0, ref, payload, loop)

    def deliver(self, now: int, frame: Pending) -> None:
        self.end_ns = now
        self.delivery.send(now, frame.frame_id, frame.extended, frame.data)

    def cycle(self, now: int, j: int, nominal_us: int, loop: LockstepLoop) -> None:
        self.end_ns = now
        for fc, data in self.nodes[j].cycle(now // 1000, nominal_us):
            self.send(now, j, fc, data, loop)
        t_ns, nominal, _ = self.releases[j].next()
        loop.schedule(t_ns, DeviceCycle(self, j, nominal))

    def arbitrate(self, now: int, loop: LockstepLoop) -> None:
        self.end_ns = now
        self.arbitrating = False
        if self.bus is None:                 # the ideal bus schedules no arbitration
            return
        started = self.bus.arbitrate(now)
        if started is not None:
            frame, deliver_ns, idle_ns = started
            loop.schedule(deliver_ns, DeviceDelivery(self, frame))
            if self.bus.pending():
                self.arbitrating = True
                loop.schedule(idle_ns, DeviceArbitration(self))

    def report(self) -> dict[str, Any]:
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

    bus_mode: ClassVar[str] = "bench"

    def __init__(self, bench_index: int, device_index: int, gateway: Gateway, model: Node) -> None:
        self.bench_index, self.device_index = bench_index, device_index
        self.gateway, self.model = gateway, model
        self.name: str = gateway.bench.name

    def routed(self, now: int, side: str, ref: FrameCodec | ObjectRef, payload: bytes | dict[str, float],
               loop: LockstepLoop) -> None:
        """A frame its gateway translated at once, onto the bench's bus from the side it came from."""
        if not isinstance(payload, bytes):
            raise DeviceError(f"{self.gateway.device.path}: a device on a CAN bus routed no frame")
        sender = self.bench_index if side == "bench" else self.device_index
        loop.release(now, sender, ref.frame_id, ref.is_extended_id, payload, now)

    def report(self) -> dict[str, Any]:
        return {**self.gateway.describe(), "mode": "model", "bus_mode": "bench", "bus": None,
                "gateway": self.gateway.stats(), "model": self.model.stats.as_dict()}


class DeviceLink:
    """A device on OPC UA in a lockstep run (transport = "opcua"): the gateway's variable side (0) and the
    device's model (1, hil.devices.model.VariableModel), each on exact releases of its own cycle; what one
    writes reaches the other at once (no bus: the link's own delays are measured in real time).  The stamp
    and echo are counted as the real-time link counts them (hil.devices.opcua.LinkMeter)."""

    bus_mode: ClassVar[str] = "opcua"

    def __init__(self, bench_index: int, gateway: Gateway, model: VariableModel, scenario: Scenario) -> None:
        side = gateway.device_side
        if not isinstance(side, VariableSide):
            raise DeviceError(f"{gateway.device.path}: the device's side of the gateway is not on OPC UA")
        self.bench_index, self.gateway, self.model, self.side = bench_index, gateway, model, side
        self.name: str = gateway.bench.name
        self.nodes: list[VariableSide | VariableModel] = [side, model]
        self.releases = [NodeRelease(n.name, n.period_us, n.offset_us, seed=scenario.seed)
                         for n in self.nodes]
        opcua = gateway.device.spec.opcua
        if opcua is None:
            raise DeviceError(f"{gateway.device.path}: a device without a CAN bus needs its [opcua] table")
        self.meter = LinkMeter(opcua, {m.frame_id: m for m in gateway.device.db.messages})
        self.end_ns = 0

    def open(self, writer: can.Listener | None) -> None:
        """No trace: the link carries variables, not frames."""

    def start(self, loop: LockstepLoop) -> None:
        for j, release in enumerate(self.releases):
            t_ns, nominal, _ = release.next()
            loop.schedule(t_ns, DeviceCycle(self, j, nominal))

    def send(self, now: int, j: int, ref: ObjectRef, values: dict[str, float]) -> None:
        """What side `j` wrote at `now`, to the other at once."""
        if j == 0:
            values = dict(values)
            self.meter.bench_wrote(ref.frame_id, values, now / 1e9)
            self.model.deliver(ref.frame_id, values)
        else:
            clean = self.meter.plc_wrote(ref.frame_id, values, now / 1e9)
            self.side.receive(ref.frame_id, clean, now // 1000)

    def routed(self, now: int, side: str, ref: FrameCodec | ObjectRef, payload: bytes | dict[str, float],
               loop: LockstepLoop) -> None:
        """What its gateway translated at once: a frame onto the bench's bus, an object to the model."""
        if side == "bench" and isinstance(payload, bytes):
            loop.release(now, self.bench_index, ref.frame_id, ref.is_extended_id, payload, now)
        elif side == "device" and isinstance(ref, ObjectRef) and isinstance(payload, dict):
            self.send(now, 0, ref, payload)
        else:
            raise DeviceError(f"{self.gateway.device.path}: the gateway routed {ref.name} to the {side} as "
                              f"neither a frame to the bench nor an object to the device")

    def cycle(self, now: int, j: int, nominal_us: int, loop: LockstepLoop) -> None:
        self.end_ns = now
        for ref, values in self.nodes[j].cycle(now // 1000, nominal_us):
            self.send(now, j, ref, values)
        t_ns, nominal, _ = self.releases[j].next()
        loop.schedule(t_ns, DeviceCycle(self, j, nominal))

    def report(self) -> dict[str, Any]:
        return {**self.gateway.describe(), "mode": "model", "bus_mode": "opcua", "bus": None,
                "gateway": self.gateway.stats(), "model": self.model.stats.as_dict(),
                "opcua": self.meter.record("none: lockstep, the model without a link", 0.0,
                                           self.end_ns / 1e9)}


Device = DeviceBus | DeviceOnBench | DeviceLink


@dataclass
class LockstepSetup:
    """The nodes of a lockstep run, built and checked against the DBC before anything is written."""

    nodes: list[Node]
    injector: FaultHook | None
    releases: list[NodeRelease]
    delays: dict[int, MessageDelay]
    devices: list[Device] = field(default_factory=list)


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
    devices: list[Device] = []
    for k, node in enumerate(list(nodes)):
        gateway = getattr(node, "gateway", None)     # a device's gateway (hil.runtime.assembly.build_node)
        if not isinstance(gateway, Gateway):
            continue
        device = gateway.device
        if device.spec.model is None:
            raise DeviceError(f"{device.path}: no key 'model': a lockstep run needs the device's model "
                              f"(model = \"module:Class\"), or run --realtime with the device on its bus")
        gateway.to_device.truth = _truth_reader(nodes[0].controller)
        if device.codec is None:                  # OPC UA: its variables, no bus
            variables = VariableModel(device, f"{node.name}.device", node.offset_us)
            devices.append(DeviceLink(k, gateway, variables, scenario))
            continue
        model = build_model_node(device, f"{node.name}.device", node.offset_us)
        if device.spec.bus == "bench":           # on the bench's bus: two more nodes of the run
            own, bench = declared_bitrate(device.db), bus_bitrate(scenario, db)
            if own and own != bench:
                print(f"notice: {device.dbc_path.name} declares {own // 1000} kbit/s; on the bench's bus "
                      f"(bus = 'bench' in {device.path.name}) the device runs at the bench's "
                      f"{bench // 1000} kbit/s", file=sys.stderr)
            devices.append(DeviceOnBench(k, len(nodes), gateway, model))
            for extra in (_device_side(gateway), model):
                nodes.append(extra)
                releases.append(NodeRelease(extra.name, extra.period_us, extra.offset_us, seed=scenario.seed))
        else:
            devices.append(DeviceBus(k, gateway, model, scenario, bus_bitrate(scenario, db)))
    return LockstepSetup(nodes, injector, releases, message_delays(scenario, db), devices)


def _truth_reader(plant_controller: object) -> Callable[[str, int], float]:
    """The plant's truth as a gateway reads it: (TruthSnapshot field, car) -> its value now."""
    plant: SteppedPlant | None = getattr(plant_controller, "plant", None)
    if plant is None:
        raise DeviceError("a device's gateway reads the plant's truth; this scenario's plant has none")

    def truth(field: str, car: int) -> float:
        value: float = getattr(plant.snapshot(), field)[car]
        return value
    return truth


class LockstepLoop:
    """The discrete-event schedule of one lockstep run, in integer ns.

    Events, by kind (EventKind); at equal times they run in this order, and events of one kind at one time
    in the order they were scheduled (node cycles: in node order):

      DELIVER           the frame on the wire reaches the end of its EOF: the trace and its receivers get it
      CYCLE             a node's cycle: the plant's first, then the other nodes in node order
      RELEASE           a frame held back (a message delay, a fault) enters its transmit queue
      ARBITRATE         the bus is idle: the lowest pending identifier wins and goes on the wire
      BABBLE            a babbling node queues its next frame
      DEVICE_DELIVER    a device's own bus: a frame delivered (then what its gateway routes at once)
      DEVICE_CYCLE      ... a cycle of the gateway's device side or of the device's model
      DEVICE_ARBITRATE  ... an arbitration

    The bench bus's own two events live outside the heap, as its state: at most one frame is on the wire
    (`on_wire`, delivered at `deliver_at`) and at most one arbitration is scheduled (`arbitration_at`);
    NEVER: none.  Every other event is in the heap, as (time, kind, key, Event): key is the node's index
    for a CYCLE, else a sequence number above every node index."""

    def __init__(self, scenario: Scenario, db: Database, codec: Codec, setup: LockstepSetup,
                 writer: can.Listener | None, device_writers: dict[str, can.Listener],
                 progress: Callable[[int, dict[str, np.ndarray]], None] | None) -> None:
        self.nodes, self.injector, self.releases = setup.nodes, setup.injector, setup.releases
        self.delays, self.devices = setup.delays, setup.devices
        plant = self.nodes[0].controller
        if not isinstance(plant, PlantView):
            raise TypeError(f"node {self.nodes[0].name}: a lockstep run's first node is the plant, whose "
                            f"controller has standstill, truth and glance(); {type(plant).__name__} has not")
        self.plant = plant
        self.progress = progress
        self.delivery = LockstepBus(self.nodes, writer)
        self.rogue = len(self.nodes)        # the transmit queue of an attacker's frames (FaultHook, ROGUE)
        self.bus: BitTimedBus | None = None
        if scenario.bus.timing == "bit":
            deadlines = {m.frame_id: int(m.cycle_time) * 1_000_000 for m in db.messages if m.cycle_time}
            self.bus = BitTimedBus(bus_bitrate(scenario, db), len(self.nodes) + 1, scenario.bus.stuffing,
                                   deadlines)
        self.max_ns: int = round(scenario.max_duration_s * 1e9)
        self.linger_ns: int = round(scenario.end_after_standstill_s * 1e9)
        self.heap: list[tuple[int, EventKind, int, Event]] = []
        self.seq = len(self.nodes)          # the key of the heap's events after every node index
        self.now = 0
        self.reason = "max_duration"
        self.ended = False                  # the train stood long enough: no more events
        self.stopped_since: int | None = None
        self.next_progress = 0
        self.faulted = 0                    # frames the fault injector added (+) or removed (-)
        # outside the heap: through it (a push and a pop more for each of them, two a frame) the default run
        # took 2-3 % more CPU compiled (1.133 against 1.107 s, best of 8 x 3 runs)
        self.deliver_at = self.arbitration_at = NEVER
        self.on_wire: Pending | None = None
        self.nominal = [0] * len(self.nodes)    # each node's next cycle on its own schedule [µs]
        self.window = [0] * len(self.nodes)     # ... and the start of its release window [ns]
        self.cycles = [NodeCycle(k) for k in range(len(self.nodes))]
        for k, release in enumerate(self.releases):
            t_ns, self.nominal[k], self.window[k] = release.next()
            self.heap.append((t_ns, EventKind.CYCLE, k, self.cycles[k]))
        heapq.heapify(self.heap)
        if self.injector is not None:
            for start_ns, end_ns, node, frame_id in self.injector.babble_windows():
                if self.bus is None:
                    raise ScenarioError("a babbling fault needs the bit-timed bus ([bus] timing = \"bit\")")
                extended = codec[frame_id].is_extended_id if frame_id in codec else False
                self.schedule(start_ns, Babble(end_ns, node, frame_id, extended, self.bus.duration_ns(47),
                                               self.bus, self.injector))
        for dev in self.devices:
            if isinstance(dev, (DeviceBus, DeviceLink)):
                dev.open(device_writers.get(dev.name))
                dev.start(self)

    # -- scheduling --------------------------------------------------------------------------------
    def schedule(self, t_ns: int, event: Event) -> None:
        """An event of the heap (not a node's cycle) at `t_ns`, after those of its kind scheduled before."""
        self.seq += 1
        heapq.heappush(self.heap, (t_ns, event.KIND, self.seq, event))

    def run(self) -> None:
        """Every event in time order (the class docstring) until none is left, the next one is beyond the
        scenario's duration (then `now` is its time), or the train has stood long enough."""
        heap = self.heap
        while not self.ended:
            heap_ns = heap[0][0] if heap else NEVER
            if heap_ns == NEVER and self.deliver_at == self.arbitration_at == NEVER:
                return                                                  # nothing left to do
            if self.on_wire is not None and self.deliver_at <= heap_ns:
                if not self._at(self.deliver_at):
                    return                                              # not delivered: still in flight
                frame, self.on_wire, self.deliver_at = self.on_wire, None, NEVER
                self.deliver(self.now, frame.frame_id, frame.extended, frame.data)
            elif self.bus is not None and (self.arbitration_at < heap_ns or (
                    self.arbitration_at == heap_ns != NEVER and heap[0][1] > EventKind.ARBITRATE)):
                if not self._at(self.arbitration_at):
                    return
                self.arbitrate(self.bus)
            else:
                if not self._at(heap_ns):
                    return                                              # left in the heap: in flight
                event = heapq.heappop(heap)[3]
                event.run(self, self.now)

    def _at(self, t_ns: int) -> bool:
        """The next event is at `t_ns`: now, if the run lasts until then."""
        self.now = t_ns
        return t_ns <= self.max_ns

    # -- what the events do ------------------------------------------------------------------------
    def cycle(self, now: int, k: int) -> None:
        """Node `k`'s cycle: its frames released (delayed ones held back), its next cycle scheduled; the
        plant's ends the run once the train has stood `end_after_standstill_s`."""
        for fc, data in self.nodes[k].cycle(now // 1000, self.nominal[k]):
            delay = self.delays.get(fc.frame_id)
            if delay is None:
                self.release(now, k, fc.frame_id, fc.is_extended_id, data, self.window[k])
            else:
                self.schedule(now + delay.next_ns(), HeldFrame(k, fc.frame_id, fc.is_extended_id, data,
                                                                self.window[k] + delay.delay_min_us * 1000,
                                                                inject=True))
        t_next, self.nominal[k], self.window[k] = self.releases[k].next()
        heapq.heappush(self.heap, (t_next, EventKind.CYCLE, k, self.cycles[k]))
        if k == 0:
            self._after_plant_cycle(now)

    def _after_plant_cycle(self, now: int) -> None:
        if self.plant.standstill:
            self.stopped_since = now if self.stopped_since is None else self.stopped_since
            if now - self.stopped_since >= self.linger_ns:
                self.reason = "standstill"
                self.ended = True
                return
        else:
            self.stopped_since = None
        if self.progress is not None and now >= self.next_progress:
            self.progress(now // 1000, self.plant.glance())
            self.next_progress += PROGRESS_NS

    def release(self, t_ns: int, k: int, frame_id: int, extended: bool, data: bytes, window_ns: int) -> None:
        """Node `k` released a frame at `t_ns`: what the fault injector (if any) makes of it enters the
        transmit queues, at once or held back."""
        if self.injector is None:
            self.enqueue(t_ns, k, frame_id, extended, data, window_ns)
            return
        out = self.injector.on_release(t_ns, k, frame_id, data)
        self.faulted += len(out) - 1
        for t_out, d_out, sender in out:
            sender = self.rogue if sender == ROGUE else sender
            if t_out == t_ns:
                self.enqueue(t_ns, sender, frame_id, extended, d_out, window_ns)
            else:
                self.schedule(t_out, HeldFrame(sender, frame_id, extended, d_out, window_ns, inject=False))

    def enqueue(self, t_ns: int, k: int, frame_id: int, extended: bool, data: bytes, window_ns: int) -> None:
        """A frame into node `k`'s transmit queue at `t_ns` (the ideal bus: delivered at once)."""
        if self.bus is None:
            self.deliver(t_ns, frame_id, extended, data)
            return
        self.bus.enqueue(Pending(k, frame_id, extended, data, t_ns, window_ns))
        if self.arbitration_at == NEVER:
            self.arbitration_at = max(t_ns, self.bus.idle_at_ns)

    def arbitrate(self, bus: BitTimedBus) -> None:
        """The bus is idle now: the winner of the arbitration goes on the wire."""
        self.arbitration_at = NEVER
        started = bus.arbitrate(self.now)
        if started is not None:
            self.on_wire, self.deliver_at, idle_ns = started
            if bus.pending():
                self.arbitration_at = idle_ns

    def deliver(self, t_ns: int, frame_id: int, extended: bool, data: bytes) -> None:
        """A frame at the end of its EOF: to the trace and its receivers, then what the gateways route at
        once."""
        self.delivery.send(t_ns, frame_id, extended, data)
        if self.devices:
            self.route(t_ns)

    def route(self, now: int) -> None:
        """What the gateways translated at once, onto the bus each frame goes to."""
        for dev in self.devices:
            if dev.gateway.outbox:
                for side, ref, payload in dev.gateway.take():
                    dev.routed(now, side, ref, payload, self)

    def frames_in_flight(self) -> int:
        """Frames released and not delivered: held back, queued or on the wire."""
        held = sum(1 for _, kind, _, _ in self.heap if kind == EventKind.RELEASE)
        return held + (self.on_wire is not None) + (self.bus.waiting() if self.bus is not None else 0)


def run_lockstep(scenario: Scenario, db: Database, codec: Codec, writer: can.Listener | None,
                 progress: Callable[[int, dict[str, np.ndarray]], None] | None = None, dbc_name: str = "DBC",
                 setup: LockstepSetup | None = None,
                 device_writers: dict[str, can.Listener] | None = None,
                 injector: FaultHook | None = None) -> RunOutcome:
    """Run `scenario` to its end in simulated time; `setup` from prepare_lockstep (built here if None, with
    the fault `injector`); `device_writers`: the trace of each device's own bus, by the node it replaces."""
    wall0 = time.perf_counter()
    setup = setup or prepare_lockstep(scenario, db, codec, dbc_name, injector)
    loop = LockstepLoop(scenario, db, codec, setup, writer, device_writers or {}, progress)
    with loop_gc():
        loop.run()
    bus, nodes, injector = loop.bus, setup.nodes, setup.injector
    return RunOutcome(mode="lockstep", end_us=loop.now // 1000, reason=loop.reason, truth=loop.plant.truth,
                      frames_by_node={n.name: n.stats.frames_sent for n in nodes},
                      node_stats={n.name: n.stats.as_dict() for n in nodes},
                      wall_s=time.perf_counter() - wall0,
                      bus=None if bus is None else bus_report(
                          bus, db, loop.now, tuple(d.gateway.device.db for d in setup.devices
                                                   if isinstance(d, DeviceOnBench))),
                      frames_in_flight=loop.frames_in_flight(),
                      frames_overwritten=sum(s.overwritten for s in bus.stats.values()) if bus else 0,
                      frames_faulted=loop.faulted,
                      faults=None if injector is None else {"counts": injector.log.counts,
                                                            "events": injector.log.events},
                      devices={dev.name: dev.report() for dev in setup.devices})
