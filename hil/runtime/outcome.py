"""What a run produced, in either mode, and whether a real-time run held real time."""

from __future__ import annotations

from dataclasses import dataclass, field

from hil.runtime.plant_node import TruthLog

HELD_MAX_LAG_US = 50_000       # a run held real time when no node's cycle fell more than this behind (the
                               # 10 ms ECUs' CATCH_UP_CYCLES) and none skipped a cycle (realtime_verdict)


@dataclass
class RunOutcome:
    """What a run produced, in either mode; the results module turns it into files and KPIs."""

    mode: str
    end_us: int
    reason: str                               # "standstill" | "max_duration" | "interrupted"
    truth: TruthLog
    frames_by_node: dict[str, int]
    node_stats: dict[str, dict] = field(default_factory=dict)
    wall_s: float = 0.0
    bus: dict | None = None                   # bit-timed lockstep bus: load and per-message timing
    frames_in_flight: int = 0                 # sent, but queued or on the wire when the run ended
    frames_overwritten: int = 0               # replaced in a transmit queue by a newer instance
    frames_faulted: int = 0                   # frames added (+) or removed (-) by injected faults
    faults: dict | None = None                # what the fault injector did: counts and events
    lateness_us: dict = field(default_factory=dict)   # real time: node -> each cycle's release lateness [µs]


def realtime_verdict(node_stats: dict[str, dict]) -> dict:
    """Did the run hold real time?  On a machine short of CPU a node starts its cycles late, or skips them,
    and the plant's sensors go stale: the closed loop is then not that of the controllers at their cycle
    times, and its figures (stopping distance, reaction times) say so little that they are flagged."""
    lag = {n: round(s.get("max_lag_us", 0) / 1e3, 1) for n, s in node_stats.items()}
    missed = {n: s.get("missed_cycles", 0) for n, s in node_stats.items()}
    held = (all(s.get("max_lag_us", 0) <= HELD_MAX_LAG_US for s in node_stats.values())
            and not any(missed.values()))
    worst = max(lag, key=lag.get, default=None)
    lateness = {n: s["lateness_us"] for n, s in node_stats.items() if s.get("lateness_us")}
    return {"held": held, "max_lag_ms": lag, "missed_cycles": missed, "worst_node": worst,
            "limit_ms": HELD_MAX_LAG_US / 1e3, "lateness_us": lateness}
