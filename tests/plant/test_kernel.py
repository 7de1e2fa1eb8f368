"""The compiled plant step (plant_sim.kernel.step_cars, numba) against the same function interpreted
(`step_cars.py_func`, which calls the plain Python `*_scalar` functions): the same bits, step for step,
for every model the step has (valve and lag cylinders, pad friction, the three adhesion curves, a θ
blend, bad inputs)."""

import dataclasses

import numpy as np
import pytest

from plant_sim import kernel
from plant_sim.params import AdhesionParams, BrakeParams, PadParams, PlantParams
from plant_sim.plant import Plant
from plant_sim.track import Track

TRACK = Track.from_segments([(-500.0, "dry"), (30.0, "wet"), (60.0, "dry", 20.0)])
STEPS = 3000

pytestmark = pytest.mark.skipif(not hasattr(kernel.step_cars, "py_func"),
                                reason="NUMBA_DISABLE_JIT is set: the step is not compiled")


def _inputs(k: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    phase = k // 400
    u = np.full(n, (0.9, -0.4, 0.0, 1.0, -1.0, 0.2, 0.6, -0.1, 1.5, 0.0)[phase % 10])
    w = np.full(n, (0, 0, 1, 0, 2, 0, 1, 0, 0, 2)[phase % 10], dtype=np.int64)
    ps = np.full(n, 100e3 + 30e3 * (phase % 5))
    if k % 997 == 0:                     # a bad valve command and a bad WSP state now and then
        u[1], w[2], ps[3] = np.nan, 7, np.nan
    return u, w, ps


@pytest.mark.parametrize("variant", ["valve", "lag", "pad", "slip_speed", "constant"])
def test_compiled_step_is_the_interpreted_step_bit_for_bit(variant: str) -> None:
    params = PlantParams()
    if variant == "lag":
        params = dataclasses.replace(params, brake=BrakeParams(pressure_model="lag"))
    elif variant == "pad":
        params = dataclasses.replace(params, pad=PadParams())
    elif variant == "slip_speed":
        params = dataclasses.replace(params, adhesion=AdhesionParams(slip_speed_peak=(0.2, 0.155)))
    elif variant == "constant":
        params = dataclasses.replace(params, adhesion=AdhesionParams(constant_mu=0.12))
    compiled, interpreted = Plant(params, TRACK, 25.0), Plant(params, TRACK, 25.0)
    n = params.n_cars
    refreshed = 0
    for k in range(STEPS):
        u, w, ps = _inputs(k, n)
        got = kernel.step_cars(compiled._st, compiled._tr, compiled._car, compiled._k, compiled._recs,
                               u, w, ps)
        want = kernel.step_cars.py_func(interpreted._st, interpreted._tr, interpreted._car, interpreted._k,
                                        interpreted._recs, u, w, ps)
        assert tuple(got) == tuple(want), f"step {k}"
        if got[0]:
            refreshed += 1
            compiled._refresh_track()
            interpreted._refresh_track()
        assert compiled._st.tobytes() == interpreted._st.tobytes(), f"{variant}: state differs at step {k}"
        assert compiled._tr.tobytes() == interpreted._tr.tobytes(), f"{variant}: θ differs at step {k}"
    assert refreshed >= 2                            # the cars met the wet and the blended dry knots
    assert compiled._st[kernel.S_MAX].max() > 0.0    # and slipped on the way


def test_bad_inputs_are_counted_and_made_safe() -> None:
    plant = Plant(PlantParams(), TRACK, 10.0)
    n = plant.n_cars
    u, w = np.zeros(n), np.zeros(n, dtype=np.int64)
    u[0], u[1], u[2], w[3] = np.nan, np.inf, 3.0, 5
    plant.step(u, w)
    snap = plant.snapshot()
    assert plant.bad_inputs == 3                     # NaN, inf, WSP 5; the 3.0 is clipped, not bad
    assert snap.u[:3] == [0.0, 0.0, 1.0] and snap.w[3] == 0


def test_as_record_reads_like_the_dataclass() -> None:
    bp = BrakeParams()
    rec = kernel.as_record(bp)[0]
    assert rec.alpha_squeeze_Nm_per_Pa == bp.alpha_squeeze_Nm_per_Pa
    assert "pressure_model" not in rec.dtype.names   # a string: not for compiled code
    cc = Plant(PlantParams(), TRACK, 0.0)._recs[2][0]
    assert cc.mass_kg.shape == (6,)


def test_sensor_readings_compiled_interpreted_and_numpy_agree_bit_for_bit() -> None:
    """The compiled readings, the interpreted ones and numpy on the (3, n) arrays with one draw per read
    (the model before the draws came in blocks): the same bits, read after read."""
    from plant_sim.params import SensorParams
    from plant_sim.sensors import NOISE_BLOCK, SensorModel

    sp, n = SensorParams(), 6
    compiled, interpreted = SensorModel(sp, 11, kernel.readings), SensorModel(sp, 11)
    rng, gen = np.random.default_rng(3), np.random.Generator(np.random.PCG64(11))
    std = np.array([[sp.axle_speed_noise_std_rad_s], [sp.pressure_noise_std_Pa], [sp.accel_noise_std_mps2]])
    q = np.array([[sp.axle_speed_quantum_rad_s], [sp.pressure_quantum_Pa], [sp.accel_quantum_mps2]])
    for _ in range(NOISE_BLOCK + 50):                 # across the end of a block of draws
        omega, p = rng.uniform(-0.01, 90.0, n), rng.uniform(-5.0, 450e3, n)
        a, sin_grade = rng.normal(0.0, 1.0, n), rng.uniform(-0.03, 0.03, n)
        got = compiled.read(omega, p, a, sin_grade, 9.81)
        again = interpreted.read(omega, p, a, sin_grade, 9.81)
        noisy = np.stack([omega, p, a + 9.81 * sin_grade]) + std * gen.standard_normal((3, n))
        want = np.round(noisy / q) * q
        want[:2] = np.maximum(want[:2], 0.0)
        for k, field in enumerate(("axle_speed_rad_s", "cyl_pressure_Pa", "accel_mps2")):
            assert getattr(got, field).tobytes() == getattr(again, field).tobytes() == want[k].tobytes()
