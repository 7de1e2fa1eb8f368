"""Reading CAN traces with python-can's readers, every failure one TraceError line naming the file.

``open_trace(path)`` picks python-can's reader by suffix (``can.LogReader``: .asc .blf .csv .db
.log .mf4 .trc, and any of them gzip-compressed as .asc.gz and so on); ``open_trace("-")`` reads
candump -L text (``(1.5) can0 123#DEADBEEF``) from stdin with python-can's ``CanutilsLogReader``.

The file is checked and its reader opened when ``open_trace`` is called, so a missing file or an
unknown suffix fails at once; corrupt content fails while iterating.  A non-empty file in which the
reader finds no frame at all (a text file of another format) is an error too: python-can's text
readers skip lines they do not understand without a word.  So is an empty file (0 bytes; empty
stdin is 0 frames), and a BLF file cut short (``blf_cut``): python-can's reader ends it quietly,
here its frames come first, then the TraceError that says where it was cut and how many were read.
``Salvage`` keeps that error instead of raising it, for the tools that report the frames read before
any damage and then the error (nothing already recorded is lost).

candump -L text is read by python-can's ``CanutilsLogReader`` with one shortcut (``CandumpReader``):
the common line, a classic data frame written as ``(seconds) channel ID#HEXDATA`` with an optional
`` R``/`` T``, single spaces, a 3- or 8-digit id without the error flag, whole data bytes, is parsed
by one regular expression into the very ``can.Message`` python-can makes of it (about 2.5x faster);
any other line (remote, CAN FD, error frames, other spacing, anything malformed) goes to python-can's
own parser, so what it yields or raises is python-can's.  A bulk parser (``hil.trace.columns``) can read
candump text a batch of lines at a time through ``Trace.candump_batches`` and hand every line it does not
take itself to ``Trace.candump_line``: the frames, the line numbers and the errors stay those of
iterating the ``Trace``.
"""

from __future__ import annotations

import gzip
import importlib.util
import logging
import pathlib
import re
import sys
from collections.abc import Iterable, Iterator
from itertools import islice
from typing import TextIO

import can
from can.io import blf
from can.io.canutils import CAN_ERR_FLAG
from can.io.player import MESSAGE_READERS

from hil.errors import RailhilError

__all__ = ["FORMATS", "CandumpReader", "Salvage", "Trace", "TraceError", "blf_cut", "id_text", "open_trace"]

#: what each suffix is expected to hold, for error messages
FORMATS = {
    ".asc": "a Vector ASC text trace",
    ".blf": "a Vector BLF binary trace",
    ".csv": "a python-can CSV trace",
    ".db": "a python-can SQLite trace",
    ".log": "a candump -L text trace ('(timestamp) channel id#data' per line)",
    ".mf4": "an ASAM MDF4 trace",
    ".trc": "a PEAK TRC text trace",
}
STDIN = "-"


class TraceError(RailhilError, ValueError):
    """A CAN trace that cannot be read: missing, of an unknown format, or corrupt."""


def id_text(arbitration_id: int, extended: bool) -> str:
    """An id as candump prints it: 3 hex digits for an 11-bit id, 8 for a 29-bit one, so the two never
    mix (the trace tools print ids so)."""
    return f"0x{arbitration_id:08X}" if extended else f"0x{arbitration_id:03X}"


class _Lines:
    """A text stream that counts the lines read from it, so a parse error can name its line."""

    def __init__(self, stream: TextIO, close: bool = True) -> None:
        self.stream = stream
        self.n = 0
        self.line = ""
        self._close = close

    def __iter__(self) -> Iterator[str]:
        for line in self.stream:
            self.n += 1
            self.line = line
            yield line

    def close(self) -> None:
        if self._close:
            self.stream.close()


