"""The scenario section [preview] (seed 000: slip-reference generators with preview), and the parameters
it sets: the reduced model's, the estimator's and the slip controller's.

Its presence in a scenario makes the run's nodes this study's (nodes.py).

Paper mode (`mode = "paper"`): the PLANT node is the reduced model of eqs. (1)-(4)
(plant_sim.reduced_train), one braking car per [train] car, car k at `spacing_m[k-2]` metres behind car 1;
each BECU is a reference generator (firmware_py.preview) whose Σ_i° reaches the plant over CAN.
The initial speed is [train] initial_speed_kmh.

Full mode (`mode = "full"`): the foundation's wheelset plant, each BECU's slip controller
(firmware_py.slipctl) tracks Sigma_i° by modulating its cylinder pressure; the `slip_*`, `brake_inverse`,
`accel_source` and `above_own` keys set that loop and matter in full mode only.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field, model_validator

from firmware_py.preview import EstimatorParams
from firmware_py.slipctl import SlipCtlParams
from hil.errors import ScenarioError
from hil.resources import profiles_dir, scenarios_dir
from hil.scenario.base import Strict
from hil.scenario.params import run_params
from plant_sim.errors import PlantConfigError
from plant_sim.params import RAIL_CONDITIONS, AdhesionParams
from plant_sim.reduced_train import ReducedTrainParams
from plant_sim.track import Track

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

DEFAULT_PROFILE = "mixed1000"    # scenarios/profiles/mixed1000.csv: extra dry ... extra wet over 1000 m


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
        None, description="theta(x): a profile name of scenarios/profiles/ (e.g. mixed1000) or the path "
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


def resolve_paths(scenario, base: Path):
    """The scenario with a relative `rail_profile` path resolved beside the scenario file (when the table
    is there); a profile name stays a name."""
    ref = scenario.preview.rail_profile
    if ref and ("/" in ref or ref.endswith(".csv")) and not Path(ref).is_absolute() \
            and (base / ref).is_file():
        preview = scenario.preview.model_copy(update={"rail_profile": str((base / ref).resolve())})
        scenario = scenario.model_copy(update={"preview": preview})
    return scenario


# ------------------------------------------------------------------------------------ θ(x) tables
# ------------------------------------------------------------------------------------ θ(x) tables
def profile_path(ref: str) -> Path:
    """The CSV file a `preview.rail_profile` names: a profile of scenarios/profiles/, or a path (relative to
    the current directory, then to scenarios/)."""
    if "/" not in ref and not ref.endswith(".csv"):
        path = profiles_dir() / f"{ref}.csv"
        if path.is_file():
            return path
        known = sorted(p.stem for p in profiles_dir().glob("*.csv"))
        raise ScenarioError(f"preview.rail_profile = {ref!r}: no such profile in {profiles_dir()}; known: "
                            f"{', '.join(known)} (or give the path of a CSV table x_m,theta1,theta2,theta3)")
    for path in (Path(ref), scenarios_dir() / ref):
        if path.is_file():
            return path
    raise ScenarioError(f"preview.rail_profile = {ref!r}: no such file (looked in the current directory and "
                        f"in {scenarios_dir()}); expected a CSV table x_m,theta1,theta2,theta3")


def load_theta_table(path: str | Path) -> Track:
    """θ(x) from a CSV file with the header x_m,theta1,theta2,theta3 (lines starting with # are comments),
    linear between rows, constant beyond the ends."""
    path = Path(path)
    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: cannot read the theta(x) table: {exc}") from None
    rows = list(csv.reader(lines))
    header = [h.strip() for h in rows[0]] if rows else []
    if header != ["x_m", "theta1", "theta2", "theta3"]:
        raise ScenarioError(f"{path}: expected the header x_m,theta1,theta2,theta3, got {','.join(header)!r}")
    xs, thetas = [], []
    for k, row in enumerate(rows[1:], start=2):
        try:
            vals = [float(c) for c in row]
        except ValueError:
            raise ScenarioError(f"{path}: data row {k}: expected 4 numbers, got {','.join(row)!r}") from None
        if len(vals) != 4 or not all(math.isfinite(v) for v in vals):
            raise ScenarioError(f"{path}: data row {k}: expected 4 finite numbers, got {','.join(row)!r}")
        xs.append(vals[0])
        thetas.append(vals[1:])
    if not xs:
        raise ScenarioError(f"{path}: the theta(x) table has no data rows")
    try:
        return Track.from_table(xs, thetas)
    except PlantConfigError as exc:
        raise ScenarioError(f"{path}: {exc}") from None


def preview_track(scenario: Scenario) -> Track:
    ref = scenario.preview.rail_profile
    if ref is None:
        try:
            return run_params(scenario).track
        except PlantConfigError as exc:
            raise ScenarioError(f"[track]: {exc}") from None
    return load_theta_table(profile_path(ref))


def reduced_train_params(scenario: Scenario) -> ReducedTrainParams:
    pv = scenario.preview
    n = scenario.train.cars
    if len(pv.spacing_m) != n - 1:
        raise ScenarioError(f"preview.spacing_m has {len(pv.spacing_m)} value(s) {pv.spacing_m}; "
                            f"train.cars = "
                            f"{n} needs {n - 1} (Delta of cars 2..{n} behind car 1)")
    return ReducedTrainParams(spacing_m=(0.0, *pv.spacing_m), alpha_per_s=pv.alpha_per_s, sigma0=pv.sigma0,
                         ideal=pv.method == "ideal", adhesion=AdhesionParams())


def estimator_params(ad: AdhesionParams) -> EstimatorParams:
    """The BECU estimator's curve family: the plant's named rail conditions, most adhesive first (the
    commissioning library a real BECU would carry), and the speed factors k_i(v)."""
    family = tuple(RAIL_CONDITIONS[c] for c in ("extra_dry", "dry", "wet", "extra_wet"))
    return EstimatorParams(family=family, pi1_s_per_m=ad.pi1_s_per_m, pi2_s_per_m=ad.pi2_s_per_m)


def full_spacing(scenario: Scenario) -> tuple[float, ...]:
    """Δ_i of full mode: the plant's car pitch; `preview.spacing_m` must say the same."""
    pitch = run_params(scenario).plant.train.car_pitch_m
    d = tuple(pitch * k for k in range(scenario.train.cars))
    if tuple(scenario.preview.spacing_m) != d[1:]:
        raise ScenarioError(f"preview.spacing_m = {scenario.preview.spacing_m}: in full mode the cars are "
                            f"the "
                            f"plant's, {pitch} m apart; expected {list(d[1:])}")
    if run_params(scenario).plant.brake.pressure_model != "lag":
        raise ScenarioError("preview.mode = 'full' needs plant.pressure_model = 'lag' (the slip controller "
                            "sets the cylinder pressure)")
    return d


def slipctl_params(scenario: Scenario, car: int) -> SlipCtlParams:
    """The slip controller of car `car` (1-based), commissioned with the plant's car and brake."""
    pp = run_params(scenario).plant
    b = pp.brake
    pv = scenario.preview
    return SlipCtlParams(alpha_c_per_s=pv.slip_alpha_c_per_s, ki_per_s2=pv.slip_ki_per_s2,
                         brake_inverse=pv.brake_inverse, accel_source=pv.accel_source, above_own=pv.above_own,
                         mass_kg=pp.train.masses_kg[car - 1], g_mps2=pp.train.g_mps2,
                         wheel_radius_m=pp.train.wheel_radius_m, inertia_kgm2=pp.train.wheel_inertia_kgm2,
                         brake_gain_Nm_per_Pa=b.alpha_squeeze_Nm_per_Pa,
                         preload_Pa=-b.beta_squeeze_Nm / b.alpha_squeeze_Nm_per_Pa, p_max_Pa=b.p_max_Pa,
                         tp_s=b.tp_s,
                         hysteresis_Pa=(b.beta_release_Nm - b.beta_squeeze_Nm) / b.alpha_release_Nm_per_Pa)
