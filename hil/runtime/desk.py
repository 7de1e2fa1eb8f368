"""DESK node: the driver's desk / ATO as a scenario script (a timeline of commands)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from hil.scenario import DeskEvent


class DeskScript:
    """step(now_us, rx) -> DESK_CMD and DESK_TARGET signals: the state after the last event at or
    before now."""

    inputs: tuple[str, ...] = ()
    outputs = ("BrakeStep", "EmergencyReq", "TargetStopValid", "TargetStopPos")

    def __init__(self, events: Sequence[DeskEvent]) -> None:
        self.events = [(round(e.at_s * 1e6), e) for e in events]
        self.next = 0
        self.state = {"BrakeStep": 0, "EmergencyReq": 0, "TargetStopValid": 0, "TargetStopPos": 0.0}

    def step(self, now_us: int, rx: Mapping[str, float]) -> dict[str, float]:
        while self.next < len(self.events) and self.events[self.next][0] <= now_us:
            e = self.events[self.next][1]
            if e.brake_step is not None:
                self.state["BrakeStep"] = e.brake_step
            if e.emergency is not None:
                self.state["EmergencyReq"] = int(e.emergency)
            if e.target_stop_m is not None:
                self.state["TargetStopValid"] = 1
                self.state["TargetStopPos"] = e.target_stop_m
            self.next += 1
        return self.state

    def first_brake_us(self) -> int | None:
        for t_us, e in self.events:
            if (e.brake_step or 0) > 0 or e.emergency:
                return t_us
        return None
