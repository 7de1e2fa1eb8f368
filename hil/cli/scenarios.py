"""`railhil scenarios` — the scenarios railhil ships, by name, each with its description.

Any of them runs by name from any directory (`railhil run default`); `railhil init DIR` writes an
editable copy.  In a checkout they are the files of scenarios/; installed, the wheel's copies
(hil.resources).
"""

from __future__ import annotations

import argparse
import shutil
import textwrap

from hil.resources import scenarios_dir, shipped_scenarios

HELP = "list the shipped scenarios with their descriptions (run one by name: railhil run NAME)"


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scenarios", help=HELP,
                       description="List the scenarios railhil ships: name and description. Any of them "
                                   "runs by name (railhil run default); railhil init DIR writes an "
                                   "editable copy of one.")
    p.add_argument("--paths", action="store_true", help="also print each scenario's file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    shipped = shipped_scenarios()
    width = max(60, min(shutil.get_terminal_size((110, 20)).columns, 140))
    name_w = max(len(s.name) for s in shipped) + 2
    for s in shipped:
        text = s.description or "(no description)"
        lines = textwrap.wrap(text, width - name_w) or [""]
        print(f"{s.name:<{name_w}}{lines[0]}")
        for line in lines[1:]:
            print(" " * name_w + line)
        if args.paths:
            print(" " * name_w + str(s.path))
    print(f"\n{len(shipped)} scenarios in {scenarios_dir()}; run one with: railhil run NAME "
          f"(e.g. railhil run {shipped[0].name if shipped else 'default'} --lockstep)")
    return 0
