"""The node bindings of precise stopping (seed 002): it runs inside the foundation BCU.

It adds no node; the BCU it is fitted to (a demand source, firmware_py.stopping.StoppingDemand, with
scenario.py's `stopping_params`) receives the desk's target stop point
(DESK_TARGET) and, on a track with balises, car 1's balise reader (PLANT_BTM), and sends where it believes
the train is against its target and curve (BCU_STOP, frames.py).
"""

from __future__ import annotations

from firmware_py.bcu import DemandSource, Follower
from firmware_py.stopping import StoppingDemand
from hil.scenario.params import RunParams, run_params
from hil.studies.precise_stop.scenario import stopping_params


def node_names(scenario, names: list[str]) -> list[str]:
    """The foundation's nodes, unchanged."""
    return names


def build_node(name, scenario, db, codec, dbc_name="DBC"):
    """None: every node is the foundation's."""
    return None


def bcu_messages(scenario, rx: list[str], tx: list[str]) -> None:
    if scenario.precise_stop.method == "plc":      # a PLC in the DESK's place: no function in the BCU
        return
    rx += ["DESK_TARGET"] + (["PLANT_BTM"] if run_params(scenario).balises else [])
    tx.append("BCU_STOP")


def bcu_stages(scenario, run: RunParams, sources: list[DemandSource], followers: list[Follower]) -> None:
    """The stopping function as a demand source of the BCU (none with a PLC in the DESK's place)."""
    params = stopping_params(scenario, run)
    if params is not None:
        sources.append(StoppingDemand(params))
