"""FMUs in the loop (hil.fmi): railhil's plant and a BECU exported by `railhil export-fmu` and imported back
give the native run's trace byte for byte; the C plant FMU of examples/fmu_plant brakes a one-car train in
lockstep and in real time; every FMU the project writes passes FMPy's validation; bad FMUs and maps are one
line, exit 2.  Real FMUs through FMPy and PythonFMU, real runs through the CLI."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from hil.fmi.fmu import open_fmu, validation_problems
from hil.fmi.mapping import fmi_unit

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "fmu_plant"
RAILHIL = [sys.executable, "-m", "hil"]
ENV = {**os.environ, "PYTHONHASHSEED": "0"}


def railhil(*args, cwd=None, timeout=600) -> subprocess.CompletedProcess:
    return subprocess.run([*RAILHIL, *map(str, args)], capture_output=True, text=True, cwd=cwd, env=ENV,
                          timeout=timeout)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> dict[str, Path]:
    """The default scenario's plant and BECU3 exported once, and the native lockstep run beside them."""
    tmp = tmp_path_factory.mktemp("fmu-export")
    out = {}
    for what, name in (("plant", "train.fmu"), ("BECU3", "becu3.fmu")):
        proc = railhil("export-fmu", what, "default", "-o", tmp / name)
        assert proc.returncode == 0, proc.stderr
        assert "FMPy validation passed" in proc.stdout
        out[what] = tmp / name
    proc = railhil("run", "default", "--lockstep", "--out", tmp / "native", "-q")
    assert proc.returncode == 0, proc.stderr
    out["native"] = tmp / "native"
    return out


