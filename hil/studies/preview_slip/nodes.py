"""The nodes of slip control with preview (seed 000), for a scenario with a [preview] section.

`node_names` gets the foundation's node list (PLANT first) and returns this study's; `build_node`
returns the study's own node for `name`, or None to let hil.runtime.assembly build the foundation's.

Paper mode: PLANT = the reduced model of eqs. (1)-(4) (plant_sim.reduced_train) stepping with the Σ_i° it
receives in BECUi_SLIP_REF (held between frames), sending the train state (PLANT_TRAIN) and each
car's slip, adhesion and oracle σ̄° (PLANT_CARi_ADH); BECU1..n = firmware_py.preview.PreviewBecu.
No DESK and no BCU: the paper's braking starts at t = 0 with the slip references.

Full mode: PLANT = the foundation's wheelset plant (FullPlantController adds the preview frames above);
BECU1..n = firmware_py.slipctl.SlipBecu, the same reference generator plus the slip controller that sets
the cylinder pressure (BECUi_PRESS_CMD), commissioned from the plant's car and brake (`slipctl_params`).
"""

from __future__ import annotations

from cantools.database.can import Database

from firmware_py.preview import PreviewBecu, RefParams
from firmware_py.slipctl import SlipBecu
from hil.can.codec import Codec
from hil.errors import ScenarioError
from hil.runtime.node import Binding, Node
from hil.runtime.plant_node import FAILSAFE_HOLD_S, TRUTH_PERIOD_US, PlantController
from hil.scenario import Scenario
from hil.scenario.params import run_params
from hil.studies.preview_slip.scenario import (
    estimator_params,
    full_spacing,
    preview_track,
    reduced_train_params,
    slipctl_params,
)
from plant_sim.adhesion import mu_scalar, slip_ratio_scalar
from plant_sim.errors import PlantConfigError
from plant_sim.params import AdhesionParams
from plant_sim.plant import Plant
from plant_sim.reduced_train import (
    Rail,
    ReducedTrain,
    ReducedTrainParams,
    ReducedTrainTruth,
    adhesion_used,
    sigma_opt_bar_scalar,
    sigma_opt_true,
)

PLANT_OFFSET_US = 0
BECU_OFFSET_US = 3_000           # + 500 µs per car, as the foundation's BECUs (hil.runtime.assembly)


# ------------------------------------------------------------------------------------ the PLANT node
class ReducedTrainPlantController:
    """step(now_us, rx): record truth (every 10 ms), send the measurements, integrate one step with the
    references last received (before the first frame of a car: its σ_i(0), i.e. no change)."""

    def __init__(self, rail: Rail, p: ReducedTrainParams, v0_mps: float, step_us: int) -> None:
        self.rail, self.p, self.n = rail, p, p.n
        self.train = ReducedTrain(rail, p, v0_mps)
        self.step_us = step_us
        self.ref_keys = [f"BECU{i}_SLIP_REF.SlipRef" for i in range(1, self.n + 1)]
        self.inputs = tuple(self.ref_keys)
        self.outputs = ("PLANT_TRAIN.Speed", "PLANT_TRAIN.Accel", "PLANT_TRAIN.HeadPos") + tuple(
            f"PLANT_CAR{i}_ADH.{s}" for i in range(1, self.n + 1)
            for s in ("Slip", "AdhesionUsed", "SigmaOptBarTrue"))
        self.refs = [p.sigma0] * self.n
        self.truth = ReducedTrainTruth(p.spacing_m)
        self.next_truth_us = 0
        self.standstill = self.train.stopped
        self.frames_applied = 0

    def glance(self) -> dict:
        import numpy as np
        return {"v_mps": np.full(self.n, self.train.v), "x_m": self.train.x1 - np.asarray(self.p.spacing_m)}

    def step(self, now_us: int, rx) -> dict[str, float]:
        for k, key in enumerate(self.ref_keys):
            r = rx[key]
            if r == r:                                   # not NaN: received
                self.refs[k] = r
        tr, rail, p = self.train, self.rail, self.p
        a = tr.accel()
        mu = adhesion_used(rail, p, tr.x1, tr.v, tr.sig)
        bars = [rail.sigma_opt_bar(tr.x1 - d) for d in p.spacing_m]
        if now_us >= self.next_truth_us:
            self.truth.record(now_us / 1e6, tr.x1, tr.v, a, tr.sig, self.refs,
                              sigma_opt_true(rail, p, tr.x1, tr.v), mu)
            self.next_truth_us += TRUTH_PERIOD_US
        out = {"PLANT_TRAIN.Speed": tr.v, "PLANT_TRAIN.Accel": a, "PLANT_TRAIN.HeadPos": tr.x1}
        for i in range(self.n):
            c = f"PLANT_CAR{i + 1}_ADH."
            out[c + "Slip"] = tr.sig[i]
            out[c + "AdhesionUsed"] = mu[i]
            out[c + "SigmaOptBarTrue"] = bars[i]
        refs = tuple(self.refs)
        tr.step(self.step_us * 1e-6, lambda x1, v, a_: refs)       # zero-order hold over the step
        if tr.stopped and not self.standstill:          # the stop itself is a truth sample (v = 0)
            self.truth.record((now_us + self.step_us) / 1e6, tr.x1, 0.0, tr.accel(), tr.sig, self.refs,
                              sigma_opt_true(rail, p, tr.x1, 0.0), adhesion_used(rail, p, tr.x1, 0.0, tr.sig))
        self.standstill = tr.stopped
        return out


