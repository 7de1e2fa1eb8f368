"""A run's clock: how the wall clock and a trace's timestamps map to the run's simulated time.

A run starts at t0 and runs at `speed` simulated seconds per wall second ([realtime] speed; 1 = real
time):

    simulated time = (clock time − t0) · speed

on two clocks at once: the monotonic clock the hosts schedule on (`t0_ns`) and the wall clock python-can
stamps frames with, which is the trace's (`t0_s`, epoch seconds: run.json's `trace_t0_s`).  A lockstep
run has no wall clock: its trace is stamped in simulated seconds from 0 (`LOCKSTEP_CLOCK`: t0 = 0,
speed 1).

The clock is made once per run — by the real-time runner when it hands out t0 (`RunClock.starting`: each
host process makes its own from the same t0, reading the wall clock's offset itself), or from run.json when
a run folder is read back (`RunClock.of_run`) — and handed to every part that converts.  Its methods keep
the arithmetic the runners always did, operation for operation, so what they compute is bit for bit the
same.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field


@dataclass(frozen=True)
class RunClock:
    """simulated = (t − t0) · speed, on the trace's clock (`t0_s`) and the monotonic one (`t0_ns`)."""

    t0_s: float = 0.0        # the trace's timestamp at simulated time 0: the wall clock [epoch s]; lockstep 0
    speed: float = 1.0       # simulated seconds per wall second
    t0_ns: int = 0           # the monotonic clock at simulated time 0 [ns] (a real-time run's hosts)
    _us_per_s: float = field(init=False, repr=False, compare=False)   # trace seconds to simulated µs

    def __post_init__(self) -> None:
        object.__setattr__(self, "_us_per_s", 1e6 * self.speed)

    @classmethod
    def starting(cls, t0_ns: int, speed: float = 1.0) -> RunClock:
        """The clock of a real-time run that starts at `t0_ns` on the monotonic clock; where that instant
        is on the wall clock is read now."""
        return cls(time.time() + (t0_ns - time.monotonic_ns()) / 1e9, speed, t0_ns)

    @classmethod
    def of_run(cls, meta: dict) -> RunClock:
        """The clock of a run folder from its run.json (`meta`): `trace_t0_s`, and in a real-time run its
        scenario's [realtime] speed (lockstep: t0 = 0, speed 1)."""
        scenario = meta.get("scenario")
        realtime = scenario.get("realtime") if isinstance(scenario, dict) else None
        speed = 1.0
        if meta.get("mode") == "realtime" and isinstance(realtime, dict):
            speed = float(realtime.get("speed", 1.0))
        return cls(float(meta.get("trace_t0_s") or 0.0), speed)

    # -- a running run: the monotonic clock ----------------------------------------------------------
    def now_us(self) -> int:
        """Simulated time now [µs] (the bus's time in a real-time host)."""
        return int((time.monotonic_ns() - self.t0_ns) * self.speed) // 1000

    def deadline_ns(self, simulated_ns: int) -> int:
        """When simulated time `simulated_ns` [ns] comes, on the monotonic clock [ns]."""
        return self.t0_ns + round(simulated_ns / self.speed)

    def wall_s(self, simulated_s: float) -> float:
        """How long `simulated_s` simulated seconds take on the wall clock [s]."""
        return simulated_s / self.speed

    # -- the trace's clock ---------------------------------------------------------------------------
    def simulated_us(self, timestamp: float) -> int:
        """A frame's timestamp [trace s] in simulated time [µs] (truncated)."""
        return int((timestamp - self.t0_s) * self._us_per_s)

    def simulated_s(self, t):
        """Trace time [s] (a float or an array of them) in simulated time [s]."""
        return (t - self.t0_s) * self.speed

    def trace_s(self, simulated_us: int) -> float:
        """Simulated time [µs] on the trace's clock [s] (the end of a run in its trace)."""
        return self.t0_s + simulated_us / 1e6 / self.speed


LOCKSTEP_CLOCK = RunClock()     # a lockstep run's: its trace is stamped in simulated seconds from 0
