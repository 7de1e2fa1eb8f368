"""The own-train GPS receiver: true position, speed and heading in, the fix a real receiver reports out.

Seed 002 §IV–§V has the anti-collision device read latitude χ, longitude ψ and speed v from a
satellite receiver; §IX reports, from the field test with an Arduino and a GPS module, that "some
signal instability was detected in the GPS feed". This model adds, to the truth:

- **horizontal error**: a first-order Gauss–Markov process per axis (north, east) — GPS position
  errors (ionosphere, orbits, multipath) drift slowly rather than jump from fix to fix — with
  stationary std σ and correlation time τ: e_k+1 = φ e_k + σ √(1 − φ²) w_k, φ = exp(−Δt/τ)
  (A. Gelb, "Applied Optimal Estimation", MIT Press 1974, §3.8); τ = 0 gives white noise;
- **speed error**: white noise on the Doppler speed; the course over ground is the direction of the
  noisy velocity vector, so its error is ≈ σ_v / v [rad] (it is held below a minimum speed, as
  receivers do when standing still);
- **dropouts**: no fix (RMC status V, GGA quality 0) for a window: at random (Poisson starts,
  exponential durations: tunnels, cuttings, bridges) and in given time windows;
- **signal instability** (§IX): episodes in which the receiver keeps reporting a *valid* fix that is
  off by tens of metres (multipath and satellite-set changes), with fewer satellites and a higher
  HDOP: Poisson starts, exponential durations, a jump vector drawn once per episode.

Seeded with numpy's PCG64 from an int (as plant_sim/sensors.py): same seed, same fixes. Time is
passed in (integer µs); no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plant_sim.errors import PlantConfigError
from plant_sim.geo import offset_north_east

# a circular bivariate normal with per-axis std σ has its median radius (CEP) at σ √(2 ln 2)
CEP_PER_SIGMA = math.sqrt(2.0 * math.log(2.0))
NEO6_CEP_M = 2.5  # u-blox NEO-6 data sheet (GPS.G6-HW-09005), horizontal position accuracy 2.5 m CEP


def _check(ok: bool, msg: str) -> None:
    if not ok:
        raise PlantConfigError(f"GpsParams: {msg}")


@dataclass(frozen=True, slots=True)
class GpsParams:
    """What the receiver adds to the truth. The GPS module of seed 002's Arduino device is not named;
    the values are those of the commonest one (u-blox NEO-6M) where its data sheet gives them, else
    representative values, chosen, with the reason."""

    rate_hz: float = 1.0                    # fix rate; NEO-6 default 1 Hz (max 5 Hz); issue #7: 1–10 Hz
    horiz_noise_std_m: float = NEO6_CEP_M / CEP_PER_SIGMA  # per-axis σ [m] from the NEO-6's 2.5 m CEP
    horiz_noise_tau_s: float = 30.0         # correlation time τ [s] of the position error; chosen
    speed_noise_std_mps: float = 0.1        # σ of speed [m/s]: NEO-6 data sheet, velocity accuracy 0.1 m/s
    heading_hold_speed_mps: float = 0.5     # below this speed the course is held [m/s]; chosen
    dropout_rate_per_h: float = 2.0         # random dropout starts per hour; chosen (a few tunnels per hour)
    dropout_mean_s: float = 8.0             # mean random dropout length [s]; chosen (short tunnel/cutting)
    outages_s: tuple[tuple[float, float], ...] = ()  # fixed no-fix windows [start, end) [s of sim time]
    instability_rate_per_h: float = 6.0     # instability episodes per hour; chosen (seed 002 §IX: observed)
    instability_mean_s: float = 5.0         # mean episode length [s]; chosen
    instability_jump_std_m: float = 30.0    # per-axis σ of the jump [m]; chosen ("tens of m", multipath)
    n_sats: int = 8                         # satellites used, nominal; chosen
    n_sats_unstable: int = 4                # satellites used during instability; chosen (fix barely held)
    hdop: float = 1.0                       # HDOP nominal [-]; chosen (open sky)
    hdop_unstable: float = 4.0              # HDOP during instability [-]; chosen

    def __post_init__(self) -> None:
        _check(math.isfinite(self.rate_hz) and 1.0 <= self.rate_hz <= 10.0,
               f"rate_hz must be in [1, 10] Hz (issue #7), got {self.rate_hz!r}")
        for name in ("horiz_noise_std_m", "horiz_noise_tau_s", "speed_noise_std_mps",
                     "heading_hold_speed_mps", "dropout_rate_per_h", "instability_rate_per_h",
                     "instability_jump_std_m"):
            val = getattr(self, name)
            _check(isinstance(val, int | float) and math.isfinite(val) and val >= 0.0,
                   f"{name} must be a finite number >= 0, got {val!r}")
        for name in ("dropout_mean_s", "instability_mean_s", "hdop", "hdop_unstable"):
            val = getattr(self, name)
            _check(isinstance(val, int | float) and math.isfinite(val) and val > 0.0,
                   f"{name} must be a finite number > 0, got {val!r}")
        for name in ("n_sats", "n_sats_unstable"):
            val = getattr(self, name)
            _check(isinstance(val, int) and 0 <= val <= 99, f"{name} must be an int in [0, 99], got {val!r}")
        for k, w in enumerate(self.outages_s):
            ok = isinstance(w, tuple | list) and len(w) == 2 and all(
                isinstance(c, int | float) and math.isfinite(c) for c in w) and w[0] < w[1]
            _check(ok, f"outages_s[{k}] must be (start_s, end_s) with start < end, got {w!r}")

    @property
    def period_us(self) -> int:
        """Time between fixes [µs], rounded to the µs."""
        return round(1e6 / self.rate_hz)


@dataclass(frozen=True, slots=True)
class GpsFix:
    """One receiver output. Angles in degrees (heading clockwise from true north, [0, 360)), SI otherwise.
    When `valid` is False there is no position: lat/lon/speed/heading are NaN."""

    t_us: int             # time of the fix [µs of sim time]
    valid: bool           # a position fix (RMC status A, GGA quality ≥ 1)
    lat_deg: float
    lon_deg: float
    alt_m: float          # altitude above mean sea level [m]
    speed_mps: float      # speed over ground [m/s], ≥ 0
    heading_deg: float    # course over ground [deg]
    n_sats: int           # satellites used
    hdop: float           # horizontal dilution of precision [-]
    unstable: bool        # ground truth, not transmitted: an instability episode is biasing this fix


class GpsModel:
    """A receiver: call `fix(t_us, truth...)` at each output time (every `params.period_us`)."""

    def __init__(self, params: GpsParams, seed: int) -> None:
        self.p = params
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._err_ne: np.ndarray | None = None       # Gauss–Markov horizontal error (north, east) [m]
        self._t_us: int | None = None
        self._dropout_until_us = -1
        self._unstable_until_us = -1
        self._jump_ne = np.zeros(2)
        self._heading_deg: float | None = None  # last course reported [deg]
        self._outages_us = [(round(a * 1e6), round(b * 1e6)) for a, b in params.outages_s]

    def _starts(self, rate_per_h: float, dt_s: float) -> bool:
        """An event of a Poisson process of `rate_per_h` occurs in the last dt_s: P = 1 − exp(−λ Δt)."""
        return bool(self._rng.random() < -math.expm1(-rate_per_h / 3600.0 * dt_s))

    def _duration_us(self, mean_s: float) -> int:
        return round(self._rng.exponential(mean_s) * 1e6)

    def fix(self, t_us: int, lat_deg: float, lon_deg: float, speed_mps: float, heading_deg: float,
            alt_m: float = 0.0) -> GpsFix:
        """The fix the receiver reports at `t_us` [µs] for the true position [deg], speed [m/s] ≥ 0,
        heading [deg] and altitude [m]. Calls must come in non-decreasing time."""
        p, rng = self.p, self._rng
        dt_s = 0.0 if self._t_us is None else max(t_us - self._t_us, 0) / 1e6
        self._t_us = t_us
        # the draws below happen in the same order every call, whatever the state: reproducible
        sigma = p.horiz_noise_std_m
        if self._err_ne is None:       # start from the stationary distribution
            self._err_ne = sigma * rng.standard_normal(2)
        else:
            phi = math.exp(-dt_s / p.horiz_noise_tau_s) if p.horiz_noise_tau_s > 0.0 else 0.0
            self._err_ne = phi * self._err_ne + sigma * math.sqrt(1.0 - phi * phi) * rng.standard_normal(2)
        dv = p.speed_noise_std_mps * rng.standard_normal(2)  # (along, across) velocity error [m/s]
        drop_start = self._starts(p.dropout_rate_per_h, dt_s)
        drop_len = self._duration_us(p.dropout_mean_s)
        inst_start = self._starts(p.instability_rate_per_h, dt_s)
        inst_len = self._duration_us(p.instability_mean_s)
        jump = p.instability_jump_std_m * rng.standard_normal(2)

        if drop_start and t_us > self._dropout_until_us:
            self._dropout_until_us = t_us + drop_len
        if inst_start and t_us > self._unstable_until_us:
            self._unstable_until_us = t_us + inst_len
            self._jump_ne = jump
        unstable = t_us < self._unstable_until_us
        no_fix = t_us < self._dropout_until_us or any(a <= t_us < b for a, b in self._outages_us)
        n_sats, hdop = (p.n_sats_unstable, p.hdop_unstable) if unstable else (p.n_sats, p.hdop)
        if no_fix:
            nan = math.nan
            return GpsFix(t_us, False, nan, nan, nan, nan, nan, 0, 99.99, unstable)

        err = self._err_ne + (self._jump_ne if unstable else 0.0)
        lat, lon = offset_north_east(lat_deg, lon_deg, float(err[0]), float(err[1]))
        # noisy velocity vector in the (along, across) frame of the true heading
        v_along, v_across = max(speed_mps, 0.0) + dv[0], dv[1]
        speed = math.hypot(v_along, v_across)
        if speed >= p.heading_hold_speed_mps:
            self._heading_deg = (heading_deg + math.degrees(math.atan2(v_across, v_along))) % 360.0
        elif self._heading_deg is None:          # first fix at standstill: the true heading, held
            self._heading_deg = heading_deg % 360.0
        return GpsFix(t_us, True, lat, lon, float(alt_m), speed, self._heading_deg, n_sats, hdop, unstable)
