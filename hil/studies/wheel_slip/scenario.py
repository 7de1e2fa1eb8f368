"""The scenario section [wheel_slip] (seed 001: the reference governor against wheel slip) and the
governor's parameters it sets in each BECU.

    [wheel_slip]
    governor = true          # false: the same run without the governor (the paper's comparison)
    slip_max_mps = 0.1       # s̄ of eq. (8)
    margin = 0.005           # torque margin, fraction of τ̄
    paper_figure = "fig8"    # print the paper's figures next to ours: "fig8" or "fig9"

The section makes the run report the study's KPIs (kpis.py) and figure (plots.py) for any BECU control
law; the governor itself needs `[becu] control = "decel"` (eq. (16)) and the slip-speed adhesion curve
(`[plant] adhesion = "slip_speed"`), from which its slip inclusion is built.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field

from firmware_py.becu import BecuParams
from firmware_py.governor import GovernorParams, governor_params
from firmware_py.pi import PIParams
from hil.scenario.base import Strict
from hil.scenario.params import plant_params
from plant_sim.adhesion import mu_slip_speed_scalar, mu_slip_speed_slope_scalar
from plant_sim.params import PlantParams

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario


class WheelSlipSpec(Strict):
    """[wheel_slip] of a scenario file."""

    governor: bool = Field(False, description="true: each BECU's reference governor (eq. 9) limits the "
                                              "deceleration reference; false: the run without it")
    slip_max_mps: Annotated[float, Field(gt=0, le=1, description="s̄ of eq. (8) [m/s]")] = 0.1
    margin: Annotated[float, Field(ge=0, lt=0.5, description="torque margin, fraction of τ̄")] = 0.005
    paper_figure: Literal["fig8", "fig9"] | None = Field(
        None, description="the paper figure this scenario redoes: its published numbers are printed next "
                          "to ours in the run summary")
    steady_state_window_s: Annotated[float, Field(
        gt=0, le=600, description="steady state = the last this many seconds of the braking window (at "
                                  "most its second half) [s]")] = 10.0


def check(scenario: Scenario) -> None:
    ws = scenario.wheel_slip
    if ws.governor and scenario.becu.control != "decel":
        raise ValueError("wheel_slip.governor = true needs becu.control = 'decel' (the governor limits the "
                         "reference of the deceleration PI, eq. (16))")
    if ws.governor and scenario.plant.adhesion != "slip_speed":
        raise ValueError("wheel_slip.governor = true needs plant.adhesion = 'slip_speed' (the governor's "
                         "slip inclusion is built from that curve family)")
    if ws.governor and ws.slip_max_mps >= scenario.plant.slip_peak_mps:
        raise ValueError(f"wheel_slip.slip_max_mps {ws.slip_max_mps} must lie below the adhesion peak "
                         f"plant.slip_peak_mps {scenario.plant.slip_peak_mps} (stable-slip region)")


def _figure(value):
    """railhil 0.1's paper_figure values named the paper: "<paper>_fig8" -> "fig8"."""
    return value.rpartition("_")[2] if isinstance(value, str) else value


#: railhil 0.1's keys of this study (hil.scenario.load reads them for one release)
LEGACY_KEYS = {
    "becu.governor": "wheel_slip.governor",
    "becu.slip_max_mps": "wheel_slip.slip_max_mps",
    "becu.governor_margin": "wheel_slip.margin",
    "report.paper_figure": ("wheel_slip.paper_figure", _figure),
    "report.steady_state_window_s": "wheel_slip.steady_state_window_s",
}


def becu_governor_params(scenario: Scenario, pp: PlantParams, car: int, pi: PIParams) -> GovernorParams:
    """The governor's model of car `car` (1-based) from the scenario's plant: F̄ = μ(s̄) N and the friction
    slope bounds f' ∈ [μ'(s̄) N, μ'(0) N] of seed 001's concave μ(s) below its peak (the cone of Fig. 5),
    cylinder Tp, brake lines (eq. 6), the BECU's PI (eq. 16) and cycle."""
    ws = scenario.wheel_slip
    mass = pp.train.masses_kg[car - 1]
    normal = mass * pp.train.g_mps2                                    # N = M g, eq. (1a) seed 001
    mu_pk, s_pk = pp.adhesion.slip_speed_peak
    bp = pp.brake
    return governor_params(
        dt_s=BecuParams().cycle_us * 1e-6, mass_kg=mass, wheel_radius_m=pp.train.wheel_radius_m,
        inertia_kgm2=pp.train.wheel_inertia_kgm2,
        friction_max_N=mu_slip_speed_scalar(ws.slip_max_mps, mu_pk, s_pk) * normal,
        slope_lo_N_per_mps=mu_slip_speed_slope_scalar(ws.slip_max_mps, mu_pk, s_pk) * normal,
        slope_hi_N_per_mps=mu_slip_speed_slope_scalar(0.0, mu_pk, s_pk) * normal, tp_s=bp.tp_s,
        alpha_squeeze=bp.alpha_squeeze_Nm_per_Pa, beta_squeeze=bp.beta_squeeze_Nm,
        alpha_release=bp.alpha_release_Nm_per_Pa, beta_release=bp.beta_release_Nm, pi=pi,
        margin_frac=ws.margin)


def becu_params(scenario: Scenario, car: int, kw: dict) -> None:
    """The governor in each BECU (hil.scenario.params.becu_params): built on the BECU's deceleration PI."""
    if scenario.wheel_slip.governor:
        kw["governor"] = becu_governor_params(scenario, plant_params(scenario), car, kw["decel_pi"])
