"""Train and wheel dynamics through the Plant: stopping on constant adhesion, standstill, couplers."""

import math

import numpy as np
import pytest

from plant_sim.dynamics import (
    car_acceleration,
    car_constants,
    coupler_extension,
    coupler_force,
    davis_resistance,
    grade_curvature_resistance,
    other_forces,
    slip_rate,
    slip_speed,
    wheel_acceleration,
)
from plant_sim.errors import PlantConfigError
from plant_sim.params import AdhesionParams, BrakeParams, PlantParams, TrainParams
from plant_sim.plant import Plant
from plant_sim.track import Track

FLAT_DRY = Track.from_segments([(-5000.0, "dry")])


def run_until_stopped(plant, valve, wsp, max_s=200.0):
    valve, wsp = np.asarray(valve, float), np.asarray(wsp, np.int64)
    while not plant.stopped and plant.t_us < max_s * 1e6:
        plant.step(valve, wsp)
    return plant.truth()


def test_constant_adhesion_locked_wheel_stops_in_v2_over_2_mu_g():
    train = TrainParams(masses_kg=(40_000.0,), davis_c0_N=0.0, davis_c1_Ns_per_m=0.0,
                        davis_c2_Ns2_per_m2=0.0, davis_c2_lead_Ns2_per_m2=0.0)
    params = PlantParams(train=train, brake=BrakeParams(fill_rate_Pa_per_s=1e9),   # full pressure at once
                         adhesion=AdhesionParams(constant_mu=0.1))
    plant = Plant(params, FLAT_DRY, v0_mps=25.0, x0_m=0.0)
    locked = False
    while not plant.stopped and plant.t_us < 60e6:
        plant.step(np.ones(1), np.zeros(1, np.int64))
        locked = locked or plant.truth()["omega_rad_s"][0] == 0.0
    truth = plant.truth()
    expected = 25.0 ** 2 / (2 * 0.1 * 9.81)                 # 318.6 m
    assert plant.stopped and locked
    assert truth["x_m"][0] == pytest.approx(expected, rel=0.01)
    assert truth["slip_speed_mps"][0] == 0.0 and truth["v_mps"][0] == 0.0


def test_initial_state_rolling_couplers_at_rest():
    plant = Plant(PlantParams(), FLAT_DRY, v0_mps=20.0, x0_m=100.0)
    truth = plant.truth()
    assert truth["x_m"] == pytest.approx(100.0 - 25.0 * np.arange(6))
    assert truth["omega_rad_s"] == pytest.approx(np.full(6, 20.0 / 0.46))
    assert truth["slip_speed_mps"].tolist() == [0.0] * 6
    assert truth["coupler_dl_m"] == pytest.approx(np.zeros(5), abs=1e-12)
    assert truth["coupler_force_N"] == pytest.approx(np.zeros(5), abs=1e-6)
    assert truth["a_mps2"].tolist() == [0.0] * 6
    assert plant.t_us == 0 and plant.n_cars == 6 and not plant.stopped


def test_time_is_an_integer_count_of_microseconds():
    plant = Plant(PlantParams(dt_us=250), FLAT_DRY, v0_mps=10.0)
    for _ in range(4001):
        plant.step(np.zeros(6), np.zeros(6, np.int64))
    assert plant.t_us == 1_000_250 and isinstance(plant.t_us, int)


def test_coasting_decelerates_by_the_davis_resistance():
    plant = Plant(PlantParams(), FLAT_DRY, v0_mps=25.0)
    plant.step(np.zeros(6), np.zeros(6, np.int64))
    cc = car_constants(TrainParams())
    decel = -plant.truth()["a_mps2"]
    f_r = davis_resistance(np.full(6, 25.0), cc)           # 800 + 25·25 + c2·625
    assert f_r[0] == pytest.approx(800 + 625 + 8 * 625) and f_r[1] == pytest.approx(800 + 625 + 3 * 625)
    # wheels keep rolling: the adhesion force that spins them down is small, so v̇ ≈ −f_r/m (the lead
    # car, with more drag, pushes on the coupler only after the first step)
    assert decel == pytest.approx(f_r / 40_000.0, rel=0.08)


def test_grade_and_curvature_resistance_eq_5():
    m = np.array([40_000.0])
    assert grade_curvature_resistance(m, np.array([0.01]), np.array([2.0]), 9.81)[0] == pytest.approx(
        40_000 * 9.81 * 0.01 + 0.004 * 40_000 * 2.0)


