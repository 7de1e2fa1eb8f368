"""The scenario section [consensus] (seed 003: observer-driven consensus braking) and the parameters it
sets: the seed-003 plant's and each consensus BECU's.

Its presence in a scenario makes the run's nodes this study's (nodes.py): the seed-003 plant
(force-actuated cars, plant_sim/consensus.py), the BCU as virtual leader and one
consensus BECU per car (firmware_py/consensus.py).  Masses and the number of cars come from [train]
(masses_kg); the defaults here are Table 2 of seed 003.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated

import numpy as np
from pydantic import Field, model_validator

from firmware_py.consensus import KMH, ConsensusBecuParams, ConsensusGains, ObserverParams
from hil.errors import ScenarioError
from hil.scenario.base import Strict
from hil.scenario.params import run_params
from plant_sim.consensus import ConsensusPlantParams, Disturbance, RailEvent
from plant_sim.params import TrainParams

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

#: Table 2 of seed 003
TABLE2_SPEEDS_KMH = [88.0, 93.0, 87.0, 89.0, 92.0, 95.5]
TABLE2_POSITIONS_M = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0]
CONS_MAX_CARS = 7          # identifiers 0x058-0x06F of hil/studies/consensus/frames.py

Gain = Annotated[float, Field(ge=0, le=1e6)]


class ConsensusSpec(Strict):
    """[consensus] of a scenario file."""

    observer: bool = Field(True, description="true: u_i3 compensates the observer's estimate (eq. 29); "
                                             "false: the paper's 'without anti-disturbance' runs")
    speeds_kmh: list[Annotated[float, Field(ge=0, le=400)]] = Field(
        default_factory=lambda: list(TABLE2_SPEEDS_KMH), description="initial speed of each car [km/h]")
    # Table 2 lists x_i(t0) = 10 ... 60 m for cars 1 ... 6; car 1 leads here (largest x), so car i starts
    # at the i-th value counted from the end: the couplers start at rest length (2d + l0 = pitch_m)
    positions_m: list[Annotated[float, Field(ge=0, le=1500)]] = Field(
        default_factory=lambda: list(TABLE2_POSITIONS_M),
        description="initial displacements of the cars [m], Table 2 order (the last is the leading car 1)")
    pitch_m: Annotated[float, Field(gt=0, le=100)] = Field(
        10.0, description="2d + l0: car centres' distance with the couplers at rest [m] (eq. 1)")
    v_ref_kmh: Annotated[float, Field(gt=0, le=400)] = Field(90.0, description="v*(t0) of eq. (9) [km/h]")
    decel_kmh_s: Annotated[float, Field(gt=0, le=14)] = Field(3.5, description="a* of eq. (9) [km/(h·s)]")
    brake_gain: Annotated[float, Field(gt=0, le=1e6)] = Field(
        1.0, description="K_b of eq. (3) [N per unit of u], every car")
    alpha1: Gain = Field(120.0, description="α1 of eq. (25) [m/s² per m/s]")
    alpha2: Gain = Field(100.0, description="α2 of eq. (25) [m/s² per cm]")
    k: Gain = Field(36.0, description="k_i of eq. (29) [1/s]")
    kd: Gain = Field(50.0, description="k_di of Table 2: bandwidth of the observer's estimate [1/s]")
    delta: Gain = Field(2.0, description="δ of eq. (27) [m/s² cm³]")
    theta_cm: Annotated[float, Field(gt=0, le=50)] = Field(1.0, description="θ2 = −θ1 [cm], the coupler band")
    u2_max_mps2: Annotated[float, Field(gt=0, le=1e4)] = Field(
        100.0, description="saturation of the potential-field term per car [m/s²]")
    loop_gain: Annotated[float, Field(gt=0, le=10)] | None = Field(
        None, description="sampled-data limit ρ: scale the velocity gains to ρ/((n α1 + k) 2T) at cycle T "
                          "(absent: the paper's gains unscaled)")
    plant_step_us: Annotated[int, Field(ge=100, le=1000)] = Field(
        1000, description="integration step of the plant [µs]: a command acts at the first step after it "
                          "arrives (1000: the paper's 1 ms; must divide the consensus frames' cycle)")
    gamma1_mps: Annotated[float, Field(gt=0, le=100)] = Field(
        0.5, description="observer γ1 of eq. (11) [m/s]")
    gamma2_mps2: Annotated[float, Field(gt=0, le=100)] = Field(
        2.0, description="observer γ2 of eq. (11) [m/s²]")
    # rail condition (§4 cases 2-3): at rail_change_s car i's braking force falls to rail_mu[i] m g for
    # skid_s, then adhesion control restores it; an entry of 0 keeps car i on fine rail
    rail_change_s: Annotated[float, Field(ge=0, le=3600)] | None = Field(
        None, description="time the rail deteriorates [s]; absent: fine rail all run")
    skid_s: Annotated[float, Field(gt=0, le=3600)] = Field(
        1.0, description="skidding time before adhesion control restores capacity [s]")
    rail_mu: list[Annotated[float, Field(ge=0, le=1)]] | None = Field(
        None, description="adhesion of each car while it skids (0 = not affected)")
    disturbance_start_s: Annotated[float, Field(ge=0, le=3600)] | None = Field(
        None, description="start of the sinusoidal disturbance [s] (§4 case 3); absent: none")
    disturbance_mps2: Annotated[float, Field(ge=0, le=10)] = Field(
        0.5, description="disturbance amplitude per unit mass [m/s²] (force = m_i times this)")
    disturbance_hz: Annotated[float, Field(gt=0, le=100)] = Field(
        1.0, description="disturbance frequency [Hz]")

    @model_validator(mode="after")
    def _lengths(self) -> ConsensusSpec:
        n = len(self.speeds_kmh)
        if not 1 <= n <= CONS_MAX_CARS:
            raise ValueError(f"speeds_kmh has {n} entries; consensus braking supports 1-{CONS_MAX_CARS} cars")
        if len(self.positions_m) != n:
            raise ValueError(f"positions_m has {len(self.positions_m)} entries for {n} speeds_kmh")
        if self.rail_mu is not None and len(self.rail_mu) != n:
            raise ValueError(f"rail_mu has {len(self.rail_mu)} entries for {n} cars")
        if self.rail_change_s is not None and self.rail_mu is None:
            raise ValueError("rail_change_s needs rail_mu (the adhesion of each car while it skids)")
        return self


def check_cars(scenario: Scenario) -> None:
    """The [consensus] section against [train]: one speed and position per car, cars ≤ 7."""
    c, n = scenario.consensus, scenario.train.cars
    if len(c.speeds_kmh) != n:
        raise ScenarioError(f"scenario key 'consensus.speeds_kmh': {len(c.speeds_kmh)} speeds for "
                            f"train.cars = {n}; "
                            "expected one initial speed per car")


def consensus_plant_params(scenario: Scenario) -> ConsensusPlantParams:
    """The seed-003 plant of the scenario: Table 2 masses from [train], couplers κ, ε of TrainParams (Table
    2), no draft-gear damping (the paper's spring has none), Davis coefficients of TrainParams (the paper
    gives none) unless [train] running_resistance = false."""
    check_cars(scenario)
    c, t = scenario.consensus, scenario.train
    n = t.cars
    kw: dict = {"masses_kg": t.masses(), "car_pitch_m": c.pitch_m, "coupler_c_Ns_per_m": 0.0}
    if not t.running_resistance:
        kw.update(davis_c0_N=0.0, davis_c1_Ns_per_m=0.0, davis_c2_Ns2_per_m2=0.0,
                  davis_c2_lead_Ns2_per_m2=0.0)
    tp = TrainParams(**kw)
    rail: tuple = ()
    if c.rail_change_s is not None:
        rail = tuple(RailEvent(round(c.rail_change_s * 1e6), round(c.skid_s * 1e6), mu) if mu > 0 else None
                     for mu in c.rail_mu)
    dist = None
    if c.disturbance_start_s is not None:
        # equal amplitude per unit mass, phases spread over the train (chosen: cars are not in step)
        dist = Disturbance(round(c.disturbance_start_s * 1e6),
                           tuple(c.disturbance_mps2 * m for m in tp.masses_kg), c.disturbance_hz,
                           tuple(2 * math.pi * k / n for k in range(n)))
    # Table 2 order: x_i(t0) ascending with i; car 1 leads here, so car i takes the i-th from the end
    x0 = tuple(reversed(c.positions_m))
    track = run_params(scenario).track
    x_mid = float(np.mean(x0))
    return ConsensusPlantParams(
        train=tp, brake_gain=(c.brake_gain,) * n, sin_grade=float(track.sin_grade_at(np.array([x_mid]))[0]),
        curvature_deg=float(track.curvature_degree_at(np.array([x_mid]))[0]), rail=rail, disturbance=dist,
        v0_mps=tuple(v * KMH for v in c.speeds_kmh), x0_m=x0, dt_us=c.plant_step_us)


def consensus_becu_params(scenario: Scenario, car: int, sample_period_us: int = 1_000,
                period_us: int = 1_000) -> ConsensusBecuParams:
    c, t = scenario.consensus, scenario.train
    gains = ConsensusGains(alpha1_per_s=c.alpha1, alpha2_per_s2_cm=c.alpha2, k_per_s=c.k, kd_per_s=c.kd,
                           delta_mps2_cm3=c.delta, theta1_cm=-c.theta_cm, theta2_cm=c.theta_cm,
                           u2_max_mps2=c.u2_max_mps2, loop_gain=c.loop_gain)
    obs = ObserverParams(gamma1_mps=c.gamma1_mps, gamma2_mps2=c.gamma2_mps2, filter_per_s=c.kd)
    return ConsensusBecuParams(car=car, n_cars=t.cars, mass_kg=t.masses()[car - 1], pitch_m=c.pitch_m,
                               brake_gain=c.brake_gain, gains=gains, observer=obs, compensate=c.observer,
                               sample_period_us=sample_period_us, period_us=period_us)
