"""`railhil control-centre --db FILE --port N` — the control centre of seed 002 as a TCP service.

Trains report their position, speed, route section and length; the centre pairs follower and leader on
each route section and relays the leader's reports to its follower (hil.links.control_centre documents the
line-delimited JSON protocol).  Reports are kept in the SQLite file FILE, so a restart of the centre
loses none.  Serves until Ctrl-C or SIGTERM, then prints its counters; exit 0, 2 for bad input.
"""

from __future__ import annotations

import argparse

HELP = ("the anti-collision control centre: pairs follower and leader trains over TCP, reports kept in "
        "SQLite")


def add_subparser(sub: argparse._SubParsersAction) -> None:
    from hil.links.control_centre import add_arguments

    p = sub.add_parser(
        "control-centre",
        help=HELP,
        description="Serves the control centre of seed 002 (steps 3-6 of its anti-collision algorithm) "
                    "on TCP: line-delimited JSON, one object per line (see hil/links/control_centre.py). "
                    "Prints 'listening on HOST:PORT (database FILE)' once listening, a summary when "
                    "stopped by Ctrl-C or SIGTERM.",
    )
    add_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hil.links.control_centre import serve

    return serve(args)
