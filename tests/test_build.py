"""The build: the hot modules compiled by mypyc, pure Python where they cannot be, and never a stale mix.

`make test` runs this file on the build it installed, and again with RAILHIL_PURE=1 (with the golden
traces): each run checks that the modules it imports are the build `hil.build.state()` names.
"""

from __future__ import annotations

import ast
import hashlib
import importlib
import importlib.machinery
import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from hil import build

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = json.loads((ROOT / "tests" / "golden_traces.json").read_text())


def mypy_files() -> set[str]:
    """The .py files [tool.mypy] checks (its folders expanded)."""
    files = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]["files"]
    out = set()
    for f in files:
        path = ROOT / f
        paths = sorted(path.rglob("*.py")) if path.is_dir() else [path]
        out |= {str(p.relative_to(ROOT)) for p in paths}
    return out


def imports_numba(path: Path) -> bool:
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "numba" for a in node.names):
            return True
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "numba":
            return True
    return False


def test_mypy_checks_every_compiled_module_and_only_numba_kernels_stay_pure():
    """What mypyc compiles, mypy --strict checks (make test fails on a type error); a checked module left
    out of the build is a package's __init__ or a numba kernel (numba compiles those itself)."""
    checked = mypy_files()
    assert set(build.COMPILED) <= checked, sorted(set(build.COMPILED) - checked)
    left_out = sorted(p for p in checked - set(build.COMPILED)
                      if not p.endswith("__init__.py") and not imports_numba(ROOT / p))
    assert not left_out, f"checked by mypy but neither compiled nor a numba kernel: {left_out}"
    assert not [p for p in build.COMPILED if imports_numba(ROOT / p)], "numba in a compiled module"


def test_make_rebuilds_when_any_compiled_module_changes():
    """The Makefile's list of compiled sources (the prerequisites of .venv/.built, read from hil/build.py
    with grep) is build.COMPILED, as make itself reads it."""
    printer = "print-compiled:\n\t@echo $(COMPILED_SRC)\n"
    make = ["make", "-s", "--no-print-directory", "-f", "Makefile", "-f", "-", "print-compiled"]
    proc = subprocess.run(make, cwd=ROOT, input=printer, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == list(build.COMPILED)


def test_the_modules_that_run_are_the_build_the_state_names():
    state = build.state()
    for name in (build.module_name(p) for p in build.COMPILED):
        origin = importlib.import_module(name).__file__
        compiled = any(origin.endswith(s) for s in importlib.machinery.EXTENSION_SUFFIXES)
        assert compiled == (state.mode == "compiled"), (name, origin, state)
    if os.environ.get(build.PURE_ENV, "") not in ("", "0"):
        assert state.mode == "pure", state
    assert state.as_dict()["mode"] in ("compiled", "pure")


def tree_of_sources(tmp_path: Path, digests: bool = True) -> Path:
    """A copy of the compiled modules' sources, each with a (stand-in) extension file beside it and the
    build's record of their digests."""
    root = tmp_path / "tree"
    for p in build.COMPILED:
        (root / p).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / p, root / p)
        (root / p).with_name(Path(p).stem + importlib.machinery.EXTENSION_SUFFIXES[0]).write_bytes(b"")
    manifest = {"mypyc": "2.4.1", "sources": {p: hashlib.sha256((root / p).read_bytes()).hexdigest()
                                              for p in build.COMPILED} if digests else {}}
    (root / "hil").mkdir(exist_ok=True)
    (root / "hil" / build.MANIFEST).write_text(json.dumps(manifest))
    return root


def test_a_fresh_build_runs_compiled_and_an_edited_source_runs_everything_pure(tmp_path):
    root = tree_of_sources(tmp_path)
    state = build.decide(root, build.read_manifest(root), "")
    assert state.mode == "compiled" and state.reason == "mypyc 2.4.1"
    assert len(state.modules) == len(build.COMPILED)

    edited = build.COMPILED[-1]
    with open(root / edited, "a") as f:
        f.write("# an edit after the build\n")
    state = build.decide(root, build.read_manifest(root), "")
    assert state.mode == "pure" and state.modules == ()
    assert state.reason.startswith(f"{edited} changed since the build compiled it"), state.reason


