"""The gateway between the bench and a device on its own CAN matrix: pure, no I/O, time passed in.

It has two sides, each a node (hil.runtime.node.Node) on one bus:

- **bench side** (named as the replaced node, e.g. BECU3): on the bench's bus, with the replaced node's
  binding: it receives what the map reads of the bench's frames (their E2E and SecOC checked, as the
  replaced node's were) and sends every frame the replaced node sent, E2E-protected and authenticated
  with the bench's keys — it stands where a real rig's gateway stands, and the bench's receivers judge
  its frames as any node's;
- **device side** (`<node>.gateway`): on the device's bus, with the device's DBC: it receives every frame
  the device sends (each checked by the device's own protection: a frame that fails is dropped and
  counted) and sends every frame the device receives, protected as the device's DBC or file declares.

A target message goes out either at once, translated from the frame that triggers it (`Route.trigger`:
a frame received and usable on the other side), or on the sending side's cyclic schedule at its DBC cycle
time with the latest values (`CyclicRoute`), as long as one of its sources is alive: a device that falls
silent is silent on the bench too, as the replaced node would have been.  Routed frames wait in `outbox`
until the host (the lockstep runner, or the real-time gateway process) puts them on their bus; cyclic
ones leave with the side's cycle.  `Translator` turns one side's latest values into the
other side's signals (hil.devices.device.Entry: affine units, value tables, a default while stale).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import reduce
from typing import NamedTuple

from cantools.database.can import Database

from firmware_py.rx import RxTable
from hil.can.codec import Codec, FrameCodec
from hil.devices.device import Device, Entry, ReplacedNode, Route
from hil.devices.protection import describe
from hil.runtime.node import Binding, Node, NodeStats

#: a truth quantity of the plant: (TruthSnapshot field, car index) -> its value now (hil.devices.device)
TruthReader = Callable[[str, int], float]


@dataclass
class TranslationStats:
    """What a translator substituted: per target ("MESSAGE.Signal"), the values it sent while the source
    was stale or not yet received (its default or its last value), and source values outside `choices`."""

    stale: dict[str, int] = field(default_factory=dict)
    unmapped: dict[str, int] = field(default_factory=dict)


@dataclass
class CyclicRoute:
    """A target message the gateway sends at its own cycle time, on the sending side's schedule."""

    route: Route
    cycle_us: int
    next_due_us: int
    sources: tuple[tuple[str, int | None], ...]   # (source "MESSAGE.Signal", its stale age [µs] or None)


class Translator:
    """One direction of the map: the target signals of `routes` from the latest values of `source` (the
    other side's node) and of the plant's truth."""

    def __init__(self, routes: Iterable[Route], truth: TruthReader | None = None) -> None:
        self.routes = {r.message: r for r in routes}
        self.source: Node | None = None        # the other side, set once both exist
        self.truth = truth
        self.last: dict[str, float] = {e.key: e.initial for r in self.routes.values() for e in r.entries}
        self.stats = TranslationStats()

    def fill(self, route: Route, out: dict[str, float], now_us: int) -> None:
        """The values of `route`'s target signals at `now_us`, into `out` (keyed "MESSAGE.Signal")."""
        rx = self.source.rx
        values = rx.latest
        for e in route.entries:
            out[e.key] = self.last[e.key] = self._value(e, values, rx, now_us)

    def alive(self, sources: tuple[tuple[str, int | None], ...], now_us: int) -> bool:
        """Whether one of a route's frame sources is fresh (received, not stale): a route all of whose
        sources fell silent is not sent, so that the other side sees its sender silent, as it would see the
        device itself (a route of constants and truth alone is always sent)."""
        if not sources:
            return True
        rx = self.source.rx
        for name, stale_us in sources:
            age = rx.age_us(name, now_us)
            if age is not None and (stale_us is None or age <= stale_us):
                return True
        return False

    def _value(self, e: Entry, values, rx, now_us: int) -> float:
        if e.constant is not None:
            return e.constant
        if e.truth is not None:
            x = self.truth(*e.truth) if self.truth is not None else math.nan
            if x == x:
                return e.a * x + e.b
            return self._substitute(e)
        x = values[e.source]
        age = rx.age_us(e.source, now_us)
        if x != x or age is None or (e.stale_us is not None and age > e.stale_us):
            return self._substitute(e)
        if e.choices is not None:
            y = e.choices.get(x)
            if y is None:
                self.stats.unmapped[e.key] = self.stats.unmapped.get(e.key, 0) + 1
                return e.default if e.default is not None else self.last[e.key]
            return y
        return e.a * x + e.b

    def _substitute(self, e: Entry) -> float:
        """A source that is stale, not yet received or not finite: the default, else the last value."""
        self.stats.stale[e.key] = self.stats.stale.get(e.key, 0) + 1
        return e.default if e.default is not None else self.last[e.key]

    def step(self, now_us: int, rx) -> dict[str, float]:
        """The sending node's controller: nothing on its own (the gateway sends every frame itself)."""
        return {}


