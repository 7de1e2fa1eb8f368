"""Which received signals reach an actuator or a set-point, derived from the node bindings by experiment.

A signal that changes what an actuator does must not be forgeable: its frame needs E2E protection and
SecOC authentication (issue #19).  Which signals those are is not declared anywhere by hand; it is
measured on a lockstep run of the scenario:

1. Every node's controller is run once through the scenario, and each of its cycles is recorded: the
   receive table it was given (values and reception times) and the outputs it returned.
2. Per node, each input the binding feeds it from a frame is perturbed: the recording is replayed
   into a fresh controller with that input forced, at every cycle and fresh, to each of a few values
   the DBC signal can carry (its minimum, its maximum, a value in between, every choice of an
   enumeration).  The outputs that differ from the unperturbed replay are the ones the input
   influences.  A replay without perturbation must give back the recorded outputs exactly, else the
   node cannot be analysed and says so.
3. The actuating signals are found by a fixed point from the actuators: every signal the PLANT
   receives drives an actuator (valve, dump valve, force, slip reference); a signal received by
   another node is actuating when it influences an output that goes out in an actuating signal.

Frames the PLANT sends are the exception: they stand for the train's own sensors and the world outside
its brake bus (wheel-speed, pressure and acceleration transducers wired to the ECU, the radio, the GNSS
feed, balises), which a real train does not receive over this bus; they are reported with
`source = "plant"` and not required to be protected.

`unprotected(links, db)` lists the actuating signals whose frame lacks E2E or SecOC: the protection
test (tests/safety/test_protection.py) requires it empty for every scenario family.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from cantools.database.can import Database

from firmware_py.rx import RxTable
from hil.can.attributes import e2e_config, secoc_data_id
from hil.can.codec import Codec, loaded_dbc
from hil.runtime.assembly import build_node
from hil.runtime.lockstep import prepare_lockstep, run_lockstep
from hil.safety.injection import build_injector

__all__ = ["Link", "actuating_links", "influence", "record_run", "unprotected"]

PLANT = "PLANT"
TOLERANCE = 1e-9          # outputs closer than this are equal (they are recomputed bit for bit anyway)


@dataclass
class Recording:
    """One node's cycles: (now_us, receive table as given) and the outputs it returned."""

    name: str
    rx_cycles: list[tuple[int, RxTable]] = field(default_factory=list)
    outputs: list[dict[str, float]] = field(default_factory=list)


class _Recorder:
    """Stands in for a node's controller: passes every call through and records each cycle."""

    def __init__(self, controller, recording: Recording) -> None:
        self._controller = controller
        self._recording = recording

    def step(self, now_us: int, rx: RxTable):
        out = self._controller.step(now_us, rx)
        self._recording.rx_cycles.append((now_us, rx.copy()))   # as the controller saw it
        self._recording.outputs.append(dict(out))
        return out

    def __getattr__(self, name: str):
        return getattr(self._controller, name)




@dataclass(frozen=True)
class Link:
    """A received signal that reaches an actuator: `message.signal` into `node` (input `key`), which
    changes the node's `outputs`; `frame_protected` = E2E and SecOC on its frame."""

    message: str
    signal: str
    node: str
    key: str
    outputs: tuple[str, ...]
    sender: str
    frame_protected: bool

    @property
    def source(self) -> str:
        return "plant" if self.sender == PLANT else "bus"


def record_run(scenario, db: Database | None = None) -> tuple[dict[str, Recording], dict]:
    """Run `scenario` in lockstep (no trace) with every node recorded; returns the recordings and the
    nodes' bindings: name -> (rx {frame id: [(signal, key)]}, tx [(message, [(signal, key)])])."""

    db, codec = (loaded_dbc(scenario.dbc) if db is None else (db, Codec(db)))
    setup = prepare_lockstep(scenario, db, codec, injector=build_injector(scenario, db, codec))
    recordings: dict[str, Recording] = {}
    bindings: dict[str, tuple] = {}
    for node in setup.nodes:
        bindings[node.name] = (dict(node.binding.rx), [(tx.codec.name, list(tx.fields)) for tx in node.tx])
        if node.name != PLANT:
            recordings[node.name] = rec = Recording(node.name)
            node.controller = _Recorder(node.controller, rec)
    run_lockstep(scenario, db, codec, writer=None, setup=setup)
    return recordings, bindings


def _values_to_try(db: Database, message: str, signal: str) -> list[float]:
    sig = db.get_message_by_name(message).get_signal_by_name(signal)
    if sig.choices:
        return sorted(float(k) for k in sig.choices)
    lo = sig.minimum if sig.minimum is not None else sig.offset
    hi = sig.maximum if sig.maximum is not None else sig.offset + sig.scale * (2 ** sig.length - 1)
    if sig.length == 1:
        return [0.0, 1.0]
    return [float(lo), float(lo + 0.37 * (hi - lo)), float(hi)]


