"""The car's sensors: take the true state, return what a real sensor reports (noise, quantisation).

Seeded with numpy's PCG64 from an int: the same seed gives the same numbers, draw for draw.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from plant_sim.params import SensorParams


@dataclass(frozen=True, slots=True)
class Sensors:
    """One reading of every car's sensors, arrays of shape (n,)."""

    axle_speed_rad_s: np.ndarray   # wheelset angular speed ω (tooth-wheel sensor), ≥ 0
    cyl_pressure_Pa: np.ndarray    # brake-cylinder gauge pressure p, ≥ 0
    accel_mps2: np.ndarray         # body-fixed longitudinal accelerometer, + forward, eq. (1) seed 004


def quantise(x: np.ndarray, quantum: float | np.ndarray) -> np.ndarray:
    """Nearest multiple of quantum (an ADC or a fixed-point signal); quantum may broadcast against x."""
    return np.round(x / quantum) * quantum


#: readings whose noise is drawn at once (chosen): numpy's generator gives a block of draws the same
#: numbers as as many draws one after the other, so this changes nothing but the cost
NOISE_BLOCK = 256


def sensor_readings(omega_rad_s, p_Pa, a_mps2, sin_grade, g_mps2, std, q, z, out) -> None:
    """The readings of every car into `out` (3, n): wheel speed, pressure, acceleration, each the true
    value plus its noise std[k] · z[k] (z standard normal), quantised to q[k] (`quantise`: round half to
    even), wheel speed and pressure kept ≥ 0; the accelerometer reads a + g sin θ, eq. (1) seed 004.
    Compiled by plant_sim.kernel; the same operations as numpy on the (3, n) arrays."""
    for i in range(omega_rad_s.shape[0]):
        w = np.rint((omega_rad_s[i] + std[0] * z[0, i]) / q[0]) * q[0]
        pr = np.rint((p_Pa[i] + std[1] * z[1, i]) / q[1]) * q[1]
        out[0, i] = 0.0 if 0.0 > w else w
        out[1, i] = 0.0 if 0.0 > pr else pr
        out[2, i] = np.rint(((a_mps2[i] + g_mps2 * sin_grade[i]) + std[2] * z[2, i]) / q[2]) * q[2]


class SensorModel:
    """Noise and quantisation of the three per-car sensors, drawing from one seeded generator."""

    def __init__(self, sp: SensorParams, seed: int, readings: Callable = sensor_readings) -> None:
        """`readings`: `sensor_readings` as it is, or compiled (the plant passes plant_sim.kernel's)."""
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._readings = readings
        self._std = np.array([sp.axle_speed_noise_std_rad_s, sp.pressure_noise_std_Pa,
                              sp.accel_noise_std_mps2])
        self._q = np.array([sp.axle_speed_quantum_rad_s, sp.pressure_quantum_Pa, sp.accel_quantum_mps2])
        self._noise = np.zeros((0, 3, 0))      # NOISE_BLOCK readings' draws, used in order
        self._next = 0

    def read(self, omega_rad_s: np.ndarray, p_Pa: np.ndarray, a_mps2: np.ndarray, sin_grade: np.ndarray,
             g_mps2: float) -> Sensors:
        """Readings from the true ω, p and v̇ (a_mps2, + forward) of each car on a slope sin θ."""
        n = len(omega_rad_s)
        if self._next == len(self._noise) or self._noise.shape[2] != n:
            self._noise = self._rng.standard_normal((NOISE_BLOCK, 3, n))
            self._next = 0
        out = np.empty((3, n))
        self._readings(np.asarray(omega_rad_s, dtype=float), np.asarray(p_Pa, dtype=float),
                 np.asarray(a_mps2, dtype=float), np.asarray(sin_grade, dtype=float), float(g_mps2),
                 self._std, self._q, self._noise[self._next], out)
        self._next += 1
        return Sensors(axle_speed_rad_s=out[0], cyl_pressure_Pa=out[1], accel_mps2=out[2])
