"""The studies as the foundation knows them: a `Study` descriptor each, listed by one registry.

A study (preview slip control, the wheel-slip governor, precise stopping, anti-collision, consensus
braking, deceleration feedback) is a folder `hil/studies/<name>/` with the same files in each:

    __init__.py  STUDY, its descriptor (this module's `Study`)
    scenario.py  its scenario section, cross-checks, and the parameters of its nodes and stages
    nodes.py     its node bindings: the nodes it adds or replaces, the stages it fits into the BCU and BECUs
    frames.py    its DBC part
    kpis.py      its KPIs (kpis.json under the study's name) and summary lines
    plots.py     its plots
    reproduce.py `railhil reproduce <name>`: the paper's campaigns next to its figures

The foundation (scenario, runtime, report, ...) never imports a study.  It asks `studies()` (or
`active(scenario)`) for the descriptors and calls their parts through `Study.part`; the registry,
hil/studies/__init__.py, is loaded here by its name on first use, the way python-can loads an
interface named in its BACKENDS table, so the import arrows still point down (cli -> studies ->
foundation).  A study package's `__init__` imports only its `scenario` part, so that building the
scenario model (which needs every section) never imports the runtime.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType, ModuleType
from typing import Any

REGISTRY_MODULE = "hil.studies"
PARTS = ("scenario", "nodes", "frames", "kpis", "plots", "reproduce")


@dataclass(frozen=True)
class Study:
    """One study.  `name` is its folder (`wheel_slip`) and its key in kpis.json; `section` the scenario
    key of its section (the study is part of a run when that section is present); `spec` the section's
    model; `cli_name` its name on the command line (`wheel-slip`)."""

    name: str
    title: str                                  # one line, for --help and the docs
    paper: str                                  # the citation: "seed 001: Danielson, Di Cairano, ..."
    section: str
    spec: type
    package: str
    # cross-section checks: called with the whole scenario when the section is present; raise ValueError
    check: Callable[[Any], None] | None = None
    # old scenario keys (dotted) -> their new keys, still read for one release (hil.scenario.model)
    legacy_keys: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def cli_name(self) -> str:
        return self.name.replace("_", "-")

    def active(self, scenario) -> bool:
        return getattr(scenario, self.section, None) is not None

    def part(self, name: str) -> ModuleType:
        """The study's module `name` (one of PARTS), imported on first use."""
        if name not in PARTS:
            raise ValueError(f"a study has no part {name!r}; its parts are {', '.join(PARTS)}")
        return importlib.import_module(f"{self.package}.{name}")


@functools.cache
def studies() -> tuple[Study, ...]:
    """Every study, in registry order (the order their hooks are called in)."""
    registry = importlib.import_module(REGISTRY_MODULE)
    try:
        return tuple(registry.STUDIES)
    except AttributeError:
        raise RuntimeError(f"{REGISTRY_MODULE} is still loading: a study's __init__ or scenario part used "
                           "the Scenario model (or the registry) at import time; use it inside functions") \
            from None


def active(scenario) -> list[Study]:
    """The studies this scenario has a section for, in registry order."""
    return [s for s in studies() if s.active(scenario)]


def by_name(name: str) -> Study:
    for s in studies():
        if name in (s.name, s.cli_name):
            return s
    raise KeyError(f"no study {name!r}; the studies are {', '.join(s.cli_name for s in studies())}")


def call_every(scenario, part: str, hook: str, *args) -> list:
    """`hook(scenario, *args)` of part `part` of every study that defines it, part of the scenario or not,
    in registry order: for the hooks that fill a study's signals in the foundation's frames in every run
    (a study's own `hook` says what it does when its section is absent)."""
    return [fn(scenario, *args) for s in studies() if (fn := getattr(s.part(part), hook, None)) is not None]


def call(scenario, part: str, hook: str, *args) -> list:
    """`hook(scenario, *args)` of part `part` of every active study that defines it, in registry order;
    the results in a list."""
    out = []
    for s in active(scenario):
        fn = getattr(s.part(part), hook, None)
        if fn is not None:
            out.append(fn(scenario, *args))
    return out
