"""The node bindings of the deceleration feedback (seed 004): it runs inside the foundation BCU, and its
correction φ in each BECU.

It adds no node; the BCU it is fitted to (a follower of its demand, firmware_py.decel_feedback
.TrainFeedback, with scenario.py's `feedback_params`) also receives the front and the rear
car's sensor frames, whose accelerometers give the slope (seed 004 §6.1).  Its state and slope estimate
ride in BCU_STATUS, its state and φ in the authenticated BCU_BRAKE_CORR (frames.py).  Each BECU in pressure
control receives BCU_BRAKE_CORR and applies φ to its set-point (firmware_py.decel_feedback.PhiCorrection, a
firmware_py.becu.SetpointStage): eq. (34) corrects the inverse brake model's pressure, which the
deceleration PI of decel control does not use.
"""

from __future__ import annotations

from firmware_py.bcu import DemandSource, Follower
from firmware_py.becu import Control, ReferenceStage, SetpointStage
from firmware_py.decel_feedback import PhiCorrection, PhiParams, TrainFeedback
from hil.scenario.params import RunParams, run_params
from hil.studies.decel_feedback.scenario import feedback_params


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


def bcu_stages(scenario, run: RunParams, sources: list[DemandSource], followers: list[Follower]) -> None:
    """The function follows the BCU's demand."""
    followers.append(TrainFeedback(feedback_params(scenario, run), scenario.train.cars))


def becu_messages(scenario, rx: list[str], tx: list[str]) -> None:
    """Each BECU in pressure control receives the correction φ (BCU_BRAKE_CORR)."""
    if run_params(scenario).becu(1).control == Control.PRESSURE:
        rx.append("BCU_BRAKE_CORR")


def becu_stages(scenario, car: int, run: RunParams, reference: list[ReferenceStage],
                setpoint: list[SetpointStage]) -> None:
    """φ on the set-point of a BECU in pressure control (a run with [decel_feedback] only)."""
    becu = run.becu(car)
    if scenario.decel_feedback is not None and becu.control == Control.PRESSURE:
        setpoint.append(PhiCorrection(PhiParams(), becu.brake_preload_Pa, becu.p_max_Pa))
