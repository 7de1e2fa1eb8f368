"""An OPC UA device's variables as the map sees them: a schema in cantools' terms.

A device on OPC UA (transport = "opcua") has no DBC: its information model is the objects and variables
its file declares under [reads] (the variables the device reads: the bench writes them) and [writes] (the
variables it writes: the bench reads them).  So that one map serves both transports (hil.devices.device
checks names, units, value tables and ranges the same way), each object becomes a message of a cantools
`Database` that is never put on a bus — its "frame" is the object's variables written at once — and each
variable a signal with the variable's unit, value table and range (its data type's, or the file's
minimum/maximum).  The device node sends its [writes] objects, at the PLC's scan cycle, and receives its
[reads] objects, each whenever a source of it changes (no cycle time: hil.devices.device routes it on its
first source's frames).
"""

from __future__ import annotations

from collections import OrderedDict

from cantools.database.can import Database, Message, Node, Signal
from cantools.database.conversion import BaseConversion

from hil.devices.description import OPCUA_TYPES, DeviceSpec, VariableSpec

DEVICE_NODE = "PLC"        # the device's node name in the schema, unless the file names one (`node`)
BENCH_NODE = "BENCH"       # the sender of the objects the device reads


def variable_signal(name: str, v: VariableSpec) -> Signal:
    """A variable as a signal: its unit, its value table, its range (the data type's unless narrowed)."""
    lo, hi = OPCUA_TYPES[v.type]
    lo = lo if v.minimum is None else max(lo, v.minimum)
    hi = hi if v.maximum is None else min(hi, v.maximum)
    choices = OrderedDict((int(k), text) for k, text in v.choices.items()) if v.choices else None
    is_float = v.type in ("Float", "Double")
    return Signal(name, 0, 64, is_signed=lo < 0, minimum=lo, maximum=hi, unit=v.unit,
                  conversion=BaseConversion.factory(1, 0, choices, is_float))


def variable_database(spec: DeviceSpec, node: str) -> Database:
    """The schema of a device's variables: an object a message (frame id: its place in the file, from 1),
    a variable a signal; `node` sends the [writes] objects and receives the [reads] ones."""
    messages = []
    cycle_ms = round(spec.opcua.cycle_ms)
    objects = [(o, True) for o in spec.writes] + [(o, False) for o in spec.reads]
    for k, (name, written) in enumerate(objects, start=1):
        variables = (spec.writes if written else spec.reads)[name]
        signals = [variable_signal(v, vs) for v, vs in variables.items()]
        messages.append(Message(k, name, 8, signals, senders=[node] if written else [BENCH_NODE],
                                cycle_time=cycle_ms if written else None, strict=False))
    for m in messages:
        if node not in m.senders:
            for s in m.signals:
                s.receivers.append(node)
    return Database(messages, nodes=[Node(node, None), Node(BENCH_NODE, None)], strict=False)
