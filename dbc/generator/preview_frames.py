"""The frames of the slip-reference-with-preview study (seed 000).

Part of dbc/generator/train_brake.py (run that script to write the DBC).
Identifiers: 0x070-0x07F and 0x108-0x11F.
"""

from __future__ import annotations

from dbcschema import Msg, Sig, becus, e2e  # noqa: F401


def messages() -> list[Msg]:
    return [

    ]