def test_coupler_force_eq_2_damping_and_end_stop():
    cc = car_constants(TrainParams(masses_kg=(1.0, 1.0)))
    dl = np.array([0.05])
    assert coupler_force(dl, np.zeros(1), cc)[0] == pytest.approx(80_000 * (1 - 0.5 * 0.05 ** 2) * 0.05)
    assert coupler_force(np.zeros(1), np.array([0.1]), cc)[0] == pytest.approx(2.0e4 * 0.1)
    beyond = coupler_force(np.array([-0.12]), np.array([-0.01]), cc)[0]
    assert beyond == pytest.approx(80_000 * (1 - 0.5 * 0.12 ** 2) * -0.12 - 2.0e4 * 0.01 - 1.0e7 * 0.02
                                   - 1.0e8 * 0.02 * 0.01)
    x = np.array([10.0, -15.2])
    assert coupler_extension(x, cc) == pytest.approx([0.2])


def test_slip_rate_is_car_minus_wheel_acceleration_eq_3():
    cc = car_constants(TrainParams())
    rng = np.random.default_rng(1)
    f_other, f, tau = rng.normal(0, 5e3, 6), rng.uniform(0, 5e4, 6), rng.uniform(0, 3e4, 6)
    expected = car_acceleration(f_other, f, cc) - cc.r_m * wheel_acceleration(f, tau, cc)
    assert slip_rate(f_other, f, tau, cc) == pytest.approx(expected, rel=1e-12)
    assert slip_speed(np.array([10.0]), np.array([20.0]), 0.46)[0] == pytest.approx(10.0 - 9.2)


def test_other_forces_sum_coupler_terms_of_eq_3():
    cc = car_constants(TrainParams(masses_kg=(1.0, 1.0, 1.0)))
    phi = np.array([100.0, -40.0])
    got = other_forces(np.zeros(3), phi, np.zeros(3), cc)
    assert got == pytest.approx([-100.0, 100.0 + 40.0, -40.0])      # Φ_{i−1} − Φ_i


def test_standstill_is_held_on_a_downhill_while_braked_and_left_when_released():
    track = Track.from_segments([(-5000.0, "dry")], gradient=[(-5000.0, -30.0)])
    plant = Plant(PlantParams(), track, v0_mps=5.0)
    run_until_stopped(plant, np.ones(6), np.zeros(6))
    assert plant.stopped
    x_stop = plant.truth()["x_m"].copy()
    for _ in range(3000):                              # 3 s braked at rest on −30 ‰
        plant.step(np.ones(6), np.zeros(6, np.int64))
        assert plant.stopped
    truth = plant.truth()
    assert truth["x_m"].tolist() == x_stop.tolist()
    # the static force holding each car is the downhill force less c0 (plus the couplers)
    assert truth["brake_force_N"].sum() == pytest.approx(6 * (40_000 * 9.81 * 0.03 / math.sqrt(1.0009) - 800),
                                                         rel=1e-3)
    for _ in range(2000):                              # release: the train rolls off downhill
        plant.step(-np.ones(6), np.zeros(6, np.int64))
    assert not plant.stopped and np.all(plant.truth()["v_mps"] > 0.1)


def test_standstill_on_the_flat_without_brakes_stays():
    plant = Plant(PlantParams(), FLAT_DRY, v0_mps=0.0)
    for _ in range(500):
        plant.step(np.zeros(6), np.zeros(6, np.int64))
    assert plant.stopped and plant.truth()["x_m"][0] == 0.0


def test_one_car_braking_alone_loads_the_couplers_within_the_end_stop():
    plant = Plant(PlantParams(), FLAT_DRY, v0_mps=20.0)
    valve = np.zeros(6)
    valve[0] = 1.0                                          # only the leading car brakes
    dl_min = 0.0
    for _ in range(5000):
        plant.step(valve, np.zeros(6, np.int64))
        truth = plant.truth()
        dl_min = min(dl_min, truth["coupler_dl_m"].min())
        assert np.all(truth["omega_rad_s"] >= 0.0)
        assert np.all(truth["omega_rad_s"] * 0.46 <= truth["v_mps"] + 1e-12)
    assert dl_min < -0.05                                    # compressed: the cars behind push
    assert dl_min > -0.12                  # ... but the buffers go solid at 0.1 m (spring alone: ~0.6 m)


def test_bad_construction_arguments_are_rejected():
    with pytest.raises(PlantConfigError, match="v0_mps"):
        Plant(PlantParams(), FLAT_DRY, v0_mps=-1.0)
    with pytest.raises(PlantConfigError, match="seed"):
        Plant(PlantParams(), FLAT_DRY, v0_mps=1.0, seed=-3)
    with pytest.raises(PlantConfigError, match="dt_us"):
        PlantParams(dt_us=0.001)
    plant = Plant(PlantParams(), FLAT_DRY, v0_mps=1.0)
    with pytest.raises(PlantConfigError, match="6 valve commands"):
        plant.step(np.zeros(5), np.zeros(5, np.int64))
