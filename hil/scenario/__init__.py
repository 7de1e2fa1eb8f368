"""Scenarios: the TOML model, its validation and loading.

`load_scenario(path)` reads and validates a file; `parse_scenario(data)` a table; `apply_set` and
`parse_set` are `railhil run --set KEY=VALUE`.  Every error is one ScenarioError line naming the file,
the key, the value and what is allowed.
"""

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
    ReportSpec,
    Scenario,
    SecOcSpec,
    SensorSpec,
    TrackSpec,
    TrainSpec,
    apply_set,
    load_scenario,
    parse_scenario,
    parse_set,
    secoc_keys,
)

__all__ = ["MAX_CARS", "RAIL_CONDITION_NAMES", "BcuSpec", "BecuSpec", "BusSpec", "CurvePoint", "DeskEvent",
           "GradientPoint", "MessageTiming", "NodeTiming", "PlantSpec", "RailRow", "RailSegment",
           "RealtimeSpec", "ReportSpec", "Scenario", "SecOcSpec", "SensorSpec", "TrackSpec", "TrainSpec",
           "apply_set", "load_scenario", "parse_scenario", "parse_set", "secoc_keys"]
