"""The metrics of a WSP type test, from a run's plant truth (`TruthLog.columns()`: t_s and per car k
`x_m_k`, `v_mps_k`, `slip_speed_mps_k`, `slip_speed_max_mps_k`, `p_Pa_k`, `wsp_valve_k`, `a_mps2_k`).

Every definition here is written out in docs/wsp-test.md; in short, for a run whose brake command came at
`t_cmd` [s]:

- stopping distance: the leading car's travel from t_cmd to the first sample at which every car stands;
- the ideal stop: a rigid train starting at the run's speed and position at t_cmd whose deceleration at
  each instant is min(demand(τ, v), available(x, v)); demand is the same strategy's deceleration on dry
  rail, τ after its brake command during the build-up and at speed v after it (`Demand`); available(x, v)
  the peak adhesion under each car times g, averaged over the cars, plus the running resistance (the S° of
  seed 000 generalised to a demand and to a rail that changes along the track); its distance is S_ideal
  and the extension S − S_ideal;
- adhesion utilisation: the achieved mean deceleration ÷ the available one, both averaged over distance
  from the end of the brake build-up (the demand's plateau) to the stop, the available one along the
  path the train really took: a = v_b² / (2 D) and ā = (1/D) ∫ min(demand(v), available(x, v)) dx;
- air: the free air the cylinders vented (every pressure drop × the car's cylinder volume ÷ atmospheric
  pressure, isothermal), summed over the cars [L];
- slide: the largest slip speed over every plant step, and the integral of slip speed above a threshold
  over time, summed over the cars (the distance the wheels slid beyond it, wheel-flat risk) [m];
- rotation: the longest time any axle's wheel turned slower than a peripheral speed while its car ran
  faster than `moving_mps` (wheel rotation monitoring) [s];
- WSP activations: the times a car's WSP valve left FILL, summed over the cars.

Pure numerics on arrays, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

STANDSTILL_MPS = 0.01             # a car below this speed stands [m/s] (as the runtime's standstill)
PLATEAU_SHARE = 0.95              # the build-up ends when the dry deceleration first reaches 95 % of it
PLATEAU_SPEEDS = (0.2, 0.8)       # the plateau: the median dry deceleration while v is 20-80 % of v0
IDEAL_DT_S = 0.01                 # the ideal stop's integration step [s] (the truth's sample period)
IDEAL_MAX_S = 3600.0              # an ideal stop longer than this is an error in its inputs


@dataclass(frozen=True)
class MetricParams:
    """Thresholds and constants of the metrics (a programme's [metrics] table)."""

    slide_threshold_mps: float = 0.5       # the slide integral counts slip speed above this [m/s]
    rotation_threshold_mps: float = 1.0    # an axle "not rotating": wheel peripheral speed below this [m/s]
    moving_mps: float = 3.0                # ... while its car runs faster than this [m/s]
    cylinder_volume_l: float = 12.0        # cylinders and pipe of one car [L]
    atmosphere_Pa: float = 101_325.0       # free air: volume at this pressure [Pa]


@dataclass(frozen=True)
class Demand:
    """What the brake asks for, from the strategy's dry run: its deceleration τ [s] after the brake command
    during the build-up (τ < build_up_s), then its deceleration at each speed (the dry run's, after its
    build-up: running resistance and any speed-dependent demand included; faster than the dry run was at
    the end of its build-up: its value there).  `plateau_mps2`: the median of the latter while v is 20-80 %
    of v0."""

    tau_s: np.ndarray
    decel_mps2: np.ndarray
    build_up_s: float
    plateau_mps2: float
    speed_mps: np.ndarray              # increasing
    speed_decel_mps2: np.ndarray

    def at(self, tau_s: float, v_mps: float) -> float:
        if tau_s < self.build_up_s:
            return float(np.interp(tau_s, self.tau_s, self.decel_mps2, left=0.0))
        return self.at_speed(v_mps)

    def at_speed(self, v_mps: float) -> float:
        return float(np.interp(v_mps, self.speed_mps, self.speed_decel_mps2))


def cars_of(cols: Mapping[str, np.ndarray]) -> int:
    n = 0
    while f"v_mps_{n + 1}" in cols:
        n += 1
    if n == 0:
        raise ValueError("the truth has no v_mps_1 column: not a foundation plant's truth")
    return n


def _stack(cols: Mapping[str, np.ndarray], key: str, n: int) -> np.ndarray:
    return np.stack([np.asarray(cols[f"{key}_{k + 1}"], dtype=float) for k in range(n)])


def train_speed(cols: Mapping[str, np.ndarray]) -> np.ndarray:
    """The train's speed: the mean of the cars' [m/s]."""
    return _stack(cols, "v_mps", cars_of(cols)).mean(axis=0)


def command_index(t_s: np.ndarray, t_cmd_s: float) -> int:
    """The first sample at or after the brake command."""
    i = int(np.searchsorted(t_s, t_cmd_s - 1e-9))
    if i >= len(t_s):
        raise ValueError(f"the run ends at {t_s[-1] if len(t_s) else 0:.2f} s, before its brake command at "
                         f"{t_cmd_s:.2f} s")
    return i


def stop_index(cols: Mapping[str, np.ndarray], start: int) -> int | None:
    """The first sample from `start` at which every car stands; None: the train did not stop."""
    v = _stack(cols, "v_mps", cars_of(cols))[:, start:]
    standing = np.all(np.abs(v) < STANDSTILL_MPS, axis=0)
    hit = np.flatnonzero(standing)
    return start + int(hit[0]) if hit.size else None


def demand_from_dry(cols: Mapping[str, np.ndarray], t_cmd_s: float) -> Demand:
    """The demand a dry run shows: the train's deceleration (−dv/dt of the mean speed) after its command."""
    t = np.asarray(cols["t_s"], dtype=float)
    v = train_speed(cols)
    i0 = command_index(t, t_cmd_s)
    end = stop_index(cols, i0)
    if end is None or end - i0 < 3:
        raise ValueError("the dry reference run did not stop: it cannot give the demand")
    tau = t[i0:end + 1] - t[i0]
    decel = np.maximum(-np.gradient(v[i0:end + 1], tau), 0.0)
    v0 = v[i0]
    band = (v[i0:end + 1] <= PLATEAU_SPEEDS[1] * v0) & (v[i0:end + 1] >= PLATEAU_SPEEDS[0] * v0)
    if not band.any():
        raise ValueError("the dry reference run has no sample between 20 and 80 % of its initial speed")
    plateau = float(np.median(decel[band]))
    reached = np.flatnonzero(decel >= PLATEAU_SHARE * plateau)
    b = int(reached[0]) if reached.size else len(tau) - 1
    speeds, decels = v[i0 + b:end + 1][::-1], decel[b:][::-1]      # increasing speed
    keep = np.concatenate(([True], np.diff(speeds) > 0))             # strictly increasing for np.interp
    return Demand(tau, decel, float(tau[b]), plateau, speeds[keep], decels[keep])


def ideal_stop(v0_mps: float, x0_m: float, demand: Demand, available: Callable[[float, float], float],
               dt_s: float = IDEAL_DT_S) -> float:
    """S_ideal [m]: the rigid train from v0 at x0 decelerating at min(demand(τ), available(x, v)) until it
    stands (the trapezoidal rule on each step)."""
    if v0_mps <= 0:
        return 0.0
    x, v, tau = 0.0, float(v0_mps), 0.0
    while v > 0.0:
        a = min(demand.at(tau, v), available(x0_m + x, v))
        if a <= 0.0 and tau > demand.build_up_s:
            raise ValueError(f"the ideal stop does not decelerate at {v:.2f} m/s (demand "
                             f"{demand.at(tau, v):.3f}, available {available(x0_m + x, v):.3f} m/s²)")
        dv = a * dt_s
        if dv >= v:                            # stands within this step
            x += v * v / (2.0 * a)
            break
        x += (v - 0.5 * dv) * dt_s
        v -= dv
        tau += dt_s
        if tau > IDEAL_MAX_S:
            raise ValueError(f"the ideal stop takes longer than {IDEAL_MAX_S:g} s: its demand or adhesion is "
                             "near zero")
    return x


def air_litres(cols: Mapping[str, np.ndarray], start: int, p: MetricParams) -> float:
    """Free air the cylinders vented from sample `start` on [L]: Σ cars Σ drops Δp · V / p_atm."""
    pressure = _stack(cols, "p_Pa", cars_of(cols))[:, start:]
    drops = np.maximum(-np.diff(pressure, axis=1), 0.0).sum()
    return float(drops * p.cylinder_volume_l / p.atmosphere_Pa)


def slide(cols: Mapping[str, np.ndarray], start: int, p: MetricParams) -> tuple[float, float]:
    """(largest slip speed [m/s], Σ cars ∫ max(0, s − threshold) dt [m]) from sample `start` on; the
    largest over every plant step where the truth has the running maximum, else over the samples."""
    n = cars_of(cols)
    t = np.asarray(cols["t_s"], dtype=float)[start:]
    s = _stack(cols, "slip_speed_mps", n)[:, start:]
    if "slip_speed_max_mps_1" in cols:
        largest = float(_stack(cols, "slip_speed_max_mps", n)[:, -1].max())
    else:
        largest = float(s.max()) if s.size else 0.0
    over = np.maximum(s - p.slide_threshold_mps, 0.0)
    integral = float(np.trapezoid(over, t, axis=1).sum()) if t.size > 1 else 0.0
    return largest, integral


def longest_not_rotating(cols: Mapping[str, np.ndarray], start: int, p: MetricParams) -> float:
    """The longest time [s] any car's wheel turned slower than rotation_threshold_mps (peripheral speed
    v − s) while that car ran faster than moving_mps, from sample `start` on."""
    n = cars_of(cols)
    t = np.asarray(cols["t_s"], dtype=float)[start:]
    if t.size < 2:
        return 0.0
    dt = float(np.median(np.diff(t)))
    v = _stack(cols, "v_mps", n)[:, start:]
    wheel = v - _stack(cols, "slip_speed_mps", n)[:, start:]
    flagged = (wheel < p.rotation_threshold_mps) & (v > p.moving_mps)
    longest = 0
    for row in flagged:
        edges = np.diff(np.concatenate(([0], row.astype(np.int8), [0])))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        if starts.size:
            longest = max(longest, int((ends - starts).max()))
    return longest * dt


def wsp_activations(cols: Mapping[str, np.ndarray], start: int) -> int:
    """The times a car's WSP valve left FILL (0), summed over the cars, from sample `start` on."""
    n = cars_of(cols)
    if "wsp_valve_1" not in cols:
        return 0
    w = _stack(cols, "wsp_valve", n)[:, start:] != 0
    return int(np.count_nonzero(w[:, 1:] & ~w[:, :-1]))


def utilisation(cols: Mapping[str, np.ndarray], start: int, stop: int, demand: Demand,
                available: Callable[[float, float], float]) -> float | None:
    """Achieved ÷ available mean deceleration over distance, from the end of the build-up to the stop (see
    the module docstring); None when the train did not stop or moved no distance after the build-up."""
    t = np.asarray(cols["t_s"], dtype=float)
    x = np.asarray(cols["x_m_1"], dtype=float)
    v = train_speed(cols)
    b = int(np.searchsorted(t, t[start] + demand.build_up_s))
    if b >= stop:
        return None
    dist = x[stop] - x[b]
    if dist <= 0:
        return None
    achieved = v[b] ** 2 / (2.0 * dist)
    path = zip(x[b:stop + 1], v[b:stop + 1], strict=True)
    avail = np.array([min(demand.at_speed(vi), available(xi, vi)) for xi, vi in path])
    mean_avail = float(np.trapezoid(avail, x[b:stop + 1]) / dist)
    return float(achieved / mean_avail) if mean_avail > 0 else None


def run_metrics(cols: Mapping[str, np.ndarray], t_cmd_s: float, p: MetricParams, demand: Demand | None,
                available: Callable[[float, float], float] | None) -> dict:
    """Every metric of one run (the ideal-based ones need the dry run's `demand` and `available`)."""
    t = np.asarray(cols["t_s"], dtype=float)
    i0 = command_index(t, t_cmd_s)
    end = stop_index(cols, i0)
    x = np.asarray(cols["x_m_1"], dtype=float)
    v = train_speed(cols)
    largest, integral = slide(cols, i0, p)
    out = {
        "stopped": end is not None,
        "stopping_distance_m": float(x[end] - x[i0]) if end is not None else None,
        "time_to_stop_s": float(t[end] - t[i0]) if end is not None else None,
        "v0_mps": float(v[i0]),
        "air_free_l": air_litres(cols, i0, p),
        "max_slip_speed_mps": largest,
        "slide_integral_m": integral,
        "longest_not_rotating_s": longest_not_rotating(cols, i0, p),
        "wsp_activations": wsp_activations(cols, i0),
        "ideal_distance_m": None, "extension_m": None, "extension_pct": None, "utilisation": None,
    }
    if demand is not None and available is not None:
        ideal = ideal_stop(float(v[i0]), float(x[i0]), demand, available)
        out["ideal_distance_m"] = ideal
        if end is not None:
            out["extension_m"] = out["stopping_distance_m"] - ideal
            out["extension_pct"] = 100.0 * out["extension_m"] / ideal if ideal > 0 else None
            out["utilisation"] = utilisation(cols, i0, end, demand, available)
    return {k: (None if isinstance(val, float) and not math.isfinite(val) else val) for k, val in out.items()}
