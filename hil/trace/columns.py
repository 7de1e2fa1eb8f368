"""A trace as numpy columns, fast: BLF read with python-can's format code, and candump text parsed in
bulk, into columns without a ``can.Message`` per frame.

``read_columns(path)`` gives the same ``hil.trace.timing.FrameArrays`` as
``frame_arrays(open_trace(path))``, column by column and bit for bit, and the same ``TraceError``
for a file that cannot be read.  A BLF file (``.blf``, also ``.blf.gz``) and an MF4 file (``.mf4``,
read_mf4_chunks: each CAN channel group in one asammdf call) take fast paths; every other format, and
stdin, goes through python-can's reader and ``frame_arrays``.

``BlockReader(path)`` gives the frames with their data bytes, for decoding (``trace decode``,
``hil.trace.fastdecode``), as ``FrameBlock`` columns of up to ``BLOCK_FRAMES`` frames: BLF through the
reader below with the data bytes (``BlfColumnReader(..., payload=True)``), candump -L text (.log,
.log.gz, stdin) through ``parse_candump`` a batch of lines at a time (numpy over the whole text;
every line it does not take goes to python-can's parser, in its place), every other format through
python-can's reader.  The rows are the frames python-can gives, and a TraceError comes after the
frames read before it, as iterating ``open_trace(path)`` gives them (tests/trace/test_columns.py).

The fast BLF path is python-can's ``can.io.blf.BLFReader`` (python-can 4.6) without the Message
objects.  ``open_trace`` opens the file with python-can, which parses the file header and its start
time; this module then walks the file as ``BLFReader.__iter__`` does -- the same object headers,
log containers, zlib decompression, the 8-byte search for the next ``LOBJ`` after an object's
padding, the tail of a container carried over to the next one -- with python-can's struct
definitions and flag constants, and reads only the fields the columns need:

* t [s] = float(Decimal(timestamp) · 1e-5 if the object header's flags == 1 else 1e-9) + the file
  header's start time, as python-can computes it; for timestamps below 2**53 numpy's
  ``timestamp / 1e5`` (or ``/ 1e9``) is the same correctly rounded float64, above it Decimal is used;
* arbitration_id = id & 0x1FFFFFFF, extended = id & CAN_MSG_EXT;
* dlc = the DLC byte for CAN_MESSAGE / CAN_MESSAGE2 / CAN_ERROR_EXT, ``dlc2len`` of it (bytes) for
  CAN_FD_MESSAGE / CAN_FD_MESSAGE_64;
* kind = error for CAN_ERROR_EXT, remote by the remote flag python-can tests, else data;
  fd = python-can's EDL test (CAN_FD_MESSAGE) or its 0x1000 flag (CAN_FD_MESSAGE_64).

How the objects are found without a Python step per object: in the decompressed payload every
``LOBJ`` is a candidate object (a few lie inside frame data); numpy gives each candidate's size and
the candidate python-can's search would find after it (the first ``LOBJ`` 0 to 4 bytes past its
end); python-can's chain of objects is then followed from the first one, a whole stretch of
candidates that follow each other directly at a time.  The fields of the frame objects are read
through one strided numpy view where the objects of one type are equally spaced (one frame type),
else gathered by their offsets.  Several containers are read at once: python-can reads each one
after the unread tail of the one before, which finds the same objects as reading them joined.
Object types python-can ignores are skipped as it skips them.  Anything python-can would warn
about or that needs its odd corners -- an unknown compression method or object header version, an
object too short for its own struct -- and any error at all make the fast path give up: the file is
then read again with python-can's reader, so the result or the error is python-can's own
(``TraceError`` naming the file, from ``open_trace``).
"""

from __future__ import annotations

import bisect
import pathlib
import re
import struct
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from decimal import Decimal
from typing import TYPE_CHECKING

import can
import numpy as np
from can.io import blf
from can.util import dlc2len

from hil.trace.readers import STDIN, Salvage, Trace, TraceError, mf4_can_frames, open_trace
from hil.trace.timing import KIND_DATA, KIND_ERROR, KIND_REMOTE, FrameArrays, frame_arrays

if TYPE_CHECKING:
    from hil.trace.timing import FrameArrays

# hil.trace.timing (and the RTA and bus-load modules it imports) is imported where FrameArrays are made:
# `trace decode` reads FrameBlocks and starts faster without it.

__all__ = ["BLOCK_FRAMES", "BlfColumnReader", "BlockReader", "FrameBlock", "NotFast", "parse_candump",
           "read_blf_columns", "read_columns", "read_trace_columns"]

ID_MASK = 0x1FFFFFFF
FD64_REMOTE = 0x0010  # CAN_FD_MESSAGE_64 flags: remote frame (python-can blf.py, literal there)
FD64_FD = 0x1000  # CAN_FD_MESSAGE_64 flags: CAN FD frame (python-can blf.py, literal there)
EXACT_FLOAT_INT = 2 ** 53  # integers below this are exact in float64
NOT_FOUND, BEYOND, SHORT = -1, -2, -3  # how an object chain ends (BlfColumnReader._chain)
BATCH_BYTES = 2 ** 21  # container payloads read together, in bytes (python-can's writer: 128 KiB each)


class NotFast(Exception):
    """The fast BLF path does not take this file; python-can's reader must read it."""


# --- field offsets from python-can's struct definitions ---------------------------------------

_TOKEN = re.compile(r"(\d*)([xcbB?hHiIlLqQnNefdspP])")


def _fields(st: struct.Struct) -> list[tuple[int, str]]:
    """(offset in bytes, struct code) of each unpacked field of a little-endian ``struct.Struct``."""
    fmt = st.format if isinstance(st.format, str) else st.format.decode()
    assert fmt[0] == "<", fmt  # no alignment: offsets are plain sums
    out, offset = [], 0
    for count, code in _TOKEN.findall(fmt[1:]):
        n = int(count) if count else 1
        size = struct.calcsize("<" + code)
        if code == "x":
            offset += n
        elif code in "sp":
            out.append((offset, f"{n}{code}"))
            offset += n
        else:
            for _ in range(n):
                out.append((offset, code))
                offset += size
    assert offset == st.size, (fmt, offset, st.size)
    return out


_NUMPY = {"B": "u1", "H": "<u2", "L": "<u4", "Q": "<u8"}
BASE_SIZE = blf.OBJ_HEADER_BASE_STRUCT.size  # "LOBJ", header size, header version, object size, type
HEADER = {1: blf.OBJ_HEADER_V1_STRUCT, 2: blf.OBJ_HEADER_V2_STRUCT}  # by header version
MIN_OBJECT = BASE_SIZE + min(h.size for h in HEADER.values())  # smaller: python-can reads past it


