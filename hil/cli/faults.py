"""`railhil faults matrix SCENARIO` — every EN 50159 threat on every safety frame, in lockstep: what
the receivers detected and what happened to the train.  Definitions in hil.safety.threat_matrix.

Writes matrix.md (a Markdown table) and matrix.json to the output folder and prints the table.
Exit 0 when every threat was detected within 3 cycles by every receiver and no outcome was unsafe
or released a brake, 1 otherwise (a verdict), 2 for bad input.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from hil.errors import RailhilError


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
        help="every threat x every safety frame: detection and outcome on plant truth",
        description="Runs the scenario once without faults, then once per (safety frame, threat): "
                    "repetition, deletion, insertion, resequencing, corruption, delay, masquerade over "
                    "2 s from 2 s after the first brake command. A cell is detected when every "
                    "receiver of the frame reported a non-OK E2E status or a SecOC rejection within 3 "
                    "cycles of the frame; unsafe when the train did not stop or stopped more than "
                    "5 % + 1 m beyond the fault-free run; released when a car's cylinder pressure fell "
                    "below half of the fault-free value for more than 0.1 s. Exit 0 when every cell is "
                    "detected, safe and not released; 1 otherwise; 2 for bad input.",
    )
    m.add_argument("scenario", type=Path, help="scenario TOML file (a short stop keeps the matrix quick)")
    m.add_argument("--message", action="append", default=[], metavar="NAME",
                   help="only this safety frame; repeatable (default: every E2E-protected frame the "
                        "scenario sends and receives)")
    m.add_argument("--threat", action="append", default=[], metavar="KIND",
                   help="only this threat; repeatable (default: all seven)")
    m.add_argument("--jobs", type=int, default=os.cpu_count() or 1, metavar="N",
                   help="parallel processes (default: the number of CPUs)")
    m.add_argument("-o", "--out", type=Path, default=None, metavar="DIR",
                   help="folder for matrix.md and matrix.json (default runs/<scenario>-faults-<date>)")
    m.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    m.set_defaults(func=matrix)


COLUMNS = ("message", "threat", "injected", "detected", "worst_ms", "first_status", "distance_change_m",
           "released", "unsafe")


def _row(c) -> dict:
    return {"message": c.message, "threat": c.threat, "injected": c.injected,
            "detected": "yes" if c.detected else "NO", "worst_ms": "" if c.worst_detection_ms is None
            else f"{c.worst_detection_ms:.1f}", "first_status": c.first_status or c.error,
            "distance_change_m": "" if c.distance_change_m is None else f"{c.distance_change_m:+.2f}",
            "released": "YES" if c.released else "no", "unsafe": "YES" if c.unsafe else "no"}


def markdown(cells, baseline: dict, scenario_name: str) -> str:
    lines = [f"# Threat matrix: {scenario_name}", "",
             f"Fault-free stopping distance {baseline['stopping_distance_m']:.2f} m. "
             "Definitions: hil/safety/threat_matrix.py.", "",
             "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for c in cells:
        r = _row(c)
        lines.append("| " + " | ".join(str(r[k]) for k in COLUMNS) + " |")
    n = len(cells)
    lines += ["", f"{sum(c.detected for c in cells)} of {n} detected within 3 cycles; "
              f"{sum(c.unsafe for c in cells)} unsafe; {sum(c.released for c in cells)} released a brake"]
    return "\n".join(lines) + "\n"


def matrix(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hil.can.codec import loaded_dbc
    from hil.report.kpis import check_out_dir
    from hil.safety.injection import MESSAGE_THREATS
    from hil.safety.threat_matrix import as_rows, run_matrix, safety_messages
    from hil.scenario import load_scenario

    if args.jobs < 1:
        raise FaultsArgError(f"--jobs {args.jobs}: expected at least 1")
    scenario = load_scenario(args.scenario)
    db, _ = loaded_dbc(scenario.dbc)            # the DBC the matrix's runs use (once per process)
    available = safety_messages(scenario, db)
    bad = [m for m in args.message if m not in available]
    if bad:
        raise FaultsArgError(f"--message {bad[0]!r}: not a safety frame this scenario sends and receives; "
                             f"those are {', '.join(available)}")
    bad = [t for t in args.threat if t not in MESSAGE_THREATS]
    if bad:
        raise FaultsArgError(f"--threat {bad[0]!r}: expected one of {', '.join(MESSAGE_THREATS)}")
    messages = args.message or available
    threats = args.threat or list(MESSAGE_THREATS)
    out = check_out_dir(args.out or Path("runs") / f"{scenario.name}-faults-{time.strftime('%Y%m%d-%H%M%S')}")
    bar = None if args.quiet else tqdm(total=len(messages) * len(threats), unit="run", file=sys.stderr,
                                       desc="threat matrix")
    cells, baseline = run_matrix(scenario, messages, threats, jobs=args.jobs,
                                 progress=(lambda c: bar.update(1)) if bar else None)
    if bar:
        bar.close()
    text = markdown(cells, baseline, scenario.name)
    (out / "matrix.md").write_text(text)
    (out / "matrix.json").write_text(json.dumps({"scenario": scenario.name, "baseline": baseline,
                                                 "cells": as_rows(cells)}, indent=2) + "\n")
    print(text, end="")
    print(f"files: {out / 'matrix.md'}, {out / 'matrix.json'}")
    ok = all(c.detected and not c.unsafe and not c.released and not c.error for c in cells)
    return 0 if ok else 1
