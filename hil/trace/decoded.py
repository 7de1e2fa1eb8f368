"""A trace decoded with a DBC into one table per message: the frames' timestamps and each signal's
physical values, with the DBC's units, value tables and comments — what `trace export` writes and what
`hil.open_run` / `hil.open_trace` give to a notebook.

The frames are read once, as columns (`hil.trace.columns.BlockReader`: the fast BLF, MF4 and candump
paths), and each message is decoded on demand, with the values cantools gives:

* a message the codec decodes by shift and mask (`FrameCodec.fallback_reason is None`: not multiplexed,
  no overlapping signals) is decoded for all its frames at once with numpy: each signal's raw bits are a
  shift and a mask of the payload taken as one integer, little-endian (Intel) or big-endian (Motorola),
  exactly as the codec takes them, and the physical value is cantools' `raw * scale + offset` computed
  in float64 where that is exact in both (the raw value and the products below 2**53), else by
  cantools' conversion itself once per distinct raw value;
* every other message (multiplexed, a signal wider than an 8-byte window) frame by frame through the
  codec (`hil.can.codec`, proven equal to cantools).

tests/trace/test_decoded.py checks both against the codec frame by frame on every corpus DBC.  A frame whose
data does not decode (too short for its message, a multiplexer value the DBC does not have) is counted
in `undecodable`, not raised; frames of ids the DBC does not have, and remote and error frames, are
counted in `unknown`.  A multiplexed message's signals that a frame does not carry are NaN in that
frame's row.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from cantools.database.can import Database

from hil.can.codec import Codec, FrameError
from hil.trace.columns import BlockReader, FrameBlock


@dataclass
class MessageTable:
    """One DBC message's frames in a trace: times [s], one float64 column per signal (physical values)."""

    name: str
    frame_id: int
    extended: bool
    comment: str
    t: np.ndarray
    columns: dict[str, np.ndarray]
    units: dict[str, str]
    choices: dict[str, dict[float, str]]        # signal -> {physical value: name} of its value table
    comments: dict[str, str]

    def choice(self, signal: str, value: float) -> str:
        """The value-table name of `value` of `signal` ("" where it has none)."""
        return self.choices.get(signal, {}).get(value, "")


@dataclass
class DecodedTrace:
    """The frames of a trace with a DBC: `table(name)` decodes a message (once), `tables()` every one that
    has frames."""

    path: Path
    db: Database
    frames: FrameBlock
    codec: Codec = field(repr=False)
    unknown: int = 0
    undecodable: int = 0
    _tables: dict[str, MessageTable] = field(default_factory=dict, repr=False)

    @classmethod
    def read(cls, path: str | Path, db: Database, codec: Codec | None = None) -> DecodedTrace:
        """Read every frame of the trace at `path` once (any format `hil.trace.readers` reads)."""
        blocks = list(BlockReader(path))
        frames = blocks[0] if len(blocks) == 1 else FrameBlock.join(blocks) if blocks else _empty_block()
        return cls(Path(path), db, frames, codec or Codec(db))

    def message_names(self) -> list[str]:
        """The DBC messages that have at least one frame in the trace, in DBC order."""
        present = set(zip(self.frames.arbitration_id.tolist(), self.frames.extended.tolist(), strict=True))
        return [m.name for m in self.db.messages if (m.frame_id, bool(m.is_extended_frame)) in present]

    def table(self, name: str) -> MessageTable:
        if name not in self._tables:
            self._tables[name] = self._decode(self.db.get_message_by_name(name))
        return self._tables[name]

    def tables(self) -> list[MessageTable]:
        return [self.table(n) for n in self.message_names()]

    def count_unknown(self) -> int:
        """Frames no DBC message takes: ids the DBC does not have (or of the other 11/29-bit kind),
        remote and error frames."""
        f = self.frames
        known = {(m.frame_id, bool(m.is_extended_frame)) for m in self.db.messages}
        ok = np.fromiter(((i, e) in known for i, e in zip(f.arbitration_id.tolist(), f.extended.tolist(),
                                                          strict=True)), dtype=bool, count=len(f))
        self.unknown = int(np.sum(~ok | f.remote | f.error))
        return self.unknown

    def _decode(self, msg) -> MessageTable:
        f = self.frames
        rows = np.flatnonzero((f.arbitration_id == msg.frame_id) & ~f.remote & ~f.error
                              & (f.extended == bool(msg.is_extended_frame)))
        fc = self.codec[msg.frame_id]
        cols = _columnar(msg, fc, f.payload[rows], f.length[rows]) if rows.size else None
        if cols is not None:
            good = f.length[rows] >= msg.length              # a shorter frame does not decode (FrameError)
            cols = {n: c[good] for n, c in cols.items()}
        else:
            cols, good = _frame_by_frame(msg, fc, f.payload, f.length, rows)
        self.undecodable += int(np.sum(~good))
        choices = {}
        for s in msg.signals:
            if s.choices:
                choices[s.name] = {float(s.conversion.raw_to_scaled(raw, decode_choices=False)): str(text)
                                   for raw, text in s.choices.items()}    # keyed as the values are computed
        return MessageTable(
            name=msg.name, frame_id=msg.frame_id, extended=bool(msg.is_extended_frame),
            comment=_text(msg.comment), t=f.t[rows][good], columns=cols,
            units={s.name: s.unit or "" for s in msg.signals}, choices=choices,
            comments={s.name: _text(s.comment) for s in msg.signals})


