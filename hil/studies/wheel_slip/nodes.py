"""The node bindings of the wheel-slip governor (seed 001): it runs inside each foundation BECU.

The governor adds no node and no frame to a binding.  Fitted by scenario.py's `becu_params` (the
governor's model of its car), it is a part of firmware_py.becu.Becu, whose outputs already carry its
state (BECUn_STATUS.GovernorActive, BECUn_DIAG.GovernedDecel / GovernorMargin / GovernorFeasible; the
study's DBC part, frames.py).  The hooks below say so to hil.runtime.assembly.
"""

from __future__ import annotations


def node_names(scenario, names: list[str]) -> list[str]:
    """The foundation's nodes, unchanged: PLANT, DESK, BCU, BECU1..n."""
    return names


def build_node(name, scenario, db, codec, dbc_name="DBC"):
    """None: every node is the foundation's (the governor is configured through its BECU parameters)."""
    return None
