"""Regression: a deterministic open-loop run of the default 6-car train pinned to recorded values.

The inputs exercise every branch of the step: coasting, EP fill and hold, WSP VENT on cars 1, 3, 5 while
2, 4, 6 are on WSP HOLD, EP venting (the release side of the hysteresis, eq. (10a) seed 001) and refill
(its play), an over-brake on the wet section that makes the leading wheels slip (1.2 m/s) until a WSP
vent lets them recover, the wet → dry blend of θ(x), 300 kPa on dry rail down to standstill, 1 s braked
at rest and 1 s released at rest.

The pinned values were computed with the scalar per-car step (plant_sim.plant) and checked against the
numpy-vectorised step it replaced (the plant before the scalar rewrite): over this run, and over the
inputs recorded from a lockstep HIL run of scenarios/default.toml, both gave bit-identical truth()
trajectories (largest difference in x, v, s, p, τ: 0.0). The step is pure Python floats (IEEE double,
correctly rounded math.sqrt), so the values do not depend on numpy or BLAS; the tolerance only leaves
room for a platform that rounds differently.
"""

import numpy as np
import pytest

from plant_sim.params import PlantParams
from plant_sim.plant import Plant
from plant_sim.track import Track

# the track of scenarios/default.toml: dry, wet from 100 m, dry again from 180 m blended over 40 m
DEFAULT_TRACK = Track.from_segments([(-500.0, "dry"), (100.0, "wet"), (180.0, "dry", 40.0)])
N_STEPS = 47_000                       # 47 s at dt = 1 ms


def inputs(k: int) -> tuple[np.ndarray, np.ndarray]:
    """EP valve openings and WSP states for step k (0-based), the same for any run."""
    u, w = np.zeros(6), np.zeros(6, np.int64)
    if 1000 <= k < 1150:
        u[:] = 1.0                     # fill to 150 kPa
    elif 4000 <= k < 4300:
        w[0::2] = 2                    # WSP vent cars 1, 3, 5
    elif 4300 <= k < 4450:
        u[:] = 1.0                     # refill 1, 3, 5 ...
        w[1::2] = 1                    # ... while WSP holds 2, 4, 6
    elif 4450 <= k < 4800:
        u[:] = -0.1                    # EP vent: release side of the hysteresis
    elif 4800 <= k < 4900:
        u[:] = 0.5                     # refill: play, then the squeeze line
    elif 6000 <= k < 6100:
        u[:] = 1.0                     # over-brake on wet rail: the leading wheels slip
    elif 6300 <= k < 6500:
        w[:] = 2                       # WSP vent: the wheels recover
    elif 6500 <= k < 6650:
        u[:] = 1.0                     # refill to 150 kPa
    elif 20000 <= k < 20150:
        u[:] = 1.0                     # 300 kPa on dry rail, to standstill
    elif 45000 <= k < 46000:
        u[:] = 1.0                     # braked at rest (full pressure)
    elif k >= 46000:
        u[:] = -1.0                    # released at rest
    return u, w


# after step k: x_1 [m], v_1, v_6 [m/s], s_1, s_6 [m/s], p_2 [Pa], τ_2 [N·m], Δl_1 [m]
PINNED = {
    4250: (102.95725751698951, 23.19561510499924, 23.108198882565734, 0.0,
           0.01168085570237029, 150000.0, 9600.0, -0.025270913022737318),
    6400: (151.58849116167784, 21.9969701620104, 21.874289240943472, 1.224338637092805,
           0.0011875238086579561, 47500.0, 3000.0, -0.031222700563702688),
    9000: (206.8533937001965, 20.513291738894548, 20.57428205061876, 0.018735735616432218,
           0.00991043510538385, 150000.0, 9600.0, -0.020028320647924147),
    14000: (302.6423406112203, 17.815201689818892, 17.76303276739685, 0.008153608312410092,
            0.04357259294502218, 150000.0, 9600.0, -0.01710947243901728),
    30000: (489.0302152836968, 3.321110426395721, 3.31434440468594, 0.006382224177422597,
            0.006357039250196858, 300000.0, 21600.0, -0.003978072054735549),
}
STOP_STEP = 32_977                     # the first step after which every car stands still
STOP_X1_M = 493.9776342342427


@pytest.fixture(scope="module")
def run():
    plant = Plant(PlantParams(), DEFAULT_TRACK, v0_mps=25.0, seed=1)
    seen, stop = {}, None
    for k in range(N_STEPS):
        plant.step(*inputs(k))
        if stop is None and plant.stopped:
            stop = (k + 1, float(plant.truth()["x_m"][0]))
        if k + 1 in PINNED:
            seen[k + 1] = plant.truth()
    return seen, stop, plant


@pytest.mark.parametrize("k", sorted(PINNED))
def test_trajectory_matches_the_pinned_values(run, k):
    t = run[0][k]
    got = (t["x_m"][0], t["v_mps"][0], t["v_mps"][5], t["slip_speed_mps"][0], t["slip_speed_mps"][5],
           t["p_Pa"][1], t["tau_Nm"][1], t["coupler_dl_m"][0])
    assert got == pytest.approx(PINNED[k], rel=1e-9, abs=1e-12)


def test_the_slipping_wheels_are_the_ones_on_wet_rail(run):
    t = run[0][6400]
    assert np.all(t["slip_speed_mps"][:2] > 1.0) and np.all(t["slip_speed_mps"][2:] < 0.05)


def test_stops_at_the_pinned_step_and_stays_there_braked_and_released(run):
    _, stop, plant = run
    assert stop == (STOP_STEP, pytest.approx(STOP_X1_M, rel=1e-12))
    truth = plant.truth()
    assert plant.stopped and plant.t_us == N_STEPS * 1000
    assert truth["x_m"][0] == stop[1]                      # held braked, then released on the flat
    assert truth["v_mps"].tolist() == [0.0] * 6 and truth["slip_speed_mps"].tolist() == [0.0] * 6
    assert truth["p_Pa"].tolist() == [0.0] * 6 and truth["tau_Nm"].tolist() == [0.0] * 6
