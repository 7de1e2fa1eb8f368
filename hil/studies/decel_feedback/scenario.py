"""The scenario section [decel_feedback] (seed 004 §5: deceleration feedback in the BCU) and the
function's parameters it sets in the BCU.

    [decel_feedback]
    closed_loop = true        # false: the function monitors only (the open-loop BCU, for comparison)
    friction_set = "bench"    # the friction-coefficient set μ(v, t): "bench" (the plant's pad model on the
                              # brake-disc bench, needs [plant] pad_friction = true) or "none" (trim alone)
    friction_set_fill = "fraction"   # how untested speed classes are filled: "fraction" or "time"
    tq_s = 0.1                # T_q of eq. (33) [s]

Absent: the BCU has no deceleration feedback.  The KPIs and the figure are the same for both loops.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field

from firmware_py.decel_feedback import FeedbackParams, FrictionSet
from hil.scenario.base import Strict
from hil.scenario.params import RunParams
from plant_sim.padbench import BenchParams, coefficient_set
from plant_sim.params import PadParams

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario


class DecelFeedbackSpec(Strict):
    """[decel_feedback] of a scenario file."""

    closed_loop: bool = Field(True, description="true: the BCU corrects the pressure (φ, eq. 34); false: the "
                                                "function monitors only (the open-loop comparison)")
    friction_set: Literal["bench", "none"] = Field(
        "bench", description="the friction-coefficient set μ(v, t): built from the plant's pad model on the "
                             "brake-disc bench (needs plant.pad_friction) or none (the loop's trim alone)")
    friction_set_fill: Literal["fraction", "time"] = Field(
        "fraction", description="how the set's untested speed classes are filled")
    tq_s: Annotated[float, Field(gt=0, le=5, description="T_q of eq. (33) [s]")] = 0.1


def check(scenario: Scenario) -> None:
    if scenario.decel_feedback.friction_set == "bench" and not scenario.plant.pad_friction:
        raise ValueError("decel_feedback.friction_set = 'bench' builds the set from the plant's pad model: "
                         "it needs plant.pad_friction = true (or decel_feedback.friction_set = 'none')")


#: railhil 0.1's keys of this study (hil.scenario.load reads them for one release)
LEGACY_KEYS = {
    "bcu.decel_feedback": "decel_feedback.closed_loop",
    "bcu.friction_set": "decel_feedback.friction_set",
    "bcu.friction_set_fill": "decel_feedback.friction_set_fill",
    "bcu.feedback_tq_s": "decel_feedback.tq_s",
}


@functools.lru_cache(maxsize=8)
def _bench_set(pad: PadParams, bench: BenchParams, method: str) -> FrictionSet:
    cs = coefficient_set(pad, bench, method)
    return FrictionSet(cs.speeds_kmh, cs.dt_s, cs.values)


def friction_set(scenario: Scenario, run: RunParams) -> FrictionSet | None:
    """The BCU's friction-coefficient set (seed 004 §4.2, §6.3): the plant's pad model on the brake-disc
    bench at the tested speed classes, braked at the full service step, filled to 10 km/h × 100 ms."""
    pad = run.plant.pad
    if scenario.decel_feedback.friction_set == "none" or pad is None:
        return None
    tp = run.plant.train
    bench = BenchParams(decel_mps2=run.bcu.step_decel_mps2[7], wheel_radius_m=tp.wheel_radius_m,
                        car_mass_kg=sum(tp.masses_kg) / len(tp.masses_kg))
    return _bench_set(pad, bench, scenario.decel_feedback.friction_set_fill)


def feedback_params(scenario: Scenario, run: RunParams) -> FeedbackParams:
    """The deceleration feedback of the BCU (nodes.py fits it)."""
    df = scenario.decel_feedback
    return FeedbackParams(enabled=df.closed_loop, tq_s=df.tq_s, friction_set=friction_set(scenario, run))
