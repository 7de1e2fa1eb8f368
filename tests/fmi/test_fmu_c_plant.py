"""The one-car brake plant written in C as an FMI 2.0 co-simulation source FMU (examples/fmu_plant): it is
valid as sources and once FMPy has compiled it, it brakes a car to a stop as railhil's plant does (the
same numbers as plant_sim.Plant for one car), its WSP dump valve vents, bad inputs are replaced by safe
values, and sub-stepping inside a long communication step changes nothing that matters.

The fixture compiles the FMU once per session (cmake and the C compiler, ~1 s); without them the tests
that need the binary skip, saying so.
"""

from __future__ import annotations

import importlib.util
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "fmu_plant"
SOURCE_TREE = EXAMPLE / "brake_car"

P_MAX_PA = 450e3          # BrakeParams.p_max_Pa
FILL_RATE_PA_S = 1.0e6    # BrakeParams.fill_rate_Pa_per_s
WSP_VENT_RATE_PA_S = 2.0e6
R_M = 0.46                # TrainParams.wheel_radius_m
OMEGA_Q, P_Q = 0.005, 10.0   # SensorParams quanta: rad/s, Pa
FULL_BRAKE = {"u_valve": 1.0, "v0": 25.0}


def _build_script():
    spec = importlib.util.spec_from_file_location("build_brake_car", EXAMPLE / "build_brake_car.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def build():
    return _build_script()


@pytest.fixture(scope="session")
def fmu_path(build, tmp_path_factory) -> str:
    """brake_car.fmu with its linux64 (this platform's) binary, compiled once per session."""
    missing = [name for name, found in (("a C compiler (cc, gcc)", shutil.which("cc") or shutil.which("gcc")),
                                        ("cmake", shutil.which("cmake"))) if not found]
    if missing:
        pytest.skip(f"cannot compile the C FMU: {' and '.join(missing)} not on PATH")
    return str(build.build_brake_car(tmp_path_factory.mktemp("fmu-c-plant") / "brake_car.fmu"))


def _simulate(fmu_path: str, stop_time: float = 25.0, output_interval: float = 0.001, **kw):
    """fmpy.simulate_fmu; FMPy steps a co-simulation FMU at output_interval (its step_size is for
    model exchange only)."""
    import fmpy

    return fmpy.simulate_fmu(fmu_path, stop_time=stop_time, output_interval=output_interval, **kw)


def _stop_index(res) -> int:
    """Index of the first sample at standstill (v = 0)."""
    stopped = np.flatnonzero(res["v"] == 0.0)
    assert stopped.size, "the car never stopped"
    return int(stopped[0])


def _quantised(value, quantum):
    return np.maximum(np.rint(np.asarray(value) / quantum) * quantum, 0.0)


class Slave:
    """The FMU stepped in a loop of our own (FMPy's examples/custom_input.py): variables by name."""

    def __init__(self, fmu_path: str, tmp: Path, **start):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        md = read_model_description(fmu_path)
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.types = {v.name: v.type for v in md.modelVariables}
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu_path, unzipdir=str(tmp)),
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName="car")
        self.fmu.instantiate()
        self.fmu.setupExperiment(startTime=0.0)
        self.set(**start)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.n = 0            # steps of dt done: time = n · dt, never a sum of floats
        self.dt = 0.001

    def set(self, **values) -> None:
        for name, value in values.items():
            if self.types[name] == "Integer":
                self.fmu.setInteger([self.vr[name]], [int(value)])
            else:
                self.fmu.setReal([self.vr[name]], [float(value)])

    def get(self, name: str) -> float:
        if self.types[name] == "Integer":
            return self.fmu.getInteger([self.vr[name]])[0]
        return self.fmu.getReal([self.vr[name]])[0]

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / self.dt)):
            self.fmu.doStep(currentCommunicationPoint=self.n * self.dt, communicationStepSize=self.dt)
            self.n += 1

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


# ------------------------------------------------------------------------------------- the source FMU
def test_source_tree_and_source_fmu_validate(build, tmp_path):
    from fmpy import read_model_description
    from fmpy.model_description import read_build_description
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(SOURCE_TREE)) == []
    source_fmu = build.write_source_fmu(tmp_path / "brake_car-source.fmu")
    assert validate_fmu(str(source_fmu)) == []
    md = read_model_description(str(source_fmu))
    assert md.fmiVersion == "2.0" and md.coSimulation.modelIdentifier == "brake_car"
    assert md.coSimulation.canHandleVariableCommunicationStepSize and not md.coSimulation.needsExecutionTool
    assert float(md.defaultExperiment.stepSize) == 0.001
    # buildDescription.xml (FMI 3.0 schema, allowed in FMI 2.0.4 source FMUs) names what <SourceFiles> names
    (config,) = read_build_description(str(SOURCE_TREE), validate=True)
    assert config.modelIdentifier == "brake_car"
    assert config.sourceFileSets[0].sourceFiles == md.buildConfigurations[0].sourceFileSets[0].sourceFiles
    # the GUID the C code checks is the model description's
    assert md.guid in (SOURCE_TREE / "sources" / "brake_car.c").read_text()


