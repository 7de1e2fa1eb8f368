"""The scenario section [preview]: seed 000 (Picasso et al.): slip-reference generators with preview.

Its presence in a scenario makes hil.runtime.assembly hand the run's nodes to hil/preview_nodes.py.

Paper mode (`mode = "paper"`): the PLANT node is the reduced model of eqs. (1)-(4)
(plant_sim.picasso), one braking car per [train] car, car k at `spacing_m[k-2]` metres behind car 1;
each BECU is a reference generator (firmware_py.preview) whose Σ_i° reaches the plant over CAN.
The initial speed is [train] initial_speed_kmh.

Full mode (`mode = "full"`): the foundation's wheelset plant, each BECU's slip controller
(firmware_py.slipctl) tracks Sigma_i° by modulating its cylinder pressure; the `slip_*`, `brake_inverse`,
`accel_source` and `above_own` keys set that loop and matter in full mode only.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from hil.scenario.base import Strict


class PreviewSpec(Strict):
    """[preview] of a scenario file."""

    mode: Literal["paper", "full"] = Field(
        "paper", description="paper: the closed-loop slip model of eq. (4) in the plant; full: the "
                             "foundation's wheelset plant, each BECU's slip controller tracks the reference "
                             "by modulating cylinder pressure (needs plant.pressure_model = 'lag'; the cars "
                             "are the plant's, spacing_m = multiples of its car pitch)")
    method: Literal["Lf", "Bd", "Dp", "ideal"] = Field(
        "Dp", description="slip reference: Lf (car 1's sigma°), Bd (own sigma°), Dp (preview, eq. 9-11), "
                          "ideal (theoretical limit S°: mu = mu°)")
    beta: Annotated[float, Field(gt=0, le=2, description="scaling of the reference (seed 000 §3.3)")] = 1.0
    alpha_per_s: Annotated[float, Field(gt=0, le=100, description="alpha of eq. (4) [1/s]: the slip "
                                                                  "loop's inverse time constant")] = 1.5
    spacing_m: list[Annotated[float, Field(gt=0, le=1000)]] = Field(
        default_factory=lambda: [50.0],
        description="Delta_i [m] of cars 2..n behind car 1, increasing; one per [train] car after the first")
    sigma0: Annotated[float, Field(ge=0, lt=0.5, description="initial slip sigma_i(0) [-]")] = 0.001
    sigma_source: Literal["oracle", "estimate"] = Field(
        "oracle", description="oracle: the plant's true sigma° (the paper's assumption); estimate: each "
                              "BECU's online estimator, cars exchange estimates")
    speed_prediction: Literal["remark2", "eq10"] = Field(
        "remark2", description="speed prediction of Dp: Remark 2 (time domain) or eq. (10) (position)")
    rail_profile: str | None = Field(
        None, description="theta(x): a profile name of scenarios/profiles/ (e.g. picasso1000) or the path "
                          "of a CSV table x_m,theta1,theta2,theta3 (relative: to the current directory, then "
                          "to scenarios/); absent: the [track] rail")
    plant_step_ms: Literal[1, 2, 5, 10] = Field(
        5, description="integration step of the reduced model in the PLANT node [ms] (RK4)")

    # ---- full mode only: the BECU's slip loop (firmware_py.slipctl.SlipCtlParams)
    slip_alpha_c_per_s: Annotated[float, Field(
        gt=0, le=100, description="full mode: alpha_c [1/s], the slip dynamics the slip loop asks for, "
                                  "sigma' = alpha_c (Sigma° - sigma); what it achieves is measured")] = 10.0
    slip_ki_per_s2: Annotated[float, Field(
        ge=0, le=1000, description="full mode: integral gain k_i of the slip loop [1/s^2]")] = 10.0
    brake_inverse: Literal["model", "direction"] = Field(
        "model", description="full mode: how the slip loop turns its torque into a cylinder set-point: "
                             "model (an internal model of the lag cylinder and of the brake's hysteresis, "
                             "exact inverse) or direction (the first version: the hysteresis line guessed "
                             "from the direction the wanted torque moves)")
    accel_source: Literal["own", "train"] = Field(
        "own", description="full mode: the deceleration in the slip loop's v'/v term: own (the car's "
                           "accelerometer, PLANT_CARi_SENSORS) or train (car 1's, PLANT_TRAIN)")
    above_own: Annotated[float, Field(ge=0, le=10)] | None = Field(
        None, description="full mode: cap the reference at (1 + above_own) times the optimum under the "
                          "car's own wheels; absent: no cap (the reference as generated)")

    @model_validator(mode="after")
    def _increasing(self) -> PreviewSpec:
        d = self.spacing_m
        if any(b <= a for a, b in zip(d, d[1:], strict=False)):
            raise ValueError(f"preview.spacing_m must increase (car 2 first), got {d}")
        return self
