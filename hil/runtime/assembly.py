"""Which nodes a scenario has and how each binds to the DBC.

`node_names(scenario)` lists them; `build_node(name, ...)` builds one (controller + binding + Node).
The lockstep runner builds them all in one process; the real-time runner builds them in its host processes
(or `railhil node` in its own) from the same function, inside `for_realtime()`, so the node code is the
same in both modes and a node that has a real device opens it only in real time.

The foundation's train is PLANT, DESK, BCU and BECU1..n.  Each study that is part of the scenario
(hil.scenario.registry) may add or replace nodes (its nodes.py `node_names(scenario, names)` and
`build_node(...)`, None for a node it leaves to the foundation), add frames to the BCU's binding
(`bcu_messages(scenario, rx, tx)`) and to each BECU's (`becu_messages(scenario, rx, tx)`), and fit stages
into the BCU's pipeline (`bcu_stages(scenario, run, sources, followers)`, firmware_py.bcu) and into each
BECU's (`becu_stages(scenario, car, run, reference, setpoint)`, firmware_py.becu; asked of every study, so
that a study whose signals ride in the BECU's frames fills them in every run).  The parameters of every
controller come from hil.scenario.params (`run`: the run's RunParams), a stage's from its study.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from contextvars import ContextVar
from dataclasses import dataclass
from typing import TYPE_CHECKING

from cantools.database.can import Database

from firmware_py.bcu import Bcu, BcuMode
from firmware_py.becu import Becu
from hil.can.codec import Codec, loaded_dbc
from hil.devices.device import ReplacedNode, load_device
from hil.devices.gateway import Gateway
from hil.errors import BindingError, ScenarioError
from hil.fmi.node import fmu_node
from hil.fmi.plant import fmu_plant
from hil.runtime.desk import DeskScript
from hil.runtime.node import Binding, Node
from hil.runtime.plant_node import PlantController
from hil.scenario import params, registry
from plant_sim.plant import Plant

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

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


def node_names(scenario: Scenario) -> list[str]:
    """The scenario's nodes, PLANT first (the lockstep runner reads its truth, standstill and glance())."""
    n = scenario.train.cars
    names = ["PLANT", "DESK", "BCU"] + [f"BECU{i}" for i in range(1, n + 1)]
    for study in registry.active(scenario):
        names = study.part("nodes").node_names(scenario, names)
    return names


def becu_messages(i: int) -> tuple[list[str], list[str]]:
    return ([f"PLANT_CAR{i}_SENSORS", "BCU_DEMAND", "BCU_EMERGENCY"],
            [f"BECU{i}_PRESS_CMD", f"BECU{i}_STATUS", f"BECU{i}_DIAG", f"BECU{i}_EST"])


def build_plant(scenario: Scenario, db: Database | None = None) -> Plant:
    """railhil's plant of the scenario, or the FMU of its [plant] fmu (hil.fmi.plant.FmuPlant, which the plant
    node steps the same way; `db`: the run's DBC, for the FMU's port)."""
    run = params.run_params(scenario)
    if scenario.plant.fmu is not None:
        return fmu_plant(scenario, db if db is not None else loaded_dbc(scenario.dbc)[0], run.plant)
    return Plant(run.plant, run.track, v0_mps=run.initial_speed_mps, x0_m=run.start_position_m, seed=run.seed)


_REALTIME: ContextVar[bool] = ContextVar("railhil_building_for_realtime", default=False)


def building_for_realtime() -> bool:
    """Whether the nodes being built will run in real time (built inside `for_realtime()`: a real-time host,
    `railhil node`), not in lockstep: a node may then open a real device, as the ACD its GPS line on a
    pseudo-terminal."""
    return _REALTIME.get()


@contextlib.contextmanager
def for_realtime() -> Iterator[None]:
    """The nodes built in this block run in real time (`building_for_realtime`)."""
    token = _REALTIME.set(True)
    try:
        yield
    finally:
        _REALTIME.reset(token)


def build_node(name: str, scenario: Scenario, db: Database, codec: Codec, dbc_name: str = "DBC") -> Node:
    """Node `name` of the scenario: a study's, else the foundation's; where a device takes its place
    ([devices.NAME]), the bench side of the device's gateway, with that node's binding and cycle (its
    `gateway` attribute is the hil.devices.gateway.Gateway)."""
    node = None
    for study in registry.active(scenario):
        node = study.part("nodes").build_node(name, scenario, db, codec, dbc_name)
        if node is not None:
            break
    if node is None:
        node = build_foundation_node(name, scenario, db, codec, dbc_name)
    elif name == "PLANT" and scenario.plant.fmu is not None:
        raise ScenarioError(f"[plant] fmu = {scenario.plant.fmu!r}: a study of this scenario brings its own "
                            "plant node; an FMU plant takes the foundation's plant node's place only")
    timing = scenario.nodes.get(name)
    if timing is not None and timing.fmu is not None:
        if name == "PLANT":
            raise ScenarioError("[nodes.PLANT] fmu: the plant's FMU is [plant] fmu = \"FILE\"")
        node = fmu_node(node, timing.fmu, timing.fmu_map, scenario, db, codec, dbc_name)
    ref = scenario.devices.get(name)
    if ref is None:
        return node
    return device_gateway(ref.file, node, scenario, db, codec, dbc_name).bench