# (seconds) channel ID#HEXDATA [R|T], exactly one space apart: python-can's CanutilsLogReader gives
# timestamp=float(seconds), channel=int if all digits, extended = more than 3 id digits, data = the bytes
_CANDUMP_LINE = re.compile(r"\((\d+\.\d+)\) (\w+) ([0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#((?:[0-9A-Fa-f]{2})*)"
                           r"(?: ([RrTt]))?", re.ASCII)


class _OneLine:
    """A reader stand-in whose ``file`` is one line, for python-can's generator to parse it."""

    def __init__(self, line: str) -> None:
        self.file = (line,)

    def stop(self) -> None:  # python-can's generator stops its reader at the end: the real one is not done
        pass


class CandumpReader(can.CanutilsLogReader):
    """python-can's candump -L reader, with the common data-frame line parsed by one regex (module
    docstring); ``list(CandumpReader(f))`` equals ``list(can.CanutilsLogReader(f))`` message by message."""

    def __iter__(self) -> Iterator[can.Message]:
        match = _CANDUMP_LINE.fullmatch
        python_can = can.CanutilsLogReader.__iter__
        fromhex = bytearray.fromhex
        message = can.Message
        for line in self.file:
            found = match(line.strip())
            if found is not None:
                seconds, channel, ident, data, direction = found.groups()
                can_id = int(ident, 16)
                if not can_id & CAN_ERR_FLAG:
                    yield message(timestamp=float(seconds), arbitration_id=can_id & 0x1FFFFFFF,
                                  is_extended_id=len(ident) > 3, is_rx=direction is None or direction in "Rr",
                                  dlc=len(data) // 2, data=fromhex(data),
                                  channel=int(channel) if channel.isdigit() else channel)
                    continue
            yield from python_can(_OneLine(line))
        self.stop()  # as python-can's reader does at the end of the file


def _suffix_of(path: pathlib.Path) -> tuple[str, bool]:
    """(format suffix, gzip-compressed?) of a trace file name."""
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        return (suffixes[-2] if len(suffixes) >= 2 else ""), True
    return (suffixes[-1] if suffixes else ""), False


def _one_line(exc: BaseException) -> str:
    kind = type(exc).__name__
    if kind == "error":  # struct.error, zlib.error
        kind = f"{type(exc).__module__}.error"
    text = " ".join(str(exc).split())
    return f"{kind}: {text}" if text else kind


def open_trace(path: str | pathlib.Path) -> Trace:
    """The frames of a trace file (or of candump text on stdin for ``"-"``), in file order."""
    if str(path) == STDIN:
        lines = _Lines(sys.stdin, close=False)
        return Trace(CandumpReader(lines), "<stdin>", FORMATS[".log"], lines, empty_ok=True)
    path = pathlib.Path(path)
    if not path.exists():
        raise TraceError(f"{path}: no such trace file")
    if not path.is_file():
        raise TraceError(f"{path}: not a file (expected a CAN trace)")
    suffix, compressed = _suffix_of(path)
    if suffix not in MESSAGE_READERS:
        known = ", ".join(sorted(MESSAGE_READERS))
        raise TraceError(f"{path}: unknown trace format {''.join(path.suffixes) or '(no suffix)'!r}; "
                         f"expected one of {known} (optionally .gz compressed), or '-' for candump "
                         f"text on stdin")
    expected = FORMATS.get(suffix, f"a {suffix} trace")
    if compressed:
        expected += ", gzip-compressed"
    lines = None
    if suffix == ".mf4" and importlib.util.find_spec("asammdf") is None:
        raise TraceError(f"{path}: cannot read {expected} here: python-can reads MF4 through asammdf, "
                         f"which is not installed")
    try:
        if suffix == ".log":  # counted lines: a parse error names its line
            stream = gzip.open(path, "rt") if compressed else path.open("r")
            lines = _Lines(stream)
            reader = CandumpReader(lines)
        elif suffix == ".mf4":
            reader = _open_mf4(path, expected)
        else:
            reader = can.LogReader(path)
    except TraceError:
        raise
    except OSError as exc:  # permission denied, an I/O error: the system's reason, not a format's
        raise TraceError(f"{path}: cannot read the trace file: {exc.strerror or _one_line(exc)}") from exc
    except Exception as exc:  # python-can raises many types; all mean "not readable as expected"
        if path.stat().st_size == 0:  # a reader that parses a file header at once (BLF)
            raise TraceError(f"{path}: empty file (0 bytes): no CAN frames (expected {expected})") from exc
        raise TraceError(f"{path}: not readable as {expected}: {_one_line(exc)}") from exc
    trace = Trace(reader, str(path), expected, lines, empty_ok=False)
    trace.empty_file = path.stat().st_size == 0
    if suffix == ".blf" and not compressed:
        trace.cut = blf_cut(path)
    return trace


