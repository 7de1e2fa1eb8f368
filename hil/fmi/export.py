"""`railhil export-fmu`: railhil's plant, or a BECU, as an FMI 2.0 co-simulation FMU (PythonFMU).

PythonFMU builds the FMU from a script (a subclass of hil.fmi.exported's slaves) and the files it needs (the
scenario as JSON, its DBC); this module then writes the units and descriptions into modelDescription.xml
(PythonFMU declares none) and checks the result with FMPy's own validation.  What it needs at run time: a
Python with railhil installed, which PythonFMU's binary loads (docs/fmu.md).
"""

from __future__ import annotations

import json
import re
import shutil
import tempfile
import zipfile
from pathlib import Path
from xml.etree import ElementTree

from hil.can.dbc import DEFAULT_DBC, load_dbc
from hil.devices.units import registry, unit_of
from hil.errors import FmuError
from hil.fmi.exported import DBC_FILE, SCENARIO_FILE
from hil.fmi.ports import SCENARIO_VALUES, node_port, plant_port
from hil.runtime.assembly import becu_messages, node_names

SCRIPT = '''"""{doc}"""
from hil.fmi.exported import {base}, hold_module_dict

hold_module_dict(globals())     # PythonFMU's loader releases a reference to this dict that it never took


class {cls}({base}):
    """{doc}"""
{extra}'''


def fmi_unit_text(unit: str) -> str:
    """A pint unit string as FMI/Modelica writes it: m/s^2 -> m/s2, N*m -> N.m."""
    return unit.replace("^", "").replace("*", ".")


def _base_unit(unit: str) -> dict[str, str]:
    """The BaseUnit attributes of an FMI 2.0 unit definition (SI exponents and factor), from pint."""

    q = registry().Quantity(1.0, unit_of(unit, "export")).to_base_units()
    exponents = {"kilogram": "kg", "meter": "m", "second": "s", "ampere": "A", "kelvin": "K", "mole": "mol",
                 "candela": "cd", "radian": "rad"}
    attrs = {}
    for name, power in q.unit_items():
        if name in exponents:
            attrs[exponents[name]] = str(int(power))
    if q.magnitude != 1.0:
        attrs["factor"] = repr(float(q.magnitude))
    return attrs


def _annotate(model_description: bytes, meta: dict[str, tuple[str | None, str]]) -> bytes:
    """modelDescription.xml with each variable's unit and description (`meta`: name -> (unit, text)) and
    the unit definitions they use."""
    root = ElementTree.fromstring(model_description)
    used: dict[str, str] = {}
    for var in root.iter("ScalarVariable"):
        unit, text = meta.get(var.get("name"), (None, ""))
        if text and not var.get("description"):
            var.set("description", text)
        real = var.find("Real")
        if real is not None and unit:
            fmi = fmi_unit_text(unit)
            real.set("unit", fmi)
            used[fmi] = unit
    if used:
        defs = ElementTree.Element("UnitDefinitions")
        for fmi, unit in sorted(used.items()):
            u = ElementTree.SubElement(defs, "Unit", {"name": fmi})
            ElementTree.SubElement(u, "BaseUnit", _base_unit(unit))
        after = root.find("CoSimulation")
        root.insert(list(root).index(after) + 1, defs)
    ElementTree.indent(root)
    return ElementTree.tostring(root, encoding="utf-8", xml_declaration=True)


def _rewrite(fmu: Path, meta: dict[str, tuple[str | None, str]]) -> None:
    tmp = fmu.with_suffix(".tmp")
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = _annotate(data, meta)
            dst.writestr(item, data)
    tmp.replace(fmu)


def _build(scenario, out: Path, cls: str, base: str, doc: str, extra: str,
           meta: dict[str, tuple[str | None, str]]) -> Path:
    from pythonfmu import FmuBuilder


    out = Path(out)
    if out.suffix != ".fmu":
        raise FmuError(f"-o {out}: an FMU's file name ends in .fmu")
    if not out.parent.is_dir():
        raise FmuError(f"-o {out}: no such directory {out.parent}")
    with tempfile.TemporaryDirectory(prefix="railhil_fmu_") as tmp:
        work = Path(tmp)
        script = work / f"{cls.lower()}.py"
        script.write_text(SCRIPT.format(doc=doc, base=base, cls=cls, extra=extra), encoding="utf-8")
        data = scenario.model_dump(mode="json", by_alias=True, exclude_none=True)
        data.pop("dbc", None)
        (work / SCENARIO_FILE).write_text(json.dumps(data, indent=1), encoding="utf-8")
        shutil.copyfile(scenario.dbc or DEFAULT_DBC, work / DBC_FILE)
        built = Path(FmuBuilder.build_FMU(script, dest=work / "out", project_files=[work / SCENARIO_FILE,
                                                                                   work / DBC_FILE]))
        _rewrite(built, meta)
        shutil.copyfile(built, out)
    return out


def _class_name(text: str) -> str:
    return "".join(part.capitalize() for part in re.split(r"[^A-Za-z0-9]+", text) if part)


def export_plant(scenario, out: Path) -> Path:
    """railhil's plant of `scenario` as an FMU at `out`."""

    db = load_dbc(scenario.dbc or DEFAULT_DBC)
    port = plant_port(db, scenario.train.cars)
    meta = {q.name: (q.unit, q.description) for q in (*port.inputs.values(), *port.outputs.values())}
    meta |= {key: (unit, text) for key, (unit, text, _) in SCENARIO_VALUES.items()}
    doc = f"railhil's plant of scenario {scenario.name}, as an FMI 2.0 co-simulation FMU"
    return _build(scenario, out, "RailhilPlant", "PlantSlave", doc, "", meta)


def export_node(scenario, node: str, out: Path) -> Path:
    """Node `node` (a BECU) of `scenario` as an FMU at `out`: its controller; the bench adds E2E and
    SecOC."""

    names = node_names(scenario)
    if not (node.startswith("BECU") and node in names):
        becus = ", ".join(n for n in names if n.startswith("BECU"))
        raise FmuError(f"export-fmu: {node!r} is not a BECU of scenario {scenario.name!r} (its BECUs: "
                       f"{becus}); the plant is `railhil export-fmu plant SCENARIO`")
    db = load_dbc(scenario.dbc or DEFAULT_DBC)
    rx, tx = becu_messages(int(node[4:]))
    port = node_port(db, [m for m in rx if m in {x.name for x in db.messages}], tx)
    meta = {q.name: (q.unit, q.description) for q in (*port.inputs.values(), *port.outputs.values())}
    doc = f"railhil's {node} of scenario {scenario.name}, as an FMI 2.0 co-simulation FMU"
    return _build(scenario, out, f"Railhil{_class_name(node)}", "NodeSlave", doc, f"    NODE = {node!r}\n",
                  meta)
