"""How an FMU's variables connect to a port of the bench (hil.fmi.ports): by name, or by a map file.

A variable named as a port quantity connects to it without a map (an FMU railhil exported has only such
names).  Any other FMU takes a map file, the device map's form with FMU variables in place of signals:

    description = "one-car brake plant (brake_car.fmu)"

    [inputs]                                   # FMU input = the bench quantity it takes
    u_valve = { from = "BECU1_PRESS_CMD.ValveCmd" }
    dump = { from = "BECU1_PRESS_CMD.WspValve" }

    [outputs]                                  # bench quantity = the FMU output it comes from
    "PLANT_CAR1_SENSORS.CylPressure" = { from = "p_cyl" }      # the FMU's bar to the DBC's Pa, by pint
    "truth.v_mps_1" = { from = "v", unit = "km/h" }             # `unit` where the FMU declares none

    [start]                                    # FMU parameters and start values
    v0 = { from = "train.initial_speed_kmh" }  # a scenario value (hil.fmi.ports.SCENARIO_VALUES) ...
    mass = { value = "40 t" }                  # ... or a constant, a number or a quantity

Each value goes from its source's unit to its target's (declared in the model description or the DBC, or
`unit`), times `scale`, plus `offset`, as y = a·x + b computed once (hil.devices.units.affine).  The map is
checked against the model description as it is read: a variable it does not have (with the closest names),
a causality that cannot play its part (an [inputs] target that is not an input, an [outputs] source that is
not an output), a type that cannot carry the quantity (an integer variable for a fraction, a Boolean for a
three-state valve), each one line naming the file and the key.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

from pydantic import Field, StrictFloat, StrictInt, StrictStr, ValidationError, model_validator

from hil.devices.units import affine, magnitude_in
from hil.errors import DeviceError, FmuError
from hil.fmi.fmu import INTEGER_TYPES, REAL_TYPES, FmuInfo, Variable, closest
from hil.fmi.ports import SCENARIO_VALUES, Port, Quantity
from hil.resources import read_toml
from hil.scenario.base import Strict

Number = StrictInt | StrictFloat


class FmuEntry(Strict):
    """Where one target takes its value: a source (`from`) or a constant (`value`)."""

    source: Annotated[str | None, Field(alias="from")] = None
    value: Number | StrictStr | None = None
    unit: StrictStr | None = None        # the source's unit where it declares none, or another
    scale: Number | StrictStr = 1.0      # a number, or a quantity text ("0.46 m")
    offset: Number | StrictStr = 0.0     # in the target's unit, or a quantity text

    model_config = {**Strict.model_config, "populate_by_name": True}

    @model_validator(mode="after")
    def _one_source(self) -> FmuEntry:
        if (self.source is None) == (self.value is None):
            raise ValueError("give exactly one of 'from' and 'value' (a constant)")
        return self


class FmuMap(Strict):
    """A map file, as read."""

    description: str = ""
    inputs: dict[str, FmuEntry] = Field(default_factory=dict)    # FMU input -> its source on the bench
    outputs: dict[str, FmuEntry] = Field(default_factory=dict)   # bench quantity -> its FMU source
    start: dict[str, FmuEntry] = Field(default_factory=dict)     # FMU parameter or start value -> value


def read_map(path: str | Path) -> FmuMap:
    """The map file at `path`, validated; an FmuError naming the file and the key if not."""
    where = str(path)
    data = read_toml(Path(path), FmuError, where, "no such FMU map file")
    try:
        return FmuMap.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
        what = ("is not a map-file key (keys: description, [inputs], [outputs], [start]; an entry takes "
                "from, value, unit, scale, offset)" if err["type"] == "extra_forbidden"
                else err["msg"].removeprefix("Value error, "))
        raise FmuError(f"{where}: key '{loc}' {what}") from None


def fmi_unit(text: str | None) -> str | None:
    """An FMI/Modelica unit string as pint reads it: "1" and "" are pure numbers, "m/s2" is m/s^2."""
    if text is None or text.strip() in ("", "1", "-"):
        return None
    return re.sub(r"([A-Za-z])(\d+)", r"\1^\2", text.strip())


@dataclass(frozen=True)
class Connection:
    """target = a·source + b, one value a step."""

    target: str
    source: str
    a: float = 1.0
    b: float = 0.0


@dataclass
class Wiring:
    """An FMU's connections to a port: inputs (FMU variable <- bench quantity), outputs (bench quantity <-
    FMU variable) and the start values set before initialisation (FMU variable -> value in its unit)."""

    inputs: list[Connection] = field(default_factory=list)
    outputs: list[Connection] = field(default_factory=list)
    start: dict[str, float] = field(default_factory=dict)
    unused_fmu_inputs: list[str] = field(default_factory=list)   # left at their start values

    def output_names(self) -> set[str]:
        return {c.target for c in self.outputs}


def _affine(src_unit, dst_unit, entry: FmuEntry | None, where: str, source: str, target: str):
    scale = entry.scale if entry is not None else 1.0
    offset = entry.offset if entry is not None else 0.0
    try:
        return affine(src_unit, dst_unit, scale, offset, where=where, source=source, target=target)
    except DeviceError as exc:
        raise FmuError(str(exc)) from None


def _carries(var: Variable, q: Quantity, where: str, model: str) -> None:
    """Whether FMU variable `var` can take the bench quantity `q`: an FmuError if its type cannot."""
    if var.type not in REAL_TYPES | INTEGER_TYPES:
        raise FmuError(f"{where}: FMU variable {var.name!r} of {model} is a {var.type}: it cannot carry "
                       f"{q.name} (a number)")
    if var.type in INTEGER_TYPES and not q.integer:
        raise FmuError(f"{where}: FMU variable {var.name!r} of {model} is an {var.type}: it cannot carry "
                       f"{q.name}, which takes fractional values ({q.lo:g} .. {q.hi:g}); give the FMU a Real "
                       "input")
    if var.type == "Boolean" and (q.lo < 0 or q.hi > 1):
        raise FmuError(f"{where}: FMU variable {var.name!r} of {model} is a Boolean: it cannot carry "
                       f"{q.name}, whose values go {q.lo:g} .. {q.hi:g}")


def _variable(info: FmuInfo, name: str, where: str) -> Variable:
    var = info.variables.get(name)
    if var is None:
        raise FmuError(f"{where}: FMU {info.model_name!r} ({info.path.name}) has no variable {name!r}"
                       f"{closest(name, list(info.variables))}")
    return var


def _scenario_value(key: str, scenario, where: str) -> tuple[float, str | None]:
    entry = SCENARIO_VALUES.get(key)
    if entry is None:
        raise FmuError(f"{where}: from = {key!r} is not a scenario value an FMU may take (those are "
                       f"{', '.join(SCENARIO_VALUES)}){closest(key, list(SCENARIO_VALUES))}")
    unit, _, getter = entry
    return float(getter(scenario)), unit


def _constant(entry: FmuEntry, unit: str | None, where: str) -> float:
    try:
        return magnitude_in(entry.value, unit, where)
    except DeviceError as exc:
        raise FmuError(str(exc)) from None


def wire(info: FmuInfo, port: Port, fmu_map: FmuMap | None, scenario, map_path: str | None = None) -> Wiring:
    """The FMU's connections to `port`: the map's, then every variable named as a port quantity; checked
    against the model description (names, causality, type, units)."""
    model = f"{info.model_name!r}"
    src = map_path or str(info.path)
    m = fmu_map or FmuMap()
    w = Wiring()
    fed: set[str] = set()
    for name, entry in m.inputs.items():
        where = f"{src}: key 'inputs.{name}'"
        var = _variable(info, name, where)
        if var.causality != "input":
            raise FmuError(f"{where}: FMU variable {name!r} of {model} has causality {var.causality!r}: the "
                           "bench sets inputs only (a parameter goes under [start])")
        if entry.value is not None:
            w.start[name] = _constant(entry, fmi_unit(var.unit), where)
        else:
            q = port.inputs.get(entry.source)
            if q is None:
                raise FmuError(f"{where}: from = {entry.source!r} is not a quantity the bench gives here"
                               f"{closest(entry.source, list(port.inputs))}")
            _carries(var, q, where, model)
            a, b = _affine(entry.unit or q.unit, fmi_unit(var.unit), entry, where, entry.source, name)
            w.inputs.append(Connection(name, entry.source, a, b))
        fed.add(name)
    taken: set[str] = set()
    for name, entry in m.outputs.items():
        where = f"{src}: key 'outputs.{name}'"
        q = port.outputs.get(name)
        if q is None:
            raise FmuError(f"{where}: {name!r} is not a quantity the bench takes here"
                           f"{closest(name, list(port.outputs))}")
        if entry.value is not None:
            raise FmuError(f"{where}: an output comes from an FMU variable: give from = \"VARIABLE\"")
        var = _variable(info, entry.source, where)
        if var.causality not in ("output", "local"):
            raise FmuError(f"{where}: FMU variable {entry.source!r} of {model} has causality "
                           f"{var.causality!r}: the bench reads outputs")
        if var.type not in REAL_TYPES | INTEGER_TYPES:
            raise FmuError(f"{where}: FMU variable {entry.source!r} of {model} is a {var.type}: it cannot "
                           f"carry {name} (a number)")
        a, b = _affine(entry.unit or fmi_unit(var.unit), q.unit, entry, where, entry.source, name)
        w.outputs.append(Connection(name, entry.source, a, b))
        taken.add(name)
    for name, entry in m.start.items():
        where = f"{src}: key 'start.{name}'"
        var = _variable(info, name, where)
        settable = var.causality in ("parameter", "input", "structuralParameter") or var.start is not None
        if not settable or var.variability == "constant":
            raise FmuError(f"{where}: FMU variable {name!r} of {model} ({var.causality}, "
                           f"{var.variability}) takes no start value")
        if entry.value is not None:
            w.start[name] = _constant(entry, fmi_unit(var.unit), where)
        else:
            value, unit = _scenario_value(entry.source, scenario, where)
            a, b = _affine(entry.unit or unit, fmi_unit(var.unit), entry, where, entry.source, name)
            w.start[name] = a * value + b
        fed.add(name)
    # by name: a variable named as a port quantity, or as a scenario value
    for var in info.variables.values():
        if var.name in fed or var.name in taken:
            continue
        where = f"{info.path}: variable {var.name!r}"
        if var.causality == "input" and var.name in port.inputs:
            q = port.inputs[var.name]
            _carries(var, q, where, model)
            a, b = _affine(q.unit, fmi_unit(var.unit), None, where, q.name, var.name)
            w.inputs.append(Connection(var.name, var.name, a, b))
        elif var.causality == "output" and var.name in port.outputs:
            q = port.outputs[var.name]
            a, b = _affine(fmi_unit(var.unit), q.unit, None, where, var.name, q.name)
            w.outputs.append(Connection(var.name, var.name, a, b))
        elif var.causality == "parameter" and var.name in SCENARIO_VALUES and scenario is not None:
            value, unit = _scenario_value(var.name, scenario, where)
            a, b = _affine(unit, fmi_unit(var.unit), None, where, var.name, var.name)
            w.start[var.name] = a * value + b
        elif var.causality == "input":
            w.unused_fmu_inputs.append(var.name)
    for name, value in w.start.items():
        if not math.isfinite(value):
            raise FmuError(f"{src}: start value of {name!r} is not finite ({value!r})")
    return w