def _open_mf4(path: pathlib.Path, expected: str) -> can.io.MF4Reader:
    """python-can's MF4 reader of a bus-logging file, or one TraceError line.  asammdf leaves a half-made
    MDF object behind when it cannot open a file, whose __del__ then prints a traceback: its frames are
    cleared and the object collected here, with that noise suppressed."""
    import gc
    import traceback

    hook = sys.unraisablehook
    sys.unraisablehook = lambda unraisable: None
    failed = True
    try:
        try:
            reader = can.LogReader(path)
            mf4_check_bus_logging(path, getattr(reader, "_mdf", None))   # python-can's own MDF, if it has one
            failed = False
            return reader
        except TraceError:
            raise
        except OSError:
            raise
        except Exception as exc:
            traceback.clear_frames(exc.__traceback__)
            raise TraceError(f"{path}: not readable as {expected}: {_one_line(exc)}") from None
    finally:
        if failed:            # the half-made MDF goes now, while its noise is suppressed (30 ms: not always)
            gc.collect()
        sys.unraisablehook = hook


#: the channels of an MF4 CAN bus-logging channel group, in the order python-can's reader looks for them
MF4_FRAME_CHANNELS = ("CAN_DataFrame", "CAN_ErrorFrame", "CAN_RemoteFrame")


def mf4_can_frames(group) -> str | None:
    """The frame channel (MF4_FRAME_CHANNELS) of an asammdf channel group flagged as bus events from a
    CAN bus source, or None for any other group."""
    from asammdf.blocks.v4_constants import BUS_TYPE_CAN, FLAG_CG_BUS_EVENT

    source = group.channel_group.acq_source
    if not group.channel_group.flags & FLAG_CG_BUS_EVENT or source is None or source.bus_type != BUS_TYPE_CAN:
        return None
    names = {c.name for c in group.channels}
    return next((n for n in MF4_FRAME_CHANNELS if n in names), None)


def mf4_check_bus_logging(path: pathlib.Path, mdf=None) -> None:
    """An MF4 file python-can reads frames from holds CAN bus logging: a channel group flagged as bus
    events from a CAN bus source, with CAN_DataFrame, CAN_ErrorFrame or CAN_RemoteFrame (ASAM MDF 4.1
    bus logging, as python-can and asammdf write it).  Another MF4 (a measurement of signals) is a
    TraceError naming what it holds instead."""
    from asammdf import MDF

    own = mdf is None                     # `mdf`: the file already open (python-can's reader's)
    mdf = MDF(str(path)) if own else mdf
    try:
        names: list[str] = []
        for group in mdf.groups:
            if mf4_can_frames(group):
                return
            names += [c.name for c in group.channels if c.name not in ("t", "time")]
    finally:
        if own:
            mdf.close()
    shown = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    raise TraceError(f"{path}: not an MF4 CAN bus-logging file: no channel group of CAN frames "
                     f"(CAN_DataFrame as python-can, asammdf and CANape log them); it holds "
                     f"{shown or 'no channels'}")


