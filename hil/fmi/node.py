"""An FMU as a node: its controller's step is the FMU's doStep, on the node's cycle.

`FmuController.step(now_us, rx)` sets the FMU's inputs from the signals the node received (NaN for a signal
not received yet; `MESSAGE.rx_age_s`, the age of each received message, where the FMU has it), calls
doStep(t, cycle) and returns its outputs as the node's signals, which the node sends at `now_us` with the
bench's E2E and SecOC like any node's.  A Simulink controller exported as a co-simulation FMU then runs as a
CAN node with no Python written.

The FMU's time starts at 0.  An FMU that takes variable communication steps is stepped from its time to the
node's `now_us` (doStep(t, now − t)), so its time is the node's, release jitter and missed cycles included:
a controller inside sees the step end at `now_us`, as railhil's own node does.  One that takes only its own
step is stepped as many node cycles as have passed.
"""

from __future__ import annotations

import math

from hil.errors import FmuError
from hil.fmi.fmu import CoSimulation, FmuInfo, checking_only, open_fmu, refs
from hil.fmi.mapping import Wiring, read_map, wire
from hil.fmi.ports import AGE_SUFFIX, node_port
from hil.runtime.node import Binding, Node


class FmuController:
    """The controller of node `name`: the FMU behind `wiring` on a `period_us` cycle."""

    def __init__(self, name: str, info: FmuInfo, wiring: Wiring, period_us: int, needed: list[str],
                 map_name: str | None = None) -> None:
        given = wiring.output_names()
        missing = [q for q in needed if q not in given]
        if missing:
            how = f"map them under [outputs] of {map_name}" if map_name else f"give [nodes.{name}] an fmu_map"
            raise FmuError(f"{info.path}: FMU {info.model_name!r} gives no {', '.join(missing[:4])}"
                           f"{f' (and {len(missing) - 4} more)' if len(missing) > 4 else ''}: {name} sent "
                           f"them; {how}")
        self.name, self.info, self.wiring, self.period_us = name, info, wiring, period_us
        self.inputs = tuple(sorted({c.source for c in wiring.inputs
                                    if not c.source.endswith("." + AGE_SUFFIX)}))
        self.outputs = tuple(c.target for c in wiring.outputs)
        self.sim = None if checking_only() else CoSimulation(info, name, wiring.start)
        self._in_refs = refs(info, [c.target for c in wiring.inputs])
        self._in = [(c.source, c.a, c.b, c.source.endswith("." + AGE_SUFFIX)) for c in wiring.inputs]
        # an age input reads the age of any signal of its message that the node receives
        self._age_key = {c.source: next((k for k in self.inputs if k.startswith(c.source[:-len(AGE_SUFFIX)])),
                                        None) for c in wiring.inputs if c.source.endswith("." + AGE_SUFFIX)}
        self._out_refs = refs(info, [c.source for c in wiring.outputs])
        self._out = [(c.target, c.a, c.b) for c in wiring.outputs]
        self._t_us = 0                            # the FMU's time [µs], from 0

    def _value(self, source: str, age: bool, rx, now_us: int) -> float:
        if age:
            key = self._age_key[source]
            age_us = rx.age_us(key, now_us) if key is not None else None
            return -1.0 if age_us is None else age_us * 1e-6
        value = rx[source]
        return value if isinstance(value, float | int) else math.nan

    def step(self, now_us: int, rx) -> dict[str, float]:
        values = [a * self._value(src, age, rx, now_us) + b for src, a, b, age in self._in]
        self.sim.set(self._in_refs, values)
        if self.info.variable_step:               # the FMU's time is the node's: one step to now
            if now_us > self._t_us:
                self.sim.step((now_us - self._t_us) * 1e-6, self._t_us * 1e-6)
            self._t_us = now_us
        else:                                     # its own fixed step: as many cycles as the node is on
            steps = max(1, round((now_us - self._t_us) / self.period_us))
            for _ in range(steps):
                self.sim.step(self.period_us * 1e-6, self._t_us * 1e-6)
                self._t_us += self.period_us
        raw = self.sim.get(self._out_refs, len(self._out))
        return {target: a * value + b for (target, a, b), value in zip(self._out, raw, strict=True)}

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()


def fmu_node(node, fmu: str, fmu_map: str | None, scenario, db, codec, dbc_name: str = "DBC"):
    """Node `node` (as the scenario builds it) with the FMU at `fmu` in its controller's place: the same
    messages, cycle and phase; the FMU's variables connected to its signals by name or by `fmu_map`."""

    info = open_fmu(fmu)
    rx_msgs = [db.get_message_by_frame_id(fid).name for fid in node.binding.rx]
    tx_msgs = [msg for msg, _ in node.binding.tx]
    port = node_port(db, rx_msgs, tx_msgs)
    wiring = wire(info, port, read_map(fmu_map) if fmu_map else None, scenario, fmu_map)
    needed = [f"{msg}.{sig}" for msg, fields in node.binding.tx for sig, _ in fields]
    ctrl = FmuController(node.name, info, wiring, node.period_us, needed, fmu_map)
    binding = Binding.build(db, node.name, ctrl.inputs, ctrl.outputs, rx_msgs, tx_msgs, dbc_name)
    qualified = {key: f"{msg}.{sig}" for msg, fields in node.binding.tx for sig, key in fields}
    safe = {qualified[key]: value for key, value in node.safe.items() if key in qualified}
    return Node(node.name, ctrl, binding, codec, db, period_us=node.period_us, offset_us=node.offset_us,
                safe_outputs=safe)
