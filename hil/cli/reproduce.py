"""`railhil reproduce STUDY` — run a paper's simulation campaigns in lockstep and print our figures next
to the paper's, with its plots as PNG.

Each study lives in its own module (``STUDIES``), which gives ``add_arguments(parser)`` for its options
and ``run(args) -> int`` (exit code); this module only dispatches.
"""

from __future__ import annotations

import argparse
import importlib

HELP = ("reproduce a paper's simulation campaigns (seed 000 picasso, seed 002 acd, seed 003 consensus) "
        "next to its figures")

#: study -> (module, one-line description)
STUDIES = {
    "picasso": ("hil.picasso", "seed 000: slip references Lf/Bd/Dp with preview, Table 1 and campaigns 2-3"),
    "acd": ("hil.acd_nodes", "seed 002: anti-collision device, randomized two-train runs with and without "
                             "prediction, judged on plant truth"),
    "consensus": ("hil.consensus_study", "seed 003: consensus braking, cases 1-3, cycle and latency sweeps"),
}


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reproduce", help=HELP, description=HELP + ".")
    studies = p.add_subparsers(dest="study", metavar="STUDY")
    studies.required = True
    for name, (module, help_line) in STUDIES.items():
        sp = studies.add_parser(name, help=help_line, description=help_line + ".")
        importlib.import_module(module).add_arguments(sp)
        sp.set_defaults(func=_runner(module))


def _runner(module: str):
    def run(args: argparse.Namespace) -> int:
        return importlib.import_module(module).run(args)
    return run
