"""`railhil init DIR` — an editable copy of a shipped scenario and of the DBC, for a user's own work.

DIR gets the scenario file(s) (default: default.toml) with `dbc = "train_brake.dbc"` added, so that the
run uses the copy of the DBC beside it, the DBC itself, and the rail-profile tables a copied scenario
names by a relative path.  Nothing is overwritten unless --force.  Then:
`railhil run DIR/default.toml`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hil.errors import RailhilError
from hil.resources import DEFAULT_DBC_NAME, default_dbc, scenarios_dir, shipped_scenarios, unknown_scenario

HELP = "write an editable copy of a shipped scenario and the DBC into a folder"
DBC_KEY = 'dbc = "{name}"          # the editable copy of the CAN schema beside this file (railhil init)\n'


class InitError(RailhilError):
    """`railhil init` cannot write what it was asked to."""


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("init", help=HELP,
                       description="Write an editable copy of shipped scenarios (default: default) and of "
                                   "the DBC (train_brake.dbc) into DIR; the copied scenarios use the copied "
                                   "DBC. Then run: railhil run DIR/<scenario>.toml. `railhil scenarios` "
                                   "lists the names.")
    p.add_argument("dir", type=Path, metavar="DIR", help="folder to write into (created if missing)")
    p.add_argument("-s", "--scenario", dest="scenarios", action="append", metavar="NAME",
                   help="a shipped scenario to copy (repeatable; default: default; 'all' for every one)")
    p.add_argument("--force", action="store_true", help="overwrite files that exist")
    p.set_defaults(func=run)


def with_local_dbc(text: str, dbc_name: str) -> str:
    """The scenario's TOML text with a top-level `dbc` key naming the DBC beside it (inserted before its
    first table, where top-level keys must be), or unchanged if it names one already."""
    import tomllib

    if "dbc" in tomllib.loads(text):
        return text
    lines = text.splitlines(keepends=True)
    at = next((k for k, line in enumerate(lines) if line.lstrip().startswith("[")), len(lines))
    return "".join(lines[:at] + [DBC_KEY.format(name=dbc_name), "\n"] + lines[at:])


def run(args: argparse.Namespace) -> int:
    import tomllib


    shipped = {s.name: s for s in shipped_scenarios()}
    names = args.scenarios or ["default"]
    if "all" in names:
        names = list(shipped)
    unknown = [n for n in names if n.removesuffix(".toml") not in shipped]
    if unknown:
        raise InitError(f"--scenario {unknown[0]!r}: no shipped scenario of that name; "
                        f"{unknown_scenario(unknown[0])}")
    out: Path = args.dir
    if out.exists() and not out.is_dir():
        raise InitError(f"{out}: exists and is not a folder; expected a folder to write the copies into")
    plan: list[tuple[Path, str | bytes]] = [(out / DEFAULT_DBC_NAME, default_dbc().read_bytes())]
    for name in dict.fromkeys(n.removesuffix(".toml") for n in names):
        src = shipped[name].path
        text = src.read_text()
        plan.append((out / src.name, with_local_dbc(text, DEFAULT_DBC_NAME)))
        profile = tomllib.loads(text).get("preview", {}).get("rail_profile")
        if profile and ("/" in profile or profile.endswith(".csv")):      # a table beside the scenario
            table = scenarios_dir() / profile
            if table.is_file():
                plan.append((out / profile, table.read_bytes()))
    exists = [p for p, _ in plan if p.exists()]
    if exists and not args.force:
        raise InitError(f"{exists[0]}: exists; railhil init overwrites nothing (use --force, or another DIR)")
    for path, content in plan:
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
    for path, _ in plan:
        print(f"wrote {path}")
    first = next(p for p, c in plan if isinstance(c, str))
    print(f"next: railhil run {first}   (edit {first.name} and {DEFAULT_DBC_NAME} as you need; "
          f"the DBC's generator is dbc/generator/ in railhil's source)")
    return 0