def test_variables_as_the_map_expects():
    from fmpy import read_model_description

    md = read_model_description(str(SOURCE_TREE))
    got = {v.name: (v.causality, v.type, v.unit) for v in md.modelVariables}
    assert got == {
        "u_valve": ("input", "Real", "1"), "dump": ("input", "Integer", None),
        "omega_axle": ("output", "Real", "rad/s"), "p_cyl": ("output", "Real", "bar"),
        "a_long": ("output", "Real", "m/s2"), "x": ("output", "Real", "m"), "v": ("output", "Real", "km/h"),
        "s_slip": ("output", "Real", "m/s"), "p_true": ("output", "Real", "Pa"),
        "v0": ("parameter", "Real", "m/s"), "x0": ("parameter", "Real", "m"),
        "mass": ("parameter", "Real", "kg"), "mu_peak": ("parameter", "Real", "1"),
    }
    assert all(v.description for v in md.modelVariables)
    params = {v.name: v for v in md.modelVariables if v.causality == "parameter"}
    assert all(v.variability == "fixed" and v.initial == "exact" for v in params.values())
    assert {n: float(v.start) for n, v in params.items()} == {"v0": 25.0, "x0": 0.0, "mass": 40_000.0,
                                                              "mu_peak": 0.2}


def test_cli_says_which_build_tool_is_missing(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "CC"}
    env["PATH"] = str(tmp_path)                        # an empty folder: neither cmake nor cc
    cmd = [sys.executable, str(EXAMPLE / "build_brake_car.py"), "-o", str(tmp_path / "x.fmu")]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:")
    assert "cmake" in lines[0] and "C compiler" in lines[0]
    assert not (tmp_path / "x.fmu").exists()


# ------------------------------------------------------------------------------------ the built FMU
def test_built_fmu_validates_and_has_this_platforms_binary(fmu_path):
    import fmpy
    from fmpy.validation import validate_fmu

    assert validate_fmu(fmu_path) == []
    assert fmpy.platform in fmpy.supported_platforms(fmu_path)


def test_valve_open_brakes_the_car_to_a_stop(fmu_path):
    res = _simulate(fmu_path, start_values=FULL_BRAKE)
    t, p = res["time"], res["p_true"]
    # the cylinder fills at 1 MPa/s to the reservoir pressure (450 kPa after 0.45 s) and stays there
    assert np.all(np.diff(p) >= 0.0)
    assert np.interp(0.2, t, p) == pytest.approx(0.2 * FILL_RATE_PA_S, rel=1e-6)
    assert p[t >= 0.45 + 1e-9] == pytest.approx(P_MAX_PA, rel=1e-12)
    # the sensors: pressure in bar at 10 Pa, axle speed at 0.005 rad/s, speed in km/h
    np.testing.assert_allclose(res["p_cyl"], _quantised(p, P_Q) * 1e-5, rtol=0, atol=1e-12)
    omega = (res["v"] / 3.6 - res["s_slip"]) / R_M
    np.testing.assert_allclose(res["omega_axle"], _quantised(omega, OMEGA_Q), rtol=0, atol=1e-9)
    assert res["omega_axle"][0] == pytest.approx(54.35)           # 25 m/s / 0.46 m = 54.348 rad/s
    assert res["v"][0] == pytest.approx(90.0) and res["x"][0] == 0.0
    # full brake: 33.6 kN m on a 40 t car at μ̂ = 0.2, below the adhesion peak: ~1.8 m/s², no wheel slide
    i_stop = _stop_index(res)
    braking = (t > 1.0) & (t < t[i_stop] - 0.5)
    assert np.all((res["a_long"][braking] < -1.7) & (res["a_long"][braking] > -1.95))
    assert np.all(res["s_slip"] < 0.155)                          # below the slip speed of the peak
    assert np.all(np.diff(res["v"]) <= 0.0)                       # decelerates, never speeds up
    assert 13.0 < t[i_stop] < 16.0
    assert 170.0 < res["x"][i_stop] < 190.0                       # v0² / 2a ≈ 170 m plus the fill time
    # at rest it stays at rest: no rolling back, x stops growing, the sensors read 0
    after = slice(i_stop, None)
    assert np.all(res["v"][after] == 0.0) and np.all(res["x"][after] == res["x"][i_stop])
    assert np.all(res["omega_axle"][after] == 0.0) and np.all(res["a_long"][i_stop + 1:] == 0.0)


