"""Helpers shared by the `railhil trace` actions: ids, options, DBC lookups, stdout, notices.

Times are seconds on the trace's time base everywhere (hil.cli.trace.timebase).  Ids print as candump
does: 3 hex digits for an 11-bit id, 8 for a 29-bit one, so the two never mix.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass

import can
from cantools.database.can import Signal

from hil.can.codec import Codec, FrameCodec
from hil.can.dbc import closest
from hil.errors import RailhilError
from hil.trace.readers import Trace, id_text

__all__ = [
    "Output", "SignalRef", "TraceArgError", "check_window", "id_text", "jsonable", "kind_of", "lookup",
    "notice_skipped", "num", "parse_id", "resolve_signal", "signal_carriers",
]


class TraceArgError(RailhilError, ValueError):
    """A trace command option that names something the DBC or the syntax does not have."""


def parse_id(text: str, option: str = "--id") -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise TraceArgError(f"{option} {text!r}: expected a CAN id, hex (0x123) or decimal (291)") from None
    if not 0 <= value <= 0x1FFFFFFF:
        raise TraceArgError(f"{option} {text!r}: expected a CAN id between 0 and 0x1FFFFFFF")
    return value


def check_window(start: float | None, end: float | None) -> None:
    """--start/--end (seconds on the trace's time base): finite, and not the wrong way round."""
    for option, value in (("--start", start), ("--end", end)):
        if value is not None and not math.isfinite(value):
            raise TraceArgError(f"{option} {value}: expected a finite time in seconds")
    if start is not None and end is not None and end < start:
        raise TraceArgError(f"--end {end} is before --start {start}")


def lookup(codec: Codec | None, msg: can.Message) -> FrameCodec | None:
    """The DBC message of a data frame (its id and its 11/29-bit kind must both match)."""
    if codec is None or msg.is_error_frame or msg.is_remote_frame:
        return None
    fc = codec.get(msg.arbitration_id)
    if fc is None or bool(fc.message.is_extended_frame) != bool(msg.is_extended_id):
        return None
    return fc


def kind_of(msg: can.Message) -> str:
    return "error" if msg.is_error_frame else "remote" if msg.is_remote_frame else "data"


def num(value: float | None, fmt: str) -> str:
    return "" if value is None or not math.isfinite(value) else format(value, fmt)


def jsonable(value: float) -> float | str:
    return value if math.isfinite(value) else repr(value)  # JSON has no NaN/inf


class Output:
    """stdout that stops quietly when the reader goes away (``railhil trace ... | head``), and writes a
    character its encoding lacks as a backslash escape."""

    def __init__(self) -> None:
        self.closed = False

    def write(self, text: str) -> None:
        if not self.closed:
            try:
                sys.stdout.write(text)
            except BrokenPipeError:
                self.pipe_closed()
            except UnicodeEncodeError:  # a DBC unit or name stdout's encoding lacks ('°' on ASCII): escaped
                encoding = getattr(sys.stdout, "encoding", None) or "utf-8"
                self.write(text.encode(encoding, "backslashreplace").decode(encoding))

    def flush(self) -> None:
        if not self.closed:
            try:
                sys.stdout.flush()
            except BrokenPipeError:
                self.pipe_closed()

    def pipe_closed(self) -> None:
        self.closed = True
        # Python flushes stdout at exit; point it at devnull so that flush cannot fail again
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)
        except (OSError, ValueError):  # stdout without a file descriptor (captured in tests)
            pass


def notice_skipped(trace: Trace) -> None:
    """The lines python-can skipped, on stderr; not when reading ended in an error (one line: the error)."""
    if trace.skipped and trace.error is None:
        print(f"notice: {trace.name}: python-can skipped {trace.skipped} unreadable lines "
              f"(first: {trace.first_skipped})", file=sys.stderr)


# --- signals named on the command line ---------------------------------------------------------


@dataclass(frozen=True)
class SignalRef:
    """One signal of one DBC message, as named on the command line (``NAME`` or ``MESSAGE.NAME``)."""

    fc: FrameCodec
    name: str

    @property
    def label(self) -> str:
        return f"{self.fc.name}.{self.name}"

    @property
    def signal(self) -> Signal:
        return self.fc.message.get_signal_by_name(self.name)

    @property
    def unit(self) -> str:
        return self.signal.unit or ""

    @property
    def key(self) -> tuple[int, bool]:
        """(arbitration id, extended?) of the frames that carry it."""
        return self.fc.frame_id, bool(self.fc.is_extended_id)


def signal_carriers(codec: Codec) -> dict[str, list[FrameCodec]]:
    """Signal name -> the DBC messages that carry a signal of that name, in DBC order."""
    carriers: dict[str, list[FrameCodec]] = {}
    for fc in codec:
        for name in fc.signal_names:
            carriers.setdefault(name, []).append(fc)
    return carriers


def resolve_signal(codec: Codec, text: str, allow_ambiguous: bool = False) -> list[SignalRef]:
    """The signals ``text`` names: ``MESSAGE.NAME`` one signal, a bare ``NAME`` every message that
    carries it (an error when there are several, unless ``allow_ambiguous``).

    Raises TraceArgError naming the closest message or signal names when nothing matches; the
    caller prefixes the DBC file name.
    """
    carriers = signal_carriers(codec)
    if "." in text:
        message_name, _, name = text.partition(".")
        names = [fc.name for fc in codec]
        if message_name not in names:
            raise TraceArgError(f"{text!r}: no message named {message_name!r} "
                                f"(closest: {closest(message_name, names)})")
        fc = codec.by_name(message_name)
        if name not in fc.signal_names:
            raise TraceArgError(f"{text!r}: message {message_name} has no signal {name!r} "
                                f"(closest: {closest(name, list(fc.signal_names))})")
        return [SignalRef(fc, name)]
    found = carriers.get(text)
    if not found:
        raise TraceArgError(f"no signal named {text!r} (closest: {closest(text, list(carriers))})")
    if len(found) > 1 and not allow_ambiguous:
        shown = ", ".join(fc.name for fc in found[:8]) + (", ..." if len(found) > 8 else "")
        raise TraceArgError(f"signal {text!r} is ambiguous: {len(found)} messages carry it ({shown}); "
                            f"write MESSAGE.SIGNAL, e.g. {found[0].name}.{text}")
    return [SignalRef(fc, text) for fc in found]
