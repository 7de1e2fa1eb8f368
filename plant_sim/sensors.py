"""The car's sensors: take the true state, return what a real sensor reports (noise, quantisation).

Seeded with numpy's PCG64 from an int: the same seed gives the same numbers, draw for draw.
"""

from __future__ import annotations

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


class SensorModel:
    """Noise and quantisation of the three per-car sensors, drawing from one seeded generator."""

    def __init__(self, sp: SensorParams, seed: int) -> None:
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._std = np.array([[sp.axle_speed_noise_std_rad_s], [sp.pressure_noise_std_Pa],
                              [sp.accel_noise_std_mps2]])
        self._q = np.array([[sp.axle_speed_quantum_rad_s], [sp.pressure_quantum_Pa], [sp.accel_quantum_mps2]])

    def read(self, omega_rad_s: np.ndarray, p_Pa: np.ndarray, a_mps2: np.ndarray, sin_grade: np.ndarray,
             g_mps2: float) -> Sensors:
        """Readings from the true ω, p and v̇ (a_mps2, + forward) of each car on a slope sin θ."""
        # the accelerometer reads a + g sin θ, eq. (1) seed 004
        noisy = np.stack([omega_rad_s, p_Pa, a_mps2 + g_mps2 * sin_grade])
        noisy += self._std * self._rng.standard_normal(noisy.shape)
        out = quantise(noisy, self._q)                  # each row to its sensor's quantum, in one pass
        np.maximum(out[:2], 0.0, out=out[:2])           # wheel speed and pressure read ≥ 0
        return Sensors(axle_speed_rad_s=out[0], cyl_pressure_Pa=out[1], accel_mps2=out[2])
