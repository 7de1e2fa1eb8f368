"""Campaign speed-up: the same campaign on 2 local worker processes against 1 (goal of issue #10: ≥ 1.8×),
and what a point costs beyond its simulation (goal of issue #18: ≤ 25 % of a point's wall).

The campaign is campaigns/mass_sweep.toml's base (the 6-car stop, scenarios/stop_30kmh.toml) cut to
SIMULATED_S simulated seconds, at N_POINTS seeds: every point a real lockstep run writing its run folder
(trace, truth.csv, kpis.json, run.json: a campaign's default, no figures), into a fresh temporary folder
each time (no cache).  `--jobs 1` runs the points in the campaign's own process, `--jobs 2` in a
ProcessPoolExecutor of 2 workers; both include writing the results table and plots.  A 2-point campaign
runs first, not measured: the process's one-time imports (which the forked workers of a 2-job campaign
inherit) are then paid by neither side.  Then 1 job and 2 jobs run alternately ROUNDS times each, and the
speed-up is best wall(1 job) / best wall(2 jobs).  On a 2-core machine it is bounded by 2 and lowered by
anything else running, and by the machine itself: a VM's two vCPUs may share one core, so the bench
prints beside it what two bare Python loops in two processes get against both in one, at the same moment.
Below it: the part of each campaign after its last point (the results table, the plots, report.html), which
is serial work on either side, and the speed-up of the points without it.  Points per minute are
N_POINTS / wall.

A point's wall is run_point's (hil.campaign.sweep: from the runtime imported and the worker prepared to
its KPIs, in its worker), its simulation RunOutcome.wall_s (the lockstep run itself: nodes built, run,
trace written); the non-simulation share is 1 - Σ simulation / Σ point wall over the points of the best
1-job campaign (one process: nothing else shares it), and for the 2-job campaign, for the record.  What a
worker does once before its first point (hil.runtime.run.prepare_worker: load the DBC, load the compiled
plant step) is printed apart: the largest `startup_s` of the points (a forked worker inherits them).

    python bench/bench_campaign.py
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ISSUE = "#10, #18"            # the issue that set the goals printed here (bench/run_all.py)
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
ROUNDS = 3            # 1 job and 2 jobs alternately, this many times each: the best of each is compared
LOOP_N = 3_000_000    # the bare loop of the machine's own 2-process speed-up (~0.4 s here)


def campaign_file(folder: Path, n_points: int = N_POINTS) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "bench.toml"
    seeds = ", ".join(str(s) for s in range(1, n_points + 1))
    path.write_text(f'base = "{ROOT / "scenarios" / "stop_30kmh.toml"}"\nname = "bench"\n'
                    f"[set]\nmax_duration_s = {SIMULATED_S}\n[grid]\nseed = [{seeds}]\n")
    return path


def wall_s(jobs: int, folder: Path, n_points: int = N_POINTS) -> tuple[float, float, list]:
    """Wall time [s] of the whole campaign with `jobs` workers, the part of it after the last point (the
    results table, the plots and report.html: serial work), and its points that ran ok (not cached)."""
    spec = load_campaign(campaign_file(folder, n_points))
    t0 = time.perf_counter()
    points = expand(spec)
    with executor_for(jobs) as executor:
        result = run_campaign(spec, folder / f"jobs{jobs}", executor, points)
    t_closing = time.perf_counter()
    write_table(result)
    write_plots(result)
    t_end = time.perf_counter()
    return t_end - t0, t_end - t_closing, [r for r in result.results
                                           if r.status == "ok" and not r.cached and r.sim_wall_s is not None]


def overhead(ran: list) -> tuple[float, float, float]:
    """(non-simulation share of the points' wall, mean point wall [s], mean simulation wall [s])."""
    wall = sum(r.wall_s for r in ran)
    sim = sum(r.sim_wall_s for r in ran)
    return 1.0 - sim / max(wall, 1e-9), wall / max(len(ran), 1), sim / max(len(ran), 1)


def _bare_loop(n: int = LOOP_N) -> float:
    """Wall [s] of a bare Python loop: the machine's own parallelism, without railhil."""
    t0 = time.perf_counter()
    s = 0
    for i in range(n):
        s += i * i % 7
    return time.perf_counter() - t0


def machine_speedup(rounds: int = 3) -> float:
    """The best of `rounds` speed-ups of two bare loops in 2 forked processes against both in this one:
    what this machine gives two processes at this moment (a VM's two vCPUs may share a core)."""
    import multiprocessing as mp

    best = 0.0
    with mp.get_context("fork").Pool(2) as pool:
        pool.map(_bare_loop, [1000, 1000])                  # the workers started
        for _ in range(rounds):
            t0 = time.perf_counter()
            _bare_loop(), _bare_loop()
            one = time.perf_counter() - t0
            t0 = time.perf_counter()
            pool.map(_bare_loop, [LOOP_N, LOOP_N], chunksize=1)
            best = max(best, one / (time.perf_counter() - t0))
    return best


def run() -> list[tuple[str, str]]:
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="railhil-bench-campaign-") as tmp:
        # warm-up, not measured: the campaign process's one-time imports (matplotlib, the compiled plant,
        # ...), which the forked workers of a 2-job campaign inherit; measured cold, the 1-job campaign
        # carried them alone and the speed-up read ~0.2x too high
        wall_s(1, Path(tmp) / "warm", n_points=2)
        ones, twos = [], []
        for r in range(ROUNDS):                               # alternately, best of each
            ones.append(wall_s(1, Path(tmp) / f"r{r}"))
            twos.append(wall_s(2, Path(tmp) / f"r{r}"))
    one, closing1, ran1 = min(ones, key=lambda x: x[0])
    two, closing2, ran2 = min(twos, key=lambda x: x[0])
    machine = machine_speedup()
    share1, wall1, sim1 = overhead(ran1)
    share2, wall2, sim2 = overhead(ran2)
    rows = [
        (f"{N_POINTS} points x {SIMULATED_S:.0f} s simulated (6 cars), 1 job (best of {ROUNDS})",
         f"{one:.1f} s ({len(ran1)} ran; all: {', '.join(f'{w:.1f}' for w, _, _ in ones)} s)"),
        (f"same, 2 jobs ({os.cpu_count()} CPUs, best of {ROUNDS})",
         f"{two:.1f} s ({len(ran2)} ran; all: {', '.join(f'{w:.1f}' for w, _, _ in twos)} s)"),
        ("points per minute, 1 job / 2 jobs", f"{60 * N_POINTS / one:.0f} / {60 * N_POINTS / two:.0f}"),
        ("non-simulation share of a point's wall (goal ≤ 25 %)",
         f"{100 * share1:.1f} % (1 job: a point {1e3 * wall1:.0f} ms wall, {1e3 * sim1:.0f} ms simulation): "
         f"{'met' if share1 <= 0.25 else 'NOT met'}"),
        ("the same with 2 jobs",
         f"{100 * share2:.1f} % (a point {1e3 * wall2:.0f} ms wall, {1e3 * sim2:.0f} ms simulation)"),
        ("worker start-up, once per process (DBC, compiled plant loaded)",
         f"{1e3 * max([r.startup_s for r in ran1 + ran2 if r.startup_s is not None] or [0.0]):.0f} ms"),
        ("speed-up 2 jobs vs 1, both warm (goal ≥ 1.8x)",
         f"{one / two:.2f}x: {'met' if one / two >= 1.8 else 'NOT met'}"),
        ("  the machine: 2 bare Python loops in 2 processes vs 1, best of 3", f"{machine:.2f}x"),
        ("  of which after the last point (table, plots, report), 1 / 2 jobs",
         f"{closing1:.2f} / {closing2:.2f} s (serial)"),
        ("  the points alone, 2 jobs vs 1", f"{(one - closing1) / max(two - closing2, 1e-9):.2f}x"),
        ("  1-min load average before / after", f"{load_before:.1f} / {os.getloadavg()[0]:.1f}"),
    ]
    return rows


if __name__ == "__main__":
    for label, figure in run():
        print(f"  {label:<62} {figure}")
