"""Brake-disc test bench (seed 004 §6.2) and the friction-coefficient set μ(v, t) built from it (§4.2, §6.3).

The bench brakes a flywheel with the inertia of one car from an initial speed class to standstill, at the
constant cylinder pressure that gives `decel_mps2` with the nominal friction μ_nominal, and records the
pad's friction coefficient every 100 ms (a torque transducer: μ_d = τ / (clamp force · r_f), with
relative noise).  It runs the plant's own pad model (`plant_sim.brake.pad_friction_scalar`, eq. (25),
and `disc_temperature_scalar`), so the data are what the plant will do on the track from a cold disc.

As in the paper only a few speed classes are tested (50, 80, 120, 160, 180 km/h, §6.2); the BCU's set
covers every 10 km/h class on a 100 ms grid (§6.3).  The paper fills the gaps with an LSTM; here two
plain interpolations are compared on held-out speed classes (`held_out_errors`) and the better one is
used (`coefficient_set`):

* ``"time"``: at each instant t, linear in the initial speed between the tested classes (a class that
  has already stopped holds its last value);
* ``"fraction"``: at each fraction t / t_stop of the stop, linear in the initial speed, with the stop's
  duration t_stop scaled from the tested classes (t_stop / v0 interpolated in v0).  A stop from a higher
  speed stretches the same speed-down and heat-up pattern over a longer time, which "time" misses.

Values are μ_d / μ_nominal: the correction φ of seed 004 eq. (34) that the set predicts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plant_sim.brake import disc_temperature_scalar, pad_friction_scalar
from plant_sim.params import PadParams

TEST_CLASSES_KMH = (50.0, 80.0, 120.0, 160.0, 180.0)     # speed classes tested on the bench, §6.2
SET_CLASSES_KMH = tuple(float(v) for v in range(10, 210, 10))   # 10 km/h classes, §6.3
FILL_METHODS = ("time", "fraction")


@dataclass(frozen=True)
class BenchParams:
    """The bench's test programme (representative values, chosen)."""

    decel_mps2: float = 1.32          # flywheel deceleration at μ_nominal [m/s²] (the line test's target)
    wheel_radius_m: float = 0.46      # wheel radius of the car the flywheel stands for [m]
    car_mass_kg: float = 40_000.0     # the flywheel's equivalent mass: one car (TrainParams default) [kg]
    sample_s: float = 0.1             # record interval [s]: the set's 100 ms grid (§6.3)
    sim_dt_s: float = 0.01            # integration step [s]
    noise_rel: float = 0.005          # torque transducer noise, relative std [-]
    seed: int = 4                     # noise seed


@dataclass(frozen=True)
class BenchRecord:
    """One bench stop: times [s] from brake application, μ_d/μ_nominal as measured (noisy) and as it was."""

    v0_kmh: float
    t_s: np.ndarray
    mu_ratio: np.ndarray
    mu_ratio_true: np.ndarray
    stop_s: float                     # time to standstill [s]


def bench_stop(v0_kmh: float, pad: PadParams, bench: BenchParams = BenchParams(),
               rng: np.random.Generator | None = None) -> BenchRecord:
    """One stop on the bench from v0 [km/h] with a cold disc (T_d = 0 at the start)."""
    v = v0_kmh / 3.6
    r, dt, a0 = bench.wheel_radius_m, bench.sim_dt_s, bench.decel_mps2
    every = max(int(round(bench.sample_s / dt)), 1)
    temp, k = 0.0, 0
    ts, mus = [], []
    while v > 0.0:
        omega = v / r
        mu_d = pad_friction_scalar(omega, temp, pad)                   # eq. (25), seed 004
        ratio = mu_d / pad.mu_nominal
        if k % every == 0:
            ts.append(k * dt)
            mus.append(ratio)
        decel = a0 * ratio                                             # eq. (24): constant P_c, F ∝ μ_d
        # the flywheel's brake torque is τ = m a r, which heats the discs of one car
        temp = disc_temperature_scalar(temp, bench.car_mass_kg * decel * r, omega, dt, pad)
        v = max(v - decel * dt, 0.0)
        k += 1
    t = np.asarray(ts)
    true = np.asarray(mus)
    rng = rng if rng is not None else np.random.default_rng(bench.seed)
    noisy = true * (1.0 + bench.noise_rel * rng.standard_normal(true.size))
    return BenchRecord(float(v0_kmh), t, noisy, true, k * dt)


