"""The scenario section [wheel_slip] (seed 001: the reference governor against wheel slip) and the
governor's parameters of each BECU (`reference_governor_params`; nodes.py fits it).

    [wheel_slip]
    governor = true          # false: the same run without the governor (the paper's comparison)
    slip_max_mps = 0.1       # s̄ of eq. (8)
    margin = 0.005           # torque margin, fraction of τ̄
    paper_figure = "fig8"    # print the paper's figures next to ours: "fig8" or "fig9"
    # with [plant] adhesion = "track" (seed 000's curves, which move with the speed):
    design_condition = "extra_wet"   # the least adherent rail the governor is designed for
    slip_fraction = 0.5      # s̄(v) = this x the peak slip speed of that rail at v
    band_mps = 0.5           # the governor's model is scheduled on SpeedEst in bands this wide

The section makes the run report the study's KPIs (kpis.py) and figure (plots.py) for any BECU control
law; the governor itself needs `[becu] control = "decel"` (eq. (16)).  Its slip inclusion is built from
the plant's adhesion curve family: seed 001's slip-speed curve (`[plant] adhesion = "slip_speed"`, s̄ =
slip_max_mps), or seed 000's rail curves (`"track"`), where the peak's slip speed σ°(v)·v and height μ°(v)
move with the speed (eq. (2) seed 000), so s̄ and the cone are scheduled on the car's speed estimate
(firmware_py.governor.GovernorSchedule).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, Literal

import numpy as np
from pydantic import Field

from firmware_py.becu import BecuParams
from firmware_py.governor import GovernorParams, GovernorSchedule, ReferenceGovernorParams, governor_params
from firmware_py.pi import PIParams
from hil.scenario.base import Strict
from hil.scenario.params import RunParams
from plant_sim.adhesion import V_EPS_MPS, mu_slip_speed_scalar, mu_slip_speed_slope_scalar, mu_theta_scalar
from plant_sim.dynamics import car_constants
from plant_sim.params import RAIL_CONDITIONS, RAIL_PEAKS, AdhesionParams, PlantParams

# the cone's slope bounds on seed 000's curves: f' sampled at this many slip speeds over [0, s̄] (the lower
# bound; the upper is infinite, the curves rising as √σ from σ = 0, so the fastest friction lag a̲ = 0)
SLOPE_SAMPLES = 32
# the schedule covers the initial speed with this margin [m/s] (a train pushed by a gradient runs faster)
SCHEDULE_MARGIN_MPS = 5.0

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
    design_condition: Literal["extra_dry", "dry", "wet", "extra_wet"] = Field(
        "extra_wet", description="with plant.adhesion = 'track': the least adherent rail condition the "
                                 "governor is designed for; its cone covers that rail's curve and every "
                                 "more adherent one of seed 000's")
    slip_fraction: Annotated[float, Field(
        gt=0, lt=1, description="with plant.adhesion = 'track': s̄(v) = this fraction of the design rail's "
                                "peak slip speed σ°(v)·v (eq. (2) seed 000)")] = 0.5
    band_mps: Annotated[float, Field(
        gt=0, le=10, description="with plant.adhesion = 'track': width of the speed bands the governor's "
                                 "model is scheduled in [m/s]")] = 0.5


def check(scenario: Scenario) -> None:
    ws = scenario.wheel_slip
    if ws.governor and scenario.becu.control != "decel":
        raise ValueError("wheel_slip.governor = true needs becu.control = 'decel' (the governor limits the "
                         "reference of the deceleration PI, eq. (16))")
    speed_curve = scenario.plant.adhesion == "slip_speed"
    if ws.governor and speed_curve and ws.slip_max_mps >= scenario.plant.slip_peak_mps:
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


def _brake_and_cycle(pp: PlantParams, pi: PIParams, margin: float) -> dict:
    bp = pp.brake
    return dict(dt_s=BecuParams().cycle_us * 1e-6, wheel_radius_m=pp.train.wheel_radius_m,
                inertia_kgm2=pp.train.wheel_inertia_kgm2, tp_s=bp.tp_s,
                alpha_squeeze=bp.alpha_squeeze_Nm_per_Pa, beta_squeeze=bp.beta_squeeze_Nm,
                alpha_release=bp.alpha_release_Nm_per_Pa, beta_release=bp.beta_release_Nm, pi=pi,
                margin_frac=margin)


def design_slip_mps(condition: str, fraction: float, v_mps, ap: AdhesionParams):
    """s̄(v) = fraction · σ°(θ, v) · max(v, V_EPS) [m/s]: a fraction of the design rail's peak slip speed at
    v, σ° = σ̄°/k2(v) (eq. (2) seed 000; the slip ratio's regularisation of plant_sim.adhesion).  v a
    number or a numpy array."""
    k2 = 1.0 + ap.pi2_s_per_m * v_mps
    return fraction * RAIL_PEAKS[condition][0] / k2 * np.maximum(v_mps, V_EPS_MPS)


def _cone(condition: str, fraction: float, v_mps: float, ap: AdhesionParams) -> tuple[float, float]:
    """(μ at s̄, the smallest dμ/ds over [0, s̄] [1/(m/s)]) over the design rail and every more adherent
    rail of seed 000 at speed v: the lower edge of the cone of seed 001 Fig. 5."""
    s_bar = float(design_slip_mps(condition, fraction, v_mps, ap))
    scale = max(v_mps, V_EPS_MPS)                      # σ = s / max(v, V_EPS), seed 000 §2.1
    family = [RAIL_CONDITIONS[name] for name, (_, mu_pk) in RAIL_PEAKS.items()
              if mu_pk >= RAIL_PEAKS[condition][1]]
    mu_at = min(mu_theta_scalar(th, s_bar / scale, v_mps, ap) for th in family)
    ds = s_bar * 1e-4
    slope = math.inf
    for th in family:
        for j in range(1, SLOPE_SAMPLES + 1):
            s = s_bar * j / SLOPE_SAMPLES
            d = (mu_theta_scalar(th, s / scale, v_mps, ap) - mu_theta_scalar(th, (s - ds) / scale, v_mps, ap))
            slope = min(slope, d / ds)
    return mu_at, slope


def becu_governor_schedule(scenario: Scenario, run: RunParams, car: int, pi: PIParams) -> GovernorSchedule:
    """The governor's model of car `car` on seed 000's rail curves, one per speed band of
    wheel_slip.band_mps up to the initial speed (+ SCHEDULE_MARGIN_MPS): F̄ = μ(s̄) N at the band's edge where
    it is smaller (k1(v) lowers the curve as v rises), the slope bounds [smallest f' over [0, s̄] at either
    edge, ∞]."""
    ws, pp = scenario.wheel_slip, run.plant
    ap = pp.adhesion
    normal = pp.train.masses_kg[car - 1] * pp.train.g_mps2             # N = M g, eq. (1a) seed 001
    common = _brake_and_cycle(pp, pi, ws.margin)
    top = run.initial_speed_mps + SCHEDULE_MARGIN_MPS
    edges = [i * ws.band_mps for i in range(int(math.ceil(top / ws.band_mps)) + 1)]
    cones = [_cone(ws.design_condition, ws.slip_fraction, v, ap) for v in edges]
    params = []
    for (mu_lo, slope_lo), (mu_hi, slope_hi) in zip(cones, cones[1:], strict=False):
        params.append(governor_params(
            mass_kg=pp.train.masses_kg[car - 1], friction_max_N=min(mu_lo, mu_hi) * normal,
            slope_lo_N_per_mps=min(slope_lo, slope_hi) * normal, slope_hi_N_per_mps=math.inf, **common))
    return GovernorSchedule(tuple(edges[:-1]), tuple(params))


def becu_governor_params(scenario: Scenario, run: RunParams, car: int, pi: PIParams) -> GovernorParams:
    """The governor's model of car `car` (1-based) from the scenario's plant: F̄ = μ(s̄) N and the friction
    slope bounds f' ∈ [μ'(s̄) N, μ'(0) N] of seed 001's concave μ(s) below its peak (the cone of Fig. 5),
    cylinder Tp, brake lines (eq. 6), the BECU's PI (eq. 16) and cycle."""
    ws, pp = scenario.wheel_slip, run.plant
    mass = pp.train.masses_kg[car - 1]
    normal = mass * pp.train.g_mps2                                    # N = M g, eq. (1a) seed 001
    mu_pk, s_pk = pp.adhesion.slip_speed_peak
    return governor_params(
        mass_kg=mass, friction_max_N=mu_slip_speed_scalar(ws.slip_max_mps, mu_pk, s_pk) * normal,
        slope_lo_N_per_mps=mu_slip_speed_slope_scalar(ws.slip_max_mps, mu_pk, s_pk) * normal,
        slope_hi_N_per_mps=mu_slip_speed_slope_scalar(0.0, mu_pk, s_pk) * normal,
        **_brake_and_cycle(pp, pi, ws.margin))


def reference_governor_params(scenario: Scenario, car: int,
                              run: RunParams) -> ReferenceGovernorParams | None:
    """The governor of car `car`'s BECU, built on that BECU's deceleration PI (eq. 16), with the car's Davis
    coefficients, as the plant's, when the train has running resistance; None when [wheel_slip] governor
    is false (the paper's comparison)."""
    if not scenario.wheel_slip.governor:
        return None
    pp = run.plant
    build = becu_governor_params if pp.adhesion.slip_speed_peak is not None else becu_governor_schedule
    resistance = None
    if pp.train.davis_c0_N or pp.train.davis_c1_Ns_per_m or pp.train.davis_c2_Ns2_per_m2:
        cc = car_constants(pp.train)
        resistance = (cc.c0_N, cc.c1_Ns_per_m, cc.c2_Ns2_per_m2[car - 1])
    return ReferenceGovernorParams(build(scenario, run, car, run.becu(car).decel_pi),
                                   running_resistance=resistance)
