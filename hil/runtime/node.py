"""The node runtime: binds a controller (or the plant) to DBC messages.

Received frames are decoded into a latest-value table with reception times (`RxTable`); each cycle
the node calls `controller.step(now_us, rx)` and encodes the frames that are due at their DBC cycle
time.  Frames the DBC marks for E2E protection (message attributes `E2EProfile` = P01/P02 and
`E2EDataID`, see hil.can.attributes) are protected by the sender (counter and CRC, hil.can.e2e) and checked by
every receiver: a frame whose status is not usable (ERROR, REPEATED, WRONGSEQUENCE, INITIAL) does
not reach the controller, and the status of each protected message is counted and given to the
controller each cycle (`RxTable.e2e`).  The same Node runs in lockstep (driven by the
discrete-event runner) and in real time (driven by a process loop on a python-can bus): only the
clock and the bus differ.

One receive path.  Every frame reaches a node through `Node.receive(frame_id, data, t_us)`: the lockstep
bus, a real-time host, a gateway's sides and an FMU node alike.  It counts the frame, checks it (SecOC,
then E2E), decodes the signals the node reads straight into its table, and then tells the node's
`receive_watch` (a `ReceiveWatch`, set before the run; hil.safety.threat_matrix watches with it what the
receivers accepted), if it has one.

Signal names.  A controller declares `inputs` and `outputs`.  A name is either a bare DBC signal name
(`AxleSpeed`), resolved among the messages the binding lists for the node, or a qualified
`MESSAGE.Signal`.  Every name is checked against the DBC when the node is built; an unknown one is a
BindingError naming it and the closest DBC names.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, SupportsFloat, SupportsIndex

from cantools.database.can import Database, Message
from mypy_extensions import mypyc_attr

from firmware_py.rx import RxTable
from hil.can import e2e, secoc
from hil.can.attributes import E2E_COUNTER, e2e_config, multiplexer_pages, secoc_data_id
from hil.can.codec import Codec, FrameCodec, FrameError
from hil.can.dbc import closest
from hil.errors import BindingError

NEVER_US = 1 << 62               # µs: a frame that is never due on the schedule
E2E_COUNTER_MODULO = 15          # AUTOSAR E2E profile 1 alive counter runs 0..14
MAX_E2E_EVENTS = 10_000          # NodeStats.e2e_events keeps the first this many

#: a receiving node's decoder of one message into its table (FrameCodec.storer): (data, values, times, t_us)
Store = Callable[[bytes, dict[str, float], dict[str, int], int], None]


class Controller(Protocol):
    """What a node runs each cycle: a firmware_py controller, the plant, a study's or a device's model.
    `step` returns the output signals by name (a mapping of numbers); anything else is a bug the node
    counts (NodeStats.step_errors) and answers with its safe values."""

    def step(self, now_us: int, rx: RxTable) -> object: ...


class ReceiveWatch(Protocol):
    """An observer of what a node takes (`Node.receive_watch`, set before a run): `accepted` is called for
    each frame whose checks passed and whose signals entered the node's table, after they did."""

    def accepted(self, node: Node, frame_id: int, data: bytes, t_us: int) -> None: ...


@dataclass
class StuckSignal:
    """A signal stuck in the sending node's software (hil.safety.injection `stuck`): in [start_us, end_us)
    every
    frame the node sends carries `value` [DBC physical unit], or, when `value` is None, the last value
    it sent before start_us.  Applied to the frame's values before encoding, so the E2E CRC and the
    SecOC MAC are computed over it (the frame is valid on the bus)."""

    signal: str                     # DBC signal name in the frame
    start_us: int
    end_us: int
    value: float | None
    on_apply: Callable[[int], None] | None = None   # called with the node time [µs] per frame altered
    last: float | None = None       # the value sent last before start_us

    def apply(self, values: dict[str, float], now_us: int) -> None:
        if now_us < self.start_us:
            self.last = values.get(self.signal, 0.0)
            return
        if now_us >= self.end_us:
            return
        if self.value is not None:
            values[self.signal] = self.value
        else:
            if self.last is None:                 # nothing sent before: frozen from now on
                self.last = values.get(self.signal, 0.0)
            values[self.signal] = self.last
        if self.on_apply is not None:
            self.on_apply(now_us)


