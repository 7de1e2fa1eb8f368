"""Campaign speed-up: the same campaign on 2 local worker processes against 1 (goal of issue #10: ≥ 1.8×).

The campaign is campaigns/mass_sweep.toml's base (the 6-car stop, scenarios/stop_30kmh.toml) cut to
SIMULATED_S simulated seconds, at N_POINTS seeds: every point a real lockstep run writing its run folder,
into a fresh temporary folder each time (no cache).  `--jobs 1` runs the points in the campaign's own
process, `--jobs 2` in a ProcessPoolExecutor of 2 workers; both include writing the results table and
plots.  The speed-up is wall(1 job) / wall(2 jobs), measured side by side in one run; on a 2-core
machine it is bounded by 2 and lowered by anything else running.

    python bench/bench_campaign.py
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from hil.campaign.sweep import (  # noqa: E402
    executor_for,
    expand,
    load_campaign,
    run_campaign,
    write_plots,
    write_table,
)

N_POINTS = 8
SIMULATED_S = 4.0


def campaign_file(folder: Path) -> Path:
    path = folder / "bench.toml"
    seeds = ", ".join(str(s) for s in range(1, N_POINTS + 1))
    path.write_text(f'base = "{ROOT / "scenarios" / "stop_30kmh.toml"}"\nname = "bench"\n'
                    f"[set]\nmax_duration_s = {SIMULATED_S}\n[grid]\nseed = [{seeds}]\n")
    return path


def wall_s(jobs: int, folder: Path) -> tuple[float, int]:
    """Wall time [s] of the whole campaign with `jobs` workers, and its number of points that ran ok."""
    spec = load_campaign(campaign_file(folder))
    t0 = time.perf_counter()
    points = expand(spec)
    with executor_for(jobs) as executor:
        result = run_campaign(spec, folder / f"jobs{jobs}", executor, points)
    write_table(result)
    write_plots(result)
    return time.perf_counter() - t0, sum(r.status == "ok" and not r.cached for r in result.results)


def run() -> list[tuple[str, str]]:
    with tempfile.TemporaryDirectory(prefix="railhil-bench-campaign-") as tmp:
        one, ok1 = wall_s(1, Path(tmp))
        two, ok2 = wall_s(2, Path(tmp))
    rows = [
        (f"{N_POINTS} points x {SIMULATED_S:.0f} s simulated (6 cars), 1 job", f"{one:.1f} s ({ok1} ran)"),
        (f"same, 2 jobs ({os.cpu_count()} CPUs)", f"{two:.1f} s ({ok2} ran)"),
        ("speed-up 2 jobs vs 1 (goal ≥ 1.8x)",
         f"{one / two:.2f}x: {'met' if one / two >= 1.8 else 'NOT met'}"),
    ]
    return rows


if __name__ == "__main__":
    for label, figure in run():
        print(f"  {label:<62} {figure}")
