"""Seed 004's plant additions: pad/disc friction μ_d(v, T) (eqs. (24)–(25)), the disc's temperature
from the braking energy, and the front/rear accelerometers on gradient steps shorter than the train."""

import math

import numpy as np
import pytest

from plant_sim.brake import disc_temperature_scalar, pad_friction_scalar
from plant_sim.params import BrakeParams, PadParams, PlantParams, SensorParams, TrainParams
from plant_sim.plant import Plant
from plant_sim.track import Track

PAD = PadParams()


@pytest.mark.parametrize("case, omega, temp, expected", [
    ("standing wheel, cold disc", 0.0, 0.0, PAD.mu_steady * (1 + PAD.n_v) * (1 + PAD.n_T)),
    ("fast, hot: steady state", 1e4, 1e4, PAD.mu_steady),
    ("v_d = 4 m/s, T_d = 35 K", 4.0 / PAD.friction_radius_m, 35.0,
     PAD.mu_steady * (PAD.n_v * math.exp(PAD.m_v_s_per_m * 4.0) + 1) * (PAD.n_T * math.exp(-1.0) + 1)),
    ("backwards wheel reads |ω|", -4.0 / PAD.friction_radius_m, 35.0,
     PAD.mu_steady * (PAD.n_v * math.exp(PAD.m_v_s_per_m * 4.0) + 1) * (PAD.n_T * math.exp(-1.0) + 1)),
])
def test_pad_friction_eq_25(case, omega, temp, expected):
    assert pad_friction_scalar(omega, temp, PAD) == pytest.approx(expected, rel=1e-12)


def test_disc_temperature_is_the_energy_balance():
    pp = PadParams(cooling_W_per_K=0.0)
    temp, energy = 0.0, 0.0
    for _ in range(1000):                       # 1 s of 20 kN·m at 30 rad/s
        temp = disc_temperature_scalar(temp, 20e3, 30.0, 1e-3, pp)
        energy += 20e3 * 30.0 * 1e-3
    assert temp == pytest.approx(energy / pp.heat_capacity_J_per_K)
    hot = 100.0                                 # cooling alone: exponential decay with C/G
    cooled = disc_temperature_scalar(hot, 0.0, 0.0, 1e-3, PAD)
    assert (hot - cooled) / 1e-3 == pytest.approx(hot * PAD.cooling_W_per_K / PAD.heat_capacity_J_per_K)


@pytest.mark.parametrize("bad", [dict(mu_steady=0.0), dict(n_T=-1.0), dict(heat_fraction=1.5),
                                 dict(cooling_W_per_K=-1.0), dict(m_v_s_per_m=float("nan"))])
def test_bad_pad_params_are_named(bad):
    from plant_sim.errors import PlantConfigError

    with pytest.raises(PlantConfigError, match="PadParams"):
        PadParams(**bad)


def braking_plant(pad: PadParams | None, cars: int = 2, v0: float = 16.7) -> Plant:
    params = PlantParams(train=TrainParams(masses_kg=(40_000.0,) * cars),
                         brake=BrakeParams(pressure_model="lag"), pad=pad)
    return Plant(params, Track.from_segments([(0.0, "dry")]), v0_mps=v0, seed=1)


def test_brake_torque_scales_with_mu_over_mu_nominal_eq_24():
    with_pad, without = braking_plant(PAD), braking_plant(None)
    u, w, ps = np.zeros(2), np.zeros(2, dtype=int), np.full(2, 300e3)
    for _ in range(500):
        with_pad.step(u, w, ps)
        without.step(u, w, ps)
    a, b = with_pad.truth(), without.truth()
    assert a["p_Pa"] == pytest.approx(b["p_Pa"])                  # same pneumatics
    line = BrakeParams().alpha_squeeze_Nm_per_Pa * a["p_Pa"] + BrakeParams().beta_squeeze_Nm
    assert a["tau_Nm"] == pytest.approx(line * a["mu_pad"] / PAD.mu_nominal, rel=1e-3)
    assert b["tau_Nm"] == pytest.approx(line)
    assert "mu_pad" not in b and "disc_temp_rise_K" not in b      # no pad model: the foundation's truth


def test_disc_heats_with_the_braking_energy_of_a_stop():
    plant = braking_plant(PAD, cars=1)
    u, w, ps = np.zeros(1), np.zeros(1, dtype=int), np.full(1, 330e3)
    energy, cooled, dt = 0.0, 0.0, 1e-3
    while not plant.stopped and plant.t_us < 30_000_000:
        plant.step(u, w, ps)
        snap = plant.snapshot()
        omega = (snap.v[0] - snap.s[0]) / TrainParams().wheel_radius_m
        energy += snap.tau_brake[0] * omega * dt
        cooled += PAD.cooling_W_per_K * snap.temp_rise[0] * dt
    temp = plant.truth()["disc_temp_rise_K"][0]
    assert plant.stopped
    assert temp * PAD.heat_capacity_J_per_K == pytest.approx(energy - cooled, rel=0.01)
    assert 30.0 < temp < 80.0                       # a 60 km/h stop of a 40 t car, 1e5 J/K of disc surface
    mu = plant.truth()["mu_pad"][0] / PAD.mu_nominal
    assert mu > 1.1                                  # warm disc, standing wheel: the friction has risen


def test_front_and_rear_accelerometers_on_a_step_shorter_than_the_train():
    """A 30 ‰ step 40 m long under a 6-car, 125 m train coasting at 20 m/s: the front car's accelerometer
    reads its acceleration plus g sin θ (eq. (1) seed 004) while it is on the step and the rear car is not,
    the rear car's later, and each reads its plain acceleration off the step (noise off)."""
    quiet = SensorParams(accel_noise_std_mps2=0.0, axle_speed_noise_std_rad_s=0.0, pressure_noise_std_Pa=0.0)
    params = PlantParams(train=TrainParams(masses_kg=(40_000.0,) * 6), sensors=quiet)
    track = Track.from_segments([(0.0, "dry")], gradient=[(0.0, 0.0), (30.0, 30.0), (70.0, 0.0)])
    plant = Plant(params, track, v0_mps=20.0, seed=1)
    g_sin = 9.81 * 0.030 / math.sqrt(1 + 0.030 ** 2)
    seen = {"front": 0, "rear": 0}
    u, w = np.zeros(6), np.zeros(6, dtype=int)
    q = SensorParams().accel_quantum_mps2
    while plant.t_us < 12_000_000:
        plant.step(u, w)
        if plant.t_us % 10_000:
            continue
        truth = plant.truth()
        x, a = truth["x_m"], truth["a_mps2"]
        gravity = plant.sense().accel_mps2 - a                        # what the reading adds to v̇
        on_front, on_rear = 30.0 <= x[0] < 70.0, 30.0 <= x[5] < 70.0
        if on_front and not on_rear:
            assert gravity[0] == pytest.approx(g_sin, abs=q) and gravity[5] == pytest.approx(0.0, abs=q)
            seen["front"] += 1
        if on_rear and not on_front:
            assert gravity[5] == pytest.approx(g_sin, abs=q) and gravity[0] == pytest.approx(0.0, abs=q)
            seen["rear"] += 1
    assert seen["front"] > 100 and seen["rear"] > 100
