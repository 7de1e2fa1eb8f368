"""`railhil wsp-test [PROGRAMME]` — a wheel-slide-protection type test in the style of EN 15595's on-track
tests: every strategy of the programme on every rail condition at every initial speed, in lockstep through
the campaign executor (`--jobs`, `--dask`), judged on plant truth (hil.typetest.metrics).

Writes results.json, table.md, table.csv, one figure per condition and report.html to the output folder,
each run's folder under it; prints one table per condition and each strategy against the first.  Exit 0
when every run ran; 1 when one failed (the others' results are still written); 2 for bad input; 130 when
interrupted.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from hil.campaign.jobs import add_executor_options, check_executor_options
from hil.progress import progress_bar


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "wsp-test",
        help="WSP type test (EN 15595 style): strategies side by side on low, extremely low and suddenly "
             "changing adhesion at three speeds",
        description="Runs a WSP test programme (default: the shipped programmes/wsp_test.toml): for each "
                    "strategy and initial speed a dry reference run (the demand the ideal stop follows), "
                    "then each rail condition, all in lockstep. Per run, from plant truth: stopping "
                    "distance, its extension over the ideal stop at the available adhesion, adhesion "
                    "utilisation, free air vented, largest slip speed, slide above a threshold, the "
                    "longest time an axle turned below a rotation threshold, WSP activations (definitions: "
                    "docs/wsp-test.md). Exit 0 when every run ran, 1 when one failed, 2 for bad input.",
    )
    p.add_argument("programme", type=Path, nargs="?", default=None,
                   help="programme TOML file (default: the shipped programmes/wsp_test.toml)")
    p.add_argument("--strategy", action="append", default=[], metavar="NAME",
                   help="only this strategy; repeatable (default: every strategy of the programme)")
    p.add_argument("--condition", action="append", default=[], metavar="NAME",
                   help="only this rail condition; repeatable (the dry reference always runs)")
    p.add_argument("--speed", action="append", default=[], type=float, metavar="KMH",
                   help="only this initial speed [km/h], one of the programme's; repeatable")
    add_executor_options(p, "runs", os.cpu_count() or 1)
    p.add_argument("-o", "--out", type=Path, default=None, metavar="DIR",
                   help="output folder (default runs/wsp-test-<name>); a run whose folder there holds its "
                        "result for the same scenario, DBC, railhil version, thresholds and demand is read, "
                        "not run again")
    p.add_argument("--fresh", action="store_true",
                   help="run everything again, ignoring the results in the folder")
    p.add_argument("--no-plots", action="store_true", help="no figures (tables, results.json, report.html)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=wsp_test)


def wsp_test(args: argparse.Namespace) -> int:
    # lazy: keeps `railhil wsp-test --help` at 50 ms, not 700 ms (the type-test runner: -X importtime)
    from hil.campaign.sweep import executor_for
    from hil.runtime.run import check_out_dir
    from hil.typetest import report
    from hil.typetest.programme import ProgrammeError, load_programme, runs
    from hil.typetest.wsp import run_programme

    check_executor_options(args, ProgrammeError)
    prog = load_programme(args.programme)
    specs = runs(prog, args.strategy or None, args.speed or None, args.condition or None)
    out = check_out_dir(args.out or Path("runs") / f"wsp-test-{prog.spec.name}")
    print(f"wsp-test {prog.spec.name}: {len(specs)} runs ({len({s.strategy for s in specs})} strategies x "
          f"{len({s.speed_kmh for s in specs})} speeds x {len({s.condition for s in specs})} rail conditions "
          f"with the dry reference) into {out}", file=sys.stderr)
    bar = progress_bar(len(specs), enabled=not args.quiet, unit="run", desc="wsp-test runs")
    t0 = time.perf_counter()
    try:
        with executor_for(args.jobs, args.dask, args.dask_timeout) as executor:
            results = run_programme(prog, specs, out, executor, progress=lambda _r: bar.update(),
                                    resume=not args.fresh)
    finally:
        bar.close()
    wall = time.perf_counter() - t0
    files = report.write(prog, results, out, wall, plots=not args.no_plots)
    print((out / "table.md").read_text(encoding="utf-8"), end="")
    failed = [r for r in results if r.status != "ok"]
    cached = sum(r.cached for r in results)
    ran = len(results) - cached
    print(f"{len(results)} runs ({cached} read from their folders, {ran} run) in {wall:.0f} s wall "
          f"({ran / max(wall, 1e-9) * 60:.1f} runs per minute), {len(failed)} failed; files: "
          f"{', '.join(str(f) for f in files)}")
    return 1 if failed else 0
