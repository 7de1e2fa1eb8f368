"""`railhil control-centre --db FILE --port N [--keys KEYS]` — the control centre of seed 002 as a TCP
service; `railhil control-centre --make-keys KEYS U1 U2` writes the trains' keys.

Trains report their position, speed, route section and length; the centre pairs follower and leader on
each route section and relays the leader's reports to its follower (hil.links.control_centre documents the
line-delimited JSON protocol and its authentication).  Reports are kept in the SQLite file FILE, so a
restart of the centre loses none.  With --keys, every hello and report must carry an HMAC-SHA256 with
its train's key and what the centre sends is signed with the receiving train's key; without it the
centre takes any client's word and warns so.  Serves until Ctrl-C or SIGTERM, then prints its counters;
exit 0, 2 for bad input.
"""

from __future__ import annotations

import argparse

from hil.links.control_centre import add_arguments, serve

HELP = ("the anti-collision control centre: pairs follower and leader trains over TCP, reports kept in "
        "SQLite")


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "control-centre",
        help=HELP,
        description="Serves the control centre of seed 002 (steps 3-6 of its anti-collision algorithm) "
                    "on TCP: line-delimited JSON, one object per line (see hil/links/control_centre.py). "
                    "With --keys FILE each train's hello and reports must be signed with its key "
                    "(HMAC-SHA256) and the centre signs what it sends; --make-keys FILE TRAIN... writes "
                    "such a file. Prints 'listening on HOST:PORT (database FILE)' once listening, a "
                    "summary when stopped by Ctrl-C or SIGTERM.",
    )
    add_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    return serve(args)