@pytest.fixture(scope="module")
def brake_car(tmp_path_factory) -> Path:
    """examples/fmu_plant's C plant compiled by FMPy (cmake and a C compiler), beside its map and scenario."""
    missing = [n for n, found in (("a C compiler", shutil.which("cc") or shutil.which("gcc")),
                                  ("cmake", shutil.which("cmake"))) if not found]
    if missing:
        pytest.skip(f"cannot compile the C plant FMU: {' and '.join(missing)} not on PATH")
    spec = importlib.util.spec_from_file_location("build_brake_car", EXAMPLE / "build_brake_car.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    folder = tmp_path_factory.mktemp("brake-car")
    module.build_brake_car(folder / "brake_car.fmu")
    for name in ("one_car.toml", "brake_car_map.toml"):
        shutil.copy(EXAMPLE / name, folder / name)
    return folder


def test_the_exported_plant_imported_back_gives_the_native_run_byte_for_byte(exported, tmp_path):
    proc = railhil("run", "default", "--lockstep", "--set", f"plant.fmu={exported['plant']}",
                   "--out", tmp_path)
    assert proc.returncode == 0, proc.stderr
    native, fmu = (json.loads((d / "kpis.json").read_text()) for d in (exported["native"], tmp_path))
    assert fmu["stopping_distance_m"] == pytest.approx(native["stopping_distance_m"], rel=1e-3)
    assert sha256(tmp_path / "trace.blf") == sha256(exported["native"] / "trace.blf")
    assert sha256(tmp_path / "truth.csv") == sha256(exported["native"] / "truth.csv")
    line = "FMU PLANT               RailhilPlant (train.fmu, FMI 2.0 co-simulation, by PythonFMU"
    assert line in proc.stdout
    recorded = json.loads((tmp_path / "run.json").read_text())["fmus"]["PLANT"]
    assert recorded["sha256"] == sha256(exported["plant"]) and recorded["model"] == "RailhilPlant"


def test_an_exported_becu_imported_as_becu3_gives_the_same_verdicts_and_trace(exported, tmp_path):
    proc = railhil("run", "default", "--lockstep", "--set", f"nodes.BECU3.fmu={exported['BECU3']}",
                   "--out", tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1].startswith("verdict: PASS")
    assert sha256(tmp_path / "trace.blf") == sha256(exported["native"] / "trace.blf")
    stats = json.loads((tmp_path / "run.json").read_text())["node_stats"]["BECU3"]
    assert stats["step_errors"] == 0 and stats["cycles"] > 2000


def test_exported_fmus_carry_the_bench_port_names_units_and_descriptions(exported):
    plant = open_fmu(exported["plant"])
    v = plant.variables
    assert v["BECU1_PRESS_CMD.ValveCmd"].causality == "input"
    assert v["BECU1_PRESS_CMD.WspValve"].type == "Integer"
    assert v["PLANT_CAR6_SENSORS.CylPressure"].unit == "Pa"
    assert v["truth.v_mps_1"].unit == "m/s" and v["truth.v_mps_1"].description
    assert v["truth.coupler_dl_m_5"].causality == "output" and "truth.coupler_dl_m_6" not in v
    speed = v["train.initial_speed_kmh"]
    assert speed.causality == "parameter" and speed.unit == "km/h"
    assert plant.step_size_s == pytest.approx(0.001)
    becu = open_fmu(exported["BECU3"])
    assert becu.variables["BCU_DEMAND.rx_age_s"].unit == "s"
    assert becu.variables["BECU3_PRESS_CMD.CylPressureSet"].unit == "Pa"
    assert becu.step_size_s == pytest.approx(0.01)
    for path in (exported["plant"], exported["BECU3"]):
        assert validation_problems(path) == []


def test_the_exported_plant_takes_the_scenario_values_as_parameters(exported, tmp_path):
    """--set train.initial_speed_kmh reaches the FMU's parameter: the same run as native at 120 km/h."""
    native = tmp_path / "native"
    fmu = tmp_path / "fmu"
    for out, extra in ((native, []), (fmu, ["--set", f"plant.fmu={exported['plant']}"])):
        proc = railhil("run", "default", "--lockstep", "--set", "train.initial_speed_kmh=120", "--set",
                       "max_duration_s=8", *extra, "--out", out, "-q")
        assert proc.returncode == 0, proc.stderr
    assert sha256(fmu / "truth.csv") == sha256(native / "truth.csv")


def test_the_c_plant_fmu_brakes_one_car_to_a_stop_in_lockstep(brake_car, tmp_path):
    assert validation_problems(brake_car / "brake_car.fmu") == []
    proc = railhil("run", brake_car / "one_car.toml", "--lockstep", "--out", tmp_path)
    assert proc.returncode == 0, proc.stderr
    kpis = json.loads((tmp_path / "kpis.json").read_text())
    assert kpis["stopped"]
    # 90 km/h at ~1 m/s² after the 0.5 s desk event: a few hundred metres
    assert 150 < kpis["stopping_distance_m"] < 450
    again = tmp_path / "again"
    assert railhil("run", brake_car / "one_car.toml", "--lockstep", "--out", again, "-q").returncode == 0
    assert sha256(again / "trace.blf") == sha256(tmp_path / "trace.blf")      # deterministic


@pytest.mark.realtime
def test_the_c_plant_fmu_brakes_one_car_to_a_stop_in_real_time(brake_car, tmp_path):
    proc = railhil("run", brake_car / "one_car.toml", "--realtime", "--out", tmp_path, timeout=300)
    last = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    # the verdict is whatever the shared machine allowed; only real time may fail it
    assert proc.returncode == 0 or "real time NOT HELD" in last, proc.stdout[-2000:] + proc.stderr
    assert json.loads((tmp_path / "kpis.json").read_text())["stopped"]


@pytest.mark.realtime
def test_the_exported_plant_fmu_runs_the_default_scenario_in_real_time(exported, tmp_path):
    proc = railhil("run", "default", "--realtime", "--set", f"plant.fmu={exported['plant']}",
                   "--out", tmp_path, timeout=300)
    last = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    assert proc.returncode == 0 or "real time NOT HELD" in last, proc.stdout[-2000:] + proc.stderr
    kpis = json.loads((tmp_path / "kpis.json").read_text())
    native = json.loads((exported["native"] / "kpis.json").read_text())
    assert kpis["stopped"]
    assert kpis["stopping_distance_m"] == pytest.approx(native["stopping_distance_m"], rel=0.02)


# ------------------------------------------------------------------------------------------------- bad input
def _model_exchange_only(src: Path, out: Path) -> Path:
    """The FMU at `src` with its co-simulation interface renamed to model exchange."""
    with zipfile.ZipFile(src) as a, zipfile.ZipFile(out, "w") as b:
        for item in a.infolist():
            data = a.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = data.replace(b"CoSimulation", b"ModelExchange")
            b.writestr(item, data)
    return out


def _without_binaries(src: Path, out: Path) -> Path:
    with zipfile.ZipFile(src) as a, zipfile.ZipFile(out, "w") as b:
        for item in a.infolist():
            if not item.filename.startswith("binaries/"):
                b.writestr(item, a.read(item.filename))
    return out


def _scenario_with_map(folder: Path, fmu: Path, map_text: str) -> Path:
    (folder / "bad_map.toml").write_text(map_text)
    text = (folder / "one_car.toml").read_text().replace('fmu_map = "brake_car_map.toml"',
                                                         'fmu_map = "bad_map.toml"')
    text = text.replace('fmu = "brake_car.fmu"', f'fmu = "{fmu}"')
    path = folder / "bad_one_car.toml"
    path.write_text(text)
    return path


GOOD_MAP = (EXAMPLE / "brake_car_map.toml").read_text()


@pytest.mark.parametrize("case, expected", [
    ("not_zip", "not an FMU"),
    ("model_exchange", "has no co-simulation interface"),
    ("no_binary", "has no binary for this platform"),
    ("unknown_variable", "has no variable 'p_cly'; closest: p_cyl"),
    ("output_as_input", "has causality 'output': the bench sets inputs only"),
    ("integer_for_fraction", "is an Integer: it cannot carry BECU1_PRESS_CMD.ValveCmd"),
    ("wrong_unit", "cannot convert"),
    ("missing_truth", "gives no truth.slip_speed_mps_1"),
])
def test_a_bad_fmu_or_map_is_one_line_and_exit_2(brake_car, tmp_path, case, expected):
    fmu = brake_car / "brake_car.fmu"
    map_text = GOOD_MAP
    if case == "not_zip":
        fmu = tmp_path / "train.fmu"
        fmu.write_text("not a zip archive\n")
    elif case == "model_exchange":
        fmu = _model_exchange_only(fmu, tmp_path / "me.fmu")
    elif case == "no_binary":
        fmu = _without_binaries(fmu, tmp_path / "src.fmu")
    elif case == "unknown_variable":
        map_text = GOOD_MAP.replace('{ from = "p_cyl" }', '{ from = "p_cly" }')
    elif case == "output_as_input":
        map_text = GOOD_MAP.replace("u_valve = {", "v = {")
    elif case == "integer_for_fraction":
        map_text = GOOD_MAP.replace('dump = { from = "BECU1_PRESS_CMD.WspValve" }',
                                    'dump = { from = "BECU1_PRESS_CMD.ValveCmd" }')
    elif case == "wrong_unit":
        map_text = GOOD_MAP.replace('{ from = "v" }', '{ from = "p_cyl" }')
    elif case == "missing_truth":
        map_text = GOOD_MAP.replace('"truth.slip_speed_mps_1" = { from = "s_slip" }\n', "")
    folder = tmp_path / "case"
    shutil.copytree(brake_car, folder)
    scenario = _scenario_with_map(folder, fmu, map_text)
    proc = railhil("run", scenario, "--lockstep", "--out", tmp_path / "out")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert expected in lines[0]
    assert "Traceback" not in proc.stderr


def test_export_fmu_refuses_what_it_cannot_export(tmp_path):
    proc = railhil("export-fmu", "BECU9", "default", "-o", tmp_path / "x.fmu")
    assert proc.returncode == 2 and "not a BECU of scenario 'default'" in proc.stderr
    proc = railhil("export-fmu", "plant", "default", "-o", tmp_path / "x.zip")
    assert proc.returncode == 2 and "ends in .fmu" in proc.stderr


def test_fmi_units_are_read_as_pint_reads_them():
    assert fmi_unit("m/s2") == "m/s^2"
    assert fmi_unit("1") is None and fmi_unit("") is None
    assert fmi_unit("km/h") == "km/h"
