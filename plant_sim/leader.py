"""The leading train U1 of seed 002 (§IV–§V): its scripted motion along the track.

U1 is not simulated physically: its motion is a script — a list of speed changes, each "from `at_s`
on, go to `speed_mps` at `rate_mps2`" — turned into a piecewise-constant acceleration profile that
can be evaluated at any time, during the run (the wayside and the radio report it) and after it (the
judgement of collisions recomputes it from the scenario alone).  The script covers the cases the
issue lists: runs, stops suddenly (a high rate to 0), crawls (a low speed), leaves the section (runs
on past its end).  U1 never reverses: speeds are ≥ 0.

Positions are track positions s [m] (plant_sim.geo.TrackGeometry: length along the track polyline,
the same axis as the plant's x), of U1's *last wagon* (its rear end, what the follower can hit); its
front is `length_m` further on.  Times are s of simulated time from the run's start.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from plant_sim.errors import PlantConfigError


@dataclass(frozen=True, slots=True)
class SpeedChange:
    """From `at_s` [s] on, accelerate or brake at `rate_mps2` [m/s², > 0, the magnitude] until the speed
    is `speed_mps` [m/s, ≥ 0], then hold it (until the next change)."""

    at_s: float
    speed_mps: float
    rate_mps2: float


class LeaderMotion:
    """U1's motion: `state(t_s)` -> (rear position s [m], speed v [m/s], acceleration a [m/s²]).

    Built once from the start state and the script: knots (t_k, s_k, v_k, a_k) with a constant
    acceleration a_k on [t_k, t_k+1); s(t) = s_k + v_k (t − t_k) + ½ a_k (t − t_k)² (exact, no
    integration error).  Changes are applied in time order; a change that comes before the previous
    one reached its speed takes over from wherever the previous one got to.
    """

    def __init__(self, rear_m: float, speed_mps: float, changes: Sequence[SpeedChange],
                 length_m: float = 100.0) -> None:
        if not (math.isfinite(rear_m) and math.isfinite(speed_mps) and speed_mps >= 0.0):
            raise PlantConfigError(f"LeaderMotion: need a finite position and a speed >= 0 m/s, got "
                                   f"{rear_m!r}, {speed_mps!r}")
        if not (math.isfinite(length_m) and length_m > 0.0):
            raise PlantConfigError(f"LeaderMotion: length_m must be > 0 m, got {length_m!r}")
        for k, c in enumerate(changes):
            if not (math.isfinite(c.at_s) and c.at_s >= 0.0 and math.isfinite(c.speed_mps)
                    and c.speed_mps >= 0.0 and math.isfinite(c.rate_mps2) and c.rate_mps2 > 0.0):
                raise PlantConfigError(f"LeaderMotion: change {k}: need at_s >= 0 s, speed >= 0 m/s and "
                                       f"rate > 0 m/s^2, got {c!r}")
        self.length_m = float(length_m)
        t, s, v = 0.0, float(rear_m), float(speed_mps)
        knots: list[tuple[float, float, float, float]] = []      # (t, s, v, a)
        todo = sorted(changes, key=lambda c: c.at_s)
        for k, c in enumerate(todo):
            if c.at_s > t:                                       # cruise until the change
                s += v * (c.at_s - t)
                knots.append((t, s - v * (c.at_s - t), v, 0.0))
                t = c.at_s
            dv = c.speed_mps - v
            if dv == 0.0:
                continue
            a = math.copysign(c.rate_mps2, dv)
            dur = abs(dv) / c.rate_mps2
            nxt = todo[k + 1].at_s if k + 1 < len(todo) else math.inf
            if t + dur > nxt:                                    # cut short by the next change
                dur = nxt - t
            knots.append((t, s, v, a))
            s += v * dur + 0.5 * a * dur * dur
            v = max(v + a * dur, 0.0)
            t += dur
        knots.append((t, s, v, 0.0))
        arr = np.array(knots)
        self.t_s, self.s_m, self.v_mps, self.a_mps2 = arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3]

    def state(self, t_s):
        """(s_m, v_mps, a_mps2) of the last wagon at time(s) t_s [s]; before t = 0 the start state."""
        t = np.maximum(np.asarray(t_s, dtype=float), 0.0)
        k = np.clip(np.searchsorted(self.t_s, t, side="right") - 1, 0, len(self.t_s) - 1)
        dt = t - self.t_s[k]
        a = self.a_mps2[k]
        s = self.s_m[k] + self.v_mps[k] * dt + 0.5 * a * dt * dt
        v = np.maximum(self.v_mps[k] + a * dt, 0.0)
        if np.ndim(s) == 0:
            return float(s), float(v), float(a)
        return s, v, a

    def rear_m(self, t_s):
        """Track position [m] of the last wagon at t_s [s]."""
        return self.state(t_s)[0]
