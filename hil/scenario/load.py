"""Loading scenarios: TOML files, `--set KEY=VALUE` overrides, keys of earlier releases.

A bad key or value gives one ScenarioError line naming the file, the key, the value and what is
allowed (exit code 2 at the CLI), with the closest valid key for a misspelt one.  A key that an
earlier release had elsewhere (a study's key that moved into the study's own section) is read and
moved, with a one-line notice (RailhilDeprecation), for one release.
"""

from __future__ import annotations

import difflib
import tomllib
import types
import typing
import warnings
from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, ValidationError

from hil.errors import RailhilError, ScenarioError
from hil.resources import read_toml, resolve_scenario
from hil.scenario import registry
from hil.scenario.model import ScenarioBase, scenario_model
from hil.scenario.params import secoc_keys

LEGACY_UNTIL = "0.3"       # the release that stops reading the keys of 0.1


class RailhilDeprecation(FutureWarning):
    """A scenario key or command name of an earlier release, still read: the notice says the new one."""


def _legacy_table() -> dict[str, tuple[str, object]]:
    """old dotted key -> (new dotted key, value conversion or None), from every study."""
    out: dict[str, tuple[str, object]] = {}
    for study in registry.studies():
        for old, new in study.legacy_keys.items():
            out[old] = new if isinstance(new, tuple) else (new, None)
    return out


_MISSING = object()
DROP = object()          # a conversion's answer: the old key's value means "absent" (no section)


def _pop(data: dict, dotted: str):
    *parents, last = dotted.split(".")
    node = data
    for part in parents:
        node = node.get(part) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            return _MISSING
    return node.pop(last, _MISSING) if isinstance(node, dict) else _MISSING


def _has(data: dict, dotted: str) -> bool:
    node = data
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def _put(data: dict, dotted: str, value) -> None:
    *parents, last = dotted.split(".")
    node = data
    for part in parents:
        node = node.setdefault(part, {})
    node[last] = value


def notice(text: str) -> None:
    warnings.warn(text, RailhilDeprecation, stacklevel=3)


def translate_legacy(data: dict, source: str) -> dict:
    """`data` with the keys of earlier releases moved to their new places (a copy when any moved)."""
    table = _legacy_table()
    if not any(_has(data, old) for old in table):
        return data
    import copy

    data = copy.deepcopy(data)
    for old, (new, convert) in table.items():
        value = _pop(data, old)
        if value is _MISSING:
            continue
        if _has(data, new):
            raise ScenarioError(f"{source}: key '{old}' (of railhil 0.1) and its new key '{new}' are both "
                                f"given; keep '{new}'")
        value = convert(value) if convert is not None else value
        if value is not DROP:
            _put(data, new, value)
        notice(f"{source}: scenario key '{old}' is now '{new}'; the old key is read until railhil "
               f"{LEGACY_UNTIL}")
    for table_key in ("bcu", "becu", "report"):       # a section the move left empty
        if data.get(table_key) == {}:
            del data[table_key]
    return data


def legacy_set(key: str, value: object, source: str) -> tuple[str, object]:
    """A `--set` key of an earlier release, moved to its new place (with a notice)."""
    entry = _legacy_table().get(key)
    if entry is None:
        return key, value
    new, convert = entry
    notice(f"{source}: --set {key} is now --set {new}; the old key is read until railhil {LEGACY_UNTIL}")
    return new, (convert(value) if convert is not None else value)


def _describe(err: dict) -> str:
    loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
    value = err.get("input")
    if err["type"] == "extra_forbidden":
        return f"key '{loc}' is not a scenario key{_closest_key(err['loc'])}"
    if err["type"] == "missing":
        return f"key '{loc}' is missing"
    shown = repr(value)
    if len(shown) > 60:
        shown = shown[:57] + "..."
    return f"key '{loc}' = {shown}: {err['msg']}"