def blf_cut(path: pathlib.Path) -> str | None:
    """Where a BLF file was cut short, or None when it is whole (or too broken for this check: then
    python-can's reader raises on it).

    python-can's reader ends a BLF file quietly where it is cut: the frames of a last, cut log
    container that it can still decompress are read and the rest is dropped without a word.  Here the
    top-level objects are walked as python-can walks them (a 16-byte base header with the object's
    size, then the padding python-can skips); the file is cut when an object runs past its end, or
    when the file is shorter than the size its header declares (python-can's writer writes the size
    when it closes the file)."""
    header = blf.FILE_HEADER_STRUCT
    base = blf.OBJ_HEADER_BASE_STRUCT
    size = path.stat().st_size
    with path.open("rb") as f:
        head = f.read(header.size)
        if len(head) < header.size:
            return None
        fields = header.unpack(head)
        if fields[0] != b"LOGG":
            return None
        declared, pos, n = fields[10], fields[1], 0
        while pos + base.size <= size:
            f.seek(pos)
            signature, _, _, obj_size, obj_type = base.unpack(f.read(base.size))
            if signature != b"LOBJ" or obj_size < base.size:
                return None
            n += 1
            if pos + obj_size > size:
                what = "log container" if obj_type == blf.LOG_CONTAINER else f"object of type {obj_type}"
                return (f"the file ends inside its object {n} (a {what} of {obj_size} bytes at byte {pos}), "
                        f"{pos + obj_size - size} bytes short")
            pos += obj_size + obj_size % 4
    if declared > size:
        return f"the file has {size} bytes, its header declares {declared}"
    return None


class Salvage:
    """The frames of a Trace up to a TraceError, which is kept in ``error`` instead of raised.

    For the tools that report what was read before a file's damage (a corrupt line, a cut), then the
    error: nothing already recorded is lost."""

    def __init__(self, frames: Iterable[can.Message]) -> None:
        self.frames = frames
        self.error: TraceError | None = None

    def __iter__(self) -> Iterator[can.Message]:
        try:
            yield from self.frames
        except TraceError as exc:
            self.error = exc
            if isinstance(self.frames, Trace):
                self.frames.error = exc

    def raise_error(self) -> None:
        """Raise the TraceError that ended the frames, if one did."""
        if self.error is not None:
            raise self.error


