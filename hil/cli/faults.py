"""`railhil faults matrix SCENARIO | --all` — every EN 50159 threat on every protected frame, a babbling
node and each sender bus-off, in lockstep: what the receivers detected and what happened to the train.
Definitions in hil.safety.threat_matrix; the table in hil.safety.matrix_report.

`--all` runs the matrix on every scenario family (ALL_SCENARIOS).  The runs go through the campaign
executor (hil.campaign.sweep.executor_for): in this process (`--jobs 1`), on local worker processes
(`--jobs N`) or on a Dask cluster (`--dask ADDRESS`).  Progress (cells done / total, ETA) on stderr.

Writes matrix.md and matrix.json to the output folder and prints the totals, the verdict and the cells
that failed (one scenario: every cell).  Exit 0 when every cell was detected within 3 cycles by every
receiver and none was unsafe, released a brake, moved a target or failed to run; 1 otherwise (a
verdict); 2 for bad input; 130 when interrupted.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from hil.campaign.jobs import add_executor_options, check_executor_options
from hil.campaign.sweep import executor_for
from hil.can.codec import loaded_dbc
from hil.errors import RailhilError
from hil.progress import progress_bar
from hil.resources import resolve_scenario
from hil.runtime.run import check_out_dir
from hil.safety import matrix_report
from hil.safety.threat_matrix import THREATS, WINDOW_S, WINDOW_START_S, plan, run_matrices, safety_messages
from hil.scenario import load_scenario

#: the scenario families of `--all` (shipped scenarios, by name)
ALL_SCENARIOS = ("default", "stop_30kmh", "precise_stop", "decel_feedback", "rg_low_adhesion",
                 "acd_anticollision", "consensus_case1")
PRINT_ALL_CELLS = 150     # print every cell when there are at most this many, else the failed ones
MAX_WINDOW_S = 60.0       # the longest --window [s]


class FaultsArgError(RailhilError, ValueError):
    """An option of `railhil faults` that names something the scenario or the DBC does not have."""


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "faults",
        help="fault injection campaigns: the EN 50159 threat matrix",
        description="Fault injection over whole scenarios, in lockstep.",
    )
    fsub = p.add_subparsers(dest="faults_command", metavar="ACTION")
    fsub.required = True
    m = fsub.add_parser(
        "matrix",
        help="every threat x every protected frame: detection and outcome on plant truth",
        description="Runs the scenario once without faults, then once per cell: every EN 50159 threat "
                    "(repetition, deletion, insertion, resequencing, corruption, delay, masquerade) on "
                    "every E2E-protected frame the scenario sends and receives, each sending node gone "
                    "bus-off, and a babbling node, over 2 s from 2 s after braking is established. A cell "
                    "is detected when every receiver of every frame it hits reported a non-OK E2E status "
                    "or a SecOC rejection within 3 cycles of the frame; unsafe by the scenario family's "
                    "criterion against the fault-free run (stop distance > 5 % + 1 m longer, stop error "
                    "> 0.3 m past the target, gap to the train ahead, coupler displacement); released "
                    "when a car's cylinder pressure fell below half of the fault-free value for more than "
                    "0.1 s; target moved when a receiving controller was handed content its legitimate "
                    "sender did not send. --all runs every scenario family. Exit 0 when every cell is "
                    "detected and none is unsafe, released, moved or failed; 1 otherwise; 2 for bad input.",
    )
    m.add_argument("scenario", type=Path, nargs="?", default=None,
                   help="scenario TOML file or a shipped scenario's name (or --all)")
    m.add_argument("--all", action="store_true",
                   help=f"every scenario family: {', '.join(ALL_SCENARIOS)}")
    m.add_argument("--message", action="append", default=[], metavar="NAME",
                   help="only the cells that hit this protected frame (its threats, its sender's bus-off, "
                        "babbling); repeatable; one SCENARIO only (default: every E2E-protected frame the "
                        "scenario sends and receives)")
    m.add_argument("--threat", action="append", default=[], metavar="KIND",
                   help=f"only this threat; repeatable (default: all nine: {', '.join(THREATS)})")
    m.add_argument("--window", type=float, default=WINDOW_S, metavar="S",
                   help=f"how long every fault acts [s], from {WINDOW_START_S:g} s after braking is "
                        f"established (default {WINDOW_S:g}; longer shows what a loss outlasting a "
                        f"fail-safe hold does; at most {MAX_WINDOW_S:g})")
    add_executor_options(m, "cells", os.cpu_count() or 1)
    m.add_argument("-o", "--out", type=Path, default=None, metavar="DIR",
                   help="folder for matrix.md and matrix.json (default runs/<scenario>-faults-<date>, "
                        "runs/faults-matrix-all-<date> with --all)")
    m.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    m.set_defaults(func=matrix)


def _scenarios(args: argparse.Namespace) -> list[tuple[str, object]]:
    if args.all and args.scenario is not None:
        raise FaultsArgError(f"--all and a SCENARIO ({args.scenario}): expected one of them")
    if not args.all and args.scenario is None:
        raise FaultsArgError("expected a SCENARIO (a TOML file or a shipped scenario's name) or --all")
    if args.all and args.message:
        raise FaultsArgError(f"--message {args.message[0]!r} with --all: a frame of one SCENARIO only")
    refs = list(ALL_SCENARIOS) if args.all else [args.scenario]
    return [(str(resolve_scenario(ref)), load_scenario(ref)) for ref in refs]


def matrix(args: argparse.Namespace) -> int:
    check_executor_options(args, FaultsArgError)
    bad = [t for t in args.threat if t not in THREATS]
    if bad:
        raise FaultsArgError(f"--threat {bad[0]!r}: expected one of {', '.join(THREATS)}")
    scenarios = _scenarios(args)
    if args.message:
        scenario = scenarios[0][1]
        available = safety_messages(scenario, loaded_dbc(scenario.dbc)[0])
        bad = [m for m in args.message if m not in available]
        if bad:
            raise FaultsArgError(f"--message {bad[0]!r}: not a protected frame this scenario sends and "
                                 f"receives; those are {', '.join(available) or 'none'}")
    if not 0.0 < args.window <= MAX_WINDOW_S:       # also NaN
        raise FaultsArgError(f"--window {args.window:g}: expected a duration in seconds, above 0 and at "
                             f"most {MAX_WINDOW_S:g}")
    threats = args.threat or list(THREATS)
    planned = plan(scenarios, threats, args.message or None, args.window)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    default = f"faults-matrix-all-{stamp}" if args.all else f"{scenarios[0][1].name}-faults-{stamp}"
    out = check_out_dir(args.out or Path("runs") / default)
    n_cells = sum(len(mx.specs) for mx in planned)
    bars = {}                                       # phase -> its progress bar

    def progress(phase: str, done: int, total: int) -> None:
        if args.quiet:
            return
        if phase not in bars:
            for bar in bars.values():
                bar.close()
            desc = "fault-free runs" if phase == "fault-free" else "threat matrix cells"
            bars[phase] = progress_bar(total, unit="run", desc=desc)
        bars[phase].update(done - bars[phase].n)

    t0 = time.perf_counter()
    try:
        with executor_for(args.jobs, args.dask, args.dask_timeout) as executor:     # connects first
            matrices = run_matrices(scenarios, executor, threats, args.message or None, progress, planned)
    finally:
        for bar in bars.values():
            bar.close()
    wall = time.perf_counter() - t0
    files = matrix_report.write(matrices, out)
    cells = [c for mx in matrices for c in mx.cells]
    text = matrix_report.markdown(matrices) if n_cells <= PRINT_ALL_CELLS else matrix_report.summary(matrices)
    print(text, end="")
    if n_cells > PRINT_ALL_CELLS:
        print(f"(every one of the {n_cells} cells in {files[0]})")
    print(f"{len(cells)} cells in {wall:.0f} s wall; files: {', '.join(str(f) for f in files)}")
    return 0 if matrix_report.totals(cells).passed else 1