def test_the_same_car_as_railhils_plant(fmu_path):
    """The FMU against plant_sim.Plant for one car with the same adhesion curve (seed 001's μ(s), μ̂ = 0.2,
    ŝ = 0.155 m/s, sliding floor 0.2 μ̂): the same equations and integrator, so the same trajectory."""
    from plant_sim import AdhesionParams, Plant, PlantParams, Track, TrainParams

    params = PlantParams(train=TrainParams(masses_kg=(40_000.0,)),
                         adhesion=AdhesionParams(slip_speed_peak=(0.2, 0.155), slip_speed_slide_ratio=0.2))
    plant = Plant(params, Track.from_segments([(0.0, "dry")]), v0_mps=25.0)
    res = _simulate(fmu_path, stop_time=20.0, start_values=FULL_BRAKE)
    for n in range(1, 20_001):
        plant.step(np.array([1.0]), np.array([0]))
        if n % 500 == 0:
            truth = plant.truth()
            assert res["time"][n] == pytest.approx(n * 1e-3)
            assert res["x"][n] == pytest.approx(truth["x_m"][0], abs=1e-6)
            assert res["v"][n] / 3.6 == pytest.approx(truth["v_mps"][0], abs=1e-9)
            assert res["s_slip"][n] == pytest.approx(truth["slip_speed_mps"][0], abs=1e-9)
            assert res["p_true"][n] == pytest.approx(truth["p_Pa"][0], abs=1e-6)
            assert res["a_long"][n] == pytest.approx(truth["a_mps2"][0], abs=1e-6)


def test_dump_valve_vents_and_holds(fmu_path):
    """dump = 2 (VENT) empties the cylinder at 2 MPa/s although the EP valve stays open; 1 (HOLD) keeps
    the pressure whatever the EP valve does; 0 (FILL) gives the EP valve back."""
    dtype = [("time", np.float64), ("u_valve", np.float64), ("dump", np.int32)]
    signals = np.array([(0.0, 1.0, 0), (1.0, 1.0, 0), (1.0, 1.0, 2), (1.1, 1.0, 2), (1.1, -1.0, 1),
                        (2.0, -1.0, 1), (2.0, 1.0, 0), (3.0, 1.0, 0)], dtype=dtype)
    res = _simulate(fmu_path, stop_time=3.0, input=signals, start_values={"v0": 25.0})
    t, p = res["time"], res["p_true"]

    def at(time):
        return p[int(np.argmin(np.abs(t - time)))]

    assert at(1.0) == pytest.approx(P_MAX_PA)
    assert at(1.05) == pytest.approx(P_MAX_PA - 0.05 * WSP_VENT_RATE_PA_S, rel=1e-6)   # venting ...
    assert at(1.1) == pytest.approx(P_MAX_PA - 0.1 * WSP_VENT_RATE_PA_S, rel=1e-6)
    vent = (t > 1.0 + 1e-9) & (t <= 1.1 + 1e-9)
    assert np.all(np.diff(p[vent]) < 0.0)                                              # ... falling
    hold = (t > 1.1 + 1e-9) & (t <= 2.0 + 1e-9)
    assert np.all(p[hold] == at(1.1))                                                  # held
    assert at(2.1) == pytest.approx(at(1.1) + 0.1 * FILL_RATE_PA_S, rel=1e-6)          # filling again
    # the vent to 0: the brake lets go, only the running resistance is left
    res = _simulate(fmu_path, stop_time=3.0, input=np.array(
        [(0.0, 1.0, 0), (1.0, 1.0, 0), (1.0, 1.0, 2), (3.0, 1.0, 2)], dtype=dtype), start_values={"v0": 25.0})
    t, p = res["time"], res["p_true"]
    assert np.all(p[t >= 1.225 + 1e-9] == 0.0)                                         # 450 kPa in 0.225 s
    a_free = res["a_long"][t > 2.0]
    assert np.all((a_free < 0.0) & (a_free > -0.2))     # Davis: −(800 + 25 v + 8 v²) N / 40 t ≈ −0.16 m/s²