@dataclass
class TxFrame:
    codec: FrameCodec
    cycle_us: int
    fields: list[tuple[str, str]]          # (DBC signal, controller output key)
    counter: bool                          # the runtime fills the E2E alive counter
    # encode(outputs, count): the codec's encode of {signal: outputs.get(key, 0.0) for fields} and the
    # counter, reading the outputs directly (FrameCodec.encoder)
    encode: Callable[[Mapping[str, float], int], bytes]
    next_due_us: int = 0
    count: int = 0
    protection: e2e.Config | None = None   # E2E
    protect_state: e2e.ProtectState = field(default_factory=e2e.ProtectState)
    secoc: secoc.SecOcSender | None = None
    authentic: int = 8                     # bytes before the SecOC trailer
    stuck: list[StuckSignal] = field(default_factory=list)   # injected sender faults (hil.safety.injection)
    # a multiplexed message whose multiplexer no output sets: (multiplexer signal, its values), one page a
    # frame in turn (multiplexer_pages)
    mux: tuple[str, tuple[int, ...]] | None = None


#: the key every authenticated message uses unless the scenario gives one ([secoc]): a test-bench
#: development key, public by design (AES-128, 16 bytes)
DEV_SECOC_KEY = bytes.fromhex("2b7e151628aed2a6abf7158809cf4f3c")


def msg_name_of(db: Database, frame_id: int) -> str:
    name: str = db.get_message_by_frame_id(frame_id).name
    return name


@dataclass
class RxCheck:
    """Receiver side of one E2E-protected message."""

    name: str
    config: e2e.Config
    state: e2e.CheckState
    cycle_us: int              # the message's DBC cycle time: one check per cycle of the message
    last_us: int = 0           # time of the last check (a frame, or a cycle without one)
    grace_us: int = field(init=False)   # a cycle without a frame is checked once now - last_us reaches
    #                                     1.5 cycles: ceil(1.5 cycle_us) [µs]

    def __post_init__(self) -> None:
        self.grace_us = (3 * self.cycle_us + 1) // 2


@dataclass
class RxRoute:
    """How a node takes the frames of one identifier it receives: their checks, then their signals."""

    name: str                                  # the message
    length: int                                # its length [bytes]: a shorter frame is malformed
    store: Store                               # the signals the node reads, decoded into its table
    verifier: secoc.SecOcReceiver | None       # SecOC, for an authenticated message
    check: RxCheck | None                      # E2E, for a protected one


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
        names: dict[str, Message] = {m.name: m for m in db.messages}
        every_signal = sorted({s.name for m in db.messages for s in m.signals}
                              | {f"{m.name}.{s.name}" for m in db.messages for s in m.signals})

        def message(name: str, role: str, user: str) -> Message:
            if name not in names:
                raise BindingError(f"node {node}: {role} {user!r}: no message {name!r} in {dbc_name}; "
                                   f"closest: {closest(name, list(names))}")
            return names[name]

        rx_msgs = [message(n, "receives", n) for n in rx_messages]
        tx_msgs = [message(n, "sends", n) for n in tx_messages]

        def resolve(key: str, role: str, pool: list[Message]) -> list[tuple[Message, str]]:
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
        input_keys = tuple(inputs)
        for key in input_keys:
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
        return cls(node=node, rx=rx, tx=list(tx_fields.items()), inputs=input_keys)


@dataclass
class NodeStats:
    cycles: int = 0
    frames_sent: int = 0
    frames_received: int = 0
    bad_frames: int = 0            # received frames that did not decode (wrong length, bad mux)
    bad_outputs: int = 0           # non-finite or non-numeric controller outputs replaced by the safe value
    clamped_outputs: int = 0       # outputs outside their DBC range, sent saturated to it
    unknown_frames: int = 0        # received frames whose identifier the DBC does not define (ignored)
    e2e_discarded: int = 0         # protected frames not given to the controller (status not usable)
    e2e_status: dict[str, int] | None = None   # E2E status -> count (frames and cycles without a frame)
    # (t_us, message, status): every E2E status but OK and every SecOC rejection (SECOC_MAC_MISMATCH,
    # SECOC_STALE_FRESHNESS, ...), the first MAX_E2E_EVENTS
    e2e_events: list[tuple[int, str, str]] | None = None
    secoc_rejected: dict[str, int] | None = None   # authenticated frames dropped: reason -> count
    step_errors: int = 0           # exceptions inside step(), caught: the node sends safe values
    last_error: str = ""
    # a study's own figures of the node by name (the ACD's GPS line: hil/studies/anticollision/nodes.py),
    # reported with the counters
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """The counters by name, then the `extra` figures, for a run's outcome (RunOutcome.node_stats,
        run.json): a new dict, whose e2e_status, e2e_events and secoc_rejected are the stats' own."""
        return {"cycles": self.cycles, "frames_sent": self.frames_sent,
                "frames_received": self.frames_received, "bad_frames": self.bad_frames,
                "bad_outputs": self.bad_outputs,
                "clamped_outputs": self.clamped_outputs, "unknown_frames": self.unknown_frames,
                "e2e_discarded": self.e2e_discarded, "e2e_status": self.e2e_status,
                "e2e_events": self.e2e_events, "secoc_rejected": self.secoc_rejected,
                "step_errors": self.step_errors, "last_error": self.last_error, **self.extra}


