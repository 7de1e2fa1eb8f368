"""The scenario's `[[faults]]` entries: what may be injected, declared and validated as scenario data.

The injection itself is hil.safety.injection (the lockstep bus, the nodes and the plant apply it);
its module docstring describes every kind.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, model_validator

from hil.scenario.base import Strict

MESSAGE_THREATS = ("repetition", "deletion", "insertion", "resequencing", "corruption", "delay", "masquerade")
NODE_FAULTS = ("babbling", "bus_off")
SOURCE_FAULTS = ("stuck", "sensor")
FAULT_KINDS = MESSAGE_THREATS + NODE_FAULTS + SOURCE_FAULTS
#: sensor name of a `sensor` fault -> the PLANT_CARn_SENSORS signal it produces (SI unit of `value`)
SENSOR_SIGNALS = {"wheel_speed": "AxleSpeed", "pressure": "CylPressure", "accelerometer": "AccelLong"}


class FaultSpec(Strict):
    """One `[[faults]]` entry of a scenario."""

    kind: Literal["repetition", "deletion", "insertion", "resequencing", "corruption", "delay",
                  "masquerade", "babbling", "bus_off", "stuck", "sensor"]
    from_s: Annotated[float, Field(ge=0)]
    to_s: Annotated[float, Field(gt=0)]
    message: str | None = None              # message threats and stuck: the DBC message
    node: str | None = None                 # babbling / bus_off: the node
    probability: Annotated[float, Field(ge=0, le=1)] = 1.0
    delay_ms: Annotated[float, Field(ge=0, le=10_000)] = 0.0
    signal: str | None = None               # masquerade / stuck: the signal the rogue frame sets ...
    value: float | None = None              # ... to this value (stuck / sensor: see the module docstring)
    frame_id: Annotated[int, Field(ge=0, le=0x7FF)] = 0x000   # babbling: the identifier it floods
    car: Annotated[int, Field(ge=1, le=8)] | None = None      # sensor: the car (1-based)
    sensor: Literal["wheel_speed", "pressure", "accelerometer"] | None = None
    mode: Literal["stuck", "bias"] | None = None              # sensor: stuck reading or added bias

    @model_validator(mode="after")
    def _consistent(self) -> FaultSpec:
        if self.value is not None and not math.isfinite(self.value):
            raise ValueError(f"value {self.value} must be a finite number")
        if self.to_s <= self.from_s:
            raise ValueError(f"to_s {self.to_s} must be after from_s {self.from_s}")
        if self.kind in MESSAGE_THREATS and not self.message:
            raise ValueError(f"a {self.kind} fault needs 'message', the DBC message it attacks")
        if self.kind in NODE_FAULTS and not self.node:
            raise ValueError(f"a {self.kind} fault needs 'node'")
        if self.kind == "masquerade" and (self.signal is None or self.value is None):
            raise ValueError("a masquerade fault needs 'signal' and 'value' (what the rogue frame claims)")
        if self.kind in ("delay",) and self.delay_ms <= 0:
            raise ValueError("a delay fault needs delay_ms > 0")
        if self.kind == "stuck" and (not self.message or self.signal is None):
            raise ValueError("a stuck fault needs 'message' and 'signal' (and optionally 'value'; without it "
                             "the signal freezes at its last value before from_s)")
        if self.kind == "sensor":
            if self.car is None or self.sensor is None or self.mode is None:
                raise ValueError("a sensor fault needs 'car', 'sensor' (wheel_speed, pressure, "
                                 "accelerometer) and 'mode' (stuck, bias)")
            if self.mode == "bias" and self.value is None:
                raise ValueError("a sensor fault with mode = 'bias' needs 'value', the bias in the sensor's "
                                 "SI unit (rad/s, Pa, m/s²)")
        if self.kind in SOURCE_FAULTS and self.probability != 1.0:
            raise ValueError(f"a {self.kind} fault is not random: 'probability' applies to message "
                             f"threats only")
        if self.kind != "sensor" and (self.car, self.sensor, self.mode) != (None, None, None):
            raise ValueError("'car', 'sensor' and 'mode' belong to sensor faults only")
        return self
