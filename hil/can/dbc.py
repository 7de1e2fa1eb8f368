"""Loading the DBC: the single source of truth for ids, layouts, cycle times and senders."""

from __future__ import annotations

import difflib
import hashlib
import io
import logging
import os
import re
import sys
from collections import defaultdict
from pathlib import Path

import cantools
from cantools.database.can import Database

from hil.errors import DbcError
from hil.resources import default_dbc

DEFAULT_DBC = default_dbc()        # dbc/train_brake.dbc, in a checkout or from the wheel (hil.resources)
_SNIFF_BYTES = 8192  # bytes looked at to tell a binary file from DBC text
CACHE_ENV = "RAILHIL_DBC_CACHE"    # a directory for the loaded-DBC cache, or "off"
CACHE_WAIT_S = 1.0     # s, the longest a load waits on the cache's lock (diskcache: 60), then it parses


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
        data = path.read_bytes()
    except OSError as exc:
        raise DbcError(f"{path}: cannot read the DBC file: {exc.strerror or exc}") from None
    if not data:
        raise DbcError(f"{path}: empty file (0 bytes), expected a DBC text file")
    if b"\0" in data[:_SNIFF_BYTES]:
        raise DbcError(f"{path}: a binary file (it holds NUL bytes), expected a DBC text file")
    try:
        db = _cached(data)
    except Exception as exc:  # cantools raises several types; all mean "not a usable DBC"
        raise DbcError(f"{path}: not a loadable DBC file: {_printable(str(exc))}") from exc
    if not isinstance(db, Database):
        raise DbcError(f"{path}: not a CAN database")
    clash = _duplicates(db)
    if clash is not None:
        raise DbcError(f"{path}: {clash}; expected one message per frame id and per name")
    unused = getattr(db, "railhil_unused_values", None)
    if unused:
        one = len(unused) == 1
        print(f"notice: {path}: {', '.join(unused)} "
              + ("names no signal of its message; the value table is" if one else
                 "name no signal of their messages; the value tables are") + " left out", file=sys.stderr)
    return db


class _Overwriting(logging.Filter):
    """Drops cantools' warning that two messages share an id or a name (its only warnings while it parses a
    DBC): load_dbc turns that into an error of its own, one line, instead of a loose log line before it."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("Overwriting message")


_UNUSED_VAL = re.compile(r"VAL_ (\d+) (\w+)")


def parse_dbc_text(text: str, strict: bool = True) -> Database:
    """cantools' load_string of DBC text, except that a value table (VAL_) naming a signal its message
    does not have is left out rather than failing the whole file: real DBCs carry such leftovers (opendbc's
    tesla_can.dbc: VAL_ 568 UI_mapSpeedLimit, a signal since renamed).  The entries left out are on the
    database as `railhil_unused_values` ("VAL_ 568 UI_mapSpeedLimit"); load_dbc says so."""
    dropped: list[str] = []
    for _ in range(3):
        try:
            db = cantools.database.load_string(text, database_format="dbc", strict=strict)
        except Exception as exc:
            message = str(exc)
            unused = _UNUSED_VAL.findall(message) if "unused VAL_ entries" in message else []
            if not unused:
                raise
            for frame_id, signal in unused:
                text = re.sub(rf"^VAL_\s+{frame_id}\s+{re.escape(signal)}\s[^;]*;[ \t]*\r?\n?", "", text,
                              flags=re.MULTILINE)
                dropped.append(f"VAL_ {frame_id} {signal}")
            continue
        db.railhil_unused_values = dropped
        return db
    raise DbcError("value tables that name no signal remain after three passes: " + ", ".join(dropped))


def _parse(data: bytes) -> Database:
    """cantools' load_file on these bytes: its DBC decoding (cp1252, undecodable bytes replaced, newlines
    translated), then load_string (parse_dbc_text)."""
    text = io.TextIOWrapper(io.BytesIO(data), encoding="cp1252", errors="replace").read()
    logger = logging.getLogger("cantools.database.can.database")
    quiet = _Overwriting()
    logger.addFilter(quiet)
    try:
        return parse_dbc_text(text)
    finally:
        logger.removeFilter(quiet)


def cache_dir() -> Path | None:
    """Where loaded DBCs are kept: RAILHIL_DBC_CACHE, else railhil/dbc under $XDG_CACHE_HOME or ~/.cache;
    None when that is "off", diskcache is not installed or the directory cannot be made or written."""
    setting = os.environ.get(CACHE_ENV, "")
    if setting == "off":
        return None
    try:
        import diskcache  # noqa: F401  (cantools' own cache library: `cantools[cache]`)
    except ImportError:
        return None
    try:
        where = Path(setting) if setting else \
            Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "railhil" / "dbc"
        where.mkdir(parents=True, exist_ok=True)
    except (OSError, RuntimeError):        # RuntimeError: no home directory to be found
        return None
    return where if os.access(where, os.W_OK) else None


def _cached(data: bytes) -> Database:
    """The database these DBC bytes hold: parsed by cantools (45–100 ms for the project's DBC), or, when
    this cantools parsed the same bytes before, unpickled from a diskcache (about 10 ms).  Keyed by the
    bytes' SHA-256, not by the file's path and modification time as cantools' own `cache_dir` is: a file
    rewritten within one tick of the kernel's coarse file clock keeps its time.  A cache that fails
    (locked, corrupt, a full disk) is passed by: the bytes are parsed as without one."""
    where = cache_dir()
    if where is None:
        return _parse(data)
    import diskcache

    key = ("dbc", cantools.__version__, hashlib.sha256(data).hexdigest())
    try:
        cache = diskcache.Cache(str(where), timeout=CACHE_WAIT_S)
    except Exception:   # the cache's own trouble, whatever diskcache or sqlite raise
        return _parse(data)
    with cache:
        try:
            hit = cache.get(key)
        except Exception:
            hit = None
        if isinstance(hit, Database):
            return hit
        db = _parse(data)
        try:
            cache.set(key, db)
        except Exception:
            pass
        return db


def closest(name: str, candidates: list[str], n: int = 3) -> str:
    found = difflib.get_close_matches(name, candidates, n=n, cutoff=0.5)
    return ", ".join(found) if found else "(nothing close)"
