"""Scenario files: TOML, validated at load with pydantic.

A bad key or value gives one ScenarioError line naming the file, the key, the value and what is
allowed (exit code 2 at the CLI).  The README documents the format; scenarios/default.toml is the
reference example.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from hil.errors import ScenarioError

MAX_CARS = 8
RAIL_CONDITION_NAMES = ("extra_dry", "dry", "wet", "extra_wet")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class TrainSpec(_Strict):
    cars: Annotated[int, Field(ge=1, le=MAX_CARS, description="number of cars, each with a BECU")] = 6
    mass_kg: Annotated[float, Field(gt=1000, le=200_000)] = 40_000.0
    masses_kg: list[Annotated[float, Field(gt=1000, le=200_000)]] | None = None
    initial_speed_kmh: Annotated[float, Field(ge=0, le=400)] = 90.0
    start_position_m: float = 0.0

    @model_validator(mode="after")
    def _masses_match_cars(self) -> TrainSpec:
        if self.masses_kg is not None and len(self.masses_kg) != self.cars:
            raise ValueError(f"masses_kg has {len(self.masses_kg)} entries for {self.cars} cars")
        return self

    def masses(self) -> tuple[float, ...]:
        return tuple(self.masses_kg) if self.masses_kg is not None else (self.mass_kg,) * self.cars


class RailSegment(_Strict):
    from_m: float
    condition: Literal["extra_dry", "dry", "wet", "extra_wet"] | None = None
    theta: tuple[float, float, float] | None = None
    transition_m: Annotated[float, Field(ge=0)] = 0.0   # blend from the previous segment over this length

    @model_validator(mode="after")
    def _one_of(self) -> RailSegment:
        if (self.condition is None) == (self.theta is None):
            raise ValueError("give exactly one of 'condition' (a name) or 'theta' ([θ1, θ2, θ3])")
        return self


class GradientPoint(_Strict):
    from_m: float
    permille: Annotated[float, Field(ge=-60, le=60)]


class CurvePoint(_Strict):
    from_m: float
    radius_m: Annotated[float, Field(ge=0)]   # 0 = straight


class RailRow(_Strict):
    x_m: float
    theta: tuple[Annotated[float, Field(gt=0)], Annotated[float, Field(ge=0)], Annotated[float, Field(gt=0)]]


class TrackSpec(_Strict):
    rail: list[RailSegment] = Field(default_factory=lambda: [RailSegment(from_m=0.0, condition="dry")])
    # θ(x) as a table instead of segments: linear between rows, constant beyond the ends
    rail_table: list[RailRow] | None = None
    gradient: list[GradientPoint] = Field(default_factory=list)
    curves: list[CurvePoint] = Field(default_factory=list)

    @field_validator("rail", "gradient", "curves")
    @classmethod
    def _increasing(cls, v):
        xs = [p.from_m for p in v]
        if any(b <= a for a, b in zip(xs, xs[1:], strict=False)):
            raise ValueError(f"from_m must increase strictly, got {xs}")
        return v

    @field_validator("rail")
    @classmethod
    def _nonempty(cls, v):
        if not v:
            raise ValueError("needs at least one segment")
        return v

    @field_validator("rail_table")
    @classmethod
    def _table_increasing(cls, v):
        if v is not None:
            xs = [r.x_m for r in v]
            if not xs or any(b <= a for a, b in zip(xs, xs[1:], strict=False)):
                raise ValueError(f"needs rows with strictly increasing x_m, got {xs}")
        return v


class DeskEvent(_Strict):
    at_s: Annotated[float, Field(ge=0)]
    brake_step: Annotated[int, Field(ge=0, le=7)] | None = None
    emergency: bool | None = None
    target_stop_m: float | None = None


class RealtimeSpec(_Strict):
    interface: str = "udp_multicast"
    channel: str | None = None        # None: a channel of this run's own (udp_multicast group/port)
    # simulated seconds per wall second: 1.0 = real time, 0.5 = half speed (for slow or loaded hosts)
    speed: Annotated[float, Field(gt=0, le=1)] = 1.0


class Scenario(_Strict):
    name: str = "unnamed"
    description: str = ""
    seed: int = 0
    max_duration_s: Annotated[float, Field(gt=0, le=3600)] = 120.0
    end_after_standstill_s: Annotated[float, Field(ge=0, le=60)] = 1.0
    dbc: str | None = None            # path relative to the scenario file; default dbc/train_brake.dbc
    train: TrainSpec = Field(default_factory=TrainSpec)
    track: TrackSpec = Field(default_factory=TrackSpec)
    desk: list[DeskEvent] = Field(default_factory=list)
    realtime: RealtimeSpec = Field(default_factory=RealtimeSpec)

    @field_validator("desk")
    @classmethod
    def _sorted(cls, v):
        ts = [e.at_s for e in v]
        if ts != sorted(ts):
            raise ValueError(f"desk events must be in time order, got at_s {ts}")
        return v


def _describe(err: dict) -> str:
    loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
    value = err.get("input")
    if err["type"] == "extra_forbidden":
        return f"key '{loc}' is not a scenario key"
    if err["type"] == "missing":
        return f"key '{loc}' is missing"
    shown = repr(value)
    if len(shown) > 60:
        shown = shown[:57] + "..."
    return f"key '{loc}' = {shown}: {err['msg']}"


def parse_scenario(data: dict, source: str = "<scenario>") -> Scenario:
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise ScenarioError(f"{source}: {_describe(errors[0])}{more}") from None


def load_scenario(path: str | Path, overrides: dict | None = None) -> Scenario:
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such scenario file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: cannot read: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None
    for key, value in (overrides or {}).items():
        data[key] = value
    scenario = parse_scenario(data, str(path))
    if scenario.dbc is not None:
        dbc_path = (path.parent / scenario.dbc).resolve()
        scenario = scenario.model_copy(update={"dbc": str(dbc_path)})
    return scenario
