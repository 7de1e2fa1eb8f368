"""Entry point of the `railhil` command.

Errors print one line `error: ...` and exit non-zero (2 for bad input); `--debug` shows the traceback.
An exception that is not a RailhilError is a bug: it too prints one line (exit 1), naming the
exception and the --debug command line that shows its traceback; an OSError on a named file (permission
denied, a disk full) prints the file and the system's reason (exit 2).

Each subcommand's module (with its numpy, matplotlib, pydantic... imports) is imported only when that
subcommand runs: ``COMMANDS`` holds each one's module and help line, so that ``railhil --help`` lists
them all without importing any (tests/cli/test_trace_cli.py checks the help lines against the modules').
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from hil import build
from hil.errors import RailhilError

INTERNAL_ERROR = 1  # exit code of an unexpected exception (bad input exits 2: hil.errors)

#: subcommand -> (module with add_subparser(sub) and the run function, its help line in `railhil --help`)
COMMANDS = {
    "run": ("hil.cli.run", "run a scenario and write its run folder"),
    "node": ("hil.cli.node", "run one node (or several) of a scenario alone on a python-can bus: the "
             "stand-in for a device, or the ECUs on another host"),
    "scenarios": ("hil.cli.scenarios", "list the shipped scenarios with their descriptions (run one by name: "
                  "railhil run NAME)"),
    "export-fmu": ("hil.cli.export_fmu", "write railhil's plant or a BECU of a scenario as an FMI 2.0 "
                   "co-simulation FMU"),
    "init": ("hil.cli.init", "write an editable copy of a shipped scenario and the DBC into a folder"),
    "trace": ("hil.cli.trace",
              "inspect a recorded CAN trace: statistics, decoding, export, plots, comparison, replay"),
    "timing": ("hil.cli.timing",
               "cycle-time conformance of a trace against the DBC, bus load, response-time analysis, "
               "latency chains"),
    "faults": ("hil.cli.faults", "fault injection campaigns: the EN 50159 threat matrix"),
    "wsp-test": ("hil.cli.wsp_test", "WSP type test (EN 15595 style): strategies side by side on low, "
                 "extremely low and suddenly changing adhesion at three speeds"),
    "campaign": ("hil.cli.campaign", "parameter sweeps of a scenario (grid and seeded random), in parallel "
                 "or on a Dask cluster; resumable"),
    "reproduce": ("hil.cli.reproduce", "reproduce a paper's simulation campaigns next to its figures (one "
                  "command per study)"),
    "report": ("hil.cli.report", "write the HTML report of a run or campaign folder, or compare two runs "
               "(--against)"),
    "control-centre": ("hil.cli.control_centre", "the anti-collision control centre: pairs follower and "
                       "leader trains over TCP, reports kept in SQLite"),
}


def version_line() -> str:
    """`railhil --version`: railhil's version and those of the libraries that read and write its frames,
    from the installed distributions' metadata (nothing imported), and the build that runs (hil.build):
    compiled by mypyc or pure Python, and why."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    def of(dist: str) -> str:
        try:
            return version(dist)
        except PackageNotFoundError:
            return "not installed"

    return (f"railhil {of('railhil')} (python-can {of('python-can')}, cantools {of('cantools')}, "
            f"Python {platform.python_version()}); {build.state().line()}")


class VersionAction(argparse.Action):
    """--version: the line of `version_line`, made only when asked for."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(version_line())
        parser.exit()


def command_of(argv: list[str]) -> str | None:
    """The subcommand named on a command line: its first word that is not an option (the top-level
    options take no value)."""
    return next((a for a in argv if not a.startswith("-")), None)


def build_parser(load: list[str] | tuple[str, ...] | None = None) -> argparse.ArgumentParser:
    """The parser of `railhil`, with the full parsers of the subcommands in `load` (their modules are
    imported) and a placeholder with the help line for every other one."""
    parser = argparse.ArgumentParser(
        prog="railhil",
        description="HIL testbench for railway brake electronics over CAN.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    parser.add_argument("--version", action=VersionAction,
                        help="print railhil's version and python-can's, cantools' and Python's, and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (module, help_line) in COMMANDS.items():
        if load is not None and name in load:
            importlib.import_module(module).add_subparser(sub)
        else:
            sub.add_parser(name, help=help_line)
    return parser


def main(argv: list[str] | None = None) -> int:
    if argv is None:
        argv = sys.argv[1:]
    command = command_of(argv)
    parser = build_parser([command] if command in COMMANDS else [])
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
    except BrokenPipeError:  # `railhil trace decode ... | head`: the reader left, not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # no second error at exit
        return 141
    except OSError as exc:  # a file the user named that the system refuses (permission, disk full...)
        if args.debug or exc.filename is None:
            raise
        print(f"error: {exc.filename}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug, not bad input: still one line, and how to get the traceback
        if args.debug:
            raise
        text = " ".join(str(exc).split())
        print(f"error: internal error, a railhil bug ({type(exc).__name__}: {text[:200]}); run "
              f"'railhil --debug {' '.join(argv)}' for the traceback and report it", file=sys.stderr)
        return INTERNAL_ERROR


if __name__ == "__main__":
    raise SystemExit(main())
