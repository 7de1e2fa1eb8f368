"""Which nodes a scenario has and how each binds to the DBC.

`node_names(scenario)` lists them; `build_node(name, ...)` builds one (controller + binding + Node).
The lockstep runner builds them all in one process; the real-time runner builds each in its own OS
process from the same function, so the node code is the same in both modes.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
from dataclasses import dataclass

from cantools.database.can import Database

from firmware_py.bcu import Bcu, BcuMode, BcuParams
from firmware_py.becu import Becu, BecuParams
from firmware_py.decel_feedback import FeedbackParams, FrictionSet
from firmware_py.governor import GovernorParams, governor_params
from firmware_py.pi import PIParams
from firmware_py.stopping import StoppingParams
from hil.can.codec import Codec
from hil.errors import BindingError
from hil.runtime.desk import DeskScript
from hil.runtime.node import Binding, Node
from hil.runtime.plant_node import PlantController, build_track, plant_params
from hil.scenario import Scenario
from plant_sim.adhesion import mu_slip_speed_scalar, mu_slip_speed_slope_scalar
from plant_sim.padbench import BenchParams, coefficient_set
from plant_sim.params import PadParams, PlantParams
from plant_sim.plant import Plant

# Phase offsets inside the 10 ms cycle, so that ECUs are not artificially synchronous (chosen).
PLANT_OFFSET_US = 0
DESK_OFFSET_US = 1_000
BCU_OFFSET_US = 2_000
BECU_OFFSET_US = 3_000          # + 500 us per car


@dataclass(frozen=True)
class NodeInfo:
    name: str
    period_us: int
    offset_us: int


#: scenario section -> the module that assembles that study's nodes.  Each module has
#: ``node_names(scenario, names) -> list[str]`` (given the foundation's names, PLANT first; the plant node
#: must stay first: the lockstep runner reads its truth, standstill and glance()) and
#: ``build_node(name, scenario, db, codec, dbc_name) -> Node | None`` (None: the foundation builds it).
STUDIES = {"preview": "hil.preview_nodes", "consensus": "hil.consensus_nodes", "acd": "hil.acd_nodes"}


def studies(scenario: Scenario) -> list:
    """The modules of the studies this scenario has a section for, in STUDIES order."""
    return [importlib.import_module(mod) for key, mod in STUDIES.items()
            if getattr(scenario, key) is not None]


def node_names(scenario: Scenario) -> list[str]:
    n = scenario.train.cars
    names = ["PLANT", "DESK", "BCU"] + [f"BECU{i}" for i in range(1, n + 1)]
    for study in studies(scenario):
        names = study.node_names(scenario, names)
    return names


def becu_messages(i: int) -> tuple[list[str], list[str]]:
    return ([f"PLANT_CAR{i}_SENSORS", "BCU_DEMAND", "BCU_EMERGENCY", "BCU_STATUS"],
            [f"BECU{i}_PRESS_CMD", f"BECU{i}_STATUS", f"BECU{i}_DIAG"])


G_MPS2 = 9.81          # bar/g -> Pa per m/s²: 1 bar = 1e5 Pa, g = 9.81 m/s²


def pad_params(scenario: Scenario) -> PadParams | None:
    """The plant's variable pad friction (seed 004 eqs. (24)-(25)) when [plant] pad_friction = true."""
    ps = scenario.plant
    if not ps.pad_friction:
        return None
    kw: dict = {"initial_temp_rise_K": ps.disc_temp_rise_K}
    if ps.pad_speed_amplitude is not None:
        kw["n_v"] = ps.pad_speed_amplitude
    if ps.pad_cold_amplitude is not None:
        kw["n_T"] = ps.pad_cold_amplitude
    return PadParams(**kw)


def scenario_plant_params(scenario: Scenario) -> PlantParams:
    """hil.runtime.plant_node.plant_params plus the pad model of seed 004 where the scenario asks for it."""
    pp = plant_params(scenario)
    pad = pad_params(scenario)
    return pp if pad is None else dataclasses.replace(pp, pad=pad)


def build_plant(scenario: Scenario) -> Plant:
    return Plant(scenario_plant_params(scenario), build_track(scenario),
                 v0_mps=scenario.train.initial_speed_kmh / 3.6, x0_m=scenario.train.start_position_m,
                 seed=scenario.seed)


@functools.lru_cache(maxsize=8)
def _bench_set(pad: PadParams, bench: BenchParams, method: str) -> FrictionSet:
    cs = coefficient_set(pad, bench, method)
    return FrictionSet(cs.speeds_kmh, cs.dt_s, cs.values)


