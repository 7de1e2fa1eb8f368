"""`railhil trace export`: a trace's decoded signals written as MF4, Parquet or CSV.

* **MF4** (ASAM MDF 4.10, through asammdf), the way asammdf's bus-logging extraction lays a decoded
  trace out: one channel group per DBC message (its acquisition name the message's name, its comment
  the message's comment and id), one channel per signal with the DBC's unit and comment, the frames'
  timestamps as the group's time; a signal with a value table gets it as the channel's value-to-text
  conversion (CANape, asammdf's GUI and `MDF.get()` show the names; `raw=True` gives the numbers).  A
  multiplexed message's frames are grouped by the signals they carry: one channel group per set.
* **Parquet** and **CSV**: one row per (frame, signal), the tidy layout every dataframe tool reads:
  ``t`` [s], ``id`` (hex as `trace decode` prints it: ``0x028``, ``0x18FEF100``), ``message``,
  ``signal``, ``value`` (physical), ``unit``, ``choice`` (the value-table name, empty where there is
  none).

The file is written beside its destination under a temporary name and renamed when complete, so an
interrupted or failed export leaves no half-written file in its place.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from hil.errors import RailhilError
from hil.trace.decoded import DecodedTrace, MessageTable
from hil.trace.readers import id_text

FORMATS = {".mf4": "ASAM MDF 4", ".parquet": "Parquet", ".csv": "CSV"}


class ExportError(RailhilError):
    """An export that cannot be written as asked."""


def export_format(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ExportError(f"-o {path}: unknown export format {path.suffix or '(no suffix)'!r}; expected "
                          + ", ".join(f"{s} ({what})" for s, what in FORMATS.items()))
    return suffix


def write_export(decoded: DecodedTrace, out: Path, messages: Iterable[str] | None = None) -> dict:
    """Write the decoded messages (all that have frames, or `messages`) to `out`, by its suffix; returns
    counts: messages, signals, frames, rows (Parquet/CSV) or channel groups (MF4)."""
    suffix = export_format(out)
    tables = [decoded.table(n) for n in (messages or decoded.message_names())]
    if out.exists() and out.is_dir():
        raise ExportError(f"-o {out}: is a folder; expected a file name ending in {suffix}")
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise ExportError(f"-o {out}: no such folder {folder}")
    # the temporary file keeps the suffix: asammdf appends .mf4 to a name without it
    fd, tmp_name = tempfile.mkstemp(prefix=f".{out.stem}.", suffix=f".part{suffix}", dir=folder)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        if suffix == ".mf4":
            counts = _write_mf4(tables, tmp)
        else:
            counts = _write_rows(tables, tmp, suffix)
        umask = os.umask(0)
        os.umask(umask)
        tmp.chmod(0o666 & ~umask)                 # as a file written directly would be (mkstemp: 0600)
        tmp.replace(out)
    except OSError as exc:        # a full disk, a folder without write permission: nothing is left behind
        tmp.unlink(missing_ok=True)
        raise ExportError(f"-o {out}: cannot write the export: {exc.strerror or exc}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return {"messages": len(tables), "signals": sum(len(t.columns) for t in tables),
            "frames": sum(len(t.t) for t in tables), **counts}


def _groups(table: MessageTable) -> list[tuple[np.ndarray, list[str]]]:
    """(rows, signals) of a message: all its rows and signals, or for a multiplexed message one entry per
    set of signals its frames carry (a signal is carried where its value is not NaN)."""
    names = list(table.columns)
    if not names or not len(table.t):
        return [(np.arange(len(table.t)), names)]
    present = np.column_stack([~np.isnan(table.columns[n]) for n in names])
    if present.all():
        return [(np.arange(len(table.t)), names)]
    out = []
    patterns, inverse = np.unique(present, axis=0, return_inverse=True)
    for k, pattern in enumerate(patterns):
        carried = [n for n, p in zip(names, pattern, strict=True) if p]
        out.append((np.flatnonzero(inverse.ravel() == k), carried))
    return out


def _conversion(choices: dict[float, str]) -> dict:
    conv: dict = {}
    for k, (value, text) in enumerate(sorted(choices.items())):
        conv[f"val_{k}"] = value
        conv[f"text_{k}"] = text
    conv["default"] = b""
    return conv


def _write_mf4(tables: list[MessageTable], path: Path) -> dict:
    from asammdf import MDF, Signal

    mdf = MDF(version="4.10")
    groups = 0
    for table in tables:
        ident = id_text(table.frame_id, table.extended)
        for rows, names in _groups(table):
            if not names:
                continue
            t = table.t[rows]
            signals = []
            for name in names:
                values = table.columns[name][rows]
                choices = table.choices.get(name)
                samples = values
                if choices and np.all(np.mod(values, 1) == 0):
                    samples = values.astype(np.int64)       # a value table maps integers to names
                signals.append(Signal(samples=samples, timestamps=t, name=name,
                                      unit=table.units.get(name, ""), comment=table.comments.get(name, ""),
                                      conversion=_conversion(choices) if choices else None,
                                      display_names={f"{table.name}.{name}": "message"}))   # as asammdf
            acq = table.name if len(names) == len(table.columns) else f"{table.name} [{', '.join(names)}]"
            mdf.append(signals, acq_name=acq, comment=f"{table.name} ({ident}) {table.comment}".strip(),
                       common_timebase=True)
            groups += 1
    mdf.save(str(path), overwrite=True)
    mdf.close()
    return {"channel_groups": groups}


def _write_rows(tables: list[MessageTable], path: Path, suffix: str) -> dict:
    import pandas as pd

    parts = []
    for table in tables:
        ident = id_text(table.frame_id, table.extended)       # 0x028, 0x18FEF100: as trace decode prints it
        for name, values in table.columns.items():
            keep = ~np.isnan(values)
            v = values[keep]
            choices = table.choices.get(name, {})
            parts.append(pd.DataFrame({
                "t": table.t[keep], "id": ident, "message": table.name, "signal": name, "value": v,
                "unit": table.units.get(name, ""),
                "choice": [choices.get(x, "") for x in v.tolist()] if choices else "",
            }))
    columns = ["t", "id", "message", "signal", "value", "unit", "choice"]
    frame = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=columns)
    frame = frame.sort_values("t", kind="stable", ignore_index=True)[columns]
    if suffix == ".parquet":
        frame.to_parquet(path, index=False)
    else:
        frame.to_csv(path, index=False)             # floats as Python's repr: the shortest exact text
    return {"rows": len(frame)}
