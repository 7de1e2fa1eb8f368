"""Loading the DBC: the single source of truth for ids, layouts, cycle times and senders."""

from __future__ import annotations

import difflib
import logging
from collections import defaultdict
from pathlib import Path

import cantools
from cantools.database.can import Database

from hil.errors import DbcError
from hil.resources import default_dbc

DEFAULT_DBC = default_dbc()        # dbc/train_brake.dbc, in a checkout or from the wheel (hil.resources)
_SNIFF_BYTES = 8192  # bytes looked at to tell a binary file from DBC text


class _Overwriting(logging.Filter):
    """Drops cantools' warning that two messages share an id or a name: load_dbc turns that into an
    error of its own, one line, instead of a loose log line before it."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("Overwriting message")


def _printable(text: str, limit: int = 200) -> str:
    """One line of `text` with control and other unprintable characters escaped, at most `limit` long."""
    text = " ".join(text.split())
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _duplicates(db: Database) -> str | None:
    """What two or more messages of `db` share (frame id or name), or None.  cantools keeps only the
    last of them in its lookup by id or name, so the others would silently never decode."""
    by_id: dict[int, list[str]] = defaultdict(list)
    by_name: dict[str, int] = defaultdict(int)
    for m in db.messages:
        by_id[m.frame_id].append(m.name)
        by_name[m.name] += 1
    for frame_id, names in by_id.items():
        if len(names) > 1:
            return f"messages {', '.join(names)} have the same frame id 0x{frame_id:X}"
    for name, count in by_name.items():
        if count > 1:
            return f"{count} messages are named {name}"
    return None


def load_dbc(path: str | Path = DEFAULT_DBC) -> Database:
    """Load a DBC with cantools (strict: overlapping signals and signals beyond the frame are errors);
    any failure becomes one DbcError line naming the file.  Also an error: an empty or binary file,
    and two messages with one frame id or one name (cantools would keep only one of them)."""
    path = Path(path)
    if not path.is_file():
        what = "a directory" if path.is_dir() else "no such DBC file"
        raise DbcError(f"{path}: {what}" + (", expected a DBC file" if path.is_dir() else ""))
    try:
        with path.open("rb") as f:
            head = f.read(_SNIFF_BYTES)
    except OSError as exc:
        raise DbcError(f"{path}: cannot read the DBC file: {exc.strerror or exc}") from None
    if not head:
        raise DbcError(f"{path}: empty file (0 bytes), expected a DBC text file")
    if b"\0" in head:
        raise DbcError(f"{path}: a binary file (it holds NUL bytes), expected a DBC text file")
    logger = logging.getLogger("cantools.database.can.database")
    quiet = _Overwriting()
    logger.addFilter(quiet)
    try:
        db = cantools.database.load_file(str(path), database_format="dbc", strict=True)
    except Exception as exc:  # cantools raises several types; all mean "not a usable DBC"
        raise DbcError(f"{path}: not a loadable DBC file: {_printable(str(exc))}") from exc
    finally:
        logger.removeFilter(quiet)
    if not isinstance(db, Database):
        raise DbcError(f"{path}: not a CAN database")
    clash = _duplicates(db)
    if clash is not None:
        raise DbcError(f"{path}: {clash}; expected one message per frame id and per name")
    return db


def closest(name: str, candidates: list[str], n: int = 3) -> str:
    found = difflib.get_close_matches(name, candidates, n=n, cutoff=0.5)
    return ", ".join(found) if found else "(nothing close)"
