"""Train brake control unit (BCU), v1.

DESK brake step (0..7) -> target deceleration for every car; an emergency request (desk or ACD) ->
full braking, latched until standstill and released request.  Later issues add deceleration feedback
(seed 004), precise stopping (seed 002) and the consensus reference (seed 003).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import IntEnum

from firmware_py.cycle import CycleTimer
from firmware_py.limits import finite_or, rate_limit


class BcuMode(IntEnum):
    """Values are the DBC choices of BCU_DEMAND.Mode."""

    RELEASED = 0
    SERVICE = 1
    EMERGENCY = 2


def bcu_mode_transition(mode: BcuMode, brake_step: int, emergency_req: bool, standstill: bool) -> BcuMode:
    """Pure mode logic: emergency latches until the train stands and the request is gone."""
    if emergency_req:
        return BcuMode.EMERGENCY
    if mode == BcuMode.EMERGENCY and not standstill:
        return BcuMode.EMERGENCY
    return BcuMode.SERVICE if brake_step > 0 else BcuMode.RELEASED


@dataclass(frozen=True)
class BcuParams:
    cycle_us: int = 10_000                   # BCU cycle, DESIGN.md node table
    # seven service brake steps, each a target deceleration (seed 004 §2: "seven levels"); linear up to
    # 1.0 m/s^2 at step 7, a typical full-service deceleration of a metro/EMU (chosen)
    step_decel_mps2: tuple[float, ...] = (0.0, 1 / 7, 2 / 7, 3 / 7, 4 / 7, 5 / 7, 6 / 7, 1.0)
    emergency_decel_mps2: float = 1.3        # emergency brake deceleration (chosen)
    jerk_limit_mps3: float = 1.0             # comfort limit on service demand changes (chosen)
    standstill_mps: float = 0.1              # train speed estimate below which the train stands
    # a car whose BECUn_STATUS (50 ms, DBC) is older than 3 of its cycles is silent: degraded mode
    status_timeout_us: int = 150_000


class Bcu:
    """step(now_us, rx) -> BCU_DEMAND / BCU_EMERGENCY / BCU_STATUS signals."""

    OUTPUTS = ("Mode", "BrakeStep", "TargetDecel", "EmergencyActive", "Source", "CarsSilent", "Degraded",
               "TrainSpeedEst")

    def __init__(self, n_cars: int, params: BcuParams | None = None) -> None:
        self.p = params or BcuParams()
        self.n_cars = n_cars
        self.mode = BcuMode.RELEASED
        self.target = 0.0
        self.timer = CycleTimer(self.p.cycle_us)
        self.inputs = ("BrakeStep", "EmergencyReq") + tuple(
            f"BECU{i}_STATUS.SpeedEst" for i in range(1, n_cars + 1))

    def step(self, now_us: int, rx: Mapping[str, float]) -> dict[str, float]:
        p = self.p
        dt_s = self.timer.dt_s(now_us)
        step_raw, _ = finite_or(rx["BrakeStep"], 0.0)
        emergency_req, _ = finite_or(rx["EmergencyReq"], 0.0)
        brake_step = int(min(max(step_raw, 0), 7))
        speeds = [finite_or(rx[name], float("nan"))[0] for name in self.inputs[2:]]
        age_us = getattr(rx, "age_us", None)         # reception times: the node runtime's RxTable
        if age_us is not None:                        # a car heard from, but not lately, is silent too
            speeds = [float("nan") if (a := age_us(name, now_us)) is not None and a > p.status_timeout_us
                      else v for name, v in zip(self.inputs[2:], speeds, strict=True)]
        known = [v for v in speeds if v == v]
        train_speed = max(known) if known else float("nan")
        silent = sum(1 << i for i, v in enumerate(speeds) if v != v)
        standstill = bool(known) and train_speed < p.standstill_mps

        self.mode = bcu_mode_transition(self.mode, brake_step, emergency_req >= 0.5, standstill)
        if self.mode == BcuMode.EMERGENCY:
            self.target = p.emergency_decel_mps2                      # no jerk limit on emergency
        else:
            wanted = p.step_decel_mps2[brake_step]
            jerk = p.jerk_limit_mps3 * dt_s
            self.target = rate_limit(wanted, self.target, jerk, jerk)
        emergency = self.mode == BcuMode.EMERGENCY
        return {
            "Mode": int(self.mode),
            "BrakeStep": brake_step,
            "TargetDecel": self.target,
            "EmergencyActive": int(emergency),
            "Source": 1 if emergency else 0,
            "CarsSilent": silent,
            "Degraded": int(silent != 0),
            "TrainSpeedEst": train_speed if known else 0.0,
        }
