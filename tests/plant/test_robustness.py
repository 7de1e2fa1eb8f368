"""Hostile inputs: the plant never produces NaN or inf, replaces bad inputs by safe ones and counts them."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_sim.params import PlantParams, TrainParams
from plant_sim.plant import Plant
from plant_sim.track import Track

TRACK = Track.from_segments([(-1000.0, "dry"), (30.0, "extra_wet"), (60.0, "wet", 20.0)],
                            gradient=[(0.0, 35.0), (40.0, -40.0)], curvature=[(10.0, 150.0)])
N = 3
PARAMS = PlantParams(train=TrainParams(masses_kg=(30_000.0, 45_000.0, 38_000.0)))

valve_values = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                         st.sampled_from([1e300, -1e300, 1.0, -1.0]))
wsp_values = st.one_of(st.integers(-5, 7), st.sampled_from([0, 1, 2]))


def all_finite(plant) -> bool:
    truth = plant.truth()
    sensed = plant.sense()
    return (all(np.all(np.isfinite(v)) for v in truth.values())
            and all(np.all(np.isfinite(a)) for a in (sensed.axle_speed_rad_s, sensed.cyl_pressure_Pa,
                                                     sensed.accel_mps2)))


@settings(max_examples=40, deadline=None)
@given(v0=st.floats(0.0, 45.0),
       inputs=st.lists(st.tuples(st.lists(valve_values, min_size=N, max_size=N),
                                 st.lists(wsp_values, min_size=N, max_size=N), st.integers(1, 400)),
                       min_size=1, max_size=8))
def test_random_and_hostile_inputs_keep_the_state_finite(v0, inputs):
    plant = Plant(PARAMS, TRACK, v0_mps=v0, seed=3)
    expected_bad = 0
    for valves, wsps, steps in inputs:
        u = np.array(valves, dtype=float)
        w = np.array(wsps, dtype=np.int64)
        bad_per_step = int(np.count_nonzero(~np.isfinite(u))) + sum(x not in (0, 1, 2) for x in wsps)
        for _ in range(steps):
            plant.step(u, w)
        expected_bad += bad_per_step * steps
        assert all_finite(plant)
        truth = plant.truth()
        assert np.all(truth["v_mps"] >= 0.0)
        assert np.all((truth["slip_ratio"] >= 0.0) & (truth["slip_ratio"] <= 1.0))
        assert np.all((truth["p_Pa"] >= 0.0) & (truth["p_Pa"] <= PARAMS.brake.p_max_Pa))
        assert np.all(truth["tau_Nm"] >= 0.0)
        assert np.all((truth["omega_rad_s"] >= 0.0)
                      & (truth["omega_rad_s"] * PARAMS.train.wheel_radius_m <= truth["v_mps"] + 1e-9))
    assert plant.bad_inputs == expected_bad


def test_non_integer_and_nan_wsp_states_are_replaced_by_fill():
    plant = Plant(PARAMS, TRACK, v0_mps=10.0)
    plant.step(np.ones(N), np.array([np.nan, 1.5, 2.0]))
    assert plant.bad_inputs == 2
    assert plant.truth()["wsp_valve"].tolist() == [0, 0, 2]
    plant.step(np.array([np.nan, 0.2, np.inf]), np.zeros(N, np.int64))
    assert plant.bad_inputs == 4
    assert plant.truth()["valve_cmd"].tolist() == [0.0, 0.2, 0.0]


def test_lists_are_accepted_as_inputs():
    plant = Plant(PARAMS, TRACK, v0_mps=10.0)
    plant.step([0.5, 2.0, -3.0], [0, 1, 2])
    assert plant.truth()["valve_cmd"].tolist() == [0.5, 1.0, -1.0]
    assert plant.bad_inputs == 0
