"""Loading the DBC: the single source of truth for ids, layouts, cycle times and senders."""

from __future__ import annotations

import difflib
from pathlib import Path

import cantools
from cantools.database.can import Database

from hil.errors import DbcError

DEFAULT_DBC = Path(__file__).resolve().parents[1] / "dbc" / "train_brake.dbc"


def load_dbc(path: str | Path = DEFAULT_DBC) -> Database:
    """Load a DBC with cantools; any failure becomes one DbcError line naming the file."""
    path = Path(path)
    if not path.is_file():
        raise DbcError(f"{path}: no such DBC file")
    try:
        db = cantools.database.load_file(str(path), database_format="dbc", strict=True)
    except Exception as exc:  # cantools raises several types; all mean "not a usable DBC"
        detail = " ".join(str(exc).split())
        raise DbcError(f"{path}: not a loadable DBC file: {detail}") from exc
    if not isinstance(db, Database):
        raise DbcError(f"{path}: not a CAN database")
    return db


def closest(name: str, candidates: list[str], n: int = 3) -> str:
    found = difflib.get_close_matches(name, candidates, n=n, cutoff=0.5)
    return ", ".join(found) if found else "(nothing close)"
