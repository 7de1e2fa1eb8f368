"""Lockstep real-time factor of the default scenario (simulated s per wall s), with and without trace.

The same run with the trace writer off shows what writing the BLF trace costs.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import can

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hil.codec import Codec  # noqa: E402
from hil.dbc import load_dbc  # noqa: E402
from hil.lockstep import run_lockstep  # noqa: E402
from hil.scenario import load_scenario  # noqa: E402


def _once(with_trace: bool) -> tuple[float, float, int]:
    scenario = load_scenario(ROOT / "scenarios" / "default.toml")
    db = load_dbc()
    codec = Codec(db)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        if with_trace:
            with can.Logger(str(Path(tmp) / "trace.blf")) as writer:
                out = run_lockstep(scenario, db, codec, writer)
        else:
            out = run_lockstep(scenario, db, codec, None)
        wall = time.perf_counter() - t0
    return out.end_us / 1e6, wall, sum(out.frames_by_node.values())


def run(repeats: int = 3) -> list[tuple[str, str]]:
    _once(False)                                   # warm-up: imports, codec generation, caches
    best = min((_once(True) for _ in range(repeats)), key=lambda r: r[1])
    sim_s, wall_s, frames = best
    no_trace = min((_once(False) for _ in range(repeats)), key=lambda r: r[1])
    return [
        ("lockstep default scenario: simulated", f"{sim_s:.2f} s"),
        (f"lockstep default scenario: wall (best of {repeats})", f"{wall_s:.2f} s"),
        ("lockstep real-time factor", f"{sim_s / wall_s:.1f}x"),
        ("lockstep frames per wall second", f"{frames / wall_s:,.0f}"),
        ("lockstep real-time factor without trace writing", f"{no_trace[0] / no_trace[1]:.1f}x"),
    ]


if __name__ == "__main__":
    for label, figure in run():
        print(f"{label:<55} {figure}")
