"""Entry point of the `railhil` command.

Errors print one line `error: ...` and exit non-zero (2 for bad input); `--debug` shows the traceback.
"""

from __future__ import annotations

import argparse
import sys

from hil.cli import run as run_cmd
from hil.cli import timing as timing_cmd
from hil.cli import trace as trace_cmd
from hil.errors import RailhilError

SUBCOMMANDS = (run_cmd, trace_cmd, timing_cmd)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="railhil",
        description="HIL testbench for railway brake electronics over CAN.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in SUBCOMMANDS:
        module.add_subparser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except RailhilError as exc:
        if args.debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
