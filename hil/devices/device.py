"""A device file checked against both DBCs: the `Device` a gateway is built from.

`load_device(path, bench_db, replaced)` reads the device file (hil.devices.description), loads the
device's DBC, and checks the map against both sides: every signal the device receives has a source on the
bench (a signal of the bench's DBC, a truth quantity of the plant, or a constant) and every signal the
replaced node sent has one on the device; each name exists (else the closest names of both DBCs), units
convert (hil.devices.units), value-table names exist.  Each mapping becomes an `Entry` — the affine
y = a·x + b of its units, scale and offset, or a table of value-table numbers — and each target message a
`Route`: the entries that fill it and what sends it (a source message's frames, or its own cycle).

Nothing is done per frame here; hil.devices.gateway applies the routes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from cantools.database.can import Database, Message, Signal

from hil.can.attributes import bench_filled_signals
from hil.can.busload import declared_bitrate
from hil.can.codec import Codec, loaded_dbc
from hil.can.dbc import closest
from hil.devices.description import DeviceSpec, MapEntry, read_device_file
from hil.devices.protection import filled_signals, message_protection
from hil.devices.units import affine, magnitude_in
from hil.devices.variables import DEVICE_NODE, variable_database
from hil.errors import DbcError, DeviceError

#: the plant's truth quantities a map may take as a source: name -> (TruthSnapshot field, unit)
TRUTH_QUANTITIES = {
    "speed": ("v", "m/s"),                 # the car's speed
    "position": ("x", "m"),                # the car's centre on the track
    "slip_speed": ("s", "m/s"),            # v − r·ω of its wheelset
    "cyl_pressure": ("p", "Pa"),           # its brake cylinder's pressure
    "brake_torque": ("tau", "N*m"),        # its brake's torque
}
#: the TruthSnapshot fields behind them, in the order a shared array keeps them (real time: the plant's host
#: writes them, a gateway reads them: hil.runtime.gateway_host.SharedTruth)
TRUTH_FIELDS = tuple(field for field, _ in TRUTH_QUANTITIES.values())
STALE_CYCLES = 3                           # a source older than this many of its message's cycles is stale
CYCLE = "cycle"                            # [trigger] value: the target goes at its own cycle time


@dataclass(frozen=True)
class Entry:
    """One target signal of a route and where its value comes from."""

    target: str                            # the signal's name in the target message
    key: str                               # "MESSAGE.Signal": the output key of the node that sends it
    source: str | None = None              # "MESSAGE.Signal" read on the other side; None: truth or constant
    truth: tuple[str, int] | None = None   # (TruthSnapshot field, car index from 0)
    a: float = 1.0                         # target = a·source + b
    b: float = 0.0
    choices: Mapping[float, float] | None = None   # source number -> target number (value tables)
    default: float | None = None           # while the source is stale or not yet received
    stale_us: int | None = None            # the source is stale when older than this; None: never
    constant: float | None = None          # the value of a constant entry
    initial: float = 0.0                   # the target's value before any source was received


@dataclass(frozen=True)
class Route:
    """A target message the gateway sends, and when: on each usable frame of `trigger` (the message the
    entries read, on the other side), or, with no trigger, every `cycle_ms` of its own."""

    message: str
    to: Literal["device", "bench"]
    entries: tuple[Entry, ...]
    trigger: str | None
    cycle_ms: int | None


@dataclass
class Device:
    """A device file checked against both DBCs, ready to build a gateway from."""

    path: Path                             # the device file
    spec: DeviceSpec
    dbc_path: Path
    db: Database                           # the device's own DBC
    codec: Codec | None                    # None: an OPC UA device (its variables are not framed)
    node: str                              # the device's node in its DBC
    replaces: str                          # the bench node it replaces
    receives: tuple[str, ...]              # the device messages the gateway sends it
    sends: tuple[str, ...]                 # the device messages it sends
    to_device: tuple[Route, ...]           # one per message in `receives`
    to_bench: tuple[Route, ...]            # one per message the replaced node sent
    protections: dict[str, object] = field(default_factory=dict)   # device message -> its E2E config
    ignored: tuple[str, ...] = ()          # device messages the gateway neither sends nor reads

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def bench_sources(self) -> tuple[str, ...]:
        """The bench signals the map reads ("MESSAGE.Signal")."""
        return tuple(dict.fromkeys(e.source for r in self.to_device for e in r.entries if e.source))

    @property
    def device_sources(self) -> tuple[str, ...]:
        """The device signals the map reads ("MESSAGE.Signal")."""
        return tuple(dict.fromkeys(e.source for r in self.to_bench for e in r.entries if e.source))

    @property
    def uses_truth(self) -> bool:
        return any(e.truth for r in self.to_device for e in r.entries)

    def protection(self, msg: Message):
        """The E2E configuration of a device message (hil.runtime.node's `protection` hook)."""
        return self.protections.get(msg.name)

    def bitrate(self) -> int | None:
        """The device bus's bit rate [bit/s]: the device file's [bus] bitrate, else its DBC's, else None."""
        bus = self.spec.bus
        if isinstance(bus, dict) and isinstance(bus.get("bitrate"), int):
            return int(bus["bitrate"])

        return declared_bitrate(self.db)


@dataclass(frozen=True)
class ReplacedNode:
    """What the bench node a device replaces received and sent (its binding) and its cycle."""

    name: str
    rx_messages: tuple[str, ...]
    tx_messages: tuple[str, ...]
    period_us: int
    offset_us: int
    car: int | None                        # BECUn: car n (its truth quantities by default)


# --------------------------------------------------------------------------------------------- loading
def load_device(path: str | Path, bench_db: Database, replaced: ReplacedNode,
                bench_dbc: str = "the bench's DBC", scenario_nodes: tuple[str, ...] = ()) -> Device:
    """The device file at `path`, checked against the bench's DBC and the node it replaces; a DeviceError
    (one line naming the file and the key) for anything that does not fit."""
    path = Path(path)
    spec = read_device_file(path)
    where = str(path)
    if scenario_nodes and spec.replaces not in scenario_nodes:
        raise DeviceError(f"{where}: key 'replaces' = {spec.replaces!r}: the scenario has no node "
                          f"{spec.replaces!r}; its nodes are {', '.join(scenario_nodes)}")
    if spec.replaces != replaced.name:
        raise DeviceError(f"{where}: key 'replaces' = {spec.replaces!r}, but it was given for node "
                          f"{replaced.name} (e.g. --device {replaced.name}=FILE)")
    if spec.transport == "opcua":           # its variables, as a schema (hil.devices.variables)

        dbc_path, codec, node = path.resolve(), None, spec.node or DEVICE_NODE
        db = variable_database(spec, node)
        _check_opcua(spec, db, where)
    else:
        dbc_path = (path.parent / spec.dbc).resolve()
        try:
            db, codec = loaded_dbc(dbc_path)
        except DbcError as exc:
            raise DeviceError(f"{where}: key 'dbc' = {spec.dbc!r}: {exc}") from None
    if spec.bus == "bench":                     # one bus: every identifier names one message
        bench_ids = {(m.frame_id, bool(m.is_extended_frame)): m.name for m in bench_db.messages}
        for m in db.messages:
            clash = bench_ids.get((m.frame_id, bool(m.is_extended_frame)))
            if clash is not None:
                raise DeviceError(f"{where}: key 'bus' = \"bench\": the device's {m.name} has the identifier "
                                  f"0x{m.frame_id:X} of the bench's {clash}; on one bus each identifier must "
                                  "be one message's (give the device a bus of its own)")
    if spec.transport == "can":
        node = _device_node(spec, db, where)
    sends = tuple(m.name for m in db.messages if node in m.senders)
    if not sends:
        raise DeviceError(f"{where}: key 'node' = {node!r}: {dbc_path.name} names no message that {node} "
                          "sends")
    receivable = _received(db, node)
    ignored = _ignored(spec, receivable, where)
    receives = tuple(n for n in receivable if n not in ignored)
    protections = {}
    for name, pspec in spec.protection.items():
        msg = _message(db, name, f"{where}: key 'protection.{name}'", dbc_path.name)
        protections[name] = message_protection(pspec, msg, f"{where}: key 'protection.{name}'")
    for msg in db.messages:                    # railhil's own attributes, where the device file says nothing
        if msg.name not in protections:
            config = message_protection(None, msg, f"{dbc_path.name}: message {msg.name}")
            if config is not None:
                protections[msg.name] = config
    for name in spec.receive:
        if name not in receives:
            what = ("a message the device sends" if name in sends else
                    "in the device's 'ignore' list" if name in ignored else
                    "not a message of " + dbc_path.name)
            raise DeviceError(f"{where}: key 'receive.{name}': {name} is {what}; [receive] maps the messages "
                              f"{node} receives: {', '.join(receives) or '(none)'}")
    for name in spec.send:
        if name not in replaced.tx_messages:
            raise DeviceError(f"{where}: key 'send.{name}': {replaced.name} does not send {name} in this "
                              f"scenario; [send] maps the messages it sent: {', '.join(replaced.tx_messages)}"
                              f"{_closest_hint(name, list(replaced.tx_messages))}")
    check = _Checker(where, spec, bench_db, db, bench_dbc, dbc_path.name, replaced, protections)
    to_device = tuple(check.route(name, "device") for name in receives)
    to_bench = tuple(check.route(name, "bench") for name in replaced.tx_messages)
    for name in spec.trigger:
        if name not in receives and name not in replaced.tx_messages:
            raise DeviceError(f"{where}: key 'trigger.{name}': not a message the gateway sends (it sends "
                              f"{', '.join((*receives, *replaced.tx_messages))})")
    return Device(path=path, spec=spec, dbc_path=dbc_path, db=db, codec=codec, node=node,
                  replaces=replaced.name, receives=receives, sends=sends, to_device=to_device,
                  to_bench=to_bench, protections=protections, ignored=ignored)


def _check_opcua(spec: DeviceSpec, db: Database, where: str) -> None:
    """[opcua] stamp and echo name a variable the device reads and one it writes, each an integer."""
    for key, objects in (("stamp", spec.reads), ("echo", spec.writes)):
        text = getattr(spec.opcua, key)
        if text is None:
            continue
        obj, _, var = text.partition(".")
        names = [f"{o}.{v}" for o, vs in objects.items() for v in vs]
        if var not in objects.get(obj, {}):
            side = "[reads] (the bench writes it)" if key == "stamp" else "[writes] (the PLC writes it)"
            raise DeviceError(f"{where}: key 'opcua.{key}' = {text!r}: not a variable of {side}"
                              f"{_closest_hint(text, names)}")
        if objects[obj][var].type in ("Float", "Double", "Boolean"):
            raise DeviceError(f"{where}: key 'opcua.{key}' = {text!r}: a count needs an integer variable "
                              f"(it is a {objects[obj][var].type})")


def _carries(target: Signal, source: Signal, a: float, b: float, where: str, src_text: str, out_key: str,
             spec: DeviceSpec) -> None:
    """An OPC UA variable the bench writes takes every value its source signal can have (its DBC range,
    through the map): else a DeviceError naming both ranges."""
    if source.minimum is None or source.maximum is None or target.minimum is None or target.maximum is None:
        return
    lo, hi = sorted((a * float(source.minimum) + b, a * float(source.maximum) + b))
    if lo < float(target.minimum) or hi > float(target.maximum):
        obj, _, var = out_key.partition(".")
        vtype = (spec.reads.get(obj) or {}).get(var)
        unit = f" {target.unit}" if target.unit else ""
        kind = vtype.type if vtype else "?"
        raise DeviceError(f"{where}: the variable {out_key} ({kind}, {target.minimum:g}..{target.maximum:g}"
                          f"{unit}) cannot carry {src_text} ({lo:g}..{hi:g}{unit} through the map): give it "
                          "a wider type, or narrow the map")


def _closest_hint(name: str, names: list[str]) -> str:
    found = closest(name, names)
    return "" if found == "(nothing close)" else f"; closest: {found}"


def _device_node(spec: DeviceSpec, db: Database, where: str) -> str:
    nodes = [n.name for n in db.nodes]
    if spec.node is not None:
        if spec.node not in nodes:
            raise DeviceError(f"{where}: key 'node' = {spec.node!r}: no such node in {spec.dbc} (its nodes: "
                              f"{', '.join(nodes) or 'none'})")
        return spec.node
    senders = sorted({s for m in db.messages for s in m.senders})
    if len(senders) != 1:
        raise DeviceError(f"{where}: key 'node' is missing: {spec.dbc} has the senders "
                          f"{', '.join(senders) or '(none)'}; name the device's")
    return senders[0]


def _received(db: Database, node: str) -> tuple[str, ...]:
    """The messages `node` receives: those its DBC lists it a receiver of; where the DBC lists no receivers
    at all, every message it does not send."""
    declared = any(m.receivers for m in db.messages)
    return tuple(m.name for m in db.messages if node not in m.senders
                 and (node in m.receivers or not declared))


def _ignored(spec: DeviceSpec, receivable: tuple[str, ...], where: str) -> tuple[str, ...]:
    """The device messages the file's `ignore` lists: the gateway neither sends nor maps them."""
    for name in spec.ignore:
        if name not in receivable:
            raise DeviceError(f"{where}: key 'ignore': {name!r} is not a message the device receives; it "
                              f"receives {', '.join(receivable) or '(none)'}"
                              f"{_closest_hint(name, list(receivable))}")
    return tuple(spec.ignore)


def _message(db: Database, name: str, where: str, dbc: str) -> Message:
    try:
        return db.get_message_by_name(name)
    except KeyError:
        raise DeviceError(f"{where}: no message {name!r} in {dbc}"
                          f"{_closest_hint(name, [m.name for m in db.messages])}") from None


def _numbers(signal: Signal) -> dict[str, float]:
    """A signal's value table: name -> number."""
    return {str(name): float(value) for value, name in (signal.choices or {}).items()}


def _start_value(signal: Signal) -> float:
    """The physical value a target signal carries before its source is first received: the DBC's start
    value (GenSigStartValue), else 0 within the signal's range."""
    raw = signal.raw_initial
    if raw is not None:
        try:
            return float(signal.conversion.raw_to_scaled(raw, decode_choices=False))
        except (TypeError, ValueError):
            pass
    lo = -math.inf if signal.minimum is None else float(signal.minimum)
    hi = math.inf if signal.maximum is None else float(signal.maximum)
    return min(max(0.0, lo), hi)


class _Checker:
    """The map's checks and compilation, one route (target message) at a time."""

    def __init__(self, where: str, spec: DeviceSpec, bench_db: Database, device_db: Database, bench_dbc: str,
                 device_dbc: str, replaced: ReplacedNode, protections: dict) -> None:
        self.where, self.spec, self.replaced = where, spec, replaced
        self.dbs = {"bench": bench_db, "device": device_db}
        self.dbc_names = {"bench": bench_dbc, "device": device_dbc}
        self.protections = protections
        self.every = sorted({f"{m.name}.{s.name}" for db in (bench_db, device_db) for m in db.messages
                             for s in m.signals})

    # the signal a source names, on the side it must come from
    def _source(self, text: str, side: str, key: str) -> tuple[Message, Signal]:
        where = f"{self.where}: key '{key}'"
        msg_name, dot, sig_name = text.partition(".")
        if not dot or not sig_name:
            raise DeviceError(f"{where}: from = {text!r}: expected MESSAGE.Signal"
                              + (" or truth.QUANTITY" if side == "bench" else ""))
        found = {}
        for s, db in self.dbs.items():
            try:
                m = db.get_message_by_name(msg_name)
            except KeyError:
                continue
            sig = next((g for g in m.signals if g.name == sig_name), None)
            if sig is not None:
                found[s] = (m, sig)
        if side in found:
            return found[side]
        if found:
            other = next(iter(found))
            raise DeviceError(f"{where}: from = {text!r} is a signal of the {other}'s DBC "
                              f"({self.dbc_names[other]}); "
                              + ("[receive] takes its sources from the bench" if side == "bench" else
                                 "[send] takes its sources from the device"))
        raise DeviceError(f"{where}: from = {text!r}: no such signal in {self.dbc_names['bench']} or "
                          f"{self.dbc_names['device']}{_closest_hint(text, self.every)}")

    def _truth(self, text: str, key: str) -> tuple[str, int, str]:
        """truth.QUANTITY (the replaced node's car) or truth.carN.QUANTITY -> (field, car index, unit)."""
        where = f"{self.where}: key '{key}'"
        parts = text.split(".")[1:]
        car = self.replaced.car
        if len(parts) == 2 and parts[0].startswith("car") and parts[0][3:].isdigit():
            car = int(parts[0][3:])
            parts = parts[1:]
        quantities = ", ".join(TRUTH_QUANTITIES)
        if len(parts) != 1 or parts[0] not in TRUTH_QUANTITIES:
            raise DeviceError(f"{where}: from = {text!r}: expected truth.QUANTITY or truth.carN.QUANTITY, "
                              f"QUANTITY one of {quantities}"
                              f"{_closest_hint(parts[-1] if parts else '', list(TRUTH_QUANTITIES))}")
        if car is None:
            raise DeviceError(f"{where}: from = {text!r}: {self.replaced.name} is not a car's node; name the "
                              "car: truth.carN.QUANTITY")
        field_name, unit = TRUTH_QUANTITIES[parts[0]]
        return field_name, car - 1, unit

    def _filled(self, msg: Message, side: str) -> set[str]:
        """The signals of a target message its sender fills itself (E2E, SecOC, counters, multiplexer)."""
        if side == "bench":
            return bench_filled_signals(msg)
        opcua = self.spec.opcua
        if opcua is not None:                      # the bench's count, which the link writes itself
            obj, _, var = (opcua.stamp or "").partition(".")
            return {var} if obj == msg.name else set()
        return filled_signals(msg, self.protections.get(msg.name))

    def route(self, message: str, to: Literal["device", "bench"]) -> Route:
        db = self.dbs[to]
        msg = db.get_message_by_name(message)
        section = "receive" if to == "device" else "send"
        table = (self.spec.receive if to == "device" else self.spec.send).get(message)
        src_side = "bench" if to == "device" else "device"
        filled = self._filled(msg, to)
        needed = [s for s in msg.signals if s.name not in filled]
        if table is None:
            if not needed:
                table = {}
            else:
                hint = (f"map each signal under [{section}.{message}]" +
                        (", or leave the message out: ignore = [\"" + message + "\"]"
                         if to == "device" else ""))
                who = "the device receives" if to == "device" else self.replaced.name + " sent"
                raise DeviceError(f"{self.where}: the map has no [{section}.{message}]: {who} {message} "
                                  f"({', '.join(s.name for s in needed)}); {hint}")
        names = {s.name: s for s in msg.signals}
        for sig_name in table:
            if sig_name not in names:
                raise DeviceError(f"{self.where}: key '{section}.{message}.{sig_name}': {message} has no "
                                  f"signal {sig_name!r}{_closest_hint(sig_name, list(names))}")
            if sig_name in filled:
                raise DeviceError(f"{self.where}: key '{section}.{message}.{sig_name}': {sig_name} is filled "
                                  f"by the {'gateway' if to == 'device' else 'bench'} itself (its protection "
                                  "or counter); leave it out")
        missing = [s.name for s in needed if s.name not in table]
        if missing:
            who = "the device receives" if to == "device" else "the bench reads"
            them = "it" if len(missing) == 1 else "them"
            raise DeviceError(f"{self.where}: key '{section}.{message}': no source for {', '.join(missing)} "
                              f"({who} {them}); give from = ... or value = ...")
        entries = tuple(self._entry(msg, names[s], e, src_side, f"{section}.{message}.{s}")
                        for s, e in table.items())
        trigger = self._trigger(msg, entries, src_side)
        cycle_ms = int(msg.cycle_time) if msg.cycle_time else None
        if trigger is None and cycle_ms is None and self.spec.opcua is not None:
            cycle_ms = round(self.spec.opcua.input_cycle_ms)   # an object of truth and constants only
        return Route(message, to, entries, trigger, cycle_ms)

    def _entry(self, msg: Message, target: Signal, e: MapEntry, src_side: str, key: str) -> Entry:
        where = f"{self.where}: key '{key}'"
        out_key = f"{msg.name}.{target.name}"
        start = _start_value(target)
        if e.value is not None:
            return Entry(target.name, out_key, constant=self._constant(e.value, target, where), initial=start)
        truth = None
        src_signal = None
        if e.source.startswith("truth."):
            if src_side != "bench":
                raise DeviceError(f"{where}: from = {e.source!r}: the plant's truth is a source of what the "
                                  "device receives ([receive]) only")
            field_name, car, unit = self._truth(e.source, key)
            truth, src_unit, stale_us, src_text = (field_name, car), unit, None, e.source
        else:
            src_msg, src_signal = self._source(e.source, src_side, key)
            src_unit = src_signal.unit
            cycle = src_msg.cycle_time
            stale_us = (round(e.stale_ms * 1000) if e.stale_ms is not None else
                        STALE_CYCLES * int(cycle) * 1000 if cycle else None)
            src_text = f"{src_msg.name}.{src_signal.name}"
        default = None if e.default is None else self._constant(e.default, target, f"{where}: default")
        if e.choices is not None:
            if src_signal is None or not src_signal.choices:
                raise DeviceError(f"{where}: choices: the source {e.source} has no value table")
            if not target.choices:
                raise DeviceError(f"{where}: choices: the target {out_key} has no value table")
            src_names, dst_names = _numbers(src_signal), _numbers(target)
            table = {}
            for a, b in e.choices.items():
                if a not in src_names:
                    raise DeviceError(f"{where}: choices: {a!r} is not a value of {src_text} (its values: "
                                      f"{', '.join(src_names)}){_closest_hint(a, list(src_names))}")
                if b not in dst_names:
                    raise DeviceError(f"{where}: choices: {a} = {b!r}: {b!r} is not a value of {out_key} "
                                      f"(its values: {', '.join(dst_names)})"
                                      f"{_closest_hint(b, list(dst_names))}")
                table[src_names[a]] = dst_names[b]
            return Entry(target.name, out_key, source=None if truth else src_text, truth=truth, choices=table,
                         default=default, stale_us=stale_us, initial=start)
        a, b = affine(e.unit or src_unit, target.unit, e.scale, e.offset, where=where, source=src_text,
                      target=out_key)
        if self.spec.opcua is not None and src_signal is not None and src_side == "bench":
            _carries(target, src_signal, a, b, where, src_text, out_key, self.spec)
        return Entry(target.name, out_key, source=None if truth else src_text, truth=truth, a=a, b=b,
                     default=default, stale_us=stale_us, initial=start)

    def _constant(self, value, target: Signal, where: str) -> float:
        """A constant or a default: a value-table name of the target, a number in its unit, or a quantity."""
        if isinstance(value, str) and target.choices:
            names = _numbers(target)
            if value in names:
                return names[value]
            if not any(ch.isdigit() for ch in value):
                raise DeviceError(f"{where}: {value!r} is not a value of {target.name} (its values: "
                                  f"{', '.join(names)}){_closest_hint(value, list(names))}")
        return magnitude_in(value, target.unit, where)

    def _trigger(self, msg: Message, entries: tuple[Entry, ...], src_side: str) -> str | None:
        given = self.spec.trigger.get(msg.name)
        sources = list(dict.fromkeys(e.source.split(".")[0] for e in entries if e.source))
        if given == CYCLE:
            return None
        if given is not None:
            if given not in sources:
                raise DeviceError(f"{self.where}: key 'trigger.{msg.name}' = {given!r}: expected "
                                  f"\"cycle\" or a message {msg.name} takes a signal from "
                                  f"({', '.join(sources) or 'none'})")
            return given
        if not sources:
            return None
        first = self.dbs[src_side].get_message_by_name(sources[0])
        if not msg.cycle_time:                      # an event message (an OPC UA object the device reads):
            return first.name                      # with its first source's frames
        if first.cycle_time and msg.cycle_time and int(first.cycle_time) == int(msg.cycle_time):
            return first.name                      # same cycle: routed, frame for frame
        return None
