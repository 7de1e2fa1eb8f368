"""Extended Kalman filter (seed 004 §3.2, eqs. (19)–(23)) and the BCU's train-deceleration and slope
estimator built on it (§3.1, eq. (1)).

`Ekf` is the filter: `predict` is the time update (19)–(20), `update` one scalar measurement update
(21)–(23) (measurements are processed one at a time, which is the same filter for uncorrelated noise).

`DecelEstimator` is what the BCU runs every cycle.  State x = [v, a, θ_f, θ_r]:
  v    train speed [m/s]
  a    train acceleration [m/s², + forward; braking is a < 0]: the a_actual of eq. (1)
  θ_f  slope angle under the front car's accelerometer [rad, + uphill in the running direction]
  θ_r  slope angle under the rear car's accelerometer [rad]
Process: v⁺ = v + a·dt, a, θ_f, θ_r random walks (braking changes a, the track changes θ).
Measurements: each accelerometer reads z = a + g·sin θ (eq. (1), nonlinear in θ: H = [0, 1, g cos θ]),
the speed estimate reads v.  The two slope mechanisms of §3.1/§5.2 are both in this one filter: a change
that only one accelerometer sees is a slope under that car (front/rear difference), and a lasting
difference between what the accelerometers read and what the speed does (its derivative) is a slope
under both.  A slope step shorter than the train passes under the front accelerometer, then under the
rear one.  The filter returns the train's actual deceleration −a and the mean slope (θ_f + θ_r)/2.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from firmware_py.constants import G_MPS2


class Ekf:
    """x̂, P and the EKF equations of seed 004 (19)–(23); Jacobians are passed in at each step."""

    def __init__(self, x0: np.ndarray, p0: np.ndarray) -> None:
        self.x = np.array(x0, dtype=float)
        self.P = np.array(p0, dtype=float)

    def predict(self, f: Callable[[np.ndarray], np.ndarray], a_jac: np.ndarray, q: np.ndarray) -> None:
        """Time update: x̂⁻ = f(x̂), P⁻ = A P Aᵀ + W Q Wᵀ (eqs. (19)–(20); q is W Q Wᵀ)."""
        self.x = f(self.x)
        self.P = a_jac @ self.P @ a_jac.T + q

    def update(self, z: float, h: float, h_row: np.ndarray, r: float) -> float:
        """Measurement update with one scalar z, predicted h(x̂⁻), Jacobian row H and variance V R Vᵀ:
        K = P Hᵀ (H P Hᵀ + R)⁻¹, x̂ = x̂⁻ + K (z − h), P = (I − K H) P (eqs. (21)–(23)).
        Returns the innovation z − h."""
        ph = self.P @ h_row
        s = float(h_row @ ph) + r
        k = ph / s
        nu = z - h
        self.x = self.x + k * nu
        self.P = self.P - np.outer(k, ph)
        self.P = 0.5 * (self.P + self.P.T)             # keep it symmetric against rounding
        return nu


@dataclass(frozen=True)
class DecelEstimatorParams:
    """Noise model of the estimator (chosen; SI units)."""

    accel_std_mps2: float = 0.05          # accelerometer noise incl. running vibration (seed 004 §3, Table 1)
    speed_std_mps: float = 0.02           # speed estimate noise (0.01 m/s resolution on CAN, wheel noise)
    # random-walk intensities [unit²/s]: a moves with braking (jerk-limited 1 m/s³ demands, pneumatic
    # lag), θ with the track (slope steps of tens of ‰ within a car's passage)
    q_accel: float = 0.2                  # [(m/s²)²/s]
    q_slope: float = 2.0e-4               # [rad²/s]
    q_speed: float = 1.0e-4               # [(m/s)²/s] (couplers, wheel speed vs train speed)
    g_mps2: float = G_MPS2


class DecelEstimator:
    """step(dt, accel_front, accel_rear, speed | None) -> (deceleration [m/s²], slope tan θ [-])."""

    def __init__(self, p: DecelEstimatorParams | None = None) -> None:
        self.p = p or DecelEstimatorParams()
        self.ekf: Ekf | None = None

    def reset(self) -> None:
        self.ekf = None

    def step(self, dt_s: float, accel_front: float, accel_rear: float,
             speed_mps: float | None) -> tuple[float, float]:
        p = self.p
        if self.ekf is None:
            v0 = speed_mps if speed_mps is not None else 0.0
            a0 = 0.5 * (accel_front + accel_rear)
            self.ekf = Ekf(np.array([v0, a0, 0.0, 0.0]), np.diag([1.0, 0.5, 1e-3, 1e-3]))
        ekf = self.ekf
        a_jac = np.array([[1.0, dt_s, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
                          [0.0, 0.0, 0.0, 1.0]])
        q = np.diag([p.q_speed, p.q_accel, p.q_slope, p.q_slope]) * dt_s
        ekf.predict(lambda x: a_jac @ x, a_jac, q)
        r_acc = p.accel_std_mps2 ** 2
        for idx, z in ((2, accel_front), (3, accel_rear)):
            theta = ekf.x[idx]
            h_row = np.zeros(4)
            h_row[1] = 1.0
            h_row[idx] = p.g_mps2 * math.cos(theta)                        # ∂h/∂θ, eq. (1)
            ekf.update(z, ekf.x[1] + p.g_mps2 * math.sin(theta), h_row, r_acc)   # eq. (1), seed 004
        if speed_mps is not None:
            ekf.update(speed_mps, ekf.x[0], np.array([1.0, 0.0, 0.0, 0.0]), p.speed_std_mps ** 2)
        return self.decel_mps2, self.slope

    @property
    def decel_mps2(self) -> float:
        """The train's actual deceleration −a [m/s², + braking], gravity removed."""
        return -float(self.ekf.x[1]) if self.ekf is not None else 0.0

    @property
    def slope(self) -> float:
        """Mean slope under the two accelerometers, tan θ [-] (+ uphill; 0.001 = 1 ‰)."""
        if self.ekf is None:
            return 0.0
        return math.tan(0.5 * (float(self.ekf.x[2]) + float(self.ekf.x[3])))

    @property
    def slopes(self) -> tuple[float, float]:
        """tan θ under the front and the rear accelerometer [-]."""
        if self.ekf is None:
            return 0.0, 0.0
        return math.tan(float(self.ekf.x[2])), math.tan(float(self.ekf.x[3]))