class _Warnings(logging.Handler):
    """Counts the lines python-can's readers skip with a logged warning (its TRC reader does)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.count = 0
        self.first = ""

    def emit(self, record: logging.LogRecord) -> None:
        self.count += 1
        if not self.first:
            self.first = " ".join(record.getMessage().split())[:120]


class Trace:
    """The frames of one trace, once; ``skipped`` and ``first_skipped`` say what the reader dropped.

    While iterating, python-can's reader warnings are counted here instead of reaching stderr as
    loose lines (they still reach any handler the application configured).
    """

    def __init__(self, reader, name: str, expected: str, lines: _Lines | None, empty_ok: bool) -> None:
        self.name = name
        self.expected = expected
        self.count = 0
        self.skipped = 0
        self.first_skipped = ""
        self.empty_file = False  # the file has 0 bytes (an error once its frames, none, are read)
        self.cut: str | None = None  # where a BLF file was cut short (blf_cut), found when it was opened
        self.error: TraceError | None = None  # what ended the frames, kept by a reader told to salvage
        self._reader = reader
        self._lines = lines
        self._empty_ok = empty_ok

    @property
    def reader(self):
        """python-can's reader of this trace (hil.trace.columns reads a BLFReader's file itself)."""
        return self._reader

    def close(self) -> None:
        """Close the file without reading on (iterating to the end closes it too)."""
        try:
            self._reader.stop()
        except Exception:  # closing must not raise over what the caller is handling
            pass

    def __iter__(self) -> Iterator[can.Message]:
        handler = _Warnings()
        logger = logging.getLogger("can.io")
        logger.addHandler(handler)
        try:
            try:
                for msg in self._reader:
                    self.count += 1
                    yield msg
            except GeneratorExit:
                raise
            except Exception as exc:
                raise self._error(exc) from exc
        finally:
            self._finish(logger, handler)
        self._check_not_empty()

    # --- candump text a batch of lines at a time (hil.trace.columns) ------------------------------

    @property
    def is_candump(self) -> bool:
        """True when the frames come from candump -L text (a .log file, .log.gz, or stdin)."""
        return isinstance(self._reader, CandumpReader) and self._lines is not None

    def candump_batches(self, max_lines: int) -> Iterator[list[str]]:
        """The lines of candump -L text, up to `max_lines` at a time, as iterating the file gives them.

        For a bulk parser of the text: it takes the lines it can, hands every other line to
        ``candump_line`` in order, and adds the frames it takes itself to ``count`` before it does
        (``count`` is the "after N frames" of an error).  A read error (a byte the text encoding
        cannot decode, say) comes after a last batch of the lines read before it, as the TraceError
        that iterating the Trace raises; so does "no CAN frames found" at the end.
        """
        if not self.is_candump:
            raise TypeError(f"{self.name}: not candump text")
        lines = self._lines
        stream = lines.stream
        handler = _Warnings()
        logger = logging.getLogger("can.io")
        logger.addHandler(handler)
        try:
            while True:
                batch: list[str] = []
                error = None
                try:
                    batch.extend(islice(stream, max_lines))  # keeps the lines read before an error
                except Exception as exc:  # the text cannot be read on: what iterating it would raise
                    error = exc
                if batch:
                    base = lines.n
                    yield batch
                    lines.n, lines.line = base + len(batch), batch[-1]
                if error is not None:
                    raise self._error(error) from error
                if not batch:
                    break
        finally:
            self._finish(logger, handler)
        self._check_not_empty()

    def candump_line(self, line: str, number: int) -> can.Message | None:
        """python-can's frame of one candump -L line (``CandumpReader``), None for a line it skips.

        `number` is the line's number in the text (1 for the first); an error is the TraceError that
        iterating the Trace raises at that line."""
        self._lines.n, self._lines.line = number, line
        try:
            return next(iter(CandumpReader.__iter__(_OneLine(line))), None)  # type: ignore[arg-type]
        except Exception as exc:
            raise self._error(exc) from exc

    # --- shared by both ways of reading -----------------------------------------------------------

    def _error(self, exc: BaseException) -> TraceError:
        """The one-line TraceError for an exception of python-can's reader or of the text stream."""
        lines = self._lines
        where = f" line {lines.n}" if lines is not None and lines.n else ""
        seen = f" {lines.line.strip()[:60]!r}" if lines is not None and lines.n else ""
        return TraceError(f"{self.name}{where}: not readable as {self.expected}{seen} "
                          f"(after {self.count} frames): {_one_line(exc)}")

    def _finish(self, logger: logging.Logger, handler: _Warnings) -> None:
        logger.removeHandler(handler)
        self.skipped, self.first_skipped = handler.count, handler.first
        try:
            self._reader.stop()
        except Exception:  # closing a half-read file must not hide the real error
            pass

    def _check_not_empty(self) -> None:
        """At the end of the frames: a file cut short, or one without a frame, is an error."""
        if self.cut is not None:
            raise self.cut_error()
        if self.count == 0 and not self._empty_ok:
            what = "empty file (0 bytes): no CAN frames" if self.empty_file else "no CAN frames found"
            raise TraceError(f"{self.name}: {what} (expected {self.expected})")

    def cut_error(self) -> TraceError:
        """The TraceError of a file cut short, raised after its frames (``count`` of them were read)."""
        return TraceError(f"{self.name}: truncated ({self.expected}): {self.cut}; "
                          f"{self.count} frames read before the cut")
