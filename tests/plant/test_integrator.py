"""The fixed-step integrator: accuracy at dt = 1 ms against dt = 0.1 ms, and why it is linearly implicit.

The slip dynamics are stiff at low speed: the wheel's eigenvalue −(1/M + r²/J)·N·μ'(σ)/v grows as v → 0
(and without bound as σ → 0, since μ ∝ √σ). Explicit Euler at 1 ms goes unstable there; the plant's
linearly-implicit step (chord slope of the adhesion) does not, and converges to the reference.
"""

import numpy as np
import pytest

from plant_sim.adhesion import mu
from plant_sim.dynamics import car_constants, slip_rate
from plant_sim.params import RAIL_CONDITIONS, AdhesionParams, PlantParams, TrainParams
from plant_sim.plant import Plant
from plant_sim.track import Track

WET_TO_DRY = Track.from_segments([(-1000.0, "wet"), (120.0, "dry")])
INPUT_PERIOD_US = 10_000          # the BECUs' cycle


def brake_with_wsp(dt_us: int, v0: float = 22.0):
    """6 cars brake from v0 on wet → dry with the same 10 ms input law for any dt: a P pressure
    controller to 250 kPa (more than wet rail can take, so the wheels slip) and a textbook WSP on the
    true slip speed (hold above 0.8 m/s, vent above 1.5 m/s). Returns the lead car's stopping
    distance, and per car the max and mean slip speed sampled at 10 ms."""
    plant = Plant(PlantParams(dt_us=dt_us), WET_TO_DRY, v0_mps=v0)
    valve, wsp = np.zeros(6), np.zeros(6, np.int64)
    slips = []
    next_input_us = 0
    while not plant.stopped:
        if plant.t_us >= next_input_us:
            next_input_us += INPUT_PERIOD_US
            truth = plant.truth()
            s = truth["slip_speed_mps"]
            wsp[:] = np.where(s > 1.5, 2, np.where(s > 0.8, 1, 0))
            valve[:] = np.clip((250e3 - truth["p_Pa"]) / 20e3, -1.0, 1.0)
            slips.append(s)
        plant.step(valve, wsp)
        assert plant.t_us < 120e6
    slips = np.array(slips)
    return plant.truth()["x_m"][0], slips.max(axis=0), slips.mean(axis=0), plant.t_us


@pytest.fixture(scope="module")
def runs():
    return brake_with_wsp(1000), brake_with_wsp(100)


def test_stopping_distance_within_half_a_percent_of_the_0_1_ms_reference(runs):
    (dist, _, _, t_stop), (dist_ref, _, _, t_ref) = runs
    assert 200.0 < dist_ref < 600.0                   # a real stop, not a slide
    assert dist == pytest.approx(dist_ref, rel=0.005)
    assert t_stop == pytest.approx(t_ref, rel=0.005)


def test_slip_within_stated_tolerance_of_the_reference(runs):
    """Max slip speed per car within 5 %, mean slip speed within 5 % (stated tolerance; the WSP's
    on/off decisions make single peaks differ a little more than integrals)."""
    (_, smax, smean, _), (_, smax_ref, smean_ref, _) = runs
    assert np.all(smax_ref > 0.8)                     # the wheels did slip: the WSP acted on every car
    assert smax == pytest.approx(smax_ref, rel=0.05)
    assert smean == pytest.approx(smean_ref, rel=0.05)


def sign_changes(seq) -> int:
    d = np.sign(np.diff(seq))
    d = d[d != 0]
    return int(np.count_nonzero(d[1:] != d[:-1]))


def test_linearly_implicit_step_is_stable_where_explicit_euler_is_not():
    """One car at 1 m/s on dry rail, brake torque held below the adhesion limit: the plant's slip speed
    rises to its equilibrium and drifts with it as the car slows, without oscillating. Explicit Euler
    on the same equation from the same state at the same dt (|λ·dt| ≈ 10 there) chatters between its
    bounds."""
    train = TrainParams(masses_kg=(40_000.0,))
    plant = Plant(PlantParams(train=train), Track.from_segments([(-100.0, "dry")]), v0_mps=1.0)
    valve, wsp = np.ones(1), np.zeros(1, np.int64)
    for _ in range(150):                              # fill to 150 kPa (τ ≈ 9.6 kN·m), then hold
        plant.step(valve, wsp)
    valve[0] = 0.0
    slips = []
    while plant.truth()["v_mps"][0] > 0.5:
        plant.step(valve, wsp)
        slips.append(plant.truth()["slip_speed_mps"][0])
    assert len(slips) > 100 and np.all(np.isfinite(slips)) and min(slips) > 0.0
    assert sign_changes(slips) <= 1

    cc = car_constants(train)
    theta = np.array([RAIL_CONDITIONS["dry"]])
    truth = plant.truth()
    tau, v, s = truth["tau_Nm"], truth["v_mps"], truth["slip_speed_mps"].copy()
    path = []
    for _ in range(20):                               # v frozen: it hardly changes in 20 ms
        f = mu(theta, s / np.maximum(v, 0.5), v, AdhesionParams()) * cc.normal_force_N
        s = np.clip(s + 1e-3 * slip_rate(np.zeros(1), f, tau, cc), 0.0, v)
        path.append(s[0])
    assert sign_changes(path) >= 10
    assert max(path) > 10 * slips[-1]
