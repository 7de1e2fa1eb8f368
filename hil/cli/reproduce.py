"""`railhil reproduce STUDY` — run a paper's simulation campaigns in lockstep and print our figures next
to the paper's, with its plots as PNG.

Every study of the registry (hil/studies/) brings its reproduction (its reproduce.py:
``add_arguments(parser)`` and ``run(args) -> int``); this module only dispatches.  The names of railhil
0.1 (hil.cli.aliases.REPRODUCE) still work for one release.
"""

from __future__ import annotations

import argparse
import sys

from hil.cli import aliases
from hil.scenario.registry import studies

HELP = "reproduce a paper's simulation campaigns next to its figures (one command per study)"


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reproduce", help=HELP, description=HELP + ".")
    parsers = p.add_subparsers(dest="study", metavar="STUDY")
    parsers.required = True
    old = {new: name for name, new in aliases.REPRODUCE.items()}
    for study in studies():
        help_line = f"{study.paper.split(':')[0]}: {study.title}"
        names = [old[study.cli_name]] if study.cli_name in old else []
        if names:
            help_line += f" (alias {names[0]}, until railhil {aliases.UNTIL})"
        sp = parsers.add_parser(study.cli_name, aliases=names, help=help_line,
                                description=f"{study.title}.  Paper: {study.paper}.")
        part = study.part("reproduce")
        part.add_arguments(sp)
        sp.set_defaults(func=_runner(study))


def _runner(study):
    def run(args: argparse.Namespace) -> int:
        if args.study != study.cli_name:
            aliases.notice(args.study, study.cli_name, "railhil reproduce")
            sys.stderr.flush()
        return study.part("reproduce").run(args)
    return run