def replaced_node(node: Node, db: Database) -> ReplacedNode:
    """What the node a device replaces received and sent, and its cycle (hil.devices.device)."""
    name = node.name
    car = int(name[4:]) if name.startswith("BECU") and name[4:].isdigit() else None
    return ReplacedNode(name, tuple(db.get_message_by_frame_id(fid).name for fid in node.binding.rx),
                        tuple(msg for msg, _ in node.binding.tx), node.period_us, node.offset_us, car)


def check_devices(scenario: Scenario) -> None:
    """Each [devices.NAME] names a node of the scenario that a device may take the place of (not the PLANT,
    whose truth the KPIs come from): a ScenarioError naming the first that does not."""
    names = node_names(scenario)
    for name, ref in scenario.devices.items():
        if name == "PLANT":
            raise ScenarioError(f"devices.PLANT (file {ref.file}): the PLANT cannot be a device: the run's "
                                "KPIs come from its ground truth")
        if name not in names:
            raise ScenarioError(f"{ref.file}: key 'replaces' = {name!r}: scenario {scenario.name!r} has no "
                                f"node {name!r} (its nodes are {', '.join(names)})")


def device_gateway(path: str, node: Node, scenario: Scenario, db: Database, codec: Codec,
                   dbc_name: str = "DBC") -> Gateway:
    """The gateway of the device file at `path` in the place of `node` (checked against both DBCs)."""
    replaced = replaced_node(node, db)
    device = load_device(path, db, replaced, dbc_name, tuple(node_names(scenario)))
    gateway = Gateway(device, replaced, db, codec, dbc_name)
    gateway.bench.gateway = gateway
    return gateway


def build_foundation_node(name: str, scenario: Scenario, db: Database, codec: Codec,
                          dbc_name: str = "DBC") -> Node:
    """A node of the foundation's train (PLANT, DESK, BCU, BECUn) as the scenario configures it."""
    n = scenario.train.cars
    if name == "PLANT":
        plant = build_plant(scenario, db)
        ctrl = PlantController(plant, n, db, dbc_name, balises=params.run_params(scenario).balises,
                               failsafe_hold_s=scenario.plant.failsafe_hold_s)
        rx_msgs = [f"BECU{i}_PRESS_CMD" for i in range(1, n + 1)]
        tx_msgs = [f"PLANT_CAR{i}_SENSORS" for i in range(1, n + 1)] + (["PLANT_BTM"] if ctrl.btm else [])
        period, offset, inputs, outputs = plant.params.dt_us, PLANT_OFFSET_US, ctrl.inputs, ctrl.outputs
    elif name == "DESK":
        ctrl = DeskScript(scenario.desk)
        rx_msgs, tx_msgs = [], ["DESK_CMD", "DESK_TARGET"]
        period, offset, inputs, outputs = 100_000, DESK_OFFSET_US, ctrl.inputs, ctrl.outputs
    elif name == "BCU":
        run = params.run_params(scenario)
        sources, followers = [], []                # the stages the studies fit (firmware_py.bcu)
        registry.call(scenario, "nodes", "bcu_stages", run, sources, followers)
        ctrl = Bcu(n, run.bcu, sources, followers)
        rx_msgs = (["DESK_CMD"] + [f"BECU{i}_STATUS" for i in range(1, n + 1)]
                   + [f"BECU{i}_DIAG" for i in range(1, n + 1)])
        tx_msgs = ["BCU_DEMAND", "BCU_EMERGENCY", "BCU_STATUS"]
        for study in registry.active(scenario):    # the frames of the BCU functions the studies fit
            hook = getattr(study.part("nodes"), "bcu_messages", None)
            if hook is not None:
                hook(scenario, rx_msgs, tx_msgs)
        period, offset = ctrl.p.cycle_us, BCU_OFFSET_US
        inputs, outputs = ctrl.inputs, ctrl.outputs
    elif name.startswith("BECU") and name[4:].isdigit() and 1 <= int(name[4:]) <= n:
        i = int(name[4:])
        run = params.run_params(scenario)
        reference, setpoint = [], []               # the stages the studies fit (firmware_py.becu)
        registry.call_every(scenario, "nodes", "becu_stages", i, run, reference, setpoint)
        ctrl = Becu(run.becu(i), reference, setpoint)
        rx_msgs, tx_msgs = becu_messages(i)
        for study in registry.active(scenario):    # the frames of the BCU functions the car takes part in
            hook = getattr(study.part("nodes"), "becu_messages", None)
            if hook is not None:
                hook(scenario, rx_msgs, tx_msgs)
        period, offset = ctrl.p.cycle_us, BECU_OFFSET_US + 500 * (i - 1)
        inputs, outputs = ctrl.inputs, ctrl.outputs
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