def _replay(build, recording: Recording, key: str | None, value: float) -> Iterator[dict[str, float]]:
    """The outputs of a fresh controller fed the recording, cycle by cycle, with `key` forced to `value`
    (None: as recorded)."""
    ctrl = build()
    for now_us, snap in recording.rx_cycles:
        rx = snap.copy()
        if key is None:
            rx.version += 1
        else:
            rx.receive({key: value}, now_us)      # bumps the version as well
        yield dict(ctrl.step(now_us, rx))


def _differs(a: float, b: float) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return False
    try:
        return abs(float(a) - float(b)) > TOLERANCE
    except (TypeError, ValueError):
        return a != b


def influence(scenario, db: Database, recordings: dict[str, Recording], bindings: dict,
              nodes: Iterable[str] | None = None) -> dict[str, dict[str, set[str]]]:
    """Per node, per input key fed from a frame: the output keys it sends on the bus that perturbing the
    input changes."""

    codec = Codec(db)
    result: dict[str, dict[str, set[str]]] = {}
    for name in nodes if nodes is not None else recordings:
        rec = recordings[name]
        def build(name=name):
            return build_node(name, scenario, db, codec).controller
        nominal = list(_replay(build, rec, None, 0.0))
        if any(_differs(a.get(k), b.get(k)) for a, b in zip(nominal, rec.outputs, strict=True) for k in b):
            raise RuntimeError(f"node {name}: a replay of its recorded inputs does not give back its "
                               "recorded outputs (its controller keeps state outside step()); it cannot be "
                               "analysed")
        rx_map, tx = bindings[name]
        # only the outputs that go out on the bus reach the plant or another node: the others are not
        # compared, and a replay stops once every one of them has changed (nothing more can be learnt)
        sent = {key for _, fields in tx for _, key in fields}
        per: dict[str, set[str]] = {}
        for fid, pairs in rx_map.items():
            msg = db.get_message_by_frame_id(fid)
            for signal, key in pairs:
                still = set(sent)                  # the sent outputs not yet seen to change
                for value in _values_to_try(db, msg.name, signal):
                    for a, b in zip(_replay(build, rec, key, value), nominal, strict=True):
                        still -= {k for k in still if a.get(k) != b.get(k) and _differs(a.get(k), b.get(k))}
                        if not still:
                            break
                    if not still:
                        break
                per[key] = sent - still
        result[name] = per
    return result


def actuating_links(db: Database, bindings: dict, influences: dict[str, dict[str, set[str]]]) -> list[Link]:
    """The fixed point of the module docstring: every received signal that reaches an actuator."""
    def protected(msg) -> bool:
        return e2e_config(msg) is not None and secoc_data_id(msg) is not None

    actuating: set[tuple[str, str]] = set()          # (message, signal) that drive an actuator
    plant_rx, _ = bindings.get(PLANT, ({}, []))
    for fid, pairs in plant_rx.items():
        actuating |= {(db.get_message_by_frame_id(fid).name, sig) for sig, _ in pairs}
    links: dict[tuple[str, str, str], Link] = {}
    for fid, pairs in plant_rx.items():
        msg = db.get_message_by_frame_id(fid)
        for sig, key in pairs:
            links[(msg.name, sig, PLANT)] = Link(msg.name, sig, PLANT, key, ("actuator",), msg.senders[0]
                                                 if msg.senders else "", protected(msg))
    changed = True
    while changed:
        changed = False
        for node, per in influences.items():
            rx_map, tx = bindings[node]
            out_to_signals: dict[str, set[tuple[str, str]]] = {}
            for message, fields in tx:
                for sig, key in fields:
                    out_to_signals.setdefault(key, set()).add((message, sig))
            for fid, pairs in rx_map.items():
                msg = db.get_message_by_frame_id(fid)
                for sig, key in pairs:
                    hits = tuple(sorted(o for o in per.get(key, ())
                                        if out_to_signals.get(o, set()) & actuating))
                    if hits and (msg.name, sig, node) not in links:
                        links[(msg.name, sig, node)] = Link(msg.name, sig, node, key, hits,
                                                            msg.senders[0] if msg.senders else "",
                                                            protected(msg))
                        if (msg.name, sig) not in actuating:
                            actuating.add((msg.name, sig))
                        changed = True
    return sorted(links.values(), key=lambda link: (link.message, link.signal, link.node))


def unprotected(links: Iterable[Link]) -> list[Link]:
    """The actuating signals on the bus (not the plant's sensors) whose frame lacks E2E or SecOC."""
    return [link for link in links if link.source == "bus" and not link.frame_protected]


def analyse(scenario, db: Database | None = None) -> list[Link]:
    """`actuating_links` of one scenario, from a recorded lockstep run."""
    db = db if db is not None else loaded_dbc(scenario.dbc)[0]
    recordings, bindings = record_run(scenario, db)
    return actuating_links(db, bindings, influence(scenario, db, recordings, bindings))