# ------------------------------------------------------------------------------------ full mode
class FullPlantController(PlantController):
    """The foundation's wheelset plant (hil.runtime.plant_node.PlantController) that also sends, every 10 ms,
    the train state (car 1's speed, acceleration, position) and each car's slip ratio, adhesion used and
    oracle σ̄° (PLANT_TRAIN, PLANT_CARi_ADH) for the slip controllers of full mode."""

    def __init__(self, plant: Plant, n_cars: int, db: Database, dbc_name: str = "the DBC",
                 failsafe_hold_s: float = FAILSAFE_HOLD_S) -> None:
        super().__init__(plant, n_cars, db, dbc_name, failsafe_hold_s=failsafe_hold_s)
        self.outputs = tuple(self.outputs) + ("PLANT_TRAIN.Speed", "PLANT_TRAIN.Accel",
                                              "PLANT_TRAIN.HeadPos") + tuple(
            f"PLANT_CAR{i}_ADH.{s}" for i in range(1, n_cars + 1)
            for s in ("Slip", "AdhesionUsed", "SigmaOptBarTrue"))
        self.next_pv_us = 0
        self._dt_s = plant.params.dt_us * 1e-6

    def step(self, now_us: int, rx) -> dict[str, float]:
        out = super().step(now_us, rx)
        if now_us >= self.next_pv_us:
            snap = self.plant.snapshot()
            ad = self.plant.params.adhesion
            out["PLANT_TRAIN.Speed"] = snap.v[0]
            out["PLANT_TRAIN.Accel"] = (snap.v[0] - snap.v_prev[0]) / self._dt_s
            out["PLANT_TRAIN.HeadPos"] = snap.x[0]
            for k in range(self.n):
                sigma = slip_ratio_scalar(snap.s[k], snap.v[k])
                c = f"PLANT_CAR{k + 1}_ADH."
                out[c + "Slip"] = sigma
                out[c + "AdhesionUsed"] = mu_scalar(tuple(snap.theta[k]), sigma, snap.v[k], ad)
                out[c + "SigmaOptBarTrue"] = sigma_opt_bar_scalar(tuple(snap.theta[k]))
            self.next_pv_us += 10_000
        return out