def finite_number(value: object) -> int | float | None:
    """A controller's output as a node sends it: an int as an int (a bool as 0 or 1), another number as a
    float; None when it is NaN, infinite or no number at all."""
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (SupportsFloat, SupportsIndex)):   # numpy's scalars, Fraction, Decimal
        try:
            number = float(value)
        except (ValueError, OverflowError):         # a signalling NaN; a number no float holds
            return None
        return number if math.isfinite(number) else None
    return None


@mypyc_attr(allow_interpreted_subclasses=True)   # hil.devices.gateway.GatewaySide is a Node
class Node:
    """A controller bound to the DBC: `receive()` frames, `cycle(now_us)` returns frames to send."""

    name: str
    binding: Binding
    controller: Controller
    codec: Codec
    period_us: int
    offset_us: int
    rx: RxTable
    safe: dict[str, float]
    outputs: dict[str, float]
    tx: list[TxFrame]
    stats: NodeStats
    receive_watch: ReceiveWatch | None

    def __init__(self, name: str, controller: Controller, binding: Binding, codec: Codec, db: Database,
                 period_us: int, offset_us: int = 0, safe_outputs: Mapping[str, float] | None = None,
                 protection: Callable[[Message], e2e.Config | None] = e2e_config,
                 routed: Iterable[str] = ()) -> None:
        """`protection(message)`: the E2E configuration of a message (default: the DBC's E2EProfile
        attributes; a device's own DBC: hil.devices); `routed`: messages sent only when `send_now` is
        called (a gateway's, at once on the frame they translate), not on the cyclic schedule."""
        self.name = name
        self.binding = binding
        self.controller = controller
        self.codec = codec
        self.period_us = period_us
        self.offset_us = offset_us
        self.rx = RxTable(binding.inputs)
        self.safe = dict(safe_outputs or {})
        self.outputs = {}
        self.receive_watch = None
        self.tx = []
        routed_names = frozenset(routed)
        for msg_name, fields in binding.tx:
            msg = db.get_message_by_name(msg_name)
            cycle_us = int(msg.cycle_time or 0) * 1000
            if cycle_us <= 0 and msg_name not in routed_names:
                continue                  # event frames are not sent cyclically by v1 nodes
            config = protection(msg)
            has_counter = config is None and any(s.name == E2E_COUNTER for s in msg.signals) and \
                all(sig != E2E_COUNTER for sig, _ in fields)
            fc = codec.by_name(msg_name)
            self.tx.append(TxFrame(fc, cycle_us, fields, has_counter,
                                   fc.encoder(fields, E2E_COUNTER if has_counter else None),
                                   next_due_us=NEVER_US if msg_name in routed_names else offset_us,
                                   protection=config, mux=multiplexer_pages(msg, fields)))
        self._tx_by_name = {tx.codec.name: tx for tx in self.tx}
        self._checks: dict[int, RxCheck] = {}
        for fid in binding.rx:
            msg = db.get_message_by_frame_id(fid)
            config = protection(msg)
            if config is not None:
                cycle_us = int(msg.cycle_time or 0) * 1000 or period_us
                self._checks[fid] = RxCheck(msg.name, config, e2e.CheckState(), cycle_us, offset_us)
        self._e2e_counts: dict[str, int] = {}          # NodeStats.e2e_status, when the node checks E2E
        self._e2e_events: list[tuple[int, str, str]] = []
        self._secoc_counts: dict[str, int] = {}        # NodeStats.secoc_rejected, when it verifies SecOC
        self.stats = NodeStats(e2e_status=self._e2e_counts if self._checks else None,
                               e2e_events=self._e2e_events)
        # frame id -> its checks and decoder (use_keys): one lookup per frame
        self._routes: dict[int, RxRoute] = {}
        # a lower bound of the earliest time a cycle without a frame is due to an E2E check (so that
        # cycle() skips the checks until then; a 1 ms plant cycle would otherwise look at six of them)
        self._e2e_due_us = min((c.last_us + c.grace_us for c in self._checks.values()), default=NEVER_US)
        self._db = db
        self._next_due_us = NEVER_US
        self.use_keys({})

    def use_keys(self, keys: Mapping[str, bytes], window: int = secoc.DEFAULT_WINDOW) -> None:
        """SecOC keys by message name ("*": every other message; default DEV_SECOC_KEY) for the
        authenticated messages this node sends and receives; freshness counters start at 0."""
        default = keys.get("*", DEV_SECOC_KEY)
        for tx in self.tx:
            data_id = secoc_data_id(tx.codec.message)
            if data_id is not None:
                tx.secoc = secoc.SecOcSender(keys.get(tx.codec.name, default), data_id)
                tx.authentic = tx.codec.message.length - secoc.AUTH_BYTES
        self._routes = {}
        for fid, pairs in self.binding.rx.items():
            msg = self._db.get_message_by_frame_id(fid)
            data_id = secoc_data_id(msg)
            verifier = (None if data_id is None
                        else secoc.SecOcReceiver(keys.get(msg.name, default), data_id, window))
            if verifier is not None:
                self.stats.secoc_rejected = self._secoc_counts
            fc = self.codec[fid]
            self._routes[fid] = RxRoute(msg.name, fc.length, fc.storer(pairs), verifier,
                                        self._checks.get(fid))
        self._next_due_us = min((tx.next_due_us for tx in self.tx), default=NEVER_US)

    def stick(self, message: str, stuck: StuckSignal) -> bool:
        """Make a signal of a frame this node sends cyclically stuck (hil.safety.injection); False: the node
        does
        not send `message`."""
        for tx in self.tx:
            if tx.codec.name == message:
                tx.stuck.append(stuck)
                return True
        return False

    def send_now(self, message: str, now_us: int) -> tuple[FrameCodec, bytes]:
        """One frame of `message` (a routed one: see __init__) from the current outputs, protected and
        counted as a cyclic frame is: (codec, payload)."""
        tx = self._tx_by_name[message]
        data = self._frame(tx, self.outputs, now_us)
        tx.count += 1
        self.stats.frames_sent += 1
        return tx.codec, data

    @property
    def next_frame_due_us(self) -> int:
        """The slot [µs, the node's own schedule] at which its next cyclic frame is due."""
        return self._next_due_us

    @property
    def rx_ids(self) -> frozenset[int]:
        return frozenset(self.binding.rx)

    def receive(self, frame_id: int, data: bytes, t_us: int) -> None:
        """A frame received at `t_us` [µs, the node's clock], as it was on the bus: counted, checked (SecOC,
        then E2E) and, when usable, the signals this node reads decoded into its table; then the
        `receive_watch` is told.  A frame of an identifier the node does not read is ignored (counted when
        the DBC does not define it); a malformed one (shorter than its message, an undefined multiplexer
        value) is counted, not raised."""
        route = self._routes.get(frame_id)
        if route is None:
            if frame_id not in self.codec:     # not a frame of this bus at all: counted, ignored
                self.stats.unknown_frames += 1
            return
        if len(data) < route.length:           # short or malformed frame on a real bus: counted, not raised
            self.stats.bad_frames += 1
            return
        if not self._passes(route, data, t_us):
            return
        try:
            self.rx.take(route.store, data, t_us)
        except FrameError:                      # a multiplexer value the DBC does not define
            self.stats.bad_frames += 1
            return
        if self.receive_watch is not None:
            self.receive_watch.accepted(self, frame_id, data, t_us)

    def _passes(self, route: RxRoute, data: bytes, t_us: int) -> bool:
        """A received frame's SecOC and E2E checks, counted: may its signals be used?"""
        stats = self.stats
        stats.frames_received += 1
        verifier = route.verifier
        if verifier is not None:                 # authentication first: a forged frame is dropped
            verdict = verifier.verify(data)
            if verdict.payload is None:          # not accepted (the authentic payload comes only with that)
                reason = verdict.reason
                self._secoc_counts[reason.value] = self._secoc_counts.get(reason.value, 0) + 1
                if len(self._e2e_events) < MAX_E2E_EVENTS:
                    self._e2e_events.append((t_us, route.name, "SECOC_" + reason.name))
                return False
            data = verdict.payload
        chk = route.check
        if chk is not None:
            chk.state, status = e2e.check(chk.config, chk.state, data)
            chk.last_us = t_us
            if t_us + chk.grace_us < self._e2e_due_us:
                self._e2e_due_us = t_us + chk.grace_us
            self._count_e2e(chk, status, t_us)
            if not status.usable:
                stats.e2e_discarded += 1
                return False
        return True

    def _count_e2e(self, chk: RxCheck, status: e2e.Status, t_us: int) -> None:
        self.rx.e2e[chk.name] = status
        value = status.value
        self._e2e_counts[value] = self._e2e_counts.get(value, 0) + 1
        if status is not e2e.Status.OK and len(self._e2e_events) < MAX_E2E_EVENTS:
            self._e2e_events.append((t_us, chk.name, value))

    def _check_missing(self, now_us: int) -> None:
        """E2E: each message cycle without a frame is NONEWDATA (checked once 1.5 cycles have passed)."""
        due_us = NEVER_US
        for chk in self._checks.values():
            if now_us >= chk.last_us + chk.grace_us:       # 2 (now - last) >= 3 cycle, in integers
                chk.state, status = e2e.check(chk.config, chk.state, None)
                chk.last_us += chk.cycle_us
                self._count_e2e(chk, status, now_us)
            due_us = min(due_us, chk.last_us + chk.grace_us)
        self._e2e_due_us = due_us

    def cycle(self, now_us: int, nominal_us: int | None = None) -> list[tuple[FrameCodec, bytes]]:
        """Run one controller step at `now_us` and return the frames due as (codec, payload).

        Which frames are due is decided on `nominal_us`, the cycle's place on the node's own
        schedule (default `now_us`): a cycle released early or late by jitter still sends the
        frames of its slot."""
        stats = self.stats
        stats.cycles += 1
        if now_us >= self._e2e_due_us:
            self._check_missing(now_us)
        try:
            result = self.controller.step(now_us, self.rx)
        except Exception as exc:  # a controller bug must not take the bus down: send safe values
            stats.step_errors += 1
            stats.last_error = f"{type(exc).__name__}: {exc}"
            result = self.safe
        if not isinstance(result, Mapping):     # no outputs: a bug too
            stats.step_errors += 1
            stats.last_error = f"step() returned {type(result).__name__}, expected a dict of output signals"
            result = self.safe
        self._take_outputs(result)
        slot_us = now_us if nominal_us is None else nominal_us
        if slot_us < self._next_due_us:         # the plant steps at 1 ms, its frames are due every 10
            return []
        frames = []
        next_due_us = NEVER_US
        for tx in self.tx:
            if slot_us >= tx.next_due_us:
                frames.append((tx.codec, self._frame(tx, self.outputs, now_us)))
                tx.count += 1
                tx.next_due_us += tx.cycle_us
                if tx.next_due_us <= slot_us:         # overrun: skip missed slots, keep the phase
                    missed = (slot_us - tx.next_due_us) // tx.cycle_us + 1
                    tx.next_due_us += missed * tx.cycle_us
            if tx.next_due_us < next_due_us:
                next_due_us = tx.next_due_us
        stats.frames_sent += len(frames)
        self._next_due_us = next_due_us
        return frames

    def _take_outputs(self, result: Mapping[Any, Any]) -> None:
        """The controller's outputs (a step's result as it came: nothing about them checked yet) into
        `outputs` (finite_number); one that is NaN, infinite or no number is counted and replaced by the
        node's safe value (0.0 where it has none)."""
        outputs = self.outputs
        for key, value in result.items():
            number = finite_number(value)
            if number is None:
                self.stats.bad_outputs += 1
                number = self.safe.get(key, 0.0)
            outputs[key] = number

    def _frame(self, tx: TxFrame, outputs: Mapping[str, float], now_us: int) -> bytes:
        """The payload of one due frame: the outputs encoded, then E2E-protected and secured."""
        codec = tx.codec
        clamped = codec.clamped
        if tx.stuck or tx.mux is not None:       # values changed before they are encoded (a stuck signal,
            values = {sig: outputs.get(key, 0.0) for sig, key in tx.fields}   # a multiplexed one's page)
            if tx.counter:
                values[E2E_COUNTER] = tx.count % E2E_COUNTER_MODULO
            if tx.mux is not None:
                mux, pages = tx.mux
                values[mux] = pages[tx.count % len(pages)]
            for stuck in tx.stuck:
                stuck.apply(values, now_us)
            data = codec.encode(values)
        else:
            data = tx.encode(outputs, tx.count % E2E_COUNTER_MODULO)
        if codec.clamped != clamped:             # the codec saturated an out-of-range value
            self.stats.clamped_outputs += codec.clamped - clamped
        if tx.secoc is not None:
            data = data[:tx.authentic]
        if tx.protection is not None:
            data = e2e.protect(tx.protection, tx.protect_state, data)
        if tx.secoc is not None:
            data = tx.secoc.secure(data)
        return data
