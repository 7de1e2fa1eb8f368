"""Scenarios: the TOML model, its validation and loading, and the parameters a scenario sets.

- `model`    the foundation's sections and `Scenario` (those plus one section per study)
- `faults`   the `[[faults]]` entries
- `load`     `load_scenario(path)`, `parse_scenario(data)`, `--set KEY=VALUE`, keys of earlier releases
- `params`   scenario -> parameters of the plant and the controllers: the one place
- `registry` the studies as the foundation knows them
- `base`     the base of every section (unknown keys are errors, values frozen, no NaN)

Every error is one ScenarioError line naming the file, the key, the value and what is allowed.
"""

from hil.scenario.load import RailhilDeprecation, apply_set, load_scenario, parse_scenario, parse_set
from hil.scenario.model import (
    MAX_CARS,
    RAIL_CONDITION_NAMES,
    BcuSpec,
    BecuSpec,
    BusSpec,
    CurvePoint,
    DeskEvent,
    GradientPoint,
    MessageTiming,
    NodeTiming,
    PlantSpec,
    RailRow,
    RailSegment,
    RealtimeSpec,
    ScenarioBase,
    SecOcSpec,
    SensorSpec,
    TraceSpec,
    TrackSpec,
    TrainSpec,
    scenario_model,
)

__all__ = ["MAX_CARS", "RAIL_CONDITION_NAMES", "BcuSpec", "BecuSpec", "BusSpec", "CurvePoint", "DeskEvent",
           "GradientPoint", "MessageTiming", "NodeTiming", "PlantSpec", "RailRow", "RailSegment",
           "RailhilDeprecation", "RealtimeSpec", "Scenario", "ScenarioBase", "SecOcSpec", "SensorSpec",
           "TraceSpec", "TrackSpec", "TrainSpec", "apply_set", "load_scenario", "parse_scenario", "parse_set",
           "scenario_model"]


def __getattr__(name: str):
    # `Scenario` is built on first use, from the study registry (hil.scenario.model.scenario_model)
    if name == "Scenario":
        return scenario_model()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