def test_railhil_pure_and_a_missing_record_run_pure_and_say_why(tmp_path):
    root = tree_of_sources(tmp_path)
    assert build.decide(root, build.read_manifest(root), "1").reason == "RAILHIL_PURE=1"
    assert build.decide(root, None, "").mode == "pure"              # extensions nobody recorded: not trusted
    for p in build.COMPILED:
        for s in importlib.machinery.EXTENSION_SUFFIXES:
            (root / p).with_name(Path(p).stem + s).unlink(missing_ok=True)
    state = build.decide(root, {"pure_reason": "built without a C compiler (cc not found)"}, "")
    assert state == build.BuildState("pure", "built without a C compiler (cc not found)", ())


def test_a_stale_build_warns_once_and_the_run_still_works(tmp_path):
    """In a process: the finder that puts the sources first is what makes a pure run out of a tree with
    extensions beside them (here: RAILHIL_PURE=1 on the real tree; the golden traces then run pure)."""
    code = ("import hil, importlib\n"
            "from hil import build\n"
            "names = [build.module_name(p) for p in build.COMPILED]\n"
            "pure = all(importlib.import_module(n).__file__.endswith('.py') for n in names)\n"
            "print(build.state().mode, pure)")
    env = dict(os.environ, **{build.PURE_ENV: "1"})
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["pure", "True"]
    assert "warning" not in proc.stderr                            # asked for: no warning


SHIPPED = ["firmware_py", "plant_sim", "hil", "railhil", "dbc", "scenarios", "campaigns", "programmes"]


def test_a_build_without_a_c_compiler_installs_pure_and_gives_the_golden_trace(tmp_path):
    """A machine without a C compiler (CC names none): the wheel is pure Python, `railhil --version` says
    so and why, and the default scenario's lockstep trace is the golden one, byte for byte."""
    src = tmp_path / "src"
    for d in SHIPPED:
        shutil.copytree(ROOT / d, src / d, ignore=shutil.ignore_patterns(
            "__pycache__", "*.so", build.MANIFEST, "*.egg-info"))
    for f in ("setup.py", "pyproject.toml", "README.md"):
        shutil.copy(ROOT / f, src / f)
    env = {k: v for k, v in os.environ.items() if k != build.PURE_ENV}
    env.update(CC="/nonexistent/cc", PIP_DISABLE_PIP_VERSION_CHECK="1")
    wheel = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
                            "-w", str(tmp_path / "dist"), str(src)], capture_output=True, text=True, env=env,
                           timeout=600)
    assert wheel.returncode == 0, wheel.stderr[-2000:]
    (whl,) = (tmp_path / "dist").glob("railhil-*.whl")
    assert whl.name.endswith("-py3-none-any.whl"), whl.name              # no compiled module in it
    site = tmp_path / "site"
    inst = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site),
                           str(whl)], capture_output=True, text=True, env=env, timeout=600)
    assert inst.returncode == 0, inst.stderr[-2000:]

    run_env = dict(env, PYTHONPATH=str(site))
    version = subprocess.run([sys.executable, "-m", "hil", "--version"], capture_output=True, text=True,
                             env=run_env, cwd=tmp_path, timeout=120)
    assert version.returncode == 0, version.stderr
    assert "pure Python (built without a C compiler (/nonexistent/cc not found))" in version.stdout
    out = tmp_path / "run"
    run = subprocess.run([sys.executable, "-m", "hil", "run", "default", "--lockstep", "--out", str(out),
                          "--quiet"], capture_output=True, text=True, env=run_env, cwd=tmp_path, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads((out / "run.json").read_text())["build"]["mode"] == "pure"
    digest = hashlib.sha256((out / "trace.blf").read_bytes()).hexdigest()
    assert digest == GOLDEN["default"]["trace.blf"]


@pytest.mark.parametrize("flag", ["--version"])
def test_railhil_version_names_the_build(flag):
    proc = subprocess.run([sys.executable, "-m", "hil", flag], capture_output=True, text=True, cwd=ROOT,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert build.state().line() in proc.stdout
