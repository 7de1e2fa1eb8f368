"""`railhil report FOLDER` — (re)write the self-contained HTML page of a run folder or a campaign folder.

A run folder (it has run.json, kpis.json, plot.png) gets report.html with the scenario, the verdicts, the
KPIs, the plots, timing and faults and what reproduces the run; a campaign folder (it has results.csv)
gets the results table and the summary plots.  `railhil run` and `railhil campaign` write these pages
already; this command rebuilds them, e.g. for folders of an older railhil.  Definitions in
hil.report.html.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "write the self-contained HTML report of a run folder or a campaign folder"


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help=HELP,
        description="Write FOLDER/report.html, one self-contained HTML page (plots embedded): for a run "
                    "folder the scenario, verdicts (pass/fail), KPIs, plots, timing, faults, versions, "
                    "seed, DBC SHA-256 and git commit; for a campaign folder the results table and the "
                    "summary plots. Prints the page's path.",
    )
    p.add_argument("folders", type=Path, nargs="+", metavar="FOLDER",
                   help="run folder (with run.json) or campaign folder (with results.csv), e.g. "
                        "runs/default-lockstep-20260101-120000")
    p.set_defaults(func=report)


def report(args: argparse.Namespace) -> int:
    from hil.report.html import write_report

    for folder in args.folders:
        print(write_report(folder))
    return 0
