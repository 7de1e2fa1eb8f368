"""`railhil report FOLDER...` — (re)write the self-contained HTML page of a run folder or a campaign folder;
`railhil report RUN --against REF` — a page comparing two run folders.

A run folder (it has run.json, kpis.json, truth.csv, plot.png) gets report.html with the scenario, the
verdicts, the KPIs with their units and meanings, the signals (interactive, plotly.js inlined), the static
figures, timing and faults and what reproduces the run; a campaign folder (it has results.csv) gets the
results table and the summary plots.  `railhil run` and `railhil campaign` write these pages already;
this command rebuilds them, e.g. for folders of an older railhil.

`--against REF` writes RUN/report-vs-<REF's folder name>.html (or `-o FILE`): both runs' scenario, seed
and versions, the scenario keys that differ, both runs' verdicts, every KPI with both values and
Δ = RUN − REF, the signals of both overlaid; it prints the comparison in one line, then the page's path.
Definitions in hil.report.html.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hil.errors import RailhilError

HELP = "write the HTML report of a run or campaign folder, or compare two runs (--against)"


class ReportArgError(RailhilError, ValueError):
    """Options of `railhil report` that do not go together (exit 2)."""


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help=HELP,
        description="Write FOLDER/report.html, one self-contained HTML page that opens offline (plots "
                    "embedded, plotly.js inlined): for a run folder the scenario, verdicts (pass/fail), "
                    "every KPI with its unit and meaning (per-car values one column per car), the signals "
                    "as an interactive figure (zoom: drag; reset: double-click), the static figures, "
                    "timing, faults, versions, seed, DBC SHA-256 and git commit; for a campaign folder the "
                    "results table and the summary plots. With --against REF: a comparison page of the run "
                    "folder RUN against the run folder REF instead, the way a regression is reviewed: both "
                    "runs' scenario, seed and versions, the scenario keys that differ, both runs' verdicts, "
                    "every KPI with both values, delta (RUN - REF) and relative delta, changed values "
                    "highlighted, and the signals of both runs overlaid (RUN solid, REF dashed); like is "
                    "compared with like: the KPIs both runs have are counted, those of one run only "
                    "listed apart. Prints the comparison in one line (per group of KPIs: the same, or how "
                    "many differ), then the page's path.",
        epilog="examples: railhil report runs/default-lockstep-20260101-120000   |   "
               "railhil report runs/seed2 --against runs/seed1   (writes runs/seed2/report-vs-seed1.html)",
    )
    p.add_argument("folders", type=Path, nargs="+", metavar="FOLDER",
                   help="run folder (with run.json) or campaign folder (with results.csv), e.g. "
                        "runs/default-lockstep-20260101-120000; with --against: the one run folder to "
                        "compare (RUN)")
    p.add_argument("--against", type=Path, default=None, metavar="REF",
                   help="compare RUN against the run folder REF (the reference): writes "
                        "RUN/report-vs-<REF's folder name>.html, delta = RUN - REF")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="FILE",
                   help="with --against: write the comparison page to FILE instead")
    p.set_defaults(func=report)


def report(args: argparse.Namespace) -> int:
    # lazy: keeps `railhil report --help` at 35 ms, not 340 ms (the HTML report, plotly: -X importtime)
    from hil.report.html import comparison_summary, write_comparison, write_report

    if args.against is None:
        if args.output is not None:
            raise ReportArgError(f"-o {args.output}: only with --against (a folder's own page is "
                                 f"FOLDER/report.html)")
        for folder in args.folders:
            print(write_report(folder))
        return 0
    if len(args.folders) != 1:
        raise ReportArgError(f"--against compares one run folder with REF; got {len(args.folders)} folders: "
                             + " ".join(str(f) for f in args.folders))
    page = write_comparison(args.folders[0], args.against, args.output)
    print(comparison_summary(args.folders[0], args.against))
    print(page)
    return 0
