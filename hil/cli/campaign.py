"""`railhil campaign FILE.toml` — a base scenario swept over a grid and a seeded random sample, run in
lockstep through local worker processes (`--jobs N`) or a Dask distributed cluster (`--dask ADDRESS`);
resumable.  File format and definitions in hil.campaign.sweep.

Writes results.csv (results.parquet with pyarrow), plot_<key>.png, report.html and one run folder per
point under the output folder (trace, truth.csv, kpis.json, run.json; with --plots also the point's
plot.png, study figures and report.html), prints a short table.  Exit 0 when every point ran, 1 when
some failed (each is recorded with its error; the others finish), 2 for bad input, 130 when interrupted
(finished points stay cached: run the same command again to resume).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hil.campaign.jobs import add_executor_options, check_executor_options
from hil.progress import progress_bar

HELP = "parameter sweeps of a scenario (grid and seeded random), in parallel or on a Dask cluster; resumable"


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "campaign",
        help=HELP,
        description="Run a campaign: the base scenario of FILE.toml at every point of its [grid] "
                    "(cartesian product) times its [random] draws (seeded), each point a lockstep run "
                    "with its own run folder. A point's result is cached by the SHA-256 of its "
                    "resolved scenario, DBC and railhil version, so a rerun (after Ctrl-C, or with "
                    "more points) runs only what is not finished. A failing point is recorded with "
                    "its error and the others go on. Writes results.csv (and results.parquet when "
                    "pyarrow is installed), plot_<key>.png and report.html. A point's run folder keeps "
                    "its trace, truth.csv, kpis.json and run.json; its figures and report.html only with "
                    "--plots. Exit 0 when every point ran, 1 when some failed, 2 for bad input, 130 when "
                    "interrupted.",
    )
    p.add_argument("campaign", type=Path, help="campaign TOML file (e.g. campaigns/mass_sweep.toml) or a "
                                               "shipped campaign's name (mass_sweep)")
    add_executor_options(p, "points", 1, "; on several hosts the output folder must be on a filesystem the "
                                         "workers share")
    p.add_argument("-o", "--out", type=Path, default=None, metavar="DIR",
                   help="campaign folder: results, plots, point run folders and their cache (default "
                        "runs/campaign-<name>; the same folder again resumes)")
    p.add_argument("--plots", action="store_true",
                   help="also write each point's figures (plot.png, the studies' <study>.png) and its "
                        "report.html, as `railhil run` does; off by default, a point then keeps its "
                        "trace, truth.csv, kpis.json and run.json (points cached without figures get them "
                        "drawn from their run folders, without running again)")
    p.add_argument("--list", action="store_true",
                   help="print the points, their swept values and whether each is cached, run nothing")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=campaign)


def _list(points, out: Path) -> int:
    # lazy: keeps `railhil campaign --help` at 50 ms, not 680 ms (the campaign runner: -X importtime)
    from hil.campaign.sweep import _read_cache, shown

    for p in points:
        cached = _read_cache(out / "points" / p.key[:16], p.key) is not None
        print(f"point {p.index:>4}  {p.key[:16]}  {'cached' if cached else 'to run':<6}  "
              f"{shown(p.values) or '(the base scenario)'}")
    print(f"{len(points)} points")
    return 0


def campaign(args: argparse.Namespace) -> int:
    # lazy: keeps `railhil campaign --help` at 50 ms, not 680 ms (the campaign runner: -X importtime)
    from hil.campaign.sweep import (
        CampaignError,
        executor_for,
        expand,
        load_campaign,
        run_campaign,
        summary_lines,
        write_plots,
        write_table,
    )

    check_executor_options(args, CampaignError)
    spec = load_campaign(args.campaign)
    points = expand(spec)
    out = args.out or Path("runs") / f"campaign-{spec.name}"
    if args.list:
        return _list(points, out)
    bar = None
    failed = 0

    def progress(r) -> None:
        nonlocal failed
        failed += r.status != "ok"
        if bar is not None:
            bar.update(1)
            if failed:
                bar.set_postfix_str(f"{failed} failed")

    try:
        with executor_for(args.jobs, args.dask, args.dask_timeout) as executor:    # connects first
            bar = progress_bar(len(points), enabled=not args.quiet, unit="point",
                               desc=f"campaign {spec.name}")
            result = run_campaign(spec, out, executor, points, progress, plots=args.plots)
    finally:
        if bar is not None:
            bar.close()
    files = write_table(result)
    files += write_plots(result)
    for line in summary_lines(result):
        print(line)
    print(f"files: {', '.join(str(f) for f in files)}; run folders under {out / 'points'}")
    if result.interrupted:
        print(f"error: interrupted: {len(result.results)} of {result.total} points finished and cached; "
              f"run the same command again to resume", file=sys.stderr)
        return 130
    if result.failed:
        print(f"error: {len(result.failed)} of {result.total} points failed (see the error column of "
              f"{files[0]})", file=sys.stderr)
        return 1
    return 0
