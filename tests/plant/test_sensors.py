"""Sensors: seeded noise and quantisation on the true state; the accelerometer sees the slope."""

import numpy as np
import pytest

from plant_sim.params import PlantParams, SensorParams
from plant_sim.plant import Plant
from plant_sim.sensors import SensorModel, quantise
from plant_sim.track import Track

TRACK = Track.from_segments([(-1000.0, "dry"), (200.0, "wet")], gradient=[(-1000.0, 5.0), (150.0, -12.0)])


def sense_sequence(seed: int, n_reads: int = 50):
    plant = Plant(PlantParams(), TRACK, v0_mps=20.0, seed=seed)
    valve, wsp = np.full(6, 0.6), np.zeros(6, np.int64)
    reads = []
    for k in range(n_reads * 10):
        if k % 10 == 0:
            reads.append(plant.sense())
        plant.step(valve, wsp)
    return reads


def as_matrix(reads):
    return np.array([[r.axle_speed_rad_s, r.cyl_pressure_Pa, r.accel_mps2] for r in reads])


def test_same_seed_same_numbers_different_seed_different_numbers():
    a, b, c = as_matrix(sense_sequence(7)), as_matrix(sense_sequence(7)), as_matrix(sense_sequence(8))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.mean(a != c) > 0.5                       # most readings differ, not just one


def test_readings_are_quantised_and_non_negative():
    reads = sense_sequence(1)
    sp = SensorParams()
    for r in reads:
        for arr, q in ((r.axle_speed_rad_s, sp.axle_speed_quantum_rad_s),
                       (r.cyl_pressure_Pa, sp.pressure_quantum_Pa), (r.accel_mps2, sp.accel_quantum_mps2)):
            assert arr.shape == (6,)
            assert np.allclose(arr / q, np.round(arr / q), atol=1e-6)
        assert np.all(r.axle_speed_rad_s >= 0.0) and np.all(r.cyl_pressure_Pa >= 0.0)


def test_noise_has_the_stated_spread_around_the_truth():
    sp = SensorParams()
    model = SensorModel(sp, seed=5)
    n = 20_000
    omega, p, a = np.full(n, 40.0), np.full(n, 2e5), np.full(n, -0.8)
    r = model.read(omega, p, a, np.zeros(n), 9.81)
    assert np.mean(r.axle_speed_rad_s) == pytest.approx(40.0, abs=0.001)
    assert np.std(r.axle_speed_rad_s) == pytest.approx(sp.axle_speed_noise_std_rad_s, rel=0.05)
    assert np.std(r.cyl_pressure_Pa) == pytest.approx(sp.pressure_noise_std_Pa, rel=0.05)
    assert np.mean(r.accel_mps2) == pytest.approx(-0.8, abs=0.001)
    assert np.std(r.accel_mps2) == pytest.approx(sp.accel_noise_std_mps2, rel=0.05)


def test_accelerometer_reads_acceleration_plus_g_sin_slope_eq_1_seed_004():
    uphill = Track.from_segments([(-1000.0, "dry")], gradient=[(-1000.0, 25.0)])
    plant = Plant(PlantParams(sensors=SensorParams(accel_noise_std_mps2=0.0)), uphill, v0_mps=0.0)
    plant.step(np.ones(6), np.zeros(6, np.int64))       # at rest, braked
    expected = 9.81 * 0.025 / np.sqrt(1 + 0.025 ** 2)
    assert plant.sense().accel_mps2 == pytest.approx(np.full(6, expected), abs=0.001)


def test_quantise():
    assert quantise(np.array([0.0124, -0.0126, 0.0175]), 0.005) == pytest.approx([0.01, -0.015, 0.02])
