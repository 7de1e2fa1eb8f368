"""The node bindings of the deceleration feedback (seed 004): it runs inside the foundation BCU.

It adds no node; the BCU it is fitted to (scenario.py `bcu_params`) also receives the front and the rear
car's sensor frames, whose accelerometers give the slope (seed 004 §6.1).  Its state and slope estimate
ride in BCU_STATUS, its state and φ in the authenticated BCU_BRAKE_CORR (frames.py).
"""

from __future__ import annotations


def node_names(scenario, names: list[str]) -> list[str]:
    """The foundation's nodes, unchanged."""
    return names


def build_node(name, scenario, db, codec, dbc_name="DBC"):
    """None: every node is the foundation's."""
    return None


def bcu_messages(scenario, rx: list[str], tx: list[str]) -> None:
    """The front and rear accelerometers (PLANT_CAR1_SENSORS, PLANT_CARn_SENSORS) for the BCU; it sends
    the correction φ in BCU_BRAKE_CORR."""
    n = scenario.train.cars
    rx += list(dict.fromkeys(["PLANT_CAR1_SENSORS", f"PLANT_CAR{n}_SENSORS"]))
    tx.append("BCU_BRAKE_CORR")


def becu_messages(scenario, rx: list[str], tx: list[str]) -> None:
    """Each BECU receives the correction φ (BCU_BRAKE_CORR)."""
    rx.append("BCU_BRAKE_CORR")
