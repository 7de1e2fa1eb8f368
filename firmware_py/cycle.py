"""Elapsed time between controller cycles, from the time passed in (never read from a clock)."""

from __future__ import annotations


class CycleTimer:
    """dt_s(now_us): seconds since the previous call; the nominal cycle on the first call."""

    def __init__(self, nominal_us: int) -> None:
        self.nominal_s = nominal_us * 1e-6
        self.last_us: int | None = None

    def dt_s(self, now_us: int) -> float:
        dt = self.nominal_s if self.last_us is None else (now_us - self.last_us) * 1e-6
        self.last_us = now_us
        return dt