def test_bad_inputs_are_replaced_safely(fmu_path, tmp_path):
    car = Slave(fmu_path, tmp_path, v0=25.0, u_valve=1.0)
    try:
        car.run(0.2)
        p_held = car.get("p_true")
        assert p_held == pytest.approx(0.2 * FILL_RATE_PA_S)
        for bad in (math.nan, math.inf, -math.inf):          # non-finite: valve closed, pressure held
            car.set(u_valve=bad)                             # fmi2Warning: FMPy does not raise
            assert car.get("u_valve") == 0.0
            car.run(0.1)
            assert car.get("p_true") == p_held
        car.set(u_valve=5.0)                                 # out of range: clipped to 1
        assert car.get("u_valve") == 1.0
        car.run(0.1)
        assert car.get("p_true") == pytest.approx(p_held + 0.1 * FILL_RATE_PA_S)
        car.set(u_valve=-3.0)
        assert car.get("u_valve") == -1.0
        for bad_dump in (7, -1, 2**31 - 1):                  # not 0/1/2: FILL, the EP valve acts
            car.set(u_valve=0.0, dump=2)
            car.set(dump=bad_dump)
            assert car.get("dump") == 0
        for name in ("omega_axle", "p_cyl", "a_long", "x", "v", "s_slip", "p_true"):
            assert math.isfinite(car.get(name)), name
    finally:
        car.close()


def test_nan_start_value_runs_and_is_reported(fmu_path, capsys):
    # The warning reaches FMPy's default logger, which prints it. (Not simulate_fmu(logger=...): FMPy's
    # native logger proxy keeps that callback in one process-wide pointer, which dangles once the run is
    # over, so the next FMU that logs in this process crashes it.)
    res = _simulate(fmu_path, stop_time=2.0, start_values={"u_valve": math.nan, "v0": 25.0})
    assert np.all(res["p_true"] == 0.0)                          # NaN is "valve closed": no brake
    assert all(np.all(np.isfinite(res[name])) for name in res.dtype.names)
    assert res["v"][-1] < 90.0 and res["x"][-1] > 49.0           # the car coasts on
    assert "[WARNING] u_valve = nan is not valid, 0 used" in capsys.readouterr().out


def test_parameters_out_of_range_are_refused(fmu_path, tmp_path):
    from fmpy import extract
    from fmpy.fmi1 import FMICallException

    unzipped = extract(fmu_path, unzipdir=str(tmp_path / "fmu"))   # simulate_fmu leaves no temp folder
    for name, value in (("mass", -1.0), ("v0", math.nan), ("mu_peak", 0.0), ("x0", math.inf)):
        with pytest.raises(FMICallException, match="fmi2SetReal"):
            _simulate(unzipped, stop_time=0.01, start_values={name: value})


@pytest.mark.parametrize("interval", [0.01, 0.0025])
def test_sub_stepping_keeps_the_stopping_distance(fmu_path, interval):
    """A communication step of 10 ms runs ten 1 ms steps inside the FMU; 2.5 ms runs three of 0.83 ms."""
    ref = _simulate(fmu_path, start_values=FULL_BRAKE)
    res = _simulate(fmu_path, output_interval=interval, start_values=FULL_BRAKE)
    assert res["time"][1] == pytest.approx(interval)
    x_stop = ref["x"][_stop_index(ref)]
    assert res["x"][_stop_index(res)] == pytest.approx(x_stop, rel=0.01)
    assert res["x"][-1] == pytest.approx(ref["x"][-1], rel=0.01)
    assert res["time"][_stop_index(res)] == pytest.approx(ref["time"][_stop_index(ref)], abs=interval + 0.01)


def test_car_at_rest_stays_at_rest(fmu_path):
    for start in ({"v0": 0.0, "x0": 12.5}, {"v0": 0.0, "x0": 12.5, "u_valve": 1.0}):
        res = _simulate(fmu_path, stop_time=2.0, start_values=start)
        assert np.all(res["v"] == 0.0) and np.all(res["x"] == 12.5) and np.all(res["s_slip"] == 0.0)
        assert np.all(res["a_long"] == 0.0)


def test_fmu_state_rolls_back(fmu_path, tmp_path):
    car = Slave(fmu_path, tmp_path, v0=25.0, u_valve=1.0)
    try:
        car.run(2.0)
        state = car.fmu.getFMUstate()
        saved = car.fmu.serializeFMUstate(state)
        car.run(1.0)
        x_3s = car.get("x")
        car.fmu.setFMUstate(state)
        car.n = 2000
        assert car.get("x") < x_3s
        car.run(1.0)
        assert car.get("x") == x_3s                              # the same steps from the same state
        restored = car.fmu.deSerializeFMUstate(saved)
        car.fmu.setFMUstate(restored)
        car.n = 2000
        car.run(1.0)
        assert car.get("x") == x_3s
        car.fmu.freeFMUstate(restored)
        car.fmu.freeFMUstate(state)
    finally:
        car.close()
