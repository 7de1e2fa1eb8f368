"""When each node's cycles and each message's frames are released in lockstep: phase, clock drift,
release jitter and extra per-message delay, seeded (scenario keys ``[nodes.NAME]`` and
``[messages.NAME]``, defaults from the DBC's CANdb++ node attributes).

Cycle k of a node with period T and phase offset o is released at

    start_delay + o + round(k·T·(1 + drift)) + j_k,      j_k ~ U(jitter_min, jitter_max)

and the controller runs at that instant; the node's transmit schedule counts cycles, so a frame due
every cycle is sent every cycle whatever the jitter.  A frame then waits U(delay_min, delay_max)
before entering the node's transmit queue.  The random draws come from one ``random.Random`` per node
and per message, seeded by the scenario seed and the name: the same seed gives the same releases.

CANdb++ node attributes (CANoe's simulation settings), read when the scenario does not give a value:
``CANoeStartDelay`` [ms], ``CANoeDrift`` [% by which the node's timers are lengthened],
``CANoeJitterMin`` / ``CANoeJitterMax`` [% of the timer interval; the fluctuation is uniform in
between].  CANoe re-arms its timers on each expiry, so there the jitter accumulates; here it does not
(a release jitter around a drifting clock, the model of the response-time analysis).
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, TypeVar

from cantools.database.can import Database
from cantools.database.can import Node as DbcNode

from hil.can.dbc import closest
from hil.errors import ScenarioError
from hil.scenario import MessageTiming, NodeTiming, Scenario

__all__ = ["MessageDelay", "NodeRelease", "dbc_node_timing", "message_delays", "node_release",
           "node_releases"]

#: nodes whose clock is the simulation's own: the plant integrates physics at a fixed step
FIXED_CLOCK_NODES = ("PLANT",)
T = TypeVar("T")


class Scheduled(Protocol):
    """What the releases of a node are computed from: a runtime Node, or a device's side or model."""

    @property
    def name(self) -> str: ...

    @property
    def period_us(self) -> int: ...

    @property
    def offset_us(self) -> int: ...


def _attr(db: Database, node: DbcNode, name: str) -> float | None:
    """A node attribute: its BA_ value, else the BA_DEF_DEF_ default, else None (not defined)."""
    attrs = getattr(getattr(node, "dbc", None), "attributes", None) or {}
    a = attrs.get(name)
    if a is not None:
        return float(a.value)
    definitions = getattr(getattr(db, "dbc", None), "attribute_definitions", None) or {}
    d = definitions.get(name)
    return None if d is None or d.default_value is None else float(d.default_value)


def dbc_node_timing(db: Database, name: str, period_us: int) -> NodeTiming:
    """The CANoe node attributes of DBC node `name` as a NodeTiming (None where absent)."""
    node = next((n for n in db.nodes if n.name == name), None)
    if node is None:
        return NodeTiming()
    start_ms, drift_pct = _attr(db, node, "CANoeStartDelay"), _attr(db, node, "CANoeDrift")
    jmin_pct, jmax_pct = _attr(db, node, "CANoeJitterMin"), _attr(db, node, "CANoeJitterMax")
    return NodeTiming(
        start_delay_us=None if start_ms is None else round(start_ms * 1000),
        drift_ppm=None if drift_pct is None else drift_pct * 1e4,
        jitter_min_us=None if jmin_pct is None else round(jmin_pct / 100 * period_us),
        jitter_max_us=None if jmax_pct is None else round(jmax_pct / 100 * period_us),
    )


