"""A WSP test programme (a TOML file, programmes/wsp_test.toml): the base scenario, the initial speeds, the
rail conditions, the strategies and the metrics' thresholds, loaded and checked; and the runs it expands
to, each a validated scenario.

    name = "wsp_test"
    base = "../scenarios/default.toml"     # relative to the programme file
    speeds_kmh = [60.0, 90.0, 120.0]
    max_duration_s = 240.0
    nominal_decel_mps2 = 1.0               # S_n = v0² / (2 a_n) places `from_fraction` segments
    [set]                                  # scenario overrides at every run (keys as `railhil run --set`)
    [metrics]                              # hil.typetest.metrics.MetricParams
    [reference]                            # the dry rail of the demand: rail = [...]
    [conditions.NAME]                      # description, rail = [{ from_m | from_fraction, condition | theta,
                                           #                        transition_m }]
    [strategies.NAME]                      # description, set = { KEY = VALUE, ... }

A bad file is a ProgrammeError naming the file and the key.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from hil.errors import ScenarioError
from hil.resources import programmes_dir, read_toml
from hil.scenario.load import apply_set, load_scenario, parse_scenario
from hil.scenario.model import ScenarioBase as Scenario
from hil.scenario.params import mps
from hil.typetest.metrics import MetricParams

REFERENCE = "reference"           # the dry run's condition name in run lists and folders


class ProgrammeError(ScenarioError):
    """A WSP test programme that cannot be used (exit 2)."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Segment(_Strict):
    from_m: float | None = None
    from_fraction: Annotated[float, Field(ge=-10, le=10)] | None = None
    condition: Literal["extra_dry", "dry", "wet", "extra_wet"] | None = None
    theta: tuple[float, float, float] | None = None
    transition_m: Annotated[float, Field(ge=0)] = 0.0

    @model_validator(mode="after")
    def _one_each(self) -> Segment:
        if (self.from_m is None) == (self.from_fraction is None):
            raise ValueError("give exactly one of 'from_m' (metres) or 'from_fraction' (of S_n)")
        if (self.condition is None) == (self.theta is None):
            raise ValueError("give exactly one of 'condition' (a name) or 'theta' ([θ1, θ2, θ3])")
        return self

    def at_speed(self, nominal_m: float) -> dict:
        """The scenario's [track] rail entry, its position in metres at a speed whose S_n is nominal_m."""
        x = self.from_m if self.from_m is not None else self.from_fraction * nominal_m
        entry: dict = {"from_m": float(x), "transition_m": self.transition_m}
        if self.condition is not None:
            entry["condition"] = self.condition
        else:
            entry["theta"] = list(self.theta)
        return entry


class Condition(_Strict):
    description: str = ""
    rail: list[Segment] = Field(min_length=1)


class Strategy(_Strict):
    description: str = ""
    set: dict[str, object] = Field(default_factory=dict)
    # judged against another strategy's dry demand: for a strategy that limits its own braking (a governor
    # designed for the least adherent rail brakes below the demand on dry rail too, so its own dry run is
    # not the demand it was asked to meet)
    demand_from: str | None = None


class Metrics(_Strict):
    slide_threshold_mps: Annotated[float, Field(ge=0, le=50)] = 0.5
    rotation_threshold_mps: Annotated[float, Field(ge=0, le=50)] = 1.0
    moving_mps: Annotated[float, Field(ge=0, le=100)] = 3.0
    cylinder_volume_l: Annotated[float, Field(gt=0, le=1000)] = 12.0
    atmosphere_Pa: Annotated[float, Field(gt=0, le=2e5)] = 101_325.0