class _Layout:
    """Where the fields of the columns lie in one object type with one header version, in bytes from
    the object's ``LOBJ``, with the numpy dtype of each; and how they make the columns."""

    def __init__(self, version: int, body: struct.Struct, ident: int, dlc: int, remote: tuple | None,
                 fd: tuple | None, error: bool, fd_dlc: bool, data: int | None, valid: int | None,
                 ext_data: int | None = None) -> None:
        head = _fields(HEADER[version])
        start = BASE_SIZE + HEADER[version].size
        fields = _fields(body)
        self.size = start + body.size  # an object shorter than this is not read here
        self.body_size = body.size
        # the data bytes (for FrameBlocks): a field of the body, or (CAN_FD_MESSAGE_64) after it
        self.data_offset = start + fields[data][0] if data is not None else self.size
        self.data_width = int(fields[data][1][:-1]) if data is not None else None
        self.dlc_offset = start + fields[dlc][0]
        self.valid_offset = start + fields[valid][0] if valid is not None else None  # valid_bytes field
        self.ext_data_offset = start + fields[ext_data][0] if ext_data is not None else None
        spec = {"hflags": head[0], "ts": head[3], "id": fields[ident], "dlc": fields[dlc]}
        if remote is not None:
            spec["remote"] = fields[remote[0]]
        if fd is not None:
            spec["fdflags"] = fields[fd[0]]
        # header fields count from the end of the base header, body fields from the end of the header
        self.offsets = {name: (BASE_SIZE if name in ("hflags", "ts") else start) + off
                        for name, (off, _) in spec.items()}
        self.dtypes = {name: _NUMPY[code] for name, (_, code) in spec.items()}
        self.remote_mask = remote[1] if remote is not None else 0
        self.fd_mask = fd[1] if fd is not None else 0
        self.error = error
        self.fd_dlc = fd_dlc
        self._view: np.dtype | None = None

    def view_dtype(self) -> np.dtype:
        """A structured dtype of just the fields needed, over the first `size` bytes of an object."""
        if self._view is None:
            names = list(self.offsets)
            self._view = np.dtype({"names": names, "formats": [self.dtypes[n] for n in names],
                                   "offsets": [self.offsets[n] for n in names], "itemsize": self.size})
        return self._view


# Frame objects python-can reads (blf.py BLFReader._parse_data): field indices of id, dlc, the remote
# flag, the FD flag, the data bytes, the valid_bytes count and ext_data_offset in each body struct, as
# python-can unpacks them.
_FRAME_TYPES = {
    blf.CAN_MESSAGE: dict(body=blf.CAN_MSG_STRUCT, ident=3, dlc=2, remote=(1, blf.REMOTE_FLAG), fd=None,
                          error=False, fd_dlc=False, data=4, valid=None),
    blf.CAN_MESSAGE2: dict(body=blf.CAN_MSG_STRUCT, ident=3, dlc=2, remote=(1, blf.REMOTE_FLAG), fd=None,
                           error=False, fd_dlc=False, data=4, valid=None),
    blf.CAN_ERROR_EXT: dict(body=blf.CAN_ERROR_EXT_STRUCT, ident=7, dlc=5, remote=None, fd=None,
                            error=True, fd_dlc=False, data=9, valid=None),
    blf.CAN_FD_MESSAGE: dict(body=blf.CAN_FD_MSG_STRUCT, ident=3, dlc=2, remote=(1, blf.REMOTE_FLAG),
                             fd=(6, blf.EDL), error=False, fd_dlc=True, data=8, valid=7),
    blf.CAN_FD_MESSAGE_64: dict(body=blf.CAN_FD_MSG_64_STRUCT, ident=4, dlc=1, remote=(6, FD64_REMOTE),
                                fd=(6, FD64_FD), error=False, fd_dlc=True, data=None, valid=2, ext_data=13),
}
LAYOUTS = {(version, kind): _Layout(version, **spec)
           for version in HEADER for kind, spec in _FRAME_TYPES.items()}
DLC2LEN = np.array([dlc2len(d) for d in range(256)], dtype=np.int64)
COLUMNS = ("t", "arbitration_id", "extended", "dlc", "kind", "fd")
DTYPES = {"t": np.float64, "arbitration_id": np.int64, "extended": bool, "dlc": np.int64, "kind": np.int8,
          "fd": bool}


def _columns(layout: _Layout, raw, start_timestamp: float) -> dict[str, np.ndarray]:
    """The FrameArrays columns of objects of one layout, from their raw fields (mapping name -> array)."""
    ident = raw["id"].astype(np.int64)
    n = len(ident)
    ts = raw["ts"]
    hflags = raw["hflags"]
    # python-can: factor = TIME_TEN_MICS_FACTOR if flags == 1 else TIME_ONE_NANS_FACTOR
    ten_us = hflags == blf.TIME_TEN_MICS
    t = np.where(ten_us, ts.astype(np.float64) / 1e5, ts.astype(np.float64) / 1e9)
    big = ts >= EXACT_FLOAT_INT
    if big.any():  # not exact in float64: python-can's Decimal arithmetic, as it does it
        for i in np.flatnonzero(big).tolist():
            factor = blf.TIME_TEN_MICS_FACTOR if ten_us[i] else blf.TIME_ONE_NANS_FACTOR
            t[i] = float(Decimal(int(ts[i])) * factor)
    t += start_timestamp
    dlc = raw["dlc"]
    if layout.error:
        kind = np.full(n, KIND_ERROR, dtype=np.int8)
    else:
        kind = np.where(raw["remote"] & layout.remote_mask, KIND_REMOTE, KIND_DATA).astype(np.int8)
    return {
        "t": t,
        "arbitration_id": ident & ID_MASK,
        "extended": (ident & blf.CAN_MSG_EXT) != 0,
        "dlc": DLC2LEN[dlc] if layout.fd_dlc else dlc.astype(np.int64),
        "kind": kind,
        "fd": (raw["fdflags"] & layout.fd_mask) != 0 if layout.fd_mask else np.zeros(n, dtype=bool),
    }