def friction_set(scenario: Scenario, step_decel_mps2: tuple[float, ...]) -> FrictionSet | None:
    """The BCU's friction-coefficient set (seed 004 §4.2, §6.3): the plant's pad model on the brake-disc
    bench at the tested speed classes, braked at the full service step, filled to 10 km/h × 100 ms."""
    pad = pad_params(scenario)
    if scenario.bcu.friction_set == "none" or pad is None:
        return None
    tp = plant_params(scenario).train
    bench = BenchParams(decel_mps2=step_decel_mps2[7], wheel_radius_m=tp.wheel_radius_m,
                        car_mass_kg=sum(tp.masses_kg) / len(tp.masses_kg))
    return _bench_set(pad, bench, scenario.bcu.friction_set_fill)


def bcu_params(scenario: Scenario) -> BcuParams:
    """BcuParams with the scenario's [bcu] step table, jerk limit and deceleration feedback where given."""
    kw: dict = {}
    if scenario.bcu.step_decel_mps2 is not None:
        kw["step_decel_mps2"] = tuple(scenario.bcu.step_decel_mps2)
    if scenario.bcu.jerk_limit_mps3 is not None:
        kw["jerk_limit_mps3"] = scenario.bcu.jerk_limit_mps3
    if scenario.bcu.decel_feedback is not None:
        steps = kw.get("step_decel_mps2", BcuParams().step_decel_mps2)
        kw["feedback"] = FeedbackParams(enabled=scenario.bcu.decel_feedback, tq_s=scenario.bcu.feedback_tq_s,
                                        friction_set=friction_set(scenario, steps))
    if scenario.bcu.stopping != "none":
        full = kw.get("step_decel_mps2", BcuParams().step_decel_mps2)[7]
        # the odometer's reference point: the train's front passes the start position at t = 0
        kw["stopping"] = StoppingParams(
            method=scenario.bcu.stopping, planned_decel_mps2=scenario.bcu.stop_decel_mps2,
            max_decel_mps2=full, hold_decel_mps2=full, start_position_m=scenario.train.start_position_m,
            start_time_us=0, pi=dataclasses.replace(StoppingParams().pi, out_max=full),
            balises=bool(scenario.track.balises))
    if scenario.acd is not None:                      # the anti-collision device's requests, seed 002
        kw["acd"] = True
    return BcuParams(**kw)


def becu_governor_params(scenario: Scenario, pp: PlantParams, car: int, pi: PIParams) -> GovernorParams:
    """The governor's model of car `car` (1-based) from the scenario's plant: F̄ = μ(s̄) N and the friction
    slope bounds f' ∈ [μ'(s̄) N, μ'(0) N] of seed 001's concave μ(s) below its peak (the cone of Fig. 5),
    cylinder Tp, brake lines (eq. 6), the BECU's PI (eq. 16) and cycle."""
    b = scenario.becu
    mass = pp.train.masses_kg[car - 1]
    normal = mass * pp.train.g_mps2                                    # N = M g, eq. (1a) seed 001
    mu_pk, s_pk = pp.adhesion.slip_speed_peak
    bp = pp.brake
    return governor_params(
        dt_s=BecuParams().cycle_us * 1e-6, mass_kg=mass, wheel_radius_m=pp.train.wheel_radius_m,
        inertia_kgm2=pp.train.wheel_inertia_kgm2,
        friction_max_N=mu_slip_speed_scalar(b.slip_max_mps, mu_pk, s_pk) * normal,
        slope_lo_N_per_mps=mu_slip_speed_slope_scalar(b.slip_max_mps, mu_pk, s_pk) * normal,
        slope_hi_N_per_mps=mu_slip_speed_slope_scalar(0.0, mu_pk, s_pk) * normal, tp_s=bp.tp_s,
        alpha_squeeze=bp.alpha_squeeze_Nm_per_Pa, beta_squeeze=bp.beta_squeeze_Nm,
        alpha_release=bp.alpha_release_Nm_per_Pa, beta_release=bp.beta_release_Nm, pi=pi,
        margin_frac=b.governor_margin)


def becu_params(scenario: Scenario, car: int) -> BecuParams:
    """BecuParams of car `car` (1-based): the v1 defaults unless the scenario's [becu] says otherwise."""
    b = scenario.becu
    d = BecuParams()
    if b.control == "pressure" and b.wsp_vent_slip_mps is None and b.wheel_trust_slip_mps is None:
        return d                                                       # the foundation's BECU, unchanged
    pp = plant_params(scenario)
    kw: dict = {"control": b.control, "car_mass_kg": pp.train.masses_kg[car - 1], "wsp_resume": b.wsp_resume,
                "wheel_radius_m": pp.train.wheel_radius_m, "p_max_Pa": pp.brake.p_max_Pa}
    pi = PIParams(kp=b.kp_bar_per_g * 1e5 / G_MPS2, ki=b.ki_bar_per_g_s * 1e5 / G_MPS2, out_min=0.0,
                  out_max=pp.brake.p_max_Pa)                           # eq. (16), 0 ≤ u ≤ p̄ (5b)
    kw["decel_pi"] = pi
    if b.wsp_vent_slip_mps is not None:                                # seed 001 §II-C: vent, then track
        kw["wsp"] = dataclasses.replace(
            d.wsp, vent_slip_mps=b.wsp_vent_slip_mps, vent_slip_per_speed=0.0,
            hold_fraction=b.wsp_refill_slip_mps / b.wsp_vent_slip_mps,
            refill_fraction=b.wsp_refill_slip_mps / b.wsp_vent_slip_mps)
    if b.wheel_trust_slip_mps is not None:
        kw["wheel_trust_slip_mps"] = b.wheel_trust_slip_mps
    if b.governor:
        kw["governor"] = becu_governor_params(scenario, pp, car, pi)
    return BecuParams(**kw)


