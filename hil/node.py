"""The node runtime: binds a controller (or the plant) to DBC messages.

Received frames are decoded into a latest-value table with reception times (`RxTable`); each cycle
the node calls `controller.step(now_us, rx)` and encodes the frames that are due at their DBC cycle
time.  The same Node runs in lockstep (driven by the discrete-event runner) and in real time (driven
by a process loop on a python-can bus): only the clock and the bus differ.

Signal names.  A controller declares `inputs` and `outputs`.  A name is either a bare DBC signal name
(`AxleSpeed`), resolved among the messages the binding lists for the node, or a qualified
`MESSAGE.Signal`.  Every name is checked against the DBC when the node is built; an unknown one is a
BindingError naming it and the closest DBC names.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass

from cantools.database.can import Database

from hil.codec import Codec, FrameCodec, FrameError
from hil.dbc import closest
from hil.errors import BindingError

NAN = float("nan")
E2E_COUNTER = "COUNTER"
E2E_COUNTER_MODULO = 15          # AUTOSAR E2E profile 1 alive counter runs 0..14


class RxTable(Mapping[str, float]):
    """Latest value of each input signal, NaN until first received, with its reception time."""

    def __init__(self, names: Iterable[str]) -> None:
        self._values: dict[str, float] = {n: NAN for n in names}
        self._times: dict[str, int] = {}
        self.version = 0            # bumps on every update: lets a node cache derived arrays

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def age_us(self, name: str, now_us: int) -> int | None:
        t = self._times.get(name)
        return None if t is None else now_us - t

    def update(self, pairs: Sequence[tuple[str, str]], values: Mapping[str, float], t_us: int) -> None:
        store, times = self._values, self._times
        for signal, key in pairs:
            store[key] = values[signal]
            times[key] = t_us
        self.version += 1


@dataclass
class TxFrame:
    codec: FrameCodec
    cycle_us: int
    fields: list[tuple[str, str]]          # (DBC signal, controller output key)
    counter: bool                          # the runtime fills the E2E alive counter
    next_due_us: int = 0
    count: int = 0


@dataclass
class Binding:
    """Which frames a node receives (and into which rx keys) and which it sends (from which outputs)."""

    node: str
    rx: dict[int, list[tuple[str, str]]]   # frame id -> [(DBC signal, rx key)]
    tx: list[tuple[str, list[tuple[str, str]]]]   # [(message name, [(DBC signal, output key)])]
    inputs: tuple[str, ...]

    @classmethod
    def build(cls, db: Database, node: str, inputs: Iterable[str], outputs: Iterable[str],
              rx_messages: Iterable[str], tx_messages: Iterable[str], dbc_name: str = "DBC") -> Binding:
        names = {m.name: m for m in db.messages}
        every_signal = sorted({s.name for m in db.messages for s in m.signals}
                              | {f"{m.name}.{s.name}" for m in db.messages for s in m.signals})

        def message(name: str, role: str, user: str):
            if name not in names:
                raise BindingError(f"node {node}: {role} {user!r}: no message {name!r} in {dbc_name}; "
                                   f"closest: {closest(name, list(names))}")
            return names[name]

        rx_msgs = [message(n, "receives", n) for n in rx_messages]
        tx_msgs = [message(n, "sends", n) for n in tx_messages]

        def resolve(key: str, role: str, pool) -> list[tuple[object, str]]:
            if "." in key:
                msg_name, sig = key.split(".", 1)
                msg = message(msg_name, role, key)
                if not any(s.name == sig for s in msg.signals):
                    raise BindingError(f"node {node}: {role} signal {key!r}: message {msg_name} of "
                                       f"{dbc_name} has no signal {sig!r}; closest: "
                                       f"{closest(sig, [s.name for s in msg.signals])}")
                hits = [(msg, sig)]
            else:
                hits = [(m, key) for m in pool if any(s.name == key for s in m.signals)]
            if not hits:
                where = ", ".join(m.name for m in pool) or "(no messages)"
                raise BindingError(f"node {node}: {role} signal {key!r} is not in {where} of {dbc_name}; "
                                   f"closest: {closest(key, every_signal)}")
            return hits

        rx: dict[int, list[tuple[str, str]]] = {}
        inputs = tuple(inputs)
        for key in inputs:
            hits = resolve(key, "input", rx_msgs)
            if len(hits) > 1:
                raise BindingError(f"node {node}: input {key!r} is in several messages "
                                   f"({', '.join(m.name for m, _ in hits)}); qualify it as MESSAGE.{key}")
            msg, sig = hits[0]
            rx.setdefault(msg.frame_id, []).append((sig, key))

        tx_fields: dict[str, list[tuple[str, str]]] = {m.name: [] for m in tx_msgs}
        for key in outputs:
            for msg, sig in resolve(key, "output", tx_msgs):
                if msg.name not in tx_fields:
                    raise BindingError(f"node {node}: output {key!r} goes to {msg.name}, "
                                       f"which the node does not send")
                tx_fields[msg.name].append((sig, key))
        return cls(node=node, rx=rx, tx=list(tx_fields.items()), inputs=inputs)


@dataclass
class NodeStats:
    cycles: int = 0
    frames_sent: int = 0
    frames_received: int = 0
    bad_frames: int = 0            # received frames that did not decode (wrong length, bad mux)
    bad_outputs: int = 0           # non-finite controller outputs replaced by the safe value
    step_errors: int = 0           # exceptions inside step(), caught: the node sends safe values
    last_error: str = ""


class Node:
    """A controller bound to the DBC: `receive()` frames, `cycle(now_us)` returns frames to send."""

    def __init__(self, name: str, controller, binding: Binding, codec: Codec, db: Database,
                 period_us: int, offset_us: int = 0, safe_outputs: Mapping[str, float] | None = None) -> None:
        self.name = name
        self.controller = controller
        self.codec = codec
        self.period_us = period_us
        self.offset_us = offset_us
        self.rx = RxTable(binding.inputs)
        self._rx_map = binding.rx
        self._rx_codecs = {fid: codec[fid] for fid in binding.rx}
        self.safe = dict(safe_outputs or {})
        self.outputs: dict[str, float] = {}
        self.tx: list[TxFrame] = []
        for msg_name, fields in binding.tx:
            msg = db.get_message_by_name(msg_name)
            cycle_us = int(msg.cycle_time or 0) * 1000
            if cycle_us <= 0:
                continue                  # event frames are not sent cyclically by v1 nodes
            has_counter = any(s.name == E2E_COUNTER for s in msg.signals) and \
                all(sig != E2E_COUNTER for sig, _ in fields)
            self.tx.append(TxFrame(codec.by_name(msg_name), cycle_us, fields, has_counter,
                                   next_due_us=offset_us))
        self.stats = NodeStats()
        self._next_due_us = min((tx.next_due_us for tx in self.tx), default=1 << 62)

    @property
    def rx_ids(self) -> frozenset[int]:
        return frozenset(self._rx_map)

    def receive(self, frame_id: int, data: bytes, t_us: int) -> None:
        fc = self._rx_codecs.get(frame_id)
        if fc is None:
            return
        try:
            values = fc.decode(data)
        except FrameError:           # short or malformed frame on a real bus: counted, not raised
            self.stats.bad_frames += 1
            return
        self.receive_values(frame_id, values, t_us)

    def receive_values(self, frame_id: int, values: Mapping[str, float], t_us: int) -> None:
        pairs = self._rx_map.get(frame_id)
        if pairs is not None:
            self.rx.update(pairs, values, t_us)
            self.stats.frames_received += 1

    def cycle(self, now_us: int, nominal_us: int | None = None) -> list[tuple[FrameCodec, bytes]]:
        """Run one controller step at `now_us` and return the frames due as (codec, payload).

        Which frames are due is decided on `nominal_us`, the cycle's place on the node's own
        schedule (default `now_us`): a cycle released early or late by jitter still sends the
        frames of its slot."""
        stats = self.stats
        stats.cycles += 1
        try:
            result = self.controller.step(now_us, self.rx)
        except Exception as exc:  # a controller bug must not take the bus down: send safe values
            stats.step_errors += 1
            stats.last_error = f"{type(exc).__name__}: {exc}"
            result = dict(self.safe)
        outputs = self.outputs
        for key, value in result.items():
            if value.__class__ is not int and not math.isfinite(value):
                stats.bad_outputs += 1
                value = self.safe.get(key, 0.0)
            outputs[key] = value
        frames = []
        slot_us = now_us if nominal_us is None else nominal_us
        if slot_us < self._next_due_us:         # the plant steps at 1 ms, its frames are due every 10
            return frames
        for tx in self.tx:
            if slot_us < tx.next_due_us:
                continue
            values = {sig: outputs.get(key, 0.0) for sig, key in tx.fields}
            if tx.counter:
                values[E2E_COUNTER] = tx.count % E2E_COUNTER_MODULO
            frames.append((tx.codec, tx.codec.encode(values)))
            tx.count += 1
            tx.next_due_us += tx.cycle_us
            if tx.next_due_us <= slot_us:         # overrun: skip missed slots, keep the phase
                missed = (slot_us - tx.next_due_us) // tx.cycle_us + 1
                tx.next_due_us += missed * tx.cycle_us
        stats.frames_sent += len(frames)
        self._next_due_us = min(tx.next_due_us for tx in self.tx)
        return frames