class ProgrammeSpec(_Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    base: str
    speeds_kmh: list[Annotated[float, Field(gt=0, le=400)]] = Field(min_length=1)
    max_duration_s: Annotated[float, Field(gt=0, le=3600)] = 240.0
    nominal_decel_mps2: Annotated[float, Field(gt=0, le=5)] = 1.0
    set: dict[str, object] = Field(default_factory=dict)
    metrics: Metrics = Field(default_factory=Metrics)
    reference: Condition
    conditions: dict[str, Condition] = Field(min_length=1)
    strategies: dict[str, Strategy] = Field(min_length=1)

    @model_validator(mode="after")
    def _names(self) -> ProgrammeSpec:
        if REFERENCE in self.conditions:
            raise ValueError(f"a condition may not be named {REFERENCE!r} (the dry run's name)")
        if len(set(self.speeds_kmh)) != len(self.speeds_kmh):
            raise ValueError(f"speeds_kmh has a speed twice: {self.speeds_kmh}")
        for name, st in self.strategies.items():
            src = self.strategies.get(st.demand_from) if st.demand_from is not None else None
            if st.demand_from is not None and (src is None or st.demand_from == name
                                               or src.demand_from is not None):
                own = ", ".join(n for n, o in self.strategies.items() if o.demand_from is None)
                raise ValueError(f"strategies.{name}.demand_from = {st.demand_from!r}: must name another "
                                 f"strategy of the programme that takes its own demand (one of {own})")
        return self


@dataclass(frozen=True)
class Programme:
    path: Path
    spec: ProgrammeSpec
    base: Scenario

    @property
    def metric_params(self) -> MetricParams:
        return MetricParams(**self.spec.metrics.model_dump())

    def demand_source(self, strategy: str) -> str:
        """The strategy whose dry run gives `strategy` its demand (itself, or its `demand_from`)."""
        return self.spec.strategies[strategy].demand_from or strategy


@dataclass(frozen=True)
class RunSpec:
    """One run of a programme: a strategy on a condition (or the dry reference) at a speed."""

    strategy: str
    condition: str
    speed_kmh: float
    scenario: Scenario

    @property
    def folder(self) -> str:
        return f"{self.strategy}/{self.condition}-{self.speed_kmh:g}kmh"


def default_programme() -> Path:
    return programmes_dir() / "wsp_test.toml"


def _describe(exc: ValidationError) -> str:
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
    more = f" (and {len(exc.errors()) - 1} more)" if len(exc.errors()) > 1 else ""
    if err["type"] == "extra_forbidden":
        return f"key '{loc}' is not a programme key{more}"
    if err["type"] == "missing":
        return f"key '{loc}' is missing{more}"
    return f"key '{loc}' = {err.get('input')!r}: {err['msg']}{more}"


def load_programme(path: str | Path | None = None) -> Programme:
    """The programme at `path` (default: the shipped programmes/wsp_test.toml), checked; its base scenario
    loaded.  Every run's scenario is validated by `runs`."""
    path = Path(path) if path is not None else default_programme()
    data = read_toml(path, ProgrammeError, str(path), "no such programme file")
    try:
        spec = ProgrammeSpec.model_validate(data)
    except ValidationError as exc:
        raise ProgrammeError(f"{path}: {_describe(exc)}") from None
    base_path = (path.parent / spec.base).resolve()
    try:
        base = load_scenario(base_path)
    except ScenarioError as exc:
        raise ProgrammeError(f"{path}: base: {exc}") from None
    return Programme(path, spec, base)


def _scenario(prog: Programme, strategy: str, condition: str, speed_kmh: float) -> Scenario:
    spec = prog.spec
    rail = spec.reference if condition == REFERENCE else spec.conditions[condition]
    v0 = mps(speed_kmh)
    nominal_m = v0 * v0 / (2.0 * spec.nominal_decel_mps2)
    data = json.loads(json.dumps(prog.base.model_dump(mode="json")))
    where = f"{prog.path}"
    sets = [(k, v, f"{where} [set]") for k, v in spec.set.items()]
    sets += [(k, v, f"{where} [strategies.{strategy}] set") for k, v in spec.strategies[strategy].set.items()]
    sets += [("train.initial_speed_kmh", float(speed_kmh), f"{where} speeds_kmh"),
             ("max_duration_s", spec.max_duration_s, f"{where} max_duration_s"),
             ("track.rail", [s.at_speed(nominal_m) for s in rail.rail],
              f"{where} [{'reference' if condition == REFERENCE else 'conditions.' + condition}] rail")]
    for key, value, source in sets:
        try:
            apply_set(data, key, value, source)
        except ScenarioError as exc:
            raise ProgrammeError(str(exc).replace(": --set ", ": ", 1)) from None
    try:
        return parse_scenario(data, f"{where}: strategy {strategy}, {condition}, {speed_kmh:g} km/h")
    except ScenarioError as exc:
        raise ProgrammeError(str(exc)) from None


def runs(prog: Programme, strategies: list[str] | None = None, speeds: list[float] | None = None,
         conditions: list[str] | None = None) -> list[RunSpec]:
    """Every run: per strategy and speed the dry reference, then each condition.  `strategies`, `speeds`
    and `conditions` select (each must be in the programme); a chosen strategy judged against another's
    demand (`demand_from`) brings that strategy's dry references along."""
    spec = prog.spec
    chosen = _select("strategy", strategies, list(spec.strategies), prog.path)
    kinds = _select("condition", conditions, list(spec.conditions), prog.path)
    if speeds:
        missing = [s for s in speeds if s not in spec.speeds_kmh]
        if missing:
            raise ProgrammeError(f"{prog.path}: --speed {missing[0]:g}: the programme's speeds_kmh are "
                                 f"{', '.join(f'{s:g}' for s in spec.speeds_kmh)}")
    at = [s for s in spec.speeds_kmh if not speeds or s in speeds]
    out = []
    sources = [prog.demand_source(s) for s in chosen]
    for strategy in dict.fromkeys(s for s in sources if s not in chosen):
        out += [RunSpec(strategy, REFERENCE, v, _scenario(prog, strategy, REFERENCE, v)) for v in at]
    for strategy in chosen:
        for speed in at:
            for condition in [REFERENCE, *kinds]:
                out.append(RunSpec(strategy, condition, speed, _scenario(prog, strategy, condition, speed)))
    return out


def _select(what: str, given: list[str] | None, known: list[str], path: Path) -> list[str]:
    if not given:
        return known
    seen = []
    for name in given:
        if name not in known:
            raise ProgrammeError(f"{path}: --{what} {name}: no such {what}; the programme has "
                                 f"{', '.join(known)}")
        if name in seen:
            raise ProgrammeError(f"--{what} {name}: given twice")
        seen.append(name)
    return seen