def build_node(name: str, scenario: Scenario, db: Database, codec: Codec, dbc_name: str = "DBC") -> Node:
    for study in studies(scenario):
        node = study.build_node(name, scenario, db, codec, dbc_name)
        if node is not None:
            return node
    return build_foundation_node(name, scenario, db, codec, dbc_name)


def build_foundation_node(name: str, scenario: Scenario, db: Database, codec: Codec,
                          dbc_name: str = "DBC") -> Node:
    """A node of the foundation's train (PLANT, DESK, BCU, BECUn) as the scenario configures it."""
    n = scenario.train.cars
    if name == "PLANT":
        plant = build_plant(scenario)
        ctrl = PlantController(plant, n, db, dbc_name, balises=scenario.track.balises)
        rx_msgs = [f"BECU{i}_PRESS_CMD" for i in range(1, n + 1)]
        tx_msgs = [f"PLANT_CAR{i}_SENSORS" for i in range(1, n + 1)] + (["PLANT_BTM"] if ctrl.btm else [])
        period, offset, inputs, outputs = plant.params.dt_us, PLANT_OFFSET_US, ctrl.inputs, ctrl.outputs
    elif name == "DESK":
        ctrl = DeskScript(scenario.desk)
        rx_msgs, tx_msgs = [], ["DESK_CMD", "DESK_TARGET"]
        period, offset, inputs, outputs = 100_000, DESK_OFFSET_US, ctrl.inputs, ctrl.outputs
    elif name == "BCU":
        ctrl = Bcu(n, bcu_params(scenario))
        rx_msgs = (["DESK_CMD"] + [f"BECU{i}_STATUS" for i in range(1, n + 1)]
                   + [f"BECU{i}_DIAG" for i in range(1, n + 1)])
        if ctrl.feedback is not None:                  # the front and rear accelerometers, seed 004 §6.1
            rx_msgs += list(dict.fromkeys(["PLANT_CAR1_SENSORS", f"PLANT_CAR{n}_SENSORS"]))
        if ctrl.p.acd:
            rx_msgs.append("ACD_BRAKE_REQ")
        tx_msgs = ["BCU_DEMAND", "BCU_EMERGENCY", "BCU_STATUS"]
        if ctrl.stopping is not None:                  # the target stop point and balises, seed 002
            rx_msgs += ["DESK_TARGET"] + (["PLANT_BTM"] if ctrl.p.stopping.balises else [])
            tx_msgs.append("BCU_STOP")
        period, offset = ctrl.p.cycle_us, BCU_OFFSET_US
        inputs, outputs = ctrl.inputs, ctrl.outputs
    elif name.startswith("BECU") and name[4:].isdigit() and 1 <= int(name[4:]) <= n:
        i = int(name[4:])
        ctrl = Becu(becu_params(scenario, i))
        rx_msgs, tx_msgs = becu_messages(i)
        period, offset = ctrl.p.cycle_us, BECU_OFFSET_US + 500 * (i - 1)
        inputs, outputs = ctrl.INPUTS, ctrl.OUTPUTS
    else:
        raise BindingError(f"no node {name!r} in this scenario; nodes are {', '.join(node_names(scenario))}")
    binding = Binding.build(db, name, inputs, outputs, rx_msgs, tx_msgs, dbc_name)
    return Node(name, ctrl, binding, codec, db, period_us=period, offset_us=offset,
                safe_outputs=safe_outputs(ctrl))


def safe_outputs(ctrl) -> dict[str, float]:
    """What a node sends in place of an output its controller could not give (step() raised, or the
    value is NaN, infinite or not a number): railway fail-safe, a brake ECU that fails brakes.  A BECU
    fills its cylinder to p̄; the BCU commands the emergency brake.  Other nodes: 0 (hil.runtime.node)."""
    if isinstance(ctrl, Becu):
        return {"CylPressureSet": ctrl.p.p_max_Pa, "ValveCmd": 1.0, "WspValve": 0, "InputMissing": 1}
    if isinstance(ctrl, Bcu):
        return {"Mode": int(BcuMode.EMERGENCY), "TargetDecel": ctrl.p.emergency_decel_mps2,
                "EmergencyActive": 1, "Source": 3, "Degraded": 1}
    return {}