class GatewaySide(Node):
    """A side of the gateway: a node that tells the gateway of every frame it received and could use (its
    checks passed), so that the frames that frame triggers go out at once, and whose cycles send the
    gateway's cyclic routes (`on_cycle`) besides its checks of frames that did not come."""

    def __init__(self, *args, on_frame: Callable[[int, int], None],
                 on_cycle: Callable[[int, int], list], **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._on_frame, self._on_cycle = on_frame, on_cycle

    def receive(self, frame_id: int, data: bytes, t_us: int) -> None:
        version = self.rx.version
        super().receive(frame_id, data, t_us)
        if self.rx.version != version:
            self._on_frame(frame_id, t_us)

    def cycle(self, now_us: int, nominal_us: int | None = None) -> list[tuple[FrameCodec, bytes]]:
        frames = super().cycle(now_us, nominal_us)
        return frames + self._on_cycle(now_us, now_us if nominal_us is None else nominal_us)


class ObjectRef(NamedTuple):
    """What a variable side's `send_now` names in place of a frame codec: an OPC UA object."""

    frame_id: int                # its place in the device's schema (hil.devices.variables)
    is_extended_id: bool
    name: str


class VariableSide:
    """The device side of the gateway for a device on OPC UA (hil.devices.opcua): its objects' variables in
    place of frames.  `receive(frame_id, values, t_us)` takes an object the device wrote (its variables'
    values); `send_now(object)` gives the values of an object the bench writes; its cycles send the cyclic
    routes of objects filled from the plant's truth or constants alone."""

    def __init__(self, name: str, device: Device, period_us: int, on_frame: Callable[[int, int], None],
                 on_cycle: Callable[[int, int], list]) -> None:
        db = device.db
        self.name, self.period_us, self.offset_us = name, period_us, 0
        self._objects = {m.name: m for m in db.messages}
        self._pairs = {m.frame_id: tuple((s.name, f"{m.name}.{s.name}") for s in m.signals)
                       for m in db.messages if m.name in device.sends}
        self.rx = RxTable([key for pairs in self._pairs.values() for _, key in pairs])
        self.outputs: dict[str, float] = {}
        self.stats = NodeStats()
        self._on_frame, self._on_cycle = on_frame, on_cycle

    @property
    def rx_ids(self) -> frozenset[int]:
        return frozenset(self._pairs)

    def receive(self, frame_id: int, values: Mapping[str, float], t_us: int) -> None:
        pairs = self._pairs.get(frame_id)
        if pairs is None:
            self.stats.unknown_frames += 1
            return
        self.stats.frames_received += 1
        self.rx.update(pairs, values, t_us)
        self._on_frame(frame_id, t_us)

    def send_now(self, message: str, now_us: int) -> tuple[ObjectRef, dict[str, float]]:
        msg = self._objects[message]
        out = self.outputs
        values = {s.name: out[f"{message}.{s.name}"] for s in msg.signals if f"{message}.{s.name}" in out}
        self.stats.frames_sent += 1
        return ObjectRef(msg.frame_id, False, message), values

    def cycle(self, now_us: int, nominal_us: int | None = None) -> list:
        self.stats.cycles += 1
        return self._on_cycle(now_us, now_us if nominal_us is None else nominal_us)


def _gcd_us(cycles_ms: Iterable[int | None], fallback_us: int) -> int:
    cycles = [int(c) * 1000 for c in cycles_ms if c]
    return reduce(math.gcd, cycles) if cycles else fallback_us


class Gateway:
    """The bench side and the device side of a device, and the map between them (module docstring)."""

    def __init__(self, device: Device, replaced: ReplacedNode, bench_db: Database, bench_codec: Codec,
                 bench_dbc: str = "DBC", truth: TruthReader | None = None) -> None:
        self.device = device
        self.to_bench = Translator(device.to_bench)
        self.to_device = Translator(device.to_device, truth)
        # ("bench" | "device", codec, payload); to a device on OPC UA: (.., its object, its values)
        self.outbox: list[tuple[str, FrameCodec | ObjectRef, bytes | dict[str, float]]] = []
        self.routed = {"bench": 0, "device": 0}                   # frames sent at once, by the side sent on
        source_messages = list(dict.fromkeys(s.split(".")[0] for s in device.bench_sources))
        bench_rx = list(dict.fromkeys([*replaced.rx_messages, *source_messages]))
        bench_out = [e.key for r in device.to_bench for e in r.entries]
        self.bench = GatewaySide(
            replaced.name, self.to_bench,
            Binding.build(bench_db, replaced.name, device.bench_sources, bench_out, bench_rx,
                          replaced.tx_messages, bench_dbc),
            bench_codec, bench_db, offset_us=replaced.offset_us,
            # its cycles: those of the frames it sends at their own cycle time (its deadlines; a routed
            # frame has its latency instead), at the replaced node's phase
            period_us=_gcd_us([r.cycle_ms for r in device.to_bench if r.trigger is None], replaced.period_us),
            routed=[r.message for r in device.to_bench], on_frame=self._from_bench,
            on_cycle=self._bench_cycle)
        ddb = device.db
        cycles = [ddb.get_message_by_name(n).cycle_time for n in (*device.sends, *device.receives)]
        self.device_side: GatewaySide | VariableSide
        if device.codec is None:                   # OPC UA: variables, not frames
            cycles += [r.cycle_ms for r in device.to_device]
            self.device_side = VariableSide(f"{replaced.name}.gateway", device,
                                            _gcd_us(cycles, replaced.period_us), self._from_device,
                                            self._device_cycle)
        else:
            device_in = [f"{m}.{s.name}" for m in device.sends for s in ddb.get_message_by_name(m).signals]
            device_out = [e.key for r in device.to_device for e in r.entries]
            self.device_side = GatewaySide(
                f"{replaced.name}.gateway", self.to_device,
                Binding.build(ddb, f"{replaced.name}.gateway", device_in, device_out, device.sends,
                              device.receives, device.name),
                device.codec, ddb, period_us=_gcd_us(cycles, replaced.period_us), offset_us=0,
                protection=device.protection, routed=[r.message for r in device.to_device],
                on_frame=self._from_device, on_cycle=self._device_cycle)
        self.to_bench.source, self.to_device.source = self.device_side, self.bench
        self._bench_triggers = self._triggers(device.to_device, bench_db)
        self._device_triggers = self._triggers(device.to_bench, ddb)
        self._cyclic = {"bench": self._schedule(device.to_bench, replaced.offset_us),
                        "device": self._schedule(device.to_device, 0)}

    @staticmethod
    def _schedule(routes: Iterable[Route], offset_us: int) -> list[CyclicRoute]:
        """The routes sent at their own cycle (no trigger), from the sending side's first cycle on."""
        return [CyclicRoute(r, r.cycle_ms * 1000, offset_us,
                            tuple((e.source, e.stale_us) for e in r.entries if e.source))
                for r in routes if r.trigger is None and r.cycle_ms]

    def _due(self, to: str, translator: Translator, side: Node, now_us: int,
             slot_us: int) -> list[tuple[FrameCodec, bytes]]:
        """The cyclic routes of `to` due at `slot_us`, each sent while one of its sources is alive."""
        frames = []
        for c in self._cyclic[to]:
            if slot_us < c.next_due_us:
                continue
            c.next_due_us += c.cycle_us
            if c.next_due_us <= slot_us:              # overrun: skip missed slots, keep the phase
                c.next_due_us += ((slot_us - c.next_due_us) // c.cycle_us + 1) * c.cycle_us
            if translator.alive(c.sources, now_us):
                translator.fill(c.route, side.outputs, now_us)
                frames.append(side.send_now(c.route.message, now_us))
        return frames

    def _bench_cycle(self, now_us: int, slot_us: int) -> list[tuple[FrameCodec, bytes]]:
        return self._due("bench", self.to_bench, self.bench, now_us, slot_us)

    def _device_cycle(self, now_us: int, slot_us: int) -> list[tuple[FrameCodec, bytes]]:
        return self._due("device", self.to_device, self.device_side, now_us, slot_us)

    @staticmethod
    def _triggers(routes: Iterable[Route], source_db: Database) -> dict[int, list[Route]]:
        out: dict[int, list[Route]] = {}
        for r in routes:
            if r.trigger is not None:
                out.setdefault(source_db.get_message_by_name(r.trigger).frame_id, []).append(r)
        return out

    def _route(self, routes: list[Route], translator: Translator, side: Node, to: str, t_us: int) -> None:
        for route in routes:
            translator.fill(route, side.outputs, t_us)
            codec, data = side.send_now(route.message, t_us)
            self.outbox.append((to, codec, data))
            self.routed[to] += 1

    def _from_bench(self, frame_id: int, t_us: int) -> None:
        routes = self._bench_triggers.get(frame_id)
        if routes:
            self._route(routes, self.to_device, self.device_side, "device", t_us)

    def _from_device(self, frame_id: int, t_us: int) -> None:
        routes = self._device_triggers.get(frame_id)
        if routes:
            self._route(routes, self.to_bench, self.bench, "bench", t_us)

    def take(self) -> list[tuple[str, FrameCodec | ObjectRef, bytes | dict[str, float]]]:
        """The frames routed since the last call, in order: ("bench" | "device", codec, payload); to a device
        on OPC UA: (.., its object, its values)."""
        out, self.outbox = self.outbox, []
        return out

    def describe(self) -> dict:
        """The device and the gateway's routes, for the run's records (hil.report.devices): its file, DBC and
        node, the node it replaces, each target message with what sends it (its trigger, or None: its own
        cycle; and its first source message), each device message's protection."""

        d = self.device

        def first_source(route: Route) -> str | None:
            return next((e.source.split(".")[0] for e in route.entries if e.source), None)

        return {"file": str(d.path), "dbc": str(d.dbc_path), "node": d.node, "replaces": d.replaces,
                "sends": list(d.sends), "receives": list(d.receives),
                "routes": [{"message": r.message, "to": r.to, "trigger": r.trigger, "source": first_source(r),
                            "cycle_ms": r.cycle_ms} for r in (*d.to_device, *d.to_bench)],
                "protection": {m: describe(d.protections.get(m)) for m in (*d.sends, *d.receives)}}

    def stats(self) -> dict:
        """What the gateway did: frames routed per side, substitutions per direction, and each side's node
        statistics (frames, E2E statuses, frames dropped)."""
        return {"routed": dict(self.routed),
                "to_device": {"stale": dict(self.to_device.stats.stale),
                              "unmapped": dict(self.to_device.stats.unmapped)},
                "to_bench": {"stale": dict(self.to_bench.stats.stale),
                             "unmapped": dict(self.to_bench.stats.unmapped)},
                "device_side": self.device_side.stats.as_dict()}
