"""A device's model: its control law as a Python class, run as the device in lockstep.

The device file's `model = "module:Class"` names a module beside the file and a class in it with
`step(now_us, rx) -> dict of output signals` on the device's own signals (its DBC's names, bare or
"MESSAGE.Signal"), as railhil's controllers have.  The class may say which signals it reads and writes
(`inputs`, `outputs`, attributes or class attributes); without them it gets every signal the device
receives and may set every signal it sends.  In lockstep the model runs on the device's own bus behind the
gateway, its frames protected as the device's DBC or file declares; in real time the real device takes its
place.  The module is loaded with its folder on the import path, so that it can import its neighbours
(a device's firmware and its model usually share their control code).
"""

from __future__ import annotations

import importlib.util
import math
import sys
from functools import reduce

from hil.devices.device import Device
from hil.devices.gateway import ObjectRef
from hil.errors import BindingError, DeviceError
from hil.runtime.node import Binding, Node, NodeStats


def model_class(device: Device) -> type:
    """The class the device file's `model` names, imported from beside the file."""
    text = device.spec.model
    where = f"{device.path}: key 'model' = {text!r}"
    module_name, _, class_name = text.partition(":")
    folder = device.path.parent.resolve()
    file = folder / (module_name.replace(".", "/") + ".py")
    if not file.is_file():
        raise DeviceError(f"{where}: no module {file.name} beside the device file (in {folder})")
    unique = f"railhil_device_model_{abs(hash(str(file)))}_{module_name.replace('.', '_')}"
    module = sys.modules.get(unique)
    if module is None:
        spec = importlib.util.spec_from_file_location(unique, file)
        module = importlib.util.module_from_spec(spec)
        added = str(folder) not in sys.path
        if added:
            sys.path.insert(0, str(folder))
        sys.modules[unique] = module     # before it runs: a dataclass in it looks its module up there
        try:
            spec.loader.exec_module(module)
        except Exception as exc:         # the user's module: its error, in one line
            del sys.modules[unique]
            raise DeviceError(f"{where}: importing {file.name} failed: {type(exc).__name__}: {exc}") from None
        finally:
            if added:
                sys.path.remove(str(folder))
    cls = getattr(module, class_name, None)
    if not isinstance(cls, type) or not callable(getattr(cls, "step", None)):
        raise DeviceError(f"{where}: {file.name} has no class {class_name!r} with a step(now_us, rx) method")
    return cls


def model_period_us(device: Device) -> int:
    """The model's cycle: the device file's model_cycle_ms, else the greatest common divisor of the cycle
    times of the frames the device sends."""
    if device.spec.model_cycle_ms is not None:
        return round(device.spec.model_cycle_ms * 1000)
    cycles = [int(device.db.get_message_by_name(n).cycle_time or 0) * 1000 for n in device.sends]
    cycles = [c for c in cycles if c > 0]
    if not cycles:
        raise DeviceError(f"{device.path}: the device's frames have no cycle time in {device.dbc_path.name}; "
                          "give model_cycle_ms")
    return reduce(math.gcd, cycles)


def build_model_node(device: Device, name: str | None = None, offset_us: int = 0) -> Node:
    """The device's model as a node on the device's own bus (lockstep), its cycles at `offset_us` into its
    period (the replaced node's phase: the model sees the frames the replaced node would have seen)."""
    where = f"{device.path}: key 'model' = {device.spec.model!r}"
    cls = model_class(device)
    try:
        model = cls()
    except Exception as exc:
        raise DeviceError(f"{where}: {cls.__name__}() failed: {type(exc).__name__}: {exc}") from None
    db = device.db
    every_in = [f"{m}.{s.name}" for m in device.receives for s in db.get_message_by_name(m).signals]
    every_out = [f"{m}.{s.name}" for m in device.sends for s in db.get_message_by_name(m).signals]
    inputs = tuple(getattr(model, "inputs", None) or every_in)
    outputs = tuple(getattr(model, "outputs", None) or every_out)
    try:
        binding = Binding.build(db, name or device.node, inputs, outputs, device.receives, device.sends,
                                device.dbc_path.name)
    except BindingError as exc:
        raise DeviceError(f"{where}: {exc}") from None
    safe = getattr(model, "safe_outputs", None)
    safe = safe() if callable(safe) else safe
    return Node(name or device.node, model, binding, device.codec, db, period_us=model_period_us(device),
                offset_us=offset_us, safe_outputs=dict(safe or {}), protection=device.protection)


class VariableModel:
    """A device on OPC UA as its model in lockstep (hil.runtime.lockstep.DeviceLink): each cycle its
    `step(now_us, rx)` on the variables the device reads — rx keyed "OBJECT.Variable", and by the bare name
    where that is unique — and what it returns ("OBJECT.Variable" or a bare name) written at once, an
    object at a time, as the PLC's write of it.  No OPC UA stack: what the link adds in real time is
    measured there (hil.devices.opcua)."""

    def __init__(self, device: Device, name: str, offset_us: int = 0) -> None:
        where = f"{device.path}: key 'model' = {device.spec.model!r}"
        cls = model_class(device)
        try:
            self.model = cls()
        except Exception as exc:
            raise DeviceError(f"{where}: {cls.__name__}() failed: {type(exc).__name__}: {exc}") from None
        self.name, self.offset_us = name, offset_us
        self.period_us = model_period_us(device)
        db = device.db
        reads = [m for m in db.messages if m.name in device.receives]
        writes = [m for m in db.messages if m.name in device.sends]
        self._objects = {m.frame_id: m for m in reads}
        self.rx: dict[str, float] = {}
        bare = [s.name for m in reads for s in m.signals]
        for m in reads:
            for s in m.signals:
                self.rx[f"{m.name}.{s.name}"] = math.nan
                if bare.count(s.name) == 1:
                    self.rx[s.name] = math.nan
        self._keys: dict[str, tuple[int, str]] = {}       # an output key -> (object's frame id, variable)
        out_bare = [s.name for m in writes for s in m.signals]
        for m in writes:
            for s in m.signals:
                self._keys[f"{m.name}.{s.name}"] = (m.frame_id, s.name)
                if out_bare.count(s.name) == 1:
                    self._keys[s.name] = (m.frame_id, s.name)
        self._written = {m.frame_id: {s.name: 0.0 for s in m.signals} for m in writes}
        self._names = {m.frame_id: m.name for m in writes}
        self.stats = NodeStats()

    def deliver(self, frame_id: int, values: dict) -> None:
        """The bench wrote an object the device reads."""
        m = self._objects.get(frame_id)
        if m is None:
            return
        for var, v in values.items():
            self.rx[f"{m.name}.{var}"] = v
            if var in self.rx:
                self.rx[var] = v

    def cycle(self, now_us: int, nominal_us: int | None = None) -> list:
        """One scan: every object the model writes, [(ObjectRef, values)]; a step() that raises, or an
        output that is not a finite number, is counted and the last values are written."""

        self.stats.cycles += 1
        try:
            out = self.model.step(now_us, self.rx) or {}
        except Exception as exc:   # noqa: BLE001 - the user's model: counted, its last values written
            self.stats.step_errors += 1
            self.stats.last_error = f"{type(exc).__name__}: {exc}"
            out = {}
        for key, v in out.items():
            where = self._keys.get(key)
            if where is None:
                continue
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                self.stats.bad_outputs += 1
                continue
            self._written[where[0]][where[1]] = float(v)
        frames = [(ObjectRef(fid, False, self._names[fid]), dict(values))   # a PLC writes every scan
                  for fid, values in self._written.items()]
        self.stats.frames_sent += len(frames)
        return frames
