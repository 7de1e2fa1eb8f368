"""The node bindings of the wheel-slip governor (seed 001): a reference stage in each foundation BECU.

The governor adds no node and no frame: it limits the demand before each BECU's deceleration PI
(firmware_py.governor.ReferenceGovernor, a firmware_py.becu.ReferenceStage), fitted to its car by
scenario.py's `reference_governor_params`, and its state rides in the BECU's frames (BECUn_STATUS
.GovernorActive, BECUn_DIAG.GovernedDecel / GovernorMargin / GovernorFeasible; the study's DBC part,
frames.py).  Those signals are in every BECU's frames, so a BECU of a run without the governor gets the
stage that says so (firmware_py.governor.Ungoverned: the demand passes, GovernedDecel = the demand).
"""

from __future__ import annotations

from firmware_py.becu import ReferenceStage, SetpointStage
from firmware_py.governor import ReferenceGovernor, Ungoverned
from hil.scenario.params import RunParams
from hil.studies.wheel_slip.scenario import reference_governor_params


def node_names(scenario, names: list[str]) -> list[str]:
    """The foundation's nodes, unchanged: PLANT, DESK, BCU, BECU1..n."""
    return names


def build_node(name, scenario, db, codec, dbc_name="DBC"):
    """None: every node is the foundation's (the governor is a stage of its BECUs)."""
    return None


def becu_stages(scenario, car: int, run: RunParams, reference: list[ReferenceStage],
                setpoint: list[SetpointStage]) -> None:
    """Car `car`'s BECU gets the governor when the scenario has [wheel_slip] governor = true, else the
    stage that fills the governor's signals as the DBC defines them for a BECU without one.  Called for
    every scenario (hil.runtime.assembly: the signals are in every BECU's frames)."""
    params = reference_governor_params(scenario, car, run) if scenario.wheel_slip is not None else None
    reference.append(Ungoverned() if params is None else ReferenceGovernor(params))
