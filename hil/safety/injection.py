"""Fault injection on the lockstep bus: the EN 50159 threats to a message, a babbling node and a node
going bus-off, each declared in the scenario with a time window and seeded.

Pure logic: `FaultInjector.on_release` gets every frame a node releases (time, node, frame id,
payload) and returns what reaches the transmit queues instead, with times; `babble_windows` gives the
babbling nodes.  The caller of a lockstep run builds the injector (`build_injector`) and hands it to the
runner, whose hook it fills (hil.runtime.lockstep.FaultHook): the runtime names no fault.

Threats (EN 50159 §5.1; applied to the frames of `message` released in [from_s, to_s), each with
`probability`, seeded):

* ``repetition``   — the frame is sent, then a copy `delay_ms` later (default: at once; the copy
  comes from the network, not from the sender's transmit buffer).
* ``deletion``     — the frame is dropped.
* ``insertion``    — an extra frame of the message is sent after it: the same payload with one random
  byte changed (a frame that does not belong there).
* ``resequencing`` — the frame is held back and sent right after the next frame of the message.
* ``corruption``   — one random bit of the payload is flipped.
* ``delay``        — the frame is sent `delay_ms` later.
* ``masquerade``   — a rogue sender's frame is sent after it: the same message with `signal` set to
  `value` (e.g. a brake release), its E2E counter and CRC correct (E2E is public, not security);
  only authentication can reject it.
* ``babbling``     — `node` floods the bus with frames of identifier `frame_id` (default 0x000, the
  highest priority) back to back for the whole window.
* ``bus_off``      — `node` sends nothing in the window (its controller went bus-off).

Sender and sensor faults (issue #9; applied at the source, so every check downstream sees a valid
frame and only plausibility can catch them):

* ``stuck``  — `signal` of `message` is stuck in the sending node's software: at `value` (physical
  units of the DBC signal), or, without `value`, frozen at the last value the node sent before
  `from_s`.  The node runtime applies it to its outputs before encoding (hil.runtime.node), so the E2E CRC
  and the SecOC MAC are computed over the stuck value.
* ``sensor`` — a sensor of car `car` fails in the plant node (hil.runtime.plant_node; plant_sim stays
  fault-free physics): `sensor` = "wheel_speed" (AxleSpeed, rad/s), "pressure" (CylPressure, Pa) or
  "accelerometer" (AccelLong, m/s²); `mode` = "stuck" (the reading frozen at its last value before
  `from_s`, or at `value`) or "bias" (`value`, in the sensor's SI unit, added to the reading, which
  is then quantised to the sensor's resolution again).

Neither draws random numbers; like the others they are counted in the fault log (one event per
frame or reading altered).
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass

from cantools.database.can import Database

from hil.can import e2e
from hil.can.attributes import authentic_length as _authentic_length
from hil.can.attributes import e2e_config as _e2e_config
from hil.can.codec import Codec
from hil.can.dbc import closest
from hil.errors import ScenarioError
from hil.runtime.assembly import node_names
from hil.runtime.lockstep import ROGUE
from hil.runtime.node import StuckSignal
from hil.runtime.plant_node import SensorFault
from hil.scenario.faults import (
    FAULT_KINDS,
    MESSAGE_THREATS,
    SENSOR_SIGNALS,
    SOURCE_FAULTS,
    FaultSpec,
)

__all__ = ["FAULT_KINDS", "MESSAGE_THREATS", "ROGUE", "SENSOR_SIGNALS", "SOURCE_FAULTS", "FaultInjector",
           "FaultLog", "FaultSpec", "build_injector"]

@dataclass
class FaultLog:
    """What the injector did: (time [s], kind, message or node) per injected event."""

    events: list[tuple[float, str, str]]
    counts: dict[str, int]

    def add(self, t_ns: int, kind: str, what: str) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1
        if len(self.events) < 10_000:
            self.events.append((t_ns / 1e9, kind, what))


@dataclass
class _Active:
    spec: FaultSpec
    frame_id: int | None
    node: int | None
    start_ns: int
    end_ns: int
    rng: random.Random
    held: tuple[int, bytes] | None = None     # resequencing: the frame held back


class FaultInjector:
    """Applies the scenario's faults to released frames (see the module docstring)."""

    def __init__(self, specs: list[FaultSpec], frame_ids: dict[str, int], node_index: dict[str, int],
                 seed: int, forge: Callable[[int, bytes, str, float], bytes] | None = None) -> None:
        """`frame_ids`: message name -> id; `node_index`: node name -> index; `forge(frame_id, payload,
        signal, value)` builds a masquerading payload (with a valid E2E trailer where the message has
        one)."""
        self.log = FaultLog([], {})
        self.forge = forge
        self.babble_rng = random.Random(f"{seed}/fault/babble")
        self.active: list[_Active] = []
        self.sources: list[tuple[int, FaultSpec]] = []     # stuck / sensor: applied at the source (attach)
        for i, spec in enumerate(specs):
            if spec.kind in SOURCE_FAULTS:
                self.sources.append((i, spec))
                continue
            fid = frame_ids[spec.message] if spec.message else None
            node = node_index[spec.node] if spec.node else None
            self.active.append(_Active(spec, fid, node, round(spec.from_s * 1e9), round(spec.to_s * 1e9),
                                       random.Random(f"{seed}/fault/{i}/{spec.kind}")))
        self.by_frame: dict[int, list[_Active]] = {}
        self.muted: list[_Active] = []
        self.babblers: list[_Active] = []
        for a in self.active:
            if a.frame_id is not None:
                self.by_frame.setdefault(a.frame_id, []).append(a)
            elif a.spec.kind == "bus_off":
                self.muted.append(a)
            else:
                self.babblers.append(a)

    def on_release(self, t_ns: int, node: int, frame_id: int, data: bytes) -> list[tuple[int, bytes, int]]:
        """The frames (time, payload, sender) that enter the transmit queues for one released frame;
        sender ROGUE is a node of the attacker's own (insertion, masquerade)."""
        return [(t, d, ROGUE if rogue else node) for t, d, rogue in self._release(t_ns, node, frame_id, data)]

    def _release(self, t_ns: int, node: int, frame_id: int, data: bytes) -> list[tuple[int, bytes, bool]]:
        for a in self.muted:
            if a.node == node and a.start_ns <= t_ns < a.end_ns:
                self.log.add(t_ns, "bus_off", a.spec.node)
                return []
        faults = self.by_frame.get(frame_id)
        if not faults:
            return [(t_ns, data, False)]
        out = [(t_ns, data, False)]
        for a in faults:
            if not (a.start_ns <= t_ns < a.end_ns):
                if a.held is not None and t_ns >= a.end_ns:     # window closed: release what was held
                    out.append((t_ns, a.held[1], True))
                    a.held = None
                continue
            if a.spec.kind == "resequencing" and a.held is not None:
                held, a.held = a.held, None
                out = out + [(t_ns, held[1], True)]           # re-sent by the network, after the next one
                self.log.add(t_ns, "resequencing", a.spec.message)
                continue
            if a.rng.random() >= a.spec.probability:
                continue
            out = self._apply(a, t_ns, frame_id, out)
        return out

    def _apply(self, a: _Active, t_ns: int, frame_id: int, out: list[tuple[int, bytes, bool]]) -> list:
        kind, rng = a.spec.kind, a.rng
        delay_ns = round(a.spec.delay_ms * 1e6)
        self.log.add(t_ns, kind, a.spec.message)
        if kind == "deletion":
            return []
        t, d, rogue = out[-1]
        if kind == "repetition":         # a copy the network made: not in the sender's own buffer
            return out + [(t + delay_ns, d, True)]
        if kind == "delay":
            return [(t + delay_ns, d, r) for t, d, r in out]
        if kind == "corruption":
            b = bytearray(d)
            bit = rng.randrange(len(b) * 8)
            b[bit // 8] ^= 1 << (bit % 8)
            return out[:-1] + [(t, bytes(b), rogue)]
        if kind == "insertion":
            b = bytearray(d)
            b[rng.randrange(len(b))] ^= rng.randrange(1, 256)
            return out + [(t, bytes(b), True)]
        if kind == "resequencing":
            a.held = out[-1]
            return out[:-1]
        if kind == "masquerade":
            forged = self.forge(frame_id, d, a.spec.signal, a.spec.value) if self.forge else d
            return out + [(t, forged, True)]
        raise ValueError(f"unknown fault kind {kind!r}")

    def attach(self, nodes: list) -> None:
        """Install the stuck and sensor faults in the nodes that produce the values: a `stuck` one in the
        node that sends its message (`Node.stick`), a `sensor` one in the plant node
        (`PlantController.add_sensor_fault`).  A message no node of the scenario sends cyclically is a
        ScenarioError naming the fault."""
        for i, spec in self.sources:
            start_us, end_us = round(spec.from_s * 1e6), round(spec.to_s * 1e6)
            if spec.kind == "stuck":
                what = f"{spec.message}.{spec.signal}"
                stuck = StuckSignal(spec.signal, start_us, end_us, spec.value,
                                    lambda t_us, what=what: self.log.add(t_us * 1000, "stuck", what))
                if not any(node.stick(spec.message, stuck) for node in nodes):
                    raise ScenarioError(f"scenario key 'faults[{i}].message' = {spec.message!r}: no node of "
                                        f"this scenario sends it cyclically; nodes are "
                                        f"{', '.join(n.name for n in nodes)}")
                continue
            plants = [n.controller for n in nodes if hasattr(n.controller, "add_sensor_fault")]
            if not plants:
                raise ScenarioError(f"scenario key 'faults[{i}]': a sensor fault needs the PLANT node")
            what = f"car{spec.car}.{spec.sensor}"
            plants[0].add_sensor_fault(SensorFault(
                spec.car - 1, SENSOR_SIGNALS[spec.sensor], spec.mode, spec.value, start_us, end_us,
                lambda t_us, what=what: self.log.add(t_us * 1000, "sensor", what)))

    def babble_windows(self) -> list[tuple[int, int, int, int]]:
        """(start ns, end ns, node index, frame id) of each babbling fault."""
        return [(a.start_ns, a.end_ns, a.node, a.spec.frame_id) for a in self.babblers]


def _check_stuck(i: int, f: FaultSpec, msg, e2e_protected: bool, authentic: int) -> None:
    """A stuck signal must be one the sender's software produces, and its value one the signal holds."""
    sig = msg.get_signal_by_name(f.signal)
    protection = (e2e_protected and f.signal in ("CHECKSUM", "COUNTER")) or sig.start >= 8 * authentic
    if protection:
        raise ScenarioError(f"scenario key 'faults[{i}].signal' = {f.signal!r}: written by the E2E/SecOC "
                            f"protection of {msg.name} after the software's values; a stuck fault needs a "
                            f"signal the sender's software produces")
    lo, hi = sig.minimum, sig.maximum
    if f.value is not None and ((lo is not None and f.value < lo) or (hi is not None and f.value > hi)):
        raise ScenarioError(f"scenario key 'faults[{i}].value' = {f.value}: outside the range of "
                            f"{msg.name}.{f.signal}, [{lo}, {hi}] {sig.unit or ''}".rstrip())


def build_injector(scenario, db: Database, codec: Codec,
                   node_names_: list[str] | None = None) -> FaultInjector | None:
    """The scenario's faults, checked against the DBC and the nodes (one ScenarioError line each), for a
    lockstep run (its `injector`); `node_names_`: the run's nodes in their order (default: the scenario's,
    hil.runtime.assembly.node_names).  None: the scenario has no faults."""
    if not scenario.faults:
        return None
    if node_names_ is None:
        node_names_ = node_names(scenario)
    names = [m.name for m in db.messages]
    for i, f in enumerate(scenario.faults):
        if f.message is not None and f.message not in names:
            raise ScenarioError(f"scenario key 'faults[{i}].message' = {f.message!r}: no such message in "
                                f"the DBC (closest: {closest(f.message, names)})")
        if f.node is not None and f.node not in node_names_:
            raise ScenarioError(f"scenario key 'faults[{i}].node' = {f.node!r}: no such node in this "
                                f"scenario; nodes are {', '.join(node_names_)}")
        if f.signal is not None:
            msg = db.get_message_by_name(f.message)
            signals = [sig.name for sig in msg.signals]
            if f.signal not in signals:
                raise ScenarioError(f"scenario key 'faults[{i}].signal' = {f.signal!r}: {f.message} has no "
                                    f"such signal (closest: {closest(f.signal, signals)})")
            if f.kind == "stuck":
                _check_stuck(i, f, msg, _e2e_config(msg) is not None, _authentic_length(msg))
        if f.kind == "sensor" and f.car > scenario.train.cars:
            raise ScenarioError(f"scenario key 'faults[{i}].car' = {f.car}: the train has "
                                f"{scenario.train.cars} car(s), expected 1..{scenario.train.cars}")

    rng = random.Random(f"{scenario.seed}/fault/forge")

    def forge(frame_id: int, payload: bytes, signal: str, value: float) -> bytes:
        """A rogue frame: the legitimate one with `signal` = `value`; where the message is E2E
        protected, the next counter and a correct CRC (anyone can compute E2E); where it is
        authenticated, the next freshness byte and a MAC the attacker must guess (no key)."""
        msg = db.get_message_by_frame_id(frame_id)
        fc = codec[frame_id]
        values = dict(fc.decode(payload))
        values[signal] = value
        data = fc.encode(values)
        authentic = _authentic_length(msg)
        body, trailer = data[:authentic], data[authentic:]
        cfg = _e2e_config(msg)
        if cfg is not None:
            counter = int(values.get("COUNTER", 0))
            modulo = 15 if isinstance(cfg, e2e.P01Config) else 16
            body = e2e.protect(cfg, e2e.ProtectState((counter + 1) % modulo), body)
        if trailer:
            trailer = bytes(((payload[authentic] + 1) & 0xFF,)) + rng.randbytes(len(trailer) - 1)
        return body + trailer

    return FaultInjector(list(scenario.faults), {m.name: m.frame_id for m in db.messages},
                         {n: k for k, n in enumerate(node_names_)}, scenario.seed, forge)
