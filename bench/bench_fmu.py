"""FMUs in the loop: cost per plant step of an FMU against railhil's own plant, and the lockstep real-time
factor of the default scenario with its plant exported as an FMU (PythonFMU) against the native plant.

The same scenario, DBC and codec; the runs alternate (native, FMU, native, ...) and the best of each is
kept, so that the machine's load moves both alike.  The plant step is timed as the plant node makes it
(FmuPlant.step: the commands set when they changed, one doStep; plant_sim.Plant.step), with the commands
changing every 10 ms as the BECUs' do.  The C plant FMU of examples/fmu_plant (one car) is timed too
where a C compiler and CMake are there to build it.

    python bench/bench_fmu.py
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ISSUE = "#44"
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hil.can.codec import Codec  # noqa: E402
from hil.can.dbc import load_dbc  # noqa: E402
from hil.fmi.export import export_plant  # noqa: E402
from hil.runtime.assembly import build_plant  # noqa: E402
from hil.runtime.lockstep import run_lockstep  # noqa: E402
from hil.scenario import load_scenario  # noqa: E402

STEPS = 5000


def _step_us(plant, n: int, steps: int = STEPS) -> float:
    """Mean wall time of one plant step [µs], commands changing every 10 steps (a 10 ms command cycle)."""
    rng = np.random.default_rng(1)
    commands = [(rng.uniform(-1, 1, n), rng.integers(0, 3, n)) for _ in range(steps // 10 + 1)]
    t0 = time.perf_counter()
    for k in range(steps):
        u, w = commands[k // 10]
        plant.step(u, w)
    return (time.perf_counter() - t0) / steps * 1e6


def _lockstep(scenario, db, codec) -> tuple[float, float]:
    t0 = time.perf_counter()
    out = run_lockstep(scenario, db, codec, None)
    return out.end_us / 1e6, time.perf_counter() - t0


def _c_plant(tmp: Path) -> Path | None:
    """examples/fmu_plant's C plant, compiled (CMake's output kept off the benchmark's table)."""
    if not (shutil.which("cmake") and (shutil.which("cc") or shutil.which("gcc"))):
        return None
    script = ROOT / "examples" / "fmu_plant" / "build_brake_car.py"
    spec = importlib.util.spec_from_file_location("build_brake_car", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            return module.build_brake_car(tmp / "brake_car.fmu")
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def run(repeats: int = 3) -> list[tuple[str, str]]:
    native = load_scenario("default")
    db = load_dbc()
    codec = Codec(db)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        fmu_path = export_plant(native, Path(tmp) / "train.fmu")
        with_fmu = load_scenario("default", sets=[f"plant.fmu={fmu_path}"])
        n = native.train.cars
        native_us = _step_us(build_plant(native), n)
        fmu_us = _step_us(build_plant(with_fmu, db), n)
        rows.append((f"plant step, native plant_sim ({n} cars)", f"{native_us:.1f} us"))
        rows.append((f"plant step, exported plant FMU ({n} cars, PythonFMU via FMPy)",
                     f"{fmu_us:.1f} us ({fmu_us / native_us:.1f}x native)"))
        c_fmu = _c_plant(Path(tmp))
        if c_fmu is not None:
            one = load_scenario(ROOT / "examples" / "fmu_plant" / "one_car.toml", sets=[f"plant.fmu={c_fmu}"])
            native_spec = one.plant.model_copy(update={"fmu": None, "fmu_map": None})
            one_native = one.model_copy(update={"plant": native_spec})
            c_us = _step_us(build_plant(one, db), 1)
            n1_us = _step_us(build_plant(one_native, db), 1)
            rows.append(("plant step, C plant FMU (1 car, examples/fmu_plant)",
                         f"{c_us:.1f} us ({c_us / n1_us:.1f}x native 1 car, {n1_us:.1f} us)"))
        else:
            rows.append(("plant step, C plant FMU (1 car)", "not measured: no C compiler or CMake"))
        _lockstep(native, db, codec)                             # warm-up: codec, caches
        best_native, best_fmu = (0.0, float("inf")), (0.0, float("inf"))
        for _ in range(repeats):
            a = _lockstep(native, db, codec)
            b = _lockstep(with_fmu, db, codec)
            best_native = min(best_native, a, key=lambda r: r[1])
            best_fmu = min(best_fmu, b, key=lambda r: r[1])
    f_native = best_native[0] / best_native[1]
    f_fmu = best_fmu[0] / best_fmu[1]
    rows.append((f"lockstep default scenario, native plant (best of {repeats})",
                 f"{f_native:.1f}x real time ({best_native[1]:.2f} s wall)"))
    rows.append((f"lockstep default scenario, exported plant FMU (best of {repeats})",
                 f"{f_fmu:.1f}x real time ({best_fmu[1]:.2f} s wall): {f_fmu / f_native:.2f} of native"))
    return rows


if __name__ == "__main__":
    for label, figure in run():
        print(f"{label:<62} {figure}")
