"""Lockstep real-time factor of the default scenario (simulated s per wall s), with and without trace.

The build that runs it (hil.build: the hot modules compiled by mypyc) against the pure build of the same
checkout: each in a process of its own (RAILHIL_PURE=1 for the pure one), alternately, best of three.
The trace is written as `railhil run` writes it (hil.trace.writers.open_writer: python-can's BLF format,
packed in bulk); the same run with the trace writer off shows what writing it costs.  One more,
instrumented run splits its wall time into the plant (plant_sim: compiled physics step and sensors),
the controllers (firmware_py, the desk script), the trace writer, and the railhil runtime (event loop,
bit-timed bus, node dispatch, codec, E2E, SecOC): the ceiling on what speeding up hil alone can give.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ISSUE = "#10, #46"            # the issues that set the goals printed here (bench/run_all.py)
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import hil.runtime.lockstep as lockstep  # noqa: E402
from hil import build  # noqa: E402
from hil.can.codec import Codec  # noqa: E402
from hil.can.dbc import load_dbc  # noqa: E402
from hil.runtime.lockstep import run_lockstep  # noqa: E402
from hil.scenario import load_scenario  # noqa: E402
from hil.trace.writers import open_writer  # noqa: E402


def _once(with_trace: bool) -> tuple[float, float, int]:
    scenario = load_scenario(ROOT / "scenarios" / "default.toml")
    db = load_dbc()
    codec = Codec(db)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        if with_trace:
            with open_writer(Path(tmp) / "trace.blf", start_time_s=0.0) as writer:   # as railhil run
                out = run_lockstep(scenario, db, codec, writer)
        else:
            out = run_lockstep(scenario, db, codec, None)
        wall = time.perf_counter() - t0
    return out.end_us / 1e6, wall, sum(out.frames_by_node.values())


def _timed(fn: Callable, part: str, spent: dict[str, float]) -> Callable:
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            spent[part] += time.perf_counter() - t0
    return wrapper


def split() -> tuple[float, dict[str, float]]:
    """(wall s, {part: s}) of one traced run whose plant, controllers and trace writer are timed
    (instance-level wrappers: about 0.2 µs per call, counted in the part they wrap)."""
    spent = {"plant_sim (physics, sensors)": 0.0, "controllers (firmware_py, desk)": 0.0,
             "trace writer (railhil BLF, python-can's format)": 0.0}
    plant_part, ctrl_part, writer_part = spent
    build_node = lockstep.build_node

    def build_timed(*args, **kwargs):
        node = build_node(*args, **kwargs)
        ctrl = node.controller
        if node.name == "PLANT":
            ctrl.plant.step = _timed(ctrl.plant.step, plant_part, spent)
            ctrl.plant.sense = _timed(ctrl.plant.sense, plant_part, spent)
        else:
            ctrl.step = _timed(ctrl.step, ctrl_part, spent)
        return node

    scenario = load_scenario(ROOT / "scenarios" / "default.toml")
    db = load_dbc()
    codec = Codec(db)
    lockstep.build_node = build_timed
    try:
        with tempfile.TemporaryDirectory() as tmp, \
                open_writer(Path(tmp) / "trace.blf", start_time_s=0.0) as writer:
            writer.write_frame = _timed(writer.write_frame, writer_part, spent)
            t0 = time.perf_counter()
            run_lockstep(scenario, db, codec, writer)
            wall = time.perf_counter() - t0
    finally:
        lockstep.build_node = build_node
    spent["railhil runtime (hil: loop, bus, nodes, codec, E2E, SecOC)"] = wall - sum(spent.values())
    return wall, spent


def in_process(pure: bool, what: str) -> dict:
    """One measurement (`what`: "once" or "split") in a fresh process of the build asked for."""
    env = {k: v for k, v in os.environ.items() if k != build.PURE_ENV}
    if pure:
        env[build.PURE_ENV] = "1"
    proc = subprocess.run([sys.executable, __file__, what], capture_output=True, text=True, env=env,
                          cwd=ROOT, check=True)
    return json.loads(proc.stdout.splitlines()[-1])


def run(repeats: int = 3) -> list[tuple[str, str]]:
    _once(False)                                   # warm-up: imports, codec generation, caches
    best = min((_once(True) for _ in range(repeats)), key=lambda r: r[1])
    sim_s, wall_s, frames = best
    no_trace = min((_once(False) for _ in range(repeats)), key=lambda r: r[1])
    state = build.state()
    rows = [
        ("build", state.line()),
        ("lockstep default scenario: simulated", f"{sim_s:.2f} s"),
        (f"lockstep default scenario: wall (best of {repeats})", f"{wall_s:.2f} s"),
        ("lockstep real-time factor (goal ≥ 50x, stretch 100x)",
         f"{sim_s / wall_s:.1f}x: {'met' if sim_s / wall_s >= 50 else 'NOT met'}"
         + (", stretch met" if sim_s / wall_s >= 100 else "")),
        ("lockstep frames per wall second", f"{frames / wall_s:,.0f}"),
        ("lockstep real-time factor without trace writing", f"{no_trace[0] / no_trace[1]:.1f}x"),
    ]
    if state.mode == "compiled":                   # compiled and pure side by side, alternately
        load = os.getloadavg()[0]
        compiled, pure = [], []
        for _ in range(repeats):
            compiled.append(in_process(False, "once"))
            pure.append(in_process(True, "once"))
        c = max(r["sim_s"] / r["wall_s"] for r in compiled)
        p = max(r["sim_s"] / r["wall_s"] for r in pure)
        rows += [
            ("1-min load average at the start of the side-by-side runs", f"{load:.1f}"),
            (f"  compiled build: real-time factor (own process, best of {repeats}; goal ≥ 45x)",
             f"{c:.1f}x: {'met' if c >= 45 else 'NOT met'}"),
            (f"  pure build (RAILHIL_PURE=1): real-time factor (best of {repeats})", f"{p:.1f}x"),
            ("  compiled / pure (goal ≥ 2x)", f"{c / p:.2f}x: {'met' if c / p >= 2 else 'NOT met'}"),
        ]
    else:
        rows.append(("compiled / pure", f"not measured: this build is pure ({state.reason})"))
    parts = in_process(True, "split")
    for part, seconds in parts["spent"].items():
        rows.append((f"  wall share, pure build: {part}", f"{100 * seconds / parts['wall_s']:.0f} %"))
    return rows


if __name__ == "__main__":
    if sys.argv[1:] == ["once"]:                   # in_process: warm-up, then one traced run
        _once(False)
        sim_s, wall_s, frames = _once(True)
        print(json.dumps({"sim_s": sim_s, "wall_s": wall_s, "frames": frames}))
    elif sys.argv[1:] == ["split"]:                # wrappers on the instances: the pure build only
        _once(False)
        wall, spent = split()
        print(json.dumps({"wall_s": wall, "spent": spent}))
    else:
        for label, figure in run():
            print(f"{label:<62} {figure}")