def _frame_by_frame(msg, fc: Codec, payload: np.ndarray, length: np.ndarray, rows: np.ndarray
                    ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """(signal -> values of the decoded frames, which frames of `rows` decoded): one codec call a frame."""
    cols = {s.name: np.full(len(rows), np.nan) for s in msg.signals}
    good = np.ones(len(rows), dtype=bool)
    for k, i in enumerate(rows.tolist()):
        try:
            values = fc.decode(payload[i, : length[i]].tobytes())
        except FrameError:
            good[k] = False
            continue
        for n, v in values.items():
            cols[n][k] = v
    return {n: c[good] for n, c in cols.items()}, good


EXACT = 2.0 ** 53     # float64 holds every integer below it


def _columnar(msg, fc, payload: np.ndarray, length: np.ndarray) -> dict[str, np.ndarray] | None:
    """Every signal of `msg` for all its frames at once (module docstring), or None when the message
    takes the frame-by-frame path.  Frames shorter than the message give garbage here; the caller drops
    them."""
    if fc.fallback_reason is not None:
        return None
    m = msg.length
    data = np.zeros((len(payload), m), dtype=np.uint8)       # data[:m] as the codec takes it, 0-padded
    width = min(m, payload.shape[1])
    keep = np.arange(width)[None, :] < length[:, None]
    data[:, :width] = np.where(keep, payload[:, :width], 0)
    cols = {}
    for s in msg.signals:
        bits = _raw_bits(data, s, m)
        if bits is None:
            return None
        cols[s.name] = _physical(s, bits)
    return cols


def _raw_bits(data: np.ndarray, signal, message_length: int) -> np.ndarray | None:
    """The signal's raw bits (uint64) in every row of `data`, or None if they span more than 8 bytes."""
    if signal.byte_order == "big_endian":
        msb = 8 * (signal.start // 8) + (7 - signal.start % 8)     # network bit number of the MSB
        shift = 8 * message_length - msb - signal.length           # LSB in int.from_bytes(data, 'big')
    else:
        shift = signal.start                                        # LSB in int.from_bytes(data, 'little')
    low, high = shift // 8, (shift + signal.length - 1) // 8
    if high - low >= 8:
        return None
    word = np.zeros(len(data), dtype=np.uint64)
    for k in range(low, high + 1):       # byte k of the integer, counted from its least significant end
        byte = data[:, message_length - 1 - k] if signal.byte_order == "big_endian" else data[:, k]
        word |= byte.astype(np.uint64) << np.uint64(8 * (k - low))
    word >>= np.uint64(shift - 8 * low)
    if signal.length < 64:
        word &= np.uint64((1 << signal.length) - 1)
    return word


def _physical(signal, bits: np.ndarray) -> np.ndarray:
    """cantools' physical values (float64) of raw bits: vectorised where float64 arithmetic gives its
    result exactly, else cantools' conversion once per distinct raw value."""
    c = signal.conversion
    scale, offset = c.scale, c.offset
    if signal.is_float:
        raw = (bits.astype(np.uint32).view(np.float32) if signal.length == 32 else bits.view(np.float64))
        return raw.astype(np.float64) * scale + offset
    n = signal.length
    if signal.is_signed:
        raw = bits.view(np.int64)
        if n < 64:
            raw = (bits ^ np.uint64(1 << (n - 1))).astype(np.int64) - (1 << (n - 1))
    else:
        raw = bits
    bound = float(2 ** n)                                             # |raw| < 2**n
    # an integer scale multiplies exactly in Python: float64 must too (and the sum with the offset)
    if bound < EXACT and (isinstance(scale, float) or bound * abs(scale) + abs(offset) < EXACT):
        return raw.astype(np.float64) * scale + offset
    values, where = np.unique(raw, return_inverse=True)
    numeric = signal.conversion
    out = np.array([float(numeric.raw_to_scaled(int(v), decode_choices=False)) for v in values.tolist()])
    return out[where.reshape(-1)]


def _text(comment) -> str:
    """A cantools comment (a str, a dict of languages, or None) as one string."""
    if comment is None:
        return ""
    if isinstance(comment, dict):
        return str(next(iter(comment.values()), ""))
    return str(comment)


def _empty_block() -> FrameBlock:
    z = np.zeros(0)
    return FrameBlock(z.astype(np.float64), z.astype(np.int64), z.astype(bool), z.astype(bool),
                      z.astype(bool), z.astype(np.int64), z.astype(np.int64), np.zeros((0, 0), np.uint8))