def bench_programme(pad: PadParams, bench: BenchParams = BenchParams(),
                    classes_kmh: tuple[float, ...] = TEST_CLASSES_KMH) -> list[BenchRecord]:
    """The tested speed classes, one seeded noise stream for the whole programme."""
    rng = np.random.default_rng(bench.seed)
    return [bench_stop(v0, pad, bench, rng) for v0 in classes_kmh]


def _predict_time(records: list[BenchRecord], v0_kmh: float, t_s: np.ndarray) -> np.ndarray:
    vs = np.array([r.v0_kmh for r in records])
    rows = np.array([np.interp(t_s, r.t_s, r.mu_ratio) for r in records])   # held past each stop
    return np.array([np.interp(v0_kmh, vs, rows[:, j]) for j in range(t_s.size)])


def _predict_fraction(records: list[BenchRecord], v0_kmh: float, t_s: np.ndarray) -> np.ndarray:
    vs = np.array([r.v0_kmh for r in records])
    per_speed = np.array([r.stop_s / r.v0_kmh for r in records])       # t_stop / v0 [s per km/h]
    stop = float(np.interp(v0_kmh, vs, per_speed)) * v0_kmh
    frac = np.minimum(t_s / stop, 1.0)
    rows = np.array([np.interp(frac, r.t_s / r.stop_s, r.mu_ratio) for r in records])
    return np.array([np.interp(v0_kmh, vs, rows[:, j]) for j in range(t_s.size)])


def predict(records: list[BenchRecord], v0_kmh: float, t_s: np.ndarray,
            method: str = "fraction") -> np.ndarray:
    """μ_d/μ_nominal of a stop from v0 [km/h] at times t_s [s], from the tested classes (module docstring)."""
    if method == "time":
        return _predict_time(records, v0_kmh, t_s)
    if method == "fraction":
        return _predict_fraction(records, v0_kmh, t_s)
    raise ValueError(f"fill method must be one of {', '.join(FILL_METHODS)}, got {method!r}")


def held_out_errors(pad: PadParams, bench: BenchParams = BenchParams(),
                    held_out_kmh: tuple[float, ...] = (80.0, 120.0, 160.0)) -> dict[str, dict[str, float]]:
    """Leave-one-out: each interior tested class is predicted from the others and compared with its true
    (noise-free) bench curve over its stop.  method -> {"rms": .., "max": ..} of μ_d/μ_nominal [-]."""
    records = bench_programme(pad, bench)
    out = {}
    for method in FILL_METHODS:
        errs = []
        for held in held_out_kmh:
            rest = [r for r in records if r.v0_kmh != held]
            truth = next(r for r in records if r.v0_kmh == held)
            errs.append(predict(rest, held, truth.t_s, method) - truth.mu_ratio_true)
        e = np.concatenate(errs)
        out[method] = {"rms": float(np.sqrt(np.mean(e * e))), "max": float(np.max(np.abs(e)))}
    return out


@dataclass(frozen=True)
class CoefficientSet:
    """μ(v, t) / μ_nominal on a grid: rows by initial speed class [km/h], columns every dt_s from 0."""

    speeds_kmh: tuple[float, ...]
    dt_s: float
    values: tuple[tuple[float, ...], ...]
    method: str


def coefficient_set(pad: PadParams, bench: BenchParams = BenchParams(), method: str = "fraction",
                    speeds_kmh: tuple[float, ...] = SET_CLASSES_KMH) -> CoefficientSet:
    """The BCU's friction-coefficient set from the bench programme, on the 10 km/h × 100 ms grid."""
    records = bench_programme(pad, bench)
    longest = max(r.stop_s / r.v0_kmh for r in records) * max(speeds_kmh)
    t = np.arange(0.0, math.ceil(longest / bench.sample_s) + 1) * bench.sample_s
    rows = tuple(tuple(round(float(x), 5) for x in predict(records, v0, t, method)) for v0 in speeds_kmh)
    return CoefficientSet(tuple(speeds_kmh), bench.sample_s, rows, method)