def _closest_key(loc: tuple) -> str:
    """'; did you mean ...' for an unknown key at `loc`, from the fields of the model it sits in."""
    kind, inner = "model", scenario_model()
    for part in loc[:-1]:
        if kind == "model":
            field = inner.model_fields.get(str(part))
            if field is None:
                return ""
            kind, inner = _unwrap(field.annotation)
        elif kind in ("dict", "list"):       # part is a name or an index
            kind, inner = _unwrap(inner)
        else:
            return ""
    if kind != "model":
        return ""
    fields = list(inner.model_fields)
    close = difflib.get_close_matches(str(loc[-1]), fields, n=1, cutoff=0.5)
    prefix = ".".join(str(p) for p in loc[:-1])
    if close:
        return f"; did you mean '{prefix + '.' if prefix else ''}{close[0]}'?"
    return f"; valid keys here: {', '.join(fields)}"


def parse_scenario(data: dict, source: str = "<scenario>") -> ScenarioBase:
    """Validate a scenario table (keys of earlier releases translated first, with a notice)."""
    data = translate_legacy(data, source)
    try:
        return scenario_model().model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise ScenarioError(f"{source}: {_describe(errors[0])}{more}") from None


# ------------------------------------------------------------------------------ --set KEY=VALUE overrides
def _unwrap(annotation):
    """The type behind Optional[...] / Annotated[...]: (kind, inner) with kind "model", "dict", "list" or
    "value"."""
    while True:
        origin = typing.get_origin(annotation)
        if origin is Annotated:
            annotation = typing.get_args(annotation)[0]
        elif origin in (typing.Union, types.UnionType):
            args = [a for a in typing.get_args(annotation) if a is not type(None)]
            if len(args) != 1:
                return "value", annotation
            annotation = args[0]
        else:
            break
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "model", annotation
    if origin is dict:
        return "dict", typing.get_args(annotation)[1]
    if origin is list:
        return "list", typing.get_args(annotation)[0]
    return "value", annotation


def parse_set(text: str) -> tuple[str, object]:
    """`KEY=VALUE` of `railhil run --set`: the dotted scenario key and the value parsed as TOML
    (`true`, `0.25`, `"decel"`, `[0.0, 1.0]`); text that is not a TOML value is taken as a string, so
    `becu.control=decel` works without shell-quoted quotes."""
    key, sep, raw = text.partition("=")
    key, raw = key.strip(), raw.strip()
    if not sep or not key or not raw:
        raise ScenarioError(f"--set {text!r}: expected KEY=VALUE with a dotted scenario key, "
                            f"e.g. train.initial_speed_kmh=120")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value


def apply_set(data: dict, key: str, value: object, source: str) -> None:
    """Put `value` at the dotted `key` of the raw scenario table `data` (in place), checking every part
    of the key against the Scenario model: an unknown key is a ScenarioError naming the closest valid
    one. Lists take an index (`desk.0.at_s`); dicts of models take any name (`nodes.BECU3.drift_ppm`).
    The value itself is validated with the whole scenario afterwards (parse_scenario)."""
    key, value = legacy_set(key, value, source)
    if value is DROP:                  # an old key's "not fitted": the section stays as the file has it
        return
    parts = key.split(".")
    kind, inner = "model", scenario_model()
    node: object = data
    for depth, part in enumerate(parts):
        here = ".".join(parts[:depth + 1])
        last = depth == len(parts) - 1
        if kind == "model":
            fields = inner.model_fields
            if part not in fields:
                close = difflib.get_close_matches(part, list(fields), n=1, cutoff=0.5)
                hint = (f"; did you mean '{'.'.join(parts[:depth] + close)}'?" if close
                        else f"; valid keys here: {', '.join(fields)}")
                raise ScenarioError(f"{source}: --set {key}: '{here}' is not a scenario key{hint}")
            kind, inner = _unwrap(fields[part].annotation)
        elif kind == "dict":
            kind, inner = _unwrap(inner)
        elif kind == "list":
            items = node
            if not part.isdigit() or not isinstance(items, list) or int(part) >= len(items):
                n = len(items) if isinstance(items, list) else 0
                raise ScenarioError(f"{source}: --set {key}: '{here}' needs an index below {n} of "
                                    f"the scenario's list '{'.'.join(parts[:depth])}'")
            if last:
                items[int(part)] = value
                return
            node = items[int(part)]
            kind, inner = _unwrap(inner)
            continue
        else:
            raise ScenarioError(f"{source}: --set {key}: '{'.'.join(parts[:depth])}' is a value, "
                                f"it has no key '{part}'")
        assert isinstance(node, dict)
        if last:
            node[part] = value
            return
        child = node.get(part)
        if child is None:
            child = node[part] = {} if kind in ("model", "dict") else []
        if kind in ("model", "dict") and not isinstance(child, dict):
            raise ScenarioError(f"{source}: --set {key}: '{here}' is not a table in the scenario")
        node = child


