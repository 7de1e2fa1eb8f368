"""The scenario section [precise_stop] (seed 002 §VII: stopping at the desk's target point) and the
stopping function's parameters it sets in the BCU.

    [precise_stop]
    method = "pi"               # "adaptive" (Fig. 2), "adaptive_diff" (Fig. 3: with the differentiation
                                # unit) or "pi" (the modern baseline: curve tracking, PI + feed-forward),
                                # in the BCU; "plc": a PLC in the DESK's place sets the brake valve
    planned_decel_mps2 = 0.6    # the braking curve's planned deceleration a_p [m/s²]

The target stop point is a `[[desk]]` event's `target_stop_m`; `[track] balises` re-anchor the BCU's
odometer.  Braking starts where a stop at a_p ends at the target (at once, and harder, when it is nearer).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field

from firmware_py.stopping import StoppingParams
from hil.errors import ScenarioError
from hil.scenario.base import Strict
from hil.scenario.load import DROP
from hil.scenario.params import RunParams, bcu_params

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario


PLC = "plc"           # the method of a PLC in the DESK's place (the BCU's function not fitted)


class PreciseStopSpec(Strict):
    """[precise_stop] of a scenario file."""

    method: Literal["adaptive", "adaptive_diff", "pi", "plc"] = Field(
        "pi", description="the paper's adaptive search without (adaptive, Fig. 2) or with the "
                          "differentiation unit (adaptive_diff, Fig. 3), or the modern baseline pi (curve "
                          "tracking, PI + feed-forward), each in the BCU; or plc: a PLC in the DESK's place "
                          "(a device, docs/plc-over-opcua.md) stops the train with the driver's brake valve "
                          "(DESK_CMD.BrakeValve) and the BCU's own function is not fitted")
    planned_decel_mps2: Annotated[float, Field(
        gt=0, le=5, description="the braking curve's planned deceleration a_p [m/s²]")] = 0.6


def check(scenario: Scenario) -> None:
    ps = scenario.precise_stop
    if not any(e.target_stop_m is not None for e in scenario.desk):
        raise ValueError(f"precise_stop (method '{ps.method}') needs a [[desk]] event with target_stop_m "
                         f"(the target stop point, track position [m])")
    full = bcu_params(scenario).step_decel_mps2[7]
    if ps.planned_decel_mps2 > full:
        raise ValueError(f"precise_stop.planned_decel_mps2 {ps.planned_decel_mps2} is above the full service "
                         f"deceleration {full} m/s² (bcu.step_decel_mps2 step 7)")


def _method(value):
    """railhil 0.1's "none" meant the function was not fitted: no section."""

    return DROP if value == "none" else value


#: railhil 0.1's keys of this study (hil.scenario.load reads them for one release)
LEGACY_KEYS = {
    "bcu.stopping": ("precise_stop.method", _method),
    "bcu.stop_decel_mps2": "precise_stop.planned_decel_mps2",
}


def stopping_params(scenario: Scenario, run: RunParams) -> StoppingParams | None:
    """The stopping function of the BCU (nodes.py fits it), braking at most at the BCU's full service step:
    the odometer's reference point is the train's front passing the start position at t = 0.  None with
    method = "plc": the stopping program runs on a PLC in the DESK's place, and the BCU obeys its brake
    valve."""
    full = run.bcu.step_decel_mps2[7]
    ps = scenario.precise_stop
    if ps.method == PLC:
        if "DESK" not in scenario.devices:
            raise ScenarioError("precise_stop.method = 'plc': the stopping program runs on a PLC in the "
                                "DESK's place; give the device (--device DESK=FILE, e.g. "
                                "examples/plc_precise_stop/plc_precise_stop.toml, or [devices.DESK])")
        return None
    return StoppingParams(
        method=ps.method, planned_decel_mps2=ps.planned_decel_mps2, max_decel_mps2=full, hold_decel_mps2=full,
        start_position_m=run.start_position_m, start_time_us=0,
        pi=dataclasses.replace(StoppingParams().pi, out_max=full), balises=bool(run.balises))
