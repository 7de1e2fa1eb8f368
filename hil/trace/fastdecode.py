"""The fast path of ``railhil trace decode``: a block of frames at a time, each DBC message decoded for all
its frames of the block at once with numpy, the text put together from pieces made once.

The output is byte for byte what the per-frame path of ``hil.cli.trace.decode`` writes -- the same
rows, filters, counts and text in the three formats (tests/trace/test_fastdecode.py compares the two on the
corpus traces and DBCs, on traces of generated DBCs and on generated candump text).  How:

* Frames come as ``hil.trace.columns.FrameBlock`` columns (timestamp [s], id, 11/29-bit, remote,
  error, DLC, data bytes).  The filters (--start/--end, --id, --message/--signal) are masks over them.
* Data frames of a DBC message that ``hil.can.codec`` decodes with its generated shift-and-mask code
  (``FrameCodec.fallback_reason is None``: not multiplexed, no overlapping signals) and that carry at
  least the message's bytes are decoded here.  A signal's raw bits are a shift and a mask of the
  payload as one integer, little-endian (Intel) or big-endian (Motorola), exactly as the codec takes
  them (``int.from_bytes(data[:length], 'little' | 'big')``), for every frame at once.
* The text of a signal's value is made once per distinct raw value and kept: the value is computed
  by ``FrameCodec.decode`` itself, on a payload that holds that raw value (the value of a signal of
  such a message depends on its bits only), its value-table name by ``choice_names`` (cantools'
  ``decode_choices=True``) on the same payload, and both are formatted with the very expression of
  the per-frame path (``f"{name}={value:.10g}"``, ``repr(value)``, ``table_word``...), with the
  constant text around it (id, name, unit, separators).  Counters, states and quantised sensors take
  few distinct values, so most frames cost an array lookup.  In jsonl a signal with a value table
  has a second text, its ``"name": "choice"`` item of the ``choices`` object, empty when its value is
  not in the table; the comma before an item depends on the items before it in the frame, so each
  item is kept with and without one and the right one taken for every frame at once.
* The timestamp is formatted as the per-frame path does (``f"{t:17.6f}"``, ``f"{t:.6f}"``,
  ``json.dumps(t)``), or, for candump text, taken from the trace's text where that is provably the
  same (``FrameBlock.stamps``).  A frame's line is then its pieces joined: the timestamp and the
  texts of its signals, in place among the other frames' pieces, one join per block.
* Data frames of ids the DBC does not know are raw rows (their data in hex, made for the whole
  group at once).  Every other frame -- remote and error frames, messages decoded by cantools
  (multiplexed...), frames shorter than their message (which fail to decode), a signal wider than an
  8-byte window -- goes to the per-frame path (``slow``), one frame at a time, in its place.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from operator import itemgetter

import can
import numpy as np
from cantools.database.can import Signal
from cantools.database.namedsignalvalue import NamedSignalValue

from hil.can.codec import Codec, FrameCodec
from hil.trace.columns import FrameBlock
from hil.trace.readers import id_text

__all__ = ["FORMATS", "BlockDecoder", "choice_names", "table_word"]

FORMATS = ("table", "csv", "jsonl")
SMALL_BITS = 16  # signals of up to this many bits keep their texts in an array indexed by raw value
CACHE_LIMIT = 1 << 20  # texts kept per wider signal; beyond, the cache starts again


def _csv_field(text: str) -> str:
    """`text` as the csv module writes it inside a row (quoted if it must be)."""
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerow((text, ""))
    return buffer.getvalue()[:-2]


# --- value-table names and units, shared with the per-frame path (hil.cli.trace.decode) --------------

_NOT_PLAIN = frozenset(' "=\\')


def table_word(text: str, choice: bool = False) -> str:
    """A value-table name (`choice`) or a unit as the table format writes it: as it is when it is one
    plain word, else as a JSON string (``"Signal error"``).  Not plain: empty, with a space, ``=``,
    ``"``, ``\\`` or a character that does not print, and, for a name, a word that ``float()`` reads as a
    number (``"1"``, ``"inf"``), so that a name never passes for a number nor a unit for a signal."""
    if text and text.isprintable() and _NOT_PLAIN.isdisjoint(text):
        if not choice:
            return text
        try:
            float(text)
        except ValueError:
            return text
    return json.dumps(text, ensure_ascii=False)


def choice_names(fc: FrameCodec, data: bytes) -> dict[str, str]:
    """The value-table name of each signal of a frame whose raw value is in the signal's table, as
    cantools decodes it (``Message.decode(decode_choices=True)`` gives a NamedSignalValue there, the
    number elsewhere), in cantools' order; {} for a message without value tables.  `data` is a payload
    that ``fc.decode`` decodes (at least the message's bytes; beyond them is ignored, as the codec
    does)."""
    message = fc.message
    if not any(s.choices for s in message.signals):
        return {}
    data = bytes(data[: fc.length])
    try:
        values = message.decode(data, decode_choices=True)
    except (ValueError, OverflowError):
        # cantools looks the name up as choices.get(int(raw)): int() raises on the NaN or infinite raw
        # value of an IEEE float signal with a value table, which has no name then
        raw = message.decode(data, decode_choices=False, scaling=False)
        return {s.name: str(s.choices[int(raw[s.name])]) for s in message.signals
                if s.choices and s.name in raw and math.isfinite(raw[s.name])
                and int(raw[s.name]) in s.choices}
    return {name: str(v) for name, v in values.items() if isinstance(v, NamedSignalValue | str)}


# The texts of a decoded signal value (the number, and its value-table name or None), as the
# per-frame path writes them (hil.cli.trace.decode.row_texts), with what comes before (`before`) and
# after them (`end`) in the line


def _table_text(before: str, name: str, unit: str, end: str) -> Callable[[float, str | None], tuple[str]]:
    after = f" {table_word(unit)}{end}" if unit else end

    def text(value: float, choice: str | None) -> tuple[str]:
        if choice is not None:
            return (f"{before}{name}={table_word(choice, True)}{end}",)
        return (f"{before}{name}={value:.10g}{after}",)

    return text


def _csv_text(before: str, unit: str) -> Callable[[float, str | None], tuple[str]]:
    unit_field = _csv_field(unit)

    def text(value: float, choice: str | None) -> tuple[str]:
        return (f"{before}{value!r},,{unit_field},{_csv_field(choice or '')}\n",)

    return text


def _json_text(before: str, name: str, end: str, with_table: bool
               ) -> Callable[[float, str | None], tuple[str, ...]]:
    """The signal's item of the ``signals`` object; for a signal with a value table (and names shown)
    also its item of the ``choices`` object without and with the ", " before it ("" and "" when the
    value is not in the table)."""
    key = json.dumps(name)

    def text(value: float, choice: str | None) -> tuple[str, ...]:
        # json.dumps writes a float with float.__repr__; a non-finite value is written as its repr, quoted
        number = f"{value!r}" if math.isfinite(value) else f'"{value!r}"'
        item = f"{before}{key}: {number}{end}"
        if not with_table:
            return (item,)
        if choice is None:
            return item, "", ""
        named = f"{key}: {json.dumps(choice)}"
        return item, named, ", " + named

    return text


def _json_float(value: float) -> str:
    """A float as json.dumps writes it (NaN and infinities as JavaScript names, as it does)."""
    if value != value:
        return "NaN"
    if value in (math.inf, -math.inf):
        return "Infinity" if value > 0 else "-Infinity"
    return float.__repr__(value)


@dataclass
class _SignalPlan:
    """One signal of a message: where its raw bits are, and the texts of each raw value seen so far
    (``fields`` of them: the signal's text, and in jsonl for a signal with a value table its two
    ``choices`` items)."""

    name: str
    big_endian: bool
    shift: int  # of the LSB in int.from_bytes(data[:message length], 'big' if big_endian else 'little')
    length: int  # bits
    text: Callable[[float, str | None], tuple[str, ...]]  # the per-frame path's texts of a decoded value
    with_table: bool  # the signal has a value table and names are shown: its name is looked up
    fields: int = 1

    def __post_init__(self) -> None:
        self.mask = (1 << self.length) - 1
        if self.length <= SMALL_BITS:
            # raw value -> whether learnt, and its row in `tables`: zeroed arrays, whose pages the OS makes
            # on first touch (an object array per raw value was filled with None up front: 88 MB and
            # about 50 ms for the project's DBC, whose 172 16-bit signals a trace may never vary)
            self.known = np.zeros(1 << self.length, dtype=bool)
            self.row = np.zeros(1 << self.length, dtype=np.int32)
            self.tables = [np.empty(64, dtype=object) for _ in range(self.fields)]  # texts by row, doubling
            self.learnt = 0                                                          # rows in use
        self.cache: dict[int, tuple[str, ...]] = {}

    def window(self, message_length: int) -> tuple[int, int] | None:
        """The bytes [first, last + 1) of the payload that hold the signal, or None if more than 8."""
        low, high = self.shift // 8, (self.shift + self.length - 1) // 8
        if high - low >= 8:
            return None
        if self.big_endian:  # byte k of the big-endian integer, counted from its end, is data[m - 1 - k]
            return message_length - 1 - high, message_length - low
        return low, high + 1

    def lookup(self, bits: np.ndarray) -> list[np.ndarray]:
        """The texts (one object array per field) of raw values already learnt."""
        if self.length <= SMALL_BITS:
            rows = self.row[bits]
            return [table[rows] for table in self.tables]
        values = np.unique(bits)  # sorted
        where = np.searchsorted(values, bits)
        known = list(map(self.cache.__getitem__, values.tolist()))
        return [np.array([k[f] for k in known], dtype=object)[where] for f in range(self.fields)]

    def learn(self, values: list[int], texts: list[tuple[str, ...]]) -> None:
        if self.length <= SMALL_BITS:                 # `values` are distinct, none learnt before
            first, end = self.learnt, self.learnt + len(values)
            if end > len(self.tables[0]):
                grown = [np.empty(max(end, 2 * len(table)), dtype=object) for table in self.tables]
                for new, old in zip(grown, self.tables, strict=True):
                    new[:first] = old[:first]
                self.tables = grown
            for f, table in enumerate(self.tables):
                table[first:end] = [t[f] for t in texts]
            self.row[values] = np.arange(first, end)
            self.known[values] = True
            self.learnt = end
        else:
            self.cache.update(zip(values, texts, strict=True))


def _shift(signal: Signal, message_length: int) -> int:
    """The LSB of a signal in the payload integer, as hil.can.codec numbers it."""
    if signal.byte_order == "big_endian":
        msb = 8 * (signal.start // 8) + (7 - signal.start % 8)  # network bit number of the MSB
        return 8 * message_length - msb - signal.length
    return signal.start


class _MessagePlan:
    """How the frames of one DBC message are decoded and written, or ``columnar = False`` when the
    per-frame path does it.

    A decoded frame is written as pieces: its timestamp (BlockDecoder._times), then the text of each
    signal, the first one with what comes between (id, name), each with what follows it (a
    separator, unit and choice columns in csv, the end of the line); in csv each signal's row starts
    with the timestamp.  In jsonl, when signals with value tables are written, the last signal's text
    ends with ``}, "choices": {``, then come their ``choices`` items (``named``), then ``tail`` (the
    ``units`` object and the end of the line).  ``empty`` is what follows the timestamp when no
    signal is written (None in csv: then nothing is written).  `raw` (``--raw``): no value-table
    names.
    """

    def __init__(self, fc: FrameCodec, fmt: str, width: int, signals: set[str] | None, raw: bool) -> None:
        self.fc = fc
        self.length = fc.length
        wanted = [s for s in fc.message.signals if signals is None or s.name in signals]
        ident = id_text(fc.frame_id, fc.is_extended_id)
        n = len(wanted)
        with_table = [not raw and bool(s.choices) for s in wanted]
        self.named = [k for k, t in enumerate(with_table) if t] if fmt == "jsonl" else []
        texts: list[Callable[[float, str | None], tuple[str, ...]]] = []
        self.empty: str | None
        self.tail = ""
        if fmt == "table":
            lead = f"  {ident:<10}  {fc.name:<{width}}  "
            self.empty = lead + "\n"
            for k, s in enumerate(wanted):
                texts.append(_table_text(lead if k == 0 else "", s.name, s.unit or "",
                                         " " if k < n - 1 else "\n"))
        elif fmt == "csv":
            self.empty = None
            for s in wanted:
                texts.append(_csv_text(f",{_csv_field(ident)},{_csv_field(fc.name)},{_csv_field(s.name)},",
                                       s.unit or ""))
        else:
            lead = f', "id": {json.dumps(ident)}, "name": {json.dumps(fc.name)}, "signals": {{'
            units = f'"units": {json.dumps({s.name: s.unit for s in wanted if s.unit})}}}\n'
            self.tail = "}, " + units  # after the choices items
            close = "}, " + ("" if raw else '"choices": {}, ') + units  # after signals with no items
            end = '}, "choices": {' if self.named else close
            self.empty = lead + close
            for k, s in enumerate(wanted):
                texts.append(_json_text(lead if k == 0 else "", s.name, ", " if k < n - 1 else end,
                                        with_table[k]))
        self.signals = [_SignalPlan(s.name, s.byte_order == "big_endian", _shift(s, fc.length), s.length,
                                    text, table, 3 if k in self.named else 1)
                        for k, (s, text, table) in enumerate(zip(wanted, texts, with_table, strict=True))]
        self.windows = [p.window(fc.length) for p in self.signals]
        self.columnar = (fc.fallback_reason is None and all(s.length >= 1 for s in fc.message.signals)
                         and None not in self.windows)
        # per frame
        self.pieces = 2 * n if fmt == "csv" else 1 + max(n, 1) + (len(self.named) + 1 if self.named else 0)

    def texts(self, payload: np.ndarray) -> list[np.ndarray]:
        """The texts of each frame, piece by piece after the timestamp (object arrays: one per signal,
        then in jsonl one per ``choices`` item), for the frames whose data bytes are the rows of
        `payload` (uint8, at least the message's length wide)."""
        m = self.length
        rows = len(payload)
        words: dict[bool, np.ndarray] = {}
        if m <= 8:  # the whole payload as one little- and/or big-endian integer
            for big_endian in {p.big_endian for p in self.signals}:
                padded = np.zeros((rows, 8), dtype=np.uint8)
                if big_endian:
                    padded[:, 8 - m:] = payload[:, :m]
                    words[True] = padded.view(">u8").ravel()
                else:
                    padded[:, :m] = payload[:, :m]
                    words[False] = padded.view("<u8").ravel()
        all_bits = []
        for plan, (first, end) in zip(self.signals, self.windows, strict=True):  # type: ignore[misc]
            if m <= 8:
                bits = (words[plan.big_endian] >> plan.shift) & plan.mask
            else:
                padded = np.zeros((rows, 8), dtype=np.uint8)
                if plan.big_endian:
                    padded[:, 8 - (end - first):] = payload[:, first:end]
                    word = padded.view(">u8").ravel()
                    bits = (word >> (plan.shift - 8 * (m - end))) & plan.mask
                else:
                    padded[:, : end - first] = payload[:, first:end]
                    word = padded.view("<u8").ravel()
                    bits = (word >> (plan.shift - 8 * first)) & plan.mask
            all_bits.append(bits)
        self._learn(all_bits)
        texts = [plan.lookup(bits) for plan, bits in zip(self.signals, all_bits, strict=True)]
        out = [fields[0] for fields in texts]
        if self.named:  # the choices items: ", " before each but the first one present in its frame
            before = np.zeros(rows, dtype=bool)
            for k in self.named:
                _, item, with_comma = texts[k]
                out.append(np.where(before, with_comma, item))
                before |= item != ""
        return out

    def _learn(self, all_bits: list[np.ndarray]) -> None:
        """Make the texts of every raw value not seen before: decode payloads that carry them (the k-th
        payload carries the k-th new value of each signal) with the codec, and the value-table names
        of those with ``choice_names``, format them."""
        new: list[list[int]] = []
        for plan, bits in zip(self.signals, all_bits, strict=True):
            if plan.length <= SMALL_BITS:
                unseen = bits[~plan.known[bits]]
                new.append(np.unique(unseen).tolist() if len(unseen) else [])
            else:
                if len(plan.cache) > CACHE_LIMIT:
                    plan.cache.clear()
                new.append([v for v in np.unique(bits).tolist() if v not in plan.cache])
        count = max(map(len, new), default=0)
        if not count:
            return
        payloads = self._payloads(new, count)
        decoded = list(map(self.fc.decode, payloads))
        named = max((len(values) for plan, values in zip(self.signals, new, strict=True) if plan.with_table),
                    default=0)  # the payloads that carry a new value of a signal with a table
        names = [choice_names(self.fc, p) for p in payloads[:named]]
        for plan, values in zip(self.signals, new, strict=True):
            if values:
                numbers = map(itemgetter(plan.name), decoded[: len(values)])
                if plan.with_table:
                    chosen = [n.get(plan.name) for n in names[: len(values)]]
                else:
                    chosen = [None] * len(values)
                plan.learn(values, list(map(plan.text, numbers, chosen)))

    def _payloads(self, new: list[list[int]], count: int) -> list[bytes]:
        """`count` payloads, the k-th with the k-th value of each signal's list (0 past its end)."""
        m = self.length
        if m <= 8:
            words = {False: np.zeros(count, dtype=np.uint64), True: np.zeros(count, dtype=np.uint64)}
            for plan, values in zip(self.signals, new, strict=True):
                if values:
                    column = np.zeros(count, dtype=np.uint64)
                    column[: len(values)] = values
                    words[plan.big_endian] |= column << np.uint64(plan.shift)
            data = (words[False].astype("<u8").view(np.uint8).reshape(count, 8)[:, :m]
                    | words[True].astype(">u8").view(np.uint8).reshape(count, 8)[:, 8 - m:]).tobytes()
            return [data[i: i + m] for i in range(0, count * m, m)]
        payloads = []
        for k in range(count):
            little = big = 0
            for plan, values in zip(self.signals, new, strict=True):
                if k < len(values):
                    if plan.big_endian:
                        big |= values[k] << plan.shift
                    else:
                        little |= values[k] << plan.shift
            payloads.append((little | int.from_bytes(big.to_bytes(m, "big"), "little")).to_bytes(m, "little"))
        return payloads


class BlockDecoder:
    """The text of `trace decode` for blocks of frames, in `fmt` (table, csv, jsonl).

    `ids` (--id), `names` (messages by --message and --signal), `signals` (--signal), `start` and
    `end` (--start/--end, trace time [s]) are the filters of the per-frame path, None when not given;
    `width` is the table's name column width; `raw` (--raw) leaves value-table names out; `slow(message)`
    is the per-frame path's text of one python-can Message (empty if its filters drop it), counting it
    in `counts` as it does.  ``text`` counts the frames it writes itself in `counts` (decoded, unknown).
    """

    def __init__(self, codec: Codec, fmt: str, *, width: int, ids: set[int] | None, names: set[str] | None,
                 signals: set[str] | None, start: float | None, end: float | None,
                 slow: Callable[[can.Message], str], counts: dict[str, int], raw: bool = False) -> None:
        if fmt not in FORMATS:
            raise ValueError(f"format {fmt!r}: expected one of {', '.join(FORMATS)}")
        self.codec = codec
        self.fmt = fmt
        self.width = width
        self.ids = None if ids is None else np.array(sorted(ids), dtype=np.int64)
        self.names = names
        self.signals = signals
        self.start = start
        self.end = end
        self.slow = slow
        self.counts = counts
        self.raw = raw
        self._plans: dict[int, _MessagePlan | None] = {}  # by key id * 2 + extended

    def _plan(self, key: int) -> _MessagePlan | None:
        """The plan of the DBC message of data frames with this key (id * 2 + extended), None when the
        DBC has none (the id and the 11/29-bit kind must both match, as hil.cli.trace.common.lookup)."""
        if key not in self._plans:
            fc = self.codec.get(key >> 1)
            if fc is not None and bool(fc.message.is_extended_frame) != bool(key & 1):
                fc = None
            self._plans[key] = None if fc is None else _MessagePlan(fc, self.fmt, self.width, self.signals,
                                                                        self.raw)
        return self._plans[key]

    def _raw_ends(self, key: int) -> tuple[bytes, bytes]:
        """What comes before and after the hex data of a data frame of an id the DBC does not know."""
        ident = id_text(key >> 1, bool(key & 1))
        if self.fmt == "table":
            return f"  {ident:<10}  {'?':<{self.width}}  data=".encode(), b"\n"
        if self.fmt == "csv":
            return f",{_csv_field(ident)},,,".encode(), b",,,\n"
        return f', "id": {json.dumps(ident)}, "name": null, "data": "'.encode(), b'"}\n'

    # --- a block ------------------------------------------------------------------------------------

    def text(self, block: FrameBlock) -> str:
        """The text of the frames of `block`, in their order."""
        n = len(block)
        t = block.t
        keep = np.ones(n, dtype=bool)
        if self.start is not None:
            keep &= ~(t < self.start)
        if self.end is not None:
            keep &= ~(t > self.end)
        if self.ids is not None:
            keep &= ~block.error & np.isin(block.arbitration_id, self.ids)
        one_by_one = block.remote | block.error  # remote and error frames: never decoded, rare
        if self.names is not None:  # only frames of the named messages: no remote or error frame
            keep &= ~one_by_one
        if block.special is not None:
            one_by_one = one_by_one | block.special
            keep |= block.special  # the per-frame path filters them itself
        data = np.flatnonzero(keep & ~one_by_one)
        keys = block.arbitration_id[data] * 2 + block.extended[data]
        order = np.argsort(keys, kind="stable")
        bounds = np.flatnonzero(np.diff(keys[order])) + 1
        # each group of rows, how it is written: a plan (decoded), an int key (raw), None (one by one)
        groups: list[tuple[np.ndarray, _MessagePlan | int | None]] = [
            (np.flatnonzero(keep & one_by_one), None)]
        for group in np.split(order, bounds) if len(order) else []:
            rows = data[group]
            key = int(keys[group[0]])
            plan = self._plan(key)
            if plan is None:
                if self.names is None:
                    groups.append((rows, key))
            elif self.names is not None and plan.fc.name not in self.names:
                continue
            elif not plan.columnar:
                groups.append((rows, None))
            else:
                whole = block.length[rows] >= plan.length  # shorter frames fail to decode
                if not whole.all():
                    groups.append((rows[~whole], None))
                    rows = rows[whole]
                groups.append((rows, plan))
        # every row's text is made of pieces: count them, then put each group's pieces in place
        count = np.zeros(n, dtype=np.int64)
        for rows, how in groups:
            count[rows] = 1 if how is None else 2 if isinstance(how, int) else how.pieces
        first = np.cumsum(count) - count
        pieces = np.empty(int(count.sum()), dtype=object)
        # the timestamps of the rows written here, made at once (numpy steps cost per call)
        here = [rows for rows, how in groups if how is not None and len(rows)]
        times = np.empty(n, dtype=object)
        if here:
            at_once = np.concatenate(here)
            times[at_once] = self._times(block, at_once)
        for rows, how in groups:
            if not len(rows):
                continue
            at = first[rows]
            if how is None:
                for i, j in zip(rows.tolist(), at.tolist(), strict=True):
                    pieces[j] = self.slow(block.message(i))
            elif isinstance(how, int):
                self._write_raw(how, block, rows, pieces, at, times[rows])
            else:
                self._write_decoded(how, block, rows, pieces, at, times[rows])
        return "".join(pieces.tolist())

    def _times(self, block: FrameBlock, rows: np.ndarray) -> list[str]:
        """The timestamps of the rows as the per-frame path prints them: f"{t:17.6f}" (table),
        f"{t:.6f}" (csv), '{"t": ' + json.dumps(t) (jsonl, with what comes before); from the trace's
        own text where the block has it (``FrameBlock.stamps``), else from the floats."""
        t = block.t[rows]
        if block.stamps is not None:
            stamps = block.stamps[rows]
            known = stamps != b""
            if self.fmt == "table":
                texts = np.strings.rjust(stamps, 17)
            elif self.fmt == "csv":
                texts = stamps
            else:  # repr(): the shortest round trip, so no trailing zeros; exponent below 1e-4 (not 0.0)
                texts = np.strings.rstrip(stamps, b"0")
                texts = np.where(np.strings.endswith(texts, b"."), np.strings.add(texts, b"0"), texts)
                texts = np.strings.add(b'{"t": ', texts)
                known &= (t >= 1e-4) | (t == 0)
            if known.all():
                return _strings(texts)
            out = np.empty(len(rows), dtype=object)
            out[known] = _strings(texts[known])
            todo = np.flatnonzero(~known)
            out[todo] = self._format_times(t[todo])
            return out.tolist()
        return self._format_times(t)

    def _format_times(self, t: np.ndarray) -> list[str]:
        values = t.tolist()
        if self.fmt == "table":
            return list(map("%17.6f".__mod__, values))
        if self.fmt == "csv":
            return list(map("%.6f".__mod__, values))
        return ['{"t": ' + _json_float(x) for x in values]

    def _write_decoded(self, plan: _MessagePlan, block: FrameBlock, rows: np.ndarray, pieces: np.ndarray,
                       at: np.ndarray, times: np.ndarray) -> None:
        """The pieces of decoded frames (`times`: their timestamps' texts) at `at` in `pieces`."""
        self.counts["decoded"] += len(rows)
        if not plan.pieces:
            return  # csv: a frame without signals has no row
        if not plan.signals:
            pieces[at] = times
            pieces[at + 1] = plan.empty
            return
        texts = plan.texts(block.payload[rows])
        if self.fmt == "csv":  # each signal's row starts with the timestamp
            for k, column in enumerate(texts):
                pieces[at + 2 * k] = times
                pieces[at + 2 * k + 1] = column
        else:
            pieces[at] = times
            for k, column in enumerate(texts):
                pieces[at + 1 + k] = column
            if plan.named:
                pieces[at + 1 + len(texts)] = plan.tail

    def _write_raw(self, key: int, block: FrameBlock, rows: np.ndarray, pieces: np.ndarray, at: np.ndarray,
                   times: np.ndarray) -> None:
        """The pieces of data frames of an id the DBC does not know: timestamp, then the rest."""
        self.counts["unknown"] += len(rows)
        before, after = self._raw_ends(key)
        lengths = block.length[rows]
        texts = np.empty(len(rows), dtype=object)
        for length in np.unique(lengths).tolist():
            of_length = np.flatnonzero(lengths == length)
            digits = block.payload[rows[of_length], :length].tobytes().hex().upper().encode("ascii")
            data = np.frombuffer(digits, dtype=f"S{2 * length}") if length else np.full(len(of_length), b"")
            texts[of_length] = _strings(np.strings.add(np.strings.add(before, data), after))
        pieces[at] = times
        pieces[at + 1] = texts


def _strings(texts: np.ndarray) -> list[str]:
    """ASCII texts (numpy "S", without NUL) as a list of str, without a Python step each."""
    if not len(texts):
        return []
    return b"\0".join(texts.tolist()).decode("ascii").split("\0")
