"""railhil works installed: the wheel carries the DBC, the scenarios, the rail profiles and the campaigns,
and an installed railhil runs a shipped scenario by name from any directory.

The wheel is built from this checkout (`pip wheel --no-deps`) and installed without its dependencies into
a fresh virtual environment outside the checkout, which borrows the dependencies (not railhil) from the
test's own environment: a `.pth` line adds that site-packages folder to the path, and the editable
install's hooks in it are not run (path entries added by a `.pth` file are not site folders).
"""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = {"dbc": ("train_brake.dbc",), "scenarios": ("default.toml", "preview_slip_dp.toml"),
        "scenarios/profiles": ("mixed1000.csv",), "campaigns": ("mass_sweep.toml",)}


def test_pyproject_lists_every_package_of_the_tree():
    """setuptools is given the package list by name (the data folders are mapped into it): a package
    added to the tree and not to pyproject.toml would be missing from the wheel."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    tops = ("hil", "firmware_py", "plant_sim", "railhil")
    tree = {".".join(p.parent.relative_to(ROOT).parts)
            for top in tops for p in (ROOT / top).rglob("__init__.py")}
    assert tree - listed == set(), "packages missing from pyproject.toml [tool.setuptools] packages"
    assert {p for p in listed - tree if not p.startswith("hil._data.")} == set()


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    env = dict(os.environ, RAILHIL_PURE="1")      # the files it carries; the compile: make's install
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out),
                           str(ROOT)], capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (whl,) = out.glob("railhil-*.whl")
    return whl


def test_the_wheel_carries_the_data_files(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for folder, files in DATA.items():
        for f in files:
            assert f"hil/_data/{folder}/{f}" in names, f"{folder}/{f} is not in {wheel.name}"
    assert not any(n.startswith("hil/_data/dbc/generator") for n in names)    # the generator stays in git
    assert "hil/studies/wheel_slip/reproduce.py" in names


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> dict[str, str]:
    venv = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    bin_dir = venv / ("Scripts" if os.name == "nt" else "bin")
    purelib = subprocess.run([str(bin_dir / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()"
                              "['purelib'])"], capture_output=True, text=True, check=True).stdout.strip()
    Path(purelib, "railhil-test-deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    proc = subprocess.run([sys.executable, "-m", "pip", "--python", str(bin_dir / "python"), "install",
                           "--no-deps", "-q", str(wheel)], capture_output=True, text=True, timeout=300)
    if proc.returncode != 0 and "--python" in proc.stderr:          # a pip older than 22.3
        proc = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target",
                               purelib, str(wheel)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    return env


def railhil(env: dict, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["railhil", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_installed_railhil_is_the_wheel_not_the_checkout(installed, tmp_path):
    proc = subprocess.run(["python", "-c", "import hil, hil.resources as r; print(hil.__file__); "
                                           "print(r.default_dbc())"],
                          cwd=tmp_path, env=installed, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    module, dbc = proc.stdout.split()
    assert not Path(module).is_relative_to(ROOT) and Path(dbc).is_file()
    assert Path(dbc).parent.parts[-2:] == ("_data", "dbc")


def test_installed_railhil_lists_and_runs_a_shipped_scenario_from_anywhere(installed, tmp_path):
    listed = railhil(installed, tmp_path, "scenarios")
    assert listed.returncode == 0, listed.stderr
    assert "default" in listed.stdout and "6-car train, 90 km/h" in listed.stdout
    run = railhil(installed, tmp_path, "run", "default", "--lockstep", "--out", "run", "-q")
    assert run.returncode == 0, run.stderr
    assert "stopping distance" in run.stdout
    trace = tmp_path / "run" / "trace.blf"
    dbc = subprocess.run(["python", "-c", "import hil.resources as r; print(r.default_dbc())"], cwd=tmp_path,
                         env=installed, capture_output=True, text=True).stdout.strip()
    decoded = railhil(installed, tmp_path, "trace", "decode", str(trace), "--dbc", dbc,
                      "--message", "BCU_DEMAND", "--format", "csv")
    assert decoded.returncode == 0, decoded.stderr
    assert decoded.stdout.count("BCU_DEMAND,TargetDecel") > 1000         # ~2900 frames of 10 ms
    assert (tmp_path / "run" / "kpis.json").is_file() and (tmp_path / "run" / "report.html").is_file()


def test_init_writes_an_editable_copy_that_runs(installed, tmp_path):
    init = railhil(installed, tmp_path, "init", "work")
    assert init.returncode == 0, init.stderr
    scenario = tmp_path / "work" / "default.toml"
    assert scenario.is_file() and (tmp_path / "work" / "train_brake.dbc").is_file()
    assert 'dbc = "train_brake.dbc"' in scenario.read_text()
    again = railhil(installed, tmp_path, "init", "work")
    assert again.returncode == 2 and again.stderr.startswith("error: ") and "exists" in again.stderr
    run = railhil(installed, tmp_path, "run", str(scenario), "--lockstep", "--out", "mine", "-q",
                  "--set", "max_duration_s=5")
    assert run.returncode == 0, run.stderr
    meta = (tmp_path / "mine" / "run.json").read_text()
    assert str(tmp_path / "work" / "train_brake.dbc") in meta                # the copy, not the wheel's
