"""The frames of the consensus-braking study (seed 003).

Part of dbc/generator/train_brake.py (run that script to write the DBC).  Identifiers: 0x058-0x06F.
"""

from __future__ import annotations

from dbcschema import Msg, Sig, becus, e2e  # noqa: F401


def messages() -> list[Msg]:
    return [

    ]