def _payload(layout: _Layout, u8: np.ndarray, at: np.ndarray, remote: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """(number of data bytes, data bytes zero-padded) of the frame objects of one layout at `at`, as
    python-can's Message has them: CAN_MESSAGE(2) and CAN_ERROR_EXT ``data[:dlc]`` of 8 bytes,
    CAN_FD_MESSAGE ``data[:valid_bytes]`` of 64, CAN_FD_MESSAGE_64 the bytes after the struct up to
    ``min(valid_bytes, (ext_data_offset or object size) - header size - struct size)`` padded with
    zeros to valid_bytes; a remote frame none (python-can's Message drops its data)."""
    if layout.data_width is not None:
        width = layout.data_width
        data = u8[at[:, None] + layout.data_offset + np.arange(width)]
        count = u8[at + (layout.valid_offset if layout.valid_offset is not None else layout.dlc_offset)]
        length = np.minimum(count, width).astype(np.int64)
    else:
        assert layout.valid_offset is not None and layout.ext_data_offset is not None
        length = u8[at + layout.valid_offset].astype(np.int64)
        ext_data = u8[at + layout.ext_data_offset].astype(np.int64)
        header_size = u8[at + 4].astype(np.int64) | u8[at + 5].astype(np.int64) << 8
        size = _gather_field(u8, at + 8, 4).astype(np.int64)
        there = np.minimum(length, np.where(ext_data != 0, ext_data, size) - header_size - layout.body_size)
        there = np.maximum(there, 0)
        if (layout.size + there > size).any():  # python-can would take bytes of what follows the object
            raise NotFast("CAN FD data beyond its object")
        width = int(length.max()) if len(at) else 0
        k = np.arange(width)
        data = u8[np.minimum(at[:, None] + layout.size + k, len(u8) - 1)]
        data[k >= there[:, None]] = 0
    length[remote] = 0
    data[np.arange(data.shape[1]) >= length[:, None]] = 0
    return length, data


# python-can's OBJ_HEADER_BASE_STRUCT "<4sHHLL": signature, header size, header version, object size, type
BASE_DTYPE = np.dtype([("signature", "S4"), ("header_size", "<u2"), ("version", "<u2"), ("size", "<u4"),
                       ("kind", "<u4")])
assert BASE_DTYPE.itemsize == BASE_SIZE


def _find_all(data: bytes, word: bytes) -> np.ndarray:
    """Every offset of the 4-byte `word` in `data`, ascending (overlaps included)."""
    value = int.from_bytes(word, "little")
    found = [np.flatnonzero(np.frombuffer(data, dtype="<u4", count=(len(data) - k) // 4, offset=k) == value)
             * 4 + k for k in range(4) if len(data) - k >= 4]
    return np.sort(np.concatenate(found)) if found else np.zeros(0, dtype=np.int64)


def _gather_field(u8: np.ndarray, at: np.ndarray, width: int) -> np.ndarray:
    """The little-endian unsigned integers of `width` bytes at the offsets `at` of `u8`."""
    if width == 1:
        return u8[at]
    return u8[at[:, None] + np.arange(width)].view(f"<u{width}").ravel()


def _gather(u8: np.ndarray, starts: np.ndarray, layout: _Layout) -> dict[str, np.ndarray]:
    """The raw fields of the objects starting at `starts` (byte offsets in `u8`)."""
    return {name: _gather_field(u8, starts + offset, np.dtype(layout.dtypes[name]).itemsize)
            for name, offset in layout.offsets.items()}


class BlfColumnReader:
    """python-can's BLFReader.__iter__ / _parse_container / _parse_data, collecting columns.

    ``BlfColumnReader(reader).read()`` reads the file of an open ``can.io.blf.BLFReader`` (whose
    constructor has parsed the file header) from where that left it to the end, `batch_bytes` of
    container payloads at a time (1: each container on its own, as python-can does)."""

    def __init__(self, reader: blf.BLFReader, batch_bytes: int = BATCH_BYTES, payload: bool = False) -> None:
        self.batch_bytes = batch_bytes  # read the container payloads in batches of this many bytes
        self.payload = payload  # also the data bytes: columns "length" and "payload" (see _payload)
        self.file = reader.file
        self.start_timestamp = reader.start_timestamp
        self.chunks: list[dict[str, np.ndarray]] = []
        self.tail = b""
        self.viewed = 0  # frame objects read through one strided numpy view (equally spaced, one type)
        self.gathered = 0  # frame objects whose fields were gathered by their offsets
        self.steps = 0  # python-level steps of the object chain (see _chain)

    def read(self) -> FrameArrays:
        chunks = self.read_chunks()
        return FrameArrays(**{c: np.concatenate([ch[c] for ch in chunks]).astype(DTYPES[c], copy=False)
                              for c in COLUMNS})

    def read_chunks(self) -> list[dict[str, np.ndarray]]:
        """The columns, as chunks of consecutive frames (dicts of column name -> array)."""
        read = self.file.read
        pending: list[bytes] = []  # container payloads not read yet
        waiting = 0
        unpack_base = blf.OBJ_HEADER_BASE_STRUCT.unpack
        while True:
            data = read(BASE_SIZE)
            if not data:
                break
            signature, _, _, obj_size, obj_type = unpack_base(data)
            if signature != b"LOBJ":
                raise blf.BLFParseError()
            obj_data = read(obj_size - BASE_SIZE)
            read(obj_size % 4)  # padding
            if obj_type == blf.LOG_CONTAINER:
                method, _ = blf.LOG_CONTAINER_STRUCT.unpack_from(obj_data)
                container = memoryview(obj_data)[blf.LOG_CONTAINER_STRUCT.size:]
                if method == blf.NO_COMPRESSION:
                    payload = bytes(container)
                elif method == blf.ZLIB_DEFLATE:
                    payload = zlib.decompressobj().decompress(container)
                else:
                    raise NotFast(f"unknown compression method {method}")  # python-can warns, skips
                pending.append(payload)
                waiting += len(payload)
                if waiting >= self.batch_bytes:
                    self._payload(pending)
                    waiting = 0
        self._payload(pending)
        if not self.chunks:
            raise NotFast("no frame")  # python-can's reader says what is wrong (or that it is empty)
        return self.chunks

    def _payload(self, payloads: list[bytes]) -> None:
        """Read the objects of consecutive container payloads, after the tail of the last ones.

        python-can reads each payload after the unread tail of the one before; that finds the same
        objects as reading the payloads joined, since its search for the next object looks at most
        8 bytes ahead and a payload's tail is exactly what it could not read yet."""
        if payloads:
            data = b"".join((self.tail, *payloads))
            payloads.clear()
            self.tail = data[self._container(data):]

    def _container(self, data: bytes) -> int:
        """Read the objects of a payload; returns where its unread tail starts."""
        u8 = np.frombuffer(data, dtype=np.uint8)
        at, heads, tail = self._chain(data, u8)
        if len(at) == 0:
            return tail
        code = heads["version"].astype(np.int64) << 32 | heads["kind"]
        frames = np.zeros(len(at), dtype=bool)
        layouts = []
        for c in ([int(code[0])] if (code == code[0]).all() else np.unique(code).tolist()):
            v, k = c >> 32, c & 0xFFFFFFFF
            if v not in HEADER:
                raise NotFast(f"object header version {v}")  # python-can warns and skips the object
            layout = LAYOUTS.get((v, k))
            of_kind = code == c
            need = layout.size if layout is not None else BASE_SIZE + HEADER[v].size
            shortest = int(heads["size"][of_kind].min())
            if shortest < need:  # python-can would read past the object
                raise NotFast(f"object of type {k} shorter than its struct ({shortest} bytes)")
            if layout is not None:
                frames |= of_kind
                layouts.append((layout, of_kind))
        if len(layouts) == 1 and frames.all():  # one frame type only: no scatter
            self.chunks.append(self._read(data, u8, at, layouts[0][0]))
        elif layouts:
            parts = [(of_kind[frames], self._read(data, u8, at[of_kind], layout))
                     for layout, of_kind in layouts]
            n = int(frames.sum())
            out = {c: np.empty(n, dtype=DTYPES[c]) for c in COLUMNS}
            if self.payload:
                width = max(cols["payload"].shape[1] for _, cols in parts)
                out["length"] = np.empty(n, dtype=np.int64)
                out["payload"] = np.zeros((n, width), dtype=np.uint8)
            for where, cols in parts:
                for c, column in cols.items():
                    if c == "payload":
                        out[c][where, : column.shape[1]] = column
                    else:
                        out[c][where] = column
            self.chunks.append(out)
        return tail

    def _chain(self, data: bytes, u8: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """Where python-can finds the objects of a payload, their base headers, and where the unread
        tail of the payload starts.

        python-can goes from object to object: from position `pos` (0, then the end of the last
        object) the next object is the first 'LOBJ' starting at pos .. pos + 4 (its padding skipped);
        it is read if its 16-byte base header and all its bytes are in the payload, else the payload
        from `pos` on waits for the next container; no 'LOBJ' with pos + 8 inside the payload is a
        BLFParseError.  Here every 'LOBJ' of the payload is a candidate (some lie inside frame data),
        each candidate's successor is found with numpy, and the chain is followed from the first:
        a stretch of candidates that follow each other directly in one step, the others one by one."""
        n = len(data)
        cand = _find_all(data, b"LOBJ")
        m = len(cand)
        full = cand + BASE_SIZE <= n  # a prefix: the candidates are ascending
        heads = np.zeros(m, dtype=BASE_DTYPE)
        whole = int(full.sum())
        step = np.diff(cand[:whole])
        if whole > 1 and (step == step[0]).all():  # equally spaced (one kind of object): one strided view
            heads[:whole] = np.ndarray((whole,), dtype=BASE_DTYPE, buffer=data, offset=int(cand[0]),
                                       strides=(int(step[0]),))
        else:
            heads[:whole] = u8[cand[:whole, None] + np.arange(BASE_SIZE)].view(BASE_DTYPE).ravel()
        end = cand + heads["size"]
        # each candidate as an object: readable (0), goes on in the next container (BEYOND), too short
        # to be read here (SHORT)
        state = np.where(~full | (end > n), BEYOND, np.where(heads["size"] < MIN_OBJECT, SHORT, 0))

        def successor(pos: np.ndarray) -> np.ndarray:
            """Index of the object found from each `pos` on, or the state that ends the chain there."""
            j = np.searchsorted(cand, pos)
            found = j < m
            found[found] &= cand[j[found]] <= pos[found] + 4
            j = np.where(found, j, 0)
            return np.where(found, np.where(state[j] == 0, j, state[j]), NOT_FOUND)

        after = successor(end)
        i = int(successor(np.zeros(1, dtype=np.int64))[0]) if m else NOT_FOUND
        breaks = np.flatnonzero(after[:-1] != np.arange(1, m)).tolist() + [m - 1]
        stretches = []
        while i >= 0:  # stretches i, i+1, ..., e of candidates that follow each other directly
            e = breaks[bisect.bisect_left(breaks, i)]
            stretches.append((i, e))
            i = int(after[e])
            self.steps += 1
        if len(stretches) == 1:
            chain = slice(stretches[0][0], stretches[0][1] + 1)
        else:
            chain = np.concatenate([np.arange(a, e + 1) for a, e in stretches]
                                   or [np.zeros(0, dtype=np.int64)])
        at, heads = cand[chain], heads[chain]
        pos = int(at[-1] + heads["size"][-1]) if len(at) else 0  # where python-can searches next
        if i == NOT_FOUND and pos + 8 <= n:
            raise blf.BLFParseError("Could not find next object")
        if i == SHORT:
            raise NotFast("an object too short to hold its own header")
        return at, heads, pos  # NOT_FOUND near the end, or BEYOND: the rest waits for more data

    def _read(self, data: bytes, u8: np.ndarray, at: np.ndarray, layout: _Layout) -> dict[str, np.ndarray]:
        """Columns of the frame objects of one layout starting at `at`."""
        steps = np.diff(at)
        if len(at) > 1 and (steps == steps[0]).all() and steps[0] >= layout.size:
            raw = np.ndarray((len(at),), dtype=layout.view_dtype(), buffer=data, offset=int(at[0]),
                             strides=(int(steps[0]),))
            self.viewed += len(at)
        else:
            raw = _gather(u8, at, layout)
            self.gathered += len(at)
        columns = _columns(layout, raw, self.start_timestamp)
        if self.payload:
            columns["length"], columns["payload"] = _payload(layout, u8, at, columns["kind"] == KIND_REMOTE)
        return columns


def read_blf_columns(reader: blf.BLFReader) -> FrameArrays:
    """The columns of an open python-can BLFReader's file, read to its end (the reader is not closed).

    Raises ``NotFast`` where python-can would warn or the file has no frame, and whatever the data
    makes python-can's struct/zlib code raise; ``read_columns`` turns both into python-can's result.
    """
    return BlfColumnReader(reader).read()


# --- MF4 (ASAM MDF 4 bus logging) --------------------------------------------------------------------------


def _is_mf4(path: str | pathlib.Path) -> bool:
    return str(path).lower().endswith(".mf4")


def read_mf4_chunks(path: str | pathlib.Path, payload: bool = False, mdf=None) -> list[dict[str, np.ndarray]]:
    """The frames of an MF4 bus-logging file as python-can's MF4Reader gives them, as columns (t, id,
    extended, dlc, kind, fd, and with `payload` the data bytes and their length), without a Message per
    frame: each CAN channel group's records are read by asammdf in one call, the fields taken as
    python-can takes them (its defaults where a field is absent: a data or error frame without IDE is
    29-bit, as `can.Message` makes it), and the groups merged by timestamp as python-can's heapq.merge
    merges them.  NotFast where python-can's result would not be plain columns of that: groups whose
    timestamps go back, variable-length data bytes."""
    from asammdf import MDF
    from asammdf.blocks.v4_constants import SOURCE_BUS


    own = mdf is None                     # `mdf`: the file already open (python-can's reader's)
    mdf = MDF(str(path)) if own else mdf
    try:
        start = mdf.header.start_time.timestamp()
        parts: list[dict[str, np.ndarray]] = []
        for index, group in enumerate(mdf.groups):
            frame = mf4_can_frames(group)                     # python-can's tests, in its order
            if (frame is None or group.channel_group.cycles_nr == 0
                    or not group.channel_group.acq_source.source_type & SOURCE_BUS):
                continue
            sig = mdf.get(frame, index, raw=False)
            rec = sig.samples
            fields = rec.dtype.names or ()

            def col(field: str, default, dtype, rec=rec, fields=fields, frame=frame):
                key = f"{frame}.{field}"
                return (np.asarray(rec[key]).astype(dtype) if key in fields
                        else np.full(len(rec), default, dtype=dtype))

            n = len(rec)
            t = np.asarray(sig.timestamps, dtype=np.float64) + start
            if n > 1 and (np.diff(t) < 0).any():
                raise NotFast("an MF4 channel group whose timestamps go back")
            part = {"t": t, "arbitration_id": col("ID", 0, np.int64) & 0x1FFFFFFF,
                    "extended": col("IDE", True, bool), "fd": col("EDL", False, bool)}
            if frame == "CAN_RemoteFrame":
                part.update(dlc=col("DLC", 0, np.int64), kind=np.full(n, KIND_REMOTE, np.int8),
                            fd=np.zeros(n, bool))
                data, length = np.zeros((n, 0), np.uint8), np.zeros(n, np.int64)
            else:
                has_data = f"{frame}.DataBytes" in fields and (frame == "CAN_DataFrame"
                                                              or f"{frame}.DataLength" in fields)
                if has_data:
                    data = np.asarray(rec[f"{frame}.DataBytes"])
                    if data.dtype != np.uint8 or data.ndim != 2:
                        raise NotFast("MF4 data bytes that are not a fixed-width byte array")
                    length = np.minimum(col("DataLength", 0, np.int64), data.shape[1])
                else:
                    data, length = np.zeros((n, 0), np.uint8), np.zeros(n, np.int64)
                part.update(dlc=length, kind=np.full(n, KIND_DATA if frame == "CAN_DataFrame" else KIND_ERROR,
                                                     np.int8))
            if payload:
                width = int(length.max()) if n else 0
                keep = np.arange(width)[None, :] < length[:, None]
                part["payload"] = np.where(keep, data[:, :width], 0).astype(np.uint8)
                part["length"] = length
            parts.append(part)
    finally:
        if own:
            mdf.close()
    if len(parts) <= 1:
        return parts
    keys = list(parts[0])
    order = np.argsort(np.concatenate([p["t"] for p in parts]), kind="stable")   # ties: group order
    width = max(p["payload"].shape[1] for p in parts) if payload else 0
    merged = {}
    for k in keys:
        if k == "payload":
            padded = [np.pad(p[k], ((0, 0), (0, width - p[k].shape[1]))) for p in parts]
            merged[k] = np.concatenate(padded)[order]
        else:
            merged[k] = np.concatenate([p[k] for p in parts])[order]
    return [merged]


def read_mf4_columns(path: str | pathlib.Path, mdf=None) -> FrameArrays:
    """``frame_arrays(open_trace(path))`` of an MF4 file, column by column (read_mf4_chunks)."""

    chunks = read_mf4_chunks(path, mdf=mdf)
    if not chunks:
        empty = np.zeros(0)
        return FrameArrays(empty.astype(np.float64), empty.astype(np.int64), empty.astype(bool),
                           empty.astype(np.int64), empty.astype(np.int8), empty.astype(bool))
    c = chunks[0]
    return FrameArrays(c["t"], c["arbitration_id"], c["extended"], c["dlc"], c["kind"], c["fd"])


def _is_blf(path: str | pathlib.Path) -> bool:
    if str(path) == STDIN:
        return False
    suffixes = [s.lower() for s in pathlib.Path(path).suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    return bool(suffixes) and suffixes[-1] == ".blf"


def read_trace_columns(path: str | pathlib.Path, salvage: bool = False) -> tuple[FrameArrays, Trace]:
    """The columns of a trace, and its ``Trace`` (for ``skipped``/``name``, as after iterating it).

    Equal to ``frame_arrays(open_trace(path))``; raises the same ``TraceError``.  With `salvage`, a
    TraceError that reading the frames raises (a corrupt line, a cut file) is not raised but kept in
    the Trace's ``error``, and the columns are those of the frames read before it: for a tool that
    reports what was read, then the error.  An error of opening the file is raised either way."""

    trace = open_trace(path)
    arrays = None
    if _is_mf4(path) and isinstance(trace.reader, can.io.MF4Reader):
        try:
            arrays = read_mf4_columns(path, getattr(trace.reader, "_mdf", None))
        except Exception:  # NotFast, or an odd file: python-can's reader gives the result or the error
            arrays = None
        if arrays is not None and len(arrays):
            trace.close()
            trace.count = len(arrays)
        else:
            arrays = None
    if _is_blf(path) and isinstance(trace.reader, blf.BLFReader):
        try:
            arrays = read_blf_columns(trace.reader)
        except Exception:  # NotFast, or a broken file: python-can's reader gives the result or the error
            arrays = None
        finally:
            trace.close()
        if arrays is not None:
            trace.count = len(arrays)
            if trace.cut is not None:  # python-can's reader ends a cut file quietly
                trace.error = trace.cut_error()
        else:
            trace = open_trace(path)
    if arrays is None:
        frames = Salvage(trace)
        arrays = frame_arrays(frames)
        trace.error = frames.error
    if trace.error is not None and not salvage:
        raise trace.error
    return arrays, trace


def read_columns(path: str | pathlib.Path) -> FrameArrays:
    """``frame_arrays(open_trace(path))``, fast for BLF files (see the module docstring)."""
    return read_trace_columns(path)[0]


# --- frames with their data, in blocks, for decoding (hil.trace.fastdecode) -----------------------------

BLOCK_FRAMES = 65_536  # frames per FrameBlock: large enough that the per-block numpy steps cost little


@dataclass
class FrameBlock:
    """Consecutive frames of a trace as columns, with their data bytes, in file order.

    Row i is the frame python-can's reader gives: ``t`` its timestamp [s] (float64), ``arbitration_id``
    (int64), ``extended`` (29-bit id), ``remote`` (remote frame), ``error`` (error frame), ``dlc`` (the
    Message's dlc field), ``length`` (its number of data bytes, ``len(Message.data)``) and ``payload``
    (uint8, rows x width: the data bytes, zero-padded to the longest).  ``messages`` holds
    python-can's Messages when the block was made of them, else None; ``special`` marks the rows whose
    Message the columns do not hold exactly (a timestamp that is not a Python float), to be taken
    from ``messages`` one by one.
    """

    t: np.ndarray
    arbitration_id: np.ndarray
    extended: np.ndarray
    remote: np.ndarray
    error: np.ndarray
    dlc: np.ndarray
    length: np.ndarray
    payload: np.ndarray
    messages: Sequence[can.Message | None] | None = None
    special: np.ndarray | None = None
    stamps: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)

    def message(self, i: int) -> can.Message:
        """Row i as python-can's Message: the one read when the block holds them, else one made of the
        columns with every field `trace decode` reads."""
        if self.messages is not None and self.messages[i] is not None:
            return self.messages[i]
        return can.Message(timestamp=float(self.t[i]), arbitration_id=int(self.arbitration_id[i]),
                           is_extended_id=bool(self.extended[i]), is_remote_frame=bool(self.remote[i]),
                           is_error_frame=bool(self.error[i]), dlc=int(self.dlc[i]),
                           data=self.payload[i, : self.length[i]].tobytes())

    @classmethod
    def from_messages(cls, messages: Sequence[can.Message]) -> FrameBlock:
        """The columns of python-can Messages (one Python step per frame); the block keeps them."""
        n = len(messages)
        data = [bytes(m.data) for m in messages]
        length = np.fromiter(map(len, data), dtype=np.int64, count=n)
        width = int(length.max()) if n else 0
        if n and (length == width).all():
            payload = np.frombuffer(b"".join(data), dtype=np.uint8).reshape(n, width).copy()
        else:
            payload = np.frombuffer(b"".join(d.ljust(width, b"\0") for d in data),
                                    dtype=np.uint8).reshape(n, width).copy()
        stamps = [m.timestamp for m in messages]
        special = np.fromiter((type(x) is not float for x in stamps), dtype=bool, count=n)
        return cls(
            t=np.array([x if type(x) is float else 0.0 for x in stamps], dtype=np.float64),
            arbitration_id=np.fromiter((m.arbitration_id for m in messages), dtype=np.int64, count=n),
            extended=np.fromiter((m.is_extended_id for m in messages), dtype=bool, count=n),
            remote=np.fromiter((m.is_remote_frame for m in messages), dtype=bool, count=n),
            error=np.fromiter((m.is_error_frame for m in messages), dtype=bool, count=n),
            dlc=np.fromiter((m.dlc for m in messages), dtype=np.int64, count=n),
            length=length,
            payload=payload,
            messages=messages,
            special=special if special.any() else None,
        )

    def take(self, rows: np.ndarray) -> FrameBlock:
        """The rows `rows` (indices, in the order given)."""
        return FrameBlock(
            self.t[rows], self.arbitration_id[rows], self.extended[rows], self.remote[rows], self.error[rows],
            self.dlc[rows], self.length[rows], self.payload[rows],
            None if self.messages is None else [self.messages[i] for i in rows.tolist()],
            None if self.special is None else self.special[rows],
            None if self.stamps is None else self.stamps[rows])

    @staticmethod
    def join(blocks: Sequence[FrameBlock]) -> FrameBlock:
        """The rows of several blocks one after the other."""
        width = max(b.payload.shape[1] for b in blocks)
        payload = np.concatenate([np.pad(b.payload, ((0, 0), (0, width - b.payload.shape[1])))
                                  for b in blocks])
        messages = special = stamps = None
        if any(b.messages is not None for b in blocks):
            messages = [m for b in blocks
                        for m in (b.messages if b.messages is not None else [None] * len(b))]
        if any(b.special is not None for b in blocks):
            special = np.concatenate([np.zeros(len(b), bool) if b.special is None else b.special
                                      for b in blocks])
        if any(b.stamps is not None for b in blocks):
            stamps = np.concatenate([np.zeros(len(b), "S1") if b.stamps is None else b.stamps
                                     for b in blocks])
        return FrameBlock(
            *(np.concatenate([getattr(b, c) for b in blocks])
              for c in ("t", "arbitration_id", "extended", "remote", "error", "dlc", "length")),
            payload=payload,
            messages=messages,
            special=special,
            stamps=stamps)


_MAX_EXACT_DIGITS = 18  # timestamp digits an int64 holds exactly (10**18 < 2**63)
STAMP_EXACT_BELOW = 4e9  # [s] timestamps with 6 decimals below this print as written (see _seconds)
STAMP_WIDTH = 17  # characters of such a timestamp at most: 10 digits, the point, 6 decimals
ERR_FLAG = 0x20000000  # candump's error-frame flag in the id (python-can canutils.CAN_ERR_FLAG)
_HEX_VALUE = np.full(256, 16, dtype=np.uint8)  # 16: not a hex digit
for _c in "0123456789abcdefABCDEF":
    _HEX_VALUE[ord(_c)] = int(_c, 16)


def _is_word_or_separator(b: np.ndarray) -> np.ndarray:
    """Per byte: an ASCII word character ([A-Za-z0-9_], ``\\w`` with re.ASCII) or one of ``()#. \\n``."""
    letter = (b | 0x20) - np.uint8(ord("a")) < 26
    digit = b - np.uint8(ord("0")) < 10
    out = letter | digit
    for c in "_()#. \n":
        out |= b == ord(c)
    return out


def parse_candump(text: str) -> tuple[FrameBlock, np.ndarray]:
    """The common candump -L lines of `text` parsed at once with numpy.

    `text` is whole lines (each ends in a newline, but maybe the last).  Returns a block of one row
    per line and the mask of the lines parsed; the rows of the other lines hold nothing of use.  A
    line is parsed here when it is exactly what ``hil.trace.readers.CandumpReader`` parses with its regular
    expression -- ``(seconds) channel ID#HEXDATA`` with an optional `` R``/`` T``, single spaces, a 3-
    or 8-digit id without the error flag, whole data bytes, nothing before or after -- and its row
    holds the very values of python-can's Message: timestamp = float(seconds), arbitration_id =
    id & 0x1FFFFFFF, extended = 8 id digits, dlc = length = the number of data bytes.  Every other line
    (remote, CAN FD, error frames, comments, blank lines, other spacing, non-ASCII...) is for
    python-can's parser.

    float(seconds) without Python: seconds with d digits in all is the integer N of its digits over
    10**f (f digits after the point); for N < 2**53 both are exact doubles (f <= 18 < 23), so the
    IEEE division N / 10**f is the correctly rounded value of the decimal, as float() computes it.
    Other timestamps are read with float().
    """
    raw = text.encode("ascii", "replace")  # one byte per character; '?' makes a line not parse
    if not raw.endswith(b"\n"):
        raw += b"\n"
    b = np.frombuffer(raw, dtype=np.uint8)
    newline = b == ord("\n")
    ends = np.flatnonzero(newline)  # where each line ends
    n = len(ends)

    def line_of(pos: np.ndarray) -> np.ndarray:
        """The line of each byte at `pos` (none a newline): the newlines before it (a cumulative sum over
        every byte costs 3x more)."""
        return np.searchsorted(ends, pos)

    starts = np.zeros(n, dtype=np.int64)
    starts[1:] = ends[:-1] + 1
    ok = np.ones(n, dtype=bool)
    ok[line_of(np.flatnonzero(~_is_word_or_separator(b)))] = False

    def occurrences(char: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(count per line, positions, index in positions of each line's first) of one character."""
        pos = np.flatnonzero(b == ord(char))
        count = np.bincount(line_of(pos), minlength=n)
        return count, pos, np.cumsum(count) - count

    def once(char: str) -> np.ndarray:
        """The position of `char` in each line; lines without exactly one are not parsed."""
        count, pos, first = occurrences(char)
        ok[count != 1] = False
        return pos[np.minimum(first, len(pos) - 1)] if len(pos) else np.zeros(n, dtype=np.int64)

    opening, closing, dot, hash_ = once("("), once(")"), once("."), once("#")
    n_spaces, spaces, first = occurrences(" ")
    ok &= (n_spaces == 2) | (n_spaces == 3)
    if not ok.any():
        return _empty_rows(n), ok
    last = len(spaces) - 1
    s1 = spaces[np.minimum(first, last)]
    s2 = spaces[np.minimum(first + 1, last)]
    s3 = spaces[np.minimum(first + 2, last)]
    suffix = n_spaces == 3
    data_end = np.where(suffix, s3, ends)  # the data digits end here
    id_digits = hash_ - s2 - 1
    data_digits = data_end - hash_ - 1
    # the order ( . ) ' ' ' ' # [' '] and what lies between: digits, a channel, 3 or 8 id digits, pairs
    ok &= (opening == starts) & (dot >= starts + 2) & (closing >= dot + 2) & (s1 == closing + 1)
    ok &= (s2 >= s1 + 2) & ((id_digits == 3) | (id_digits == 8)) & (data_digits >= 0) & (data_digits % 2 == 0)
    direction = b[ends - 1]
    ok &= ~suffix | ((s3 == ends - 2) & ((direction | 0x20 == ord("r")) | (direction | 0x20 == ord("t"))))

    rows = np.flatnonzero(ok)
    bad = np.zeros(len(rows), dtype=bool)  # a character out of place after all
    # id: 3 or 8 hex digits before the '#', a column of digits at a time (numpy is fast along rows);
    # masks only where the rows differ
    hash_, id_digits = hash_[rows], id_digits[rows]
    fewest = int(id_digits.min()) if len(rows) else 8
    can_id = np.zeros(len(rows), dtype=np.int64)
    for j in range(8 - int(id_digits.max()) if len(rows) else 8, 8):
        nibble = _HEX_VALUE[b[hash_ - 8 + j]]
        if j < 8 - fewest:
            nibble[id_digits < 8 - j] = 0
        bad |= nibble > 15
        can_id = (can_id << 4) | nibble
    extended = id_digits == 8
    # data: the pairs of hex digits after the '#'
    n_bytes = data_digits[rows] // 2
    width = int(n_bytes.max()) if len(rows) else 0
    fewest = int(n_bytes.min()) if len(rows) else 0
    payload = np.zeros((len(rows), width), dtype=np.uint8)
    for k in range(width):
        if k < fewest:
            high = _HEX_VALUE[b[hash_ + 1 + 2 * k]]
            low = _HEX_VALUE[b[hash_ + 2 + 2 * k]]
        else:
            high = _HEX_VALUE[b[np.minimum(hash_ + 1 + 2 * k, len(b) - 2)]]
            low = _HEX_VALUE[b[np.minimum(hash_ + 2 + 2 * k, len(b) - 1)]]
            beyond = n_bytes <= k
            high[beyond] = 0
            low[beyond] = 0
        bad |= (high | low) > 15
        payload[:, k] = (high << 4) | low
    t, digits_ok, stamps = _seconds(raw, b, starts[rows], dot[rows], closing[rows])
    # error flag: python-can decides what the line is
    good = ~bad & digits_ok & ~(extended & (can_id & ERR_FLAG != 0))
    if not good.all():
        ok[rows[~good]] = False
        rows, can_id, extended, n_bytes, payload, t, stamps = (
            x[good] for x in (rows, can_id, extended, n_bytes, payload, t, stamps))
    block = FrameBlock(
        t=t,
        arbitration_id=can_id & 0x1FFFFFFF,
        extended=extended,
        remote=np.zeros(len(rows), dtype=bool),
        error=np.zeros(len(rows), dtype=bool),
        dlc=n_bytes,
        length=n_bytes.copy(),
        payload=payload,
        stamps=stamps,
    )
    if len(rows) == n:
        return block, ok
    full = _empty_rows(n, width)
    full.stamps = np.zeros(n, dtype=stamps.dtype)
    for name in ("t", "arbitration_id", "extended", "dlc", "length", "payload", "stamps"):
        getattr(full, name)[rows] = getattr(block, name)
    return full, ok


def _empty_rows(n: int, width: int = 0) -> FrameBlock:
    return FrameBlock(np.zeros(n), np.zeros(n, dtype=np.int64), np.zeros(n, dtype=bool),
                      np.zeros(n, dtype=bool), np.zeros(n, dtype=bool), np.zeros(n, dtype=np.int64),
                      np.zeros(n, dtype=np.int64), np.zeros((n, width), dtype=np.uint8))


def _seconds(raw: bytes, b: np.ndarray, starts: np.ndarray, dot: np.ndarray, closing: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """float() of the text between '(' at `starts` and ')' at `closing` with the point at `dot`
    (parse_candump's docstring says why the division is exact); whether that text is all digits but
    the point; and the text itself where it is ``format(float(text), '.6f')`` (b"" elsewhere).

    The text is that format of its float when it has 6 decimals, no leading zero, and is below 4e9:
    then the float is less than 2**-53 * 4e9 < 0.5e-6 from it, and rounds back to it."""
    if not len(starts):
        return np.zeros(0), np.ones(0, dtype=bool), np.zeros(0, dtype="S1")
    n_int = dot - starts - 1
    n_frac = closing - dot - 1
    w_int, w_frac = int(n_int.max()), int(n_frac.max())
    fewest_int, fewest_frac = int(n_int.min()), int(n_frac.min())
    worst = np.zeros(len(starts), dtype=np.uint8)  # the largest "digit" (a non-digit is above 9)
    number = np.zeros(len(starts), dtype=np.int64)  # the digits as one integer (if it fits)
    for j in range(w_int):  # the integer part, right-aligned on the point, a column at a time
        if j >= w_int - fewest_int:
            digit = b[dot - w_int + j] - np.uint8(ord("0"))
        else:  # some rows have fewer digits: zeros in front
            digit = b[np.maximum(dot - w_int + j, 0)] - np.uint8(ord("0"))
            digit[n_int < w_int - j] = 0
        np.maximum(worst, digit, out=worst)
        number = number * 10 + digit
    for j in range(w_frac):  # the fraction, left-aligned on the point, zero-padded
        if j < fewest_frac:
            digit = b[dot + 1 + j] - np.uint8(ord("0"))
        else:
            digit = b[np.minimum(dot + 1 + j, len(b) - 1)] - np.uint8(ord("0"))
            digit[n_frac <= j] = 0
        np.maximum(worst, digit, out=worst)
        number = number * 10 + digit
    digits_ok = worst < 10
    if w_int + w_frac <= _MAX_EXACT_DIGITS:
        t = number / float(10 ** w_frac)
        inexact = np.flatnonzero(digits_ok & (number >= 2 ** 53))
    else:
        t = np.zeros(len(starts))
        inexact = np.flatnonzero(digits_ok)
    for i in inexact.tolist():
        t[i] = float(raw[starts[i] + 1: closing[i]])
    six = digits_ok & (n_frac == 6) & ((n_int == 1) | (b[starts + 1] != ord("0"))) & (t < STAMP_EXACT_BELOW)
    if fewest_int == w_int:  # one length for all: the texts are one slice of each line
        width = w_int + 7
        text = b[starts[:, None] + 1 + np.arange(width)]
        text[~six] = 0
    else:
        width = STAMP_WIDTH
        text = b[np.minimum(starts[:, None] + 1 + np.arange(width), len(b) - 1)]
        text[(n_int[:, None] + 7 <= np.arange(width)) | ~six[:, None]] = 0
    return t, digits_ok, text.view(f"S{width}").ravel()


class BlockReader:
    """The frames of a trace as FrameBlocks of up to `max_frames` rows, in file order.

    ``trace`` is the Trace read (its ``name``, ``count``, ``skipped`` as after iterating it).  candump
    text (.log, .log.gz, stdin) is parsed a batch of lines at a time by ``parse_candump``, every line
    it does not take by python-can's parser (``Trace.candump_line``); every other format is read by
    python-can's reader, ``max_frames`` Messages at a time.  Either way the frames, and a TraceError
    that reading raises, are those of iterating ``open_trace(path)``; the frames read before the error
    come first, as a last block.
    """

    def __init__(self, path: str | pathlib.Path, max_frames: int = BLOCK_FRAMES) -> None:
        self.path = path
        self.trace = open_trace(path)
        self.max_frames = max_frames

    def __iter__(self) -> Iterator[FrameBlock]:
        if self.trace.is_candump:
            yield from self._candump()
            return
        if _is_mf4(self.path) and isinstance(self.trace.reader, can.io.MF4Reader):
            blocks = self._mf4()
            if blocks:
                yield from blocks
                return
        if _is_blf(self.path) and isinstance(self.trace.reader, blf.BLFReader):
            blocks = self._blf()
            if blocks is not None:
                yield from blocks
                if self.trace.cut is not None:  # python-can's reader ends a cut file quietly
                    raise self.trace.cut_error()
                return
            self.trace = open_trace(self.path)  # python-can's reader gives the result or the error
        frames = iter(self.trace)
        while True:
            batch: list[can.Message] = []
            error = None
            try:
                for msg in frames:
                    batch.append(msg)
                    if len(batch) >= self.max_frames:
                        break
            except TraceError as exc:
                error = exc
            if batch:
                yield FrameBlock.from_messages(batch)
            if error is not None:
                raise error
            if not batch:
                return

    def _blf(self) -> list[FrameBlock] | None:
        """The frames of a BLF file read by BlfColumnReader (payload included), None where it gives up."""
        try:
            chunks = BlfColumnReader(self.trace.reader, payload=True).read_chunks()
        except Exception:  # NotFast, or a broken file: python-can's reader gives the result or the error
            return None
        finally:
            self.trace.close()

        blocks: list[FrameBlock] = []
        group: list[FrameBlock] = []  # consecutive pieces of chunks, up to max_frames rows together
        rows = 0
        for chunk in chunks:
            block = FrameBlock(
                t=chunk["t"], arbitration_id=chunk["arbitration_id"], extended=chunk["extended"],
                remote=chunk["kind"] == KIND_REMOTE, error=chunk["kind"] == KIND_ERROR, dlc=chunk["dlc"],
                length=chunk["length"], payload=chunk["payload"])
            for first in range(0, len(block), self.max_frames):
                piece = block if len(block) <= self.max_frames else block.take(
                    np.arange(first, min(first + self.max_frames, len(block))))
                if rows + len(piece) > self.max_frames:
                    blocks.append(group[0] if len(group) == 1 else FrameBlock.join(group))
                    group, rows = [], 0
                group.append(piece)
                rows += len(piece)
        if group:
            blocks.append(group[0] if len(group) == 1 else FrameBlock.join(group))
        self.trace.count = sum(map(len, blocks))
        return blocks

    def _mf4(self) -> list[FrameBlock] | None:
        """The frames of an MF4 file read by read_mf4_chunks (payload included), in blocks of up to
        max_frames rows; None where it gives up (python-can's reader then reads the file)."""

        try:
            chunks = read_mf4_chunks(self.path, payload=True, mdf=getattr(self.trace.reader, "_mdf", None))
        except Exception:  # NotFast, or an odd file
            return None
        if not chunks:
            return None
        self.trace.close()
        c = chunks[0]
        whole = FrameBlock(t=c["t"], arbitration_id=c["arbitration_id"], extended=c["extended"],
                           remote=c["kind"] == KIND_REMOTE, error=c["kind"] == KIND_ERROR, dlc=c["dlc"],
                           length=c["length"], payload=c["payload"])
        blocks = [whole if len(whole) <= self.max_frames else
                  whole.take(np.arange(first, min(first + self.max_frames, len(whole))))
                  for first in range(0, len(whole), self.max_frames)]
        self.trace.count = len(whole)
        return blocks

    def _candump(self) -> Iterator[FrameBlock]:
        trace = self.trace
        lines_before = 0
        for lines in trace.candump_batches(self.max_frames):
            block, ok = parse_candump("".join(lines))
            if ok.all():
                trace.count += len(lines)
                yield block
            else:
                yield from self._mixed(lines, lines_before, block, ok)
            lines_before += len(lines)

    def _mixed(self, lines: list[str], lines_before: int, block: FrameBlock, ok: np.ndarray
               ) -> Iterator[FrameBlock]:
        """A batch with lines for python-can's parser: its frames, then the error a line raised."""
        trace = self.trace
        start = trace.count
        parsed_before = np.cumsum(ok) - ok  # frames of parsed lines before each line
        taken: list[int] = []
        messages: list[can.Message] = []
        error = None
        end = len(lines)
        for j in np.flatnonzero(~ok).tolist():
            trace.count = start + int(parsed_before[j]) + len(messages)
            try:
                msg = trace.candump_line(lines[j], lines_before + j + 1)
            except TraceError as exc:
                error, end = exc, j
                break
            if msg is not None:
                taken.append(j)
                messages.append(msg)
        parsed = np.flatnonzero(ok[:end])
        trace.count = start + len(parsed) + len(messages)
        if len(parsed) or messages:
            parts = [block.take(parsed)]
            if messages:
                parts.append(FrameBlock.from_messages(messages))
            order = np.argsort(np.concatenate([parsed, np.array(taken, dtype=np.int64)]), kind="stable")
            yield FrameBlock.join(parts).take(order)
        if error is not None:
            raise error