class NodeRelease:
    """Release times of one node's cycles, in ns; `next()` gives (release, nominal µs, window start)."""

    name: str
    period_us: int
    offset_us: int
    start_delay_us: int
    drift_ppm: float
    jitter_min_us: int
    jitter_max_us: int
    seed: int
    k: int                      # cycles released so far
    jittered: bool              # a release jitter is drawn for every cycle

    def __init__(self, name: str, period_us: int, offset_us: int, start_delay_us: int = 0,
                 drift_ppm: float = 0.0, jitter_min_us: int = 0, jitter_max_us: int = 0,
                 seed: int = 0) -> None:
        self.name, self.period_us, self.offset_us = name, period_us, offset_us
        self.start_delay_us, self.drift_ppm, self.seed = start_delay_us, drift_ppm, seed
        self.jitter_min_us, self.jitter_max_us = jitter_min_us, jitter_max_us
        self.k = 0
        self._rng = random.Random(f"{seed}/node/{name}")
        self._scale = period_us * 1000 * (1.0 + drift_ppm * 1e-6)     # ns per cycle on the node's clock
        self._base_ns = (start_delay_us + offset_us) * 1000
        self.jittered = jitter_min_us != jitter_max_us or jitter_min_us != 0
        self._window_ns = jitter_min_us * 1000

    @property
    def exact(self) -> bool:
        """No drift, delay or jitter: releases on the nominal grid."""
        return not self.jittered and self.drift_ppm == 0 and self.start_delay_us == 0

    def next(self) -> tuple[int, int, int]:
        k = self.k
        self.k += 1
        nominal_us = self.offset_us + k * self.period_us
        clock_ns = self._base_ns + round(k * self._scale)
        if not self.jittered:
            return max(0, clock_ns), nominal_us, max(0, clock_ns + self._window_ns)
        jitter_ns = round(self._rng.uniform(self.jitter_min_us, self.jitter_max_us) * 1000)
        return max(0, clock_ns + jitter_ns), nominal_us, max(0, clock_ns + self._window_ns)


def node_release(scenario: Scenario, db: Database, node: Scheduled) -> NodeRelease:
    """The NodeRelease of one node: scenario values over DBC attributes over zero."""
    given = scenario.nodes.get(node.name, NodeTiming()).model_copy(update={"external": False})
    fixed = node.name in FIXED_CLOCK_NODES
    if fixed and given != NodeTiming():
        raise ScenarioError(f"scenario key 'nodes.{node.name}': the plant steps the physics on a fixed "
                            f"clock and cannot jitter; delay its frames under [messages.NAME] instead")
    dbc = NodeTiming() if fixed else dbc_node_timing(db, node.name, node.period_us)
    jmin = _first(given.jitter_min_us, dbc.jitter_min_us, 0)
    jmax = _first(given.jitter_max_us, dbc.jitter_max_us, 0)
    if jmax < jmin:
        raise ScenarioError(f"node {node.name}: jitter_max_us {jmax} is below jitter_min_us {jmin}")
    if jmax - jmin >= node.period_us:
        raise ScenarioError(f"scenario key 'nodes.{node.name}': jitter range {jmax - jmin} us must be "
                            f"shorter than the node's period {node.period_us} us")
    return NodeRelease(node.name, node.period_us, node.offset_us,
                       _first(given.start_delay_us, dbc.start_delay_us, 0),
                       float(_first(given.drift_ppm, dbc.drift_ppm, 0.0)), jmin, jmax, scenario.seed)


def _first(given: T | None, dbc: T | None, default: T) -> T:
    """The scenario's value, else the DBC's, else `default`."""
    return given if given is not None else dbc if dbc is not None else default


def node_releases(scenario: Scenario, db: Database, nodes: Sequence[Scheduled]) -> list[NodeRelease]:
    """One NodeRelease per node (same order); a scenario key naming no node is an error."""
    names = [n.name for n in nodes]
    unknown = sorted(set(scenario.nodes) - set(names))
    if unknown:
        raise ScenarioError(f"scenario key 'nodes.{unknown[0]}': no such node in this scenario; "
                            f"nodes are {', '.join(names)}")
    return [node_release(scenario, db, node) for node in nodes]


@dataclass
class MessageDelay:
    """Extra delay of one message's frames before they enter the transmit queue, in ns."""

    name: str
    delay_min_us: int
    delay_max_us: int
    seed: int = 0
    _rng: random.Random = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._rng = random.Random(f"{self.seed}/message/{self.name}")

    def next_ns(self) -> int:
        if self.delay_min_us == self.delay_max_us:
            return self.delay_min_us * 1000
        return round(self._rng.uniform(self.delay_min_us, self.delay_max_us) * 1000)


def message_delays(scenario: Scenario, db: Database) -> dict[int, MessageDelay]:
    """Frame id -> MessageDelay for the messages the scenario delays."""
    out = {}
    names = [m.name for m in db.messages]
    for name, spec in scenario.messages.items():
        try:
            msg = db.get_message_by_name(name)
        except KeyError:
            raise ScenarioError(f"scenario key 'messages.{name}': no such message in the DBC "
                                f"(closest: {closest(name, names)})") from None
        if spec != MessageTiming():
            out[msg.frame_id] = MessageDelay(name, spec.delay_min_us, spec.delay_max_us, scenario.seed)
    return out