def _resolve_fmus(scenario: ScenarioBase, folder: Path, set_keys: list[str]) -> ScenarioBase:
    """The FMU files of [plant] and [nodes.NAME] as absolute paths: beside the scenario, or beside the working
    directory where --set gave them."""
    def where(value: str | None, key: str) -> str | None:
        if value is None:
            return None
        base = Path.cwd() if key in set_keys else folder
        return str((base / value).resolve())

    plant = scenario.plant
    if plant.fmu or plant.fmu_map:
        plant = plant.model_copy(update={"fmu": where(plant.fmu, "plant.fmu"),
                                         "fmu_map": where(plant.fmu_map, "plant.fmu_map")})
    nodes = {name: (t.model_copy(update={"fmu": where(t.fmu, f"nodes.{name}.fmu"),
                                         "fmu_map": where(t.fmu_map, f"nodes.{name}.fmu_map")})
                    if t.fmu or t.fmu_map else t) for name, t in scenario.nodes.items()}
    return scenario.model_copy(update={"plant": plant, "nodes": nodes})


def load_scenario(path: str | Path, overrides: dict | None = None,
                  sets: list[str] | tuple[str, ...] = ()) -> ScenarioBase:
    """Load and validate a scenario file: a path, or the name of a shipped scenario (`default`;
    hil.resources.resolve_scenario). `overrides` replace top-level keys; `sets` are `railhil run
    --set KEY=VALUE` texts (dotted keys, TOML values) applied after them, in order.  Relative paths in
    the file (the DBC, a study's tables) are resolved beside it."""
    path = resolve_scenario(path)
    data = read_toml(path, ScenarioError, str(path), "no such scenario file")
    for key, value in (overrides or {}).items():
        data[key] = value
    set_keys = []
    for text in sets:
        key, value = parse_set(text)
        apply_set(data, key, value, str(path))
        set_keys.append(key)
    try:
        scenario = parse_scenario(data, str(path))
    except ScenarioError as exc:
        given = [k for k in set_keys if f"key '{k}'" in str(exc)]
        if given:
            raise ScenarioError(f"{exc} (given by --set {given[-1]}=...)") from None
        raise
    if scenario.dbc is not None:
        dbc_path = (path.parent / scenario.dbc).resolve()
        scenario = scenario.model_copy(update={"dbc": str(dbc_path)})
    if scenario.secoc.key_file is not None:
        key_file = str((path.parent / scenario.secoc.key_file).resolve())
        secoc = scenario.secoc.model_copy(update={"key_file": key_file})
        scenario = scenario.model_copy(update={"secoc": secoc})
    scenario = _resolve_fmus(scenario, path.parent, set_keys)
    if scenario.devices:                              # device files named relative to the scenario
        devices = {name: ref.model_copy(update={"file": str((path.parent / ref.file).resolve())})
                   for name, ref in scenario.devices.items()}
        scenario = scenario.model_copy(update={"devices": devices})
    for study in registry.active(scenario):           # a study's files named relative to the scenario
        resolve = getattr(study.part("scenario"), "resolve_paths", None)
        if resolve is not None:
            scenario = resolve(scenario, path.parent)
    try:
        secoc_keys(scenario)            # a missing or malformed key: one line now, not in a node process
    except RailhilError as exc:
        raise ScenarioError(f"{path}: {exc}") from None
    return scenario