def build_full_node(name: str, scenario: Scenario, db: Database, codec: Codec, dbc_name: str) -> Node | None:
    pv = scenario.preview
    spacing = full_spacing(scenario)
    n = len(spacing)
    if name == "PLANT":
        try:
            run = run_params(scenario)
            plant = Plant(run.plant, preview_track(scenario),
                          v0_mps=run.initial_speed_mps, x0_m=run.start_position_m,
                          seed=scenario.seed)
        except PlantConfigError as exc:
            raise ScenarioError(f"full mode plant: {exc}") from None
        ctrl = FullPlantController(plant, n, db, dbc_name, scenario.plant.failsafe_hold_s)
        rx_msgs = [f"BECU{i}_PRESS_CMD" for i in range(1, n + 1)]
        tx_msgs = ([f"PLANT_CAR{i}_SENSORS" for i in range(1, n + 1)] + ["PLANT_TRAIN"]
                   + [f"PLANT_CAR{i}_ADH" for i in range(1, n + 1)])
        binding = Binding.build(db, name, ctrl.inputs, ctrl.outputs, rx_msgs, tx_msgs, dbc_name)
        return Node(name, ctrl, binding, codec, db, period_us=plant.params.dt_us, offset_us=PLANT_OFFSET_US)
    if name.startswith("BECU") and name[4:].isdigit() and 1 <= int(name[4:]) <= n:
        i = int(name[4:])
        ad = AdhesionParams()
        rp = RefParams(car=i, spacing_m=spacing[i - 1], method=pv.method, beta=pv.beta,
                       alpha_per_s=pv.alpha_per_s, pi2_s_per_m=ad.pi2_s_per_m, prediction=pv.speed_prediction,
                       sigma0=pv.sigma0)
        ctrl = SlipBecu(rp, n, pv.sigma_source, estimator_params(ad), slipctl_params(scenario, i))
        rx_msgs = ["PLANT_TRAIN", f"PLANT_CAR{i}_ADH"] + [f"BECU{j}_PREVIEW" for j in range(1, i)]
        if ctrl.p.accel_source == "own":
            rx_msgs.append(f"PLANT_CAR{i}_SENSORS")            # the car's own accelerometer
        tx_msgs = [f"BECU{i}_SLIP_REF", f"BECU{i}_PREVIEW", f"BECU{i}_PRESS_CMD"]
        binding = Binding.build(db, name, ctrl.inputs, ctrl.OUTPUTS, rx_msgs, tx_msgs, dbc_name)
        return Node(name, ctrl, binding, codec, db, period_us=10_000,
                    offset_us=BECU_OFFSET_US + 500 * (i - 1),
                    safe_outputs={f"BECU{i}_PRESS_CMD.CylPressureSet": 450e3})
    return None


# ------------------------------------------------------------------------------------ assembly hooks
def node_names(scenario: Scenario, names: list[str]) -> list[str]:
    if scenario.preview.mode == "full":
        full_spacing(scenario)
    else:
        reduced_train_params(scenario)                  # a spacing list that does not fit the train: fail now
    return ["PLANT"] + [f"BECU{i}" for i in range(1, scenario.train.cars + 1)]


def build_node(name: str, scenario: Scenario, db: Database, codec: Codec,
               dbc_name: str = "DBC") -> Node | None:
    pv = scenario.preview
    if pv.mode == "full":
        return build_full_node(name, scenario, db, codec, dbc_name)
    p = reduced_train_params(scenario)
    n = p.n
    if name == "PLANT":
        ctrl = ReducedTrainPlantController(Rail(preview_track(scenario)), p,
                                      run_params(scenario).initial_speed_mps, pv.plant_step_ms * 1000)
        rx_msgs = [f"BECU{i}_SLIP_REF" for i in range(1, n + 1)]
        tx_msgs = ["PLANT_TRAIN"] + [f"PLANT_CAR{i}_ADH" for i in range(1, n + 1)]
        binding = Binding.build(db, name, ctrl.inputs, ctrl.outputs, rx_msgs, tx_msgs, dbc_name)
        return Node(name, ctrl, binding, codec, db, period_us=ctrl.step_us, offset_us=PLANT_OFFSET_US)
    if name.startswith("BECU") and name[4:].isdigit() and 1 <= int(name[4:]) <= n:
        i = int(name[4:])
        ad = AdhesionParams()
        rp = RefParams(car=i, spacing_m=p.spacing_m[i - 1], method=pv.method, beta=pv.beta,
                       alpha_per_s=pv.alpha_per_s, pi2_s_per_m=ad.pi2_s_per_m, prediction=pv.speed_prediction,
                       sigma0=pv.sigma0)
        ctrl = PreviewBecu(rp, n, pv.sigma_source, estimator_params(ad))
        rx_msgs = ["PLANT_TRAIN", f"PLANT_CAR{i}_ADH"] + [f"BECU{j}_PREVIEW" for j in range(1, i)]
        tx_msgs = [f"BECU{i}_SLIP_REF", f"BECU{i}_PREVIEW"]
        binding = Binding.build(db, name, ctrl.inputs, ctrl.OUTPUTS, rx_msgs, tx_msgs, dbc_name)
        return Node(name, ctrl, binding, codec, db, period_us=10_000,
                    offset_us=BECU_OFFSET_US + 500 * (i - 1))
    return None
