"""Which nodes a scenario has and how each binds to the DBC.

`node_names(scenario)` lists them; `build_node(name, ...)` builds one (controller + binding + Node).
The lockstep runner builds them all in one process; the real-time runner builds each in its own OS
process from the same function, so the node code is the same in both modes.
"""

from __future__ import annotations

from dataclasses import dataclass

from cantools.database.can import Database

from firmware_py.bcu import Bcu
from firmware_py.becu import Becu
from hil.codec import Codec
from hil.desk import DeskScript
from hil.errors import BindingError
from hil.node import Binding, Node
from hil.plant_node import PlantController, build_plant
from hil.scenario import Scenario

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
    n = scenario.train.cars
    return ["PLANT", "DESK", "BCU"] + [f"BECU{i}" for i in range(1, n + 1)]


def becu_messages(i: int) -> tuple[list[str], list[str]]:
    return ([f"PLANT_CAR{i}_SENSORS", "BCU_DEMAND", "BCU_EMERGENCY"],
            [f"BECU{i}_PRESS_CMD", f"BECU{i}_STATUS"])


def build_node(name: str, scenario: Scenario, db: Database, codec: Codec, dbc_name: str = "DBC") -> Node:
    n = scenario.train.cars
    if name == "PLANT":
        plant = build_plant(scenario)
        ctrl = PlantController(plant, n, db)
        rx_msgs = [f"BECU{i}_PRESS_CMD" for i in range(1, n + 1)]
        tx_msgs = [f"PLANT_CAR{i}_SENSORS" for i in range(1, n + 1)]
        period, offset, inputs, outputs = plant.params.dt_us, PLANT_OFFSET_US, ctrl.inputs, ctrl.outputs
    elif name == "DESK":
        ctrl = DeskScript(scenario.desk)
        rx_msgs, tx_msgs = [], ["DESK_CMD"]
        period, offset, inputs, outputs = 100_000, DESK_OFFSET_US, ctrl.inputs, ctrl.outputs
    elif name == "BCU":
        ctrl = Bcu(n)
        rx_msgs = ["DESK_CMD"] + [f"BECU{i}_STATUS" for i in range(1, n + 1)]
        tx_msgs = ["BCU_DEMAND", "BCU_EMERGENCY", "BCU_STATUS"]
        period, offset = ctrl.p.cycle_us, BCU_OFFSET_US
        inputs, outputs = ctrl.inputs, ctrl.OUTPUTS
    elif name.startswith("BECU") and name[4:].isdigit() and 1 <= int(name[4:]) <= n:
        i = int(name[4:])
        ctrl = Becu()
        rx_msgs, tx_msgs = becu_messages(i)
        period, offset = ctrl.p.cycle_us, BECU_OFFSET_US + 500 * (i - 1)
        inputs, outputs = ctrl.INPUTS, ctrl.OUTPUTS
    else:
        raise BindingError(f"no node {name!r} in this scenario; nodes are {', '.join(node_names(scenario))}")
    binding = Binding.build(db, name, inputs, outputs, rx_msgs, tx_msgs, dbc_name)
    return Node(name, ctrl, binding, codec, db, period_us=period, offset_us=offset)
