"""`railhil reproduce anticollision` (alias `acd`): seed 002's anti-collision device in randomized
two-train runs, judged on plant truth (kpis.py), with the ACD's position prediction on and off.

`railhil reproduce anticollision campaign campaigns/acd_random.toml --jobs 2` runs a campaign file's points
(hil.campaign.sweep's seeded draws) with prediction on and off and prints the figures;
`railhil reproduce anticollision judge SCENARIO|RUN_DIR` judges one run.
"""

from __future__ import annotations

import argparse
import math
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from hil.campaign.sweep import CampaignError, expand, load_campaign
from hil.progress import progress_bar
from hil.scenario import Scenario, load_scenario
from hil.studies.anticollision.kpis import judge_run_dir, run_judged
from hil.studies.anticollision.scenario import AcdStudyError, spec_of


def campaign_scenarios(path: str | Path) -> list[Scenario]:
    """The points of a campaign file (hil.campaign.sweep: base, [set], [grid], seeded [random])."""

    try:
        points = expand(load_campaign(path))
    except CampaignError as exc:
        raise AcdStudyError(str(exc)) from None
    bad = [p.index for p in points if p.scenario.acd is None]
    if bad:
        raise AcdStudyError(f"{path}: point {bad[0]} has no [acd] section; expected an ACD base scenario")
    return [p.scenario for p in points]


def with_prediction(scenario: Scenario, on: bool) -> Scenario:
    acd = spec_of(scenario).model_copy(update={"prediction": on})
    return scenario.model_copy(update={"acd": acd})


def summarize(rows: list[dict]) -> list[str]:
    """Figures of a set of judged runs: collisions, overruns, min gap distribution, brakes."""
    gaps = np.array([r["min_gap_m"] for r in rows if math.isfinite(r["min_gap_m"])])
    q = np.percentile(gaps, [0, 5, 50, 95, 100]) if gaps.size else [math.nan] * 5
    lines = [f"runs {len(rows)}: collisions {sum(r['collision'] for r in rows)}, "
             f"red-signal overruns {sum(r['overruns'] for r in rows)}, "
             f"runs ended by {', '.join(sorted({r['end'] for r in rows}))}",
             "min gap to U1 [m]: min {:.1f}, p5 {:.1f}, median {:.1f}, p95 {:.1f}, max {:.1f}".format(*q),
             f"ACD brake applications {sum(r['applications'] for r in rows)}, unnecessary "
             f"{sum(r['unnecessary'] for r in rows)} (in {sum(r['unnecessary'] > 0 for r in rows)} runs)"]
    sig = [r["min_signal_m"] for r in rows if math.isfinite(r["min_signal_m"])]
    if sig:
        lines.append(f"closest approach to a red signal [m]: min {min(sig):.1f}, median {np.median(sig):.1f}")
    return lines


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of `railhil reproduce anticollision`."""
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    c = sub.add_parser("campaign", help="run a campaign file's points with prediction on and off, judged "
                                        "on plant truth")
    c.add_argument("campaign", type=Path, help="campaign TOML (hil.campaign.sweep) over an ACD scenario")
    c.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    c.add_argument("--prediction", choices=("both", "on", "off"), default="both",
                   help="run the points with the ACD's prediction on, off, or both (default both)")
    c.add_argument("--limit", type=int, default=None, help="run only the first N points")
    c.add_argument("--csv", type=Path, default=None, help="write one row per run to this CSV file")
    j = sub.add_parser("judge", help="judge a run folder, or run a scenario in lockstep (no files) and "
                                     "judge it, on plant truth")
    j.add_argument("scenario", type=Path, help="scenario TOML with an [acd] section, or a run folder of "
                                               "`railhil run` (lockstep or --realtime)")
    j.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key, as railhil run --set")


def run(args: argparse.Namespace) -> int:
    if args.command == "judge":
        if args.scenario.is_dir():
            r = judge_run_dir(args.scenario)
        else:
            scenario = load_scenario(args.scenario, sets=args.set)
            spec_of(scenario)
            r = run_judged(scenario.model_dump_json())
        for k, v in r.items():
            print(f"{k:>14}: {v}")
        return 0
    if args.jobs < 1:
        raise AcdStudyError(f"--jobs {args.jobs}: expected 1 or more worker processes")
    if args.limit is not None and args.limit < 1:
        raise AcdStudyError(f"--limit {args.limit}: expected 1 or more points")
    scenarios = campaign_scenarios(args.campaign)[:args.limit]
    modes = {"both": (True, False), "on": (True,), "off": (False,)}[args.prediction]
    jobs = [with_prediction(s, m).model_dump_json() for m in modes for s in scenarios]
    t0 = time.perf_counter()
    bar = progress_bar(len(jobs), unit="run")
    rows: list[dict] = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for r in pool.map(run_judged, jobs, chunksize=1):
            rows.append(r)
            bar.update()
    bar.close()
    for m in modes:
        print(f"prediction {'on' if m else 'off'}:")
        for line in summarize([r for r in rows if r["prediction"] == m]):
            print("  " + line)
    if len(modes) == 2:                      # rows are in job order: the points with, then without
        def bad(r: dict) -> bool:
            return r["collision"] or r["overruns"] > 0

        n = len(scenarios)
        avoided = sum(bad(off) and not bad(on) for on, off in zip(rows[:n], rows[n:], strict=True))
        caused = sum(bad(on) and not bad(off) for on, off in zip(rows[:n], rows[n:], strict=True))
        print(f"points with a collision or overrun that prediction avoids: {avoided} (that it causes: "
              f"{caused})")
    print(f"{len(rows)} runs in {time.perf_counter() - t0:.0f} s wall, {args.jobs} jobs")
    if args.csv is not None:
        import csv

        with open(args.csv, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        print(f"wrote {args.csv}")
    return 0
