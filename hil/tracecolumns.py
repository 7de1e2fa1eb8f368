"""A trace as numpy columns for the timing analysis, fast: BLF read with python-can's format code into
columns without a ``can.Message`` per frame.

``read_columns(path)`` gives the same ``hil.timing.FrameArrays`` as
``frame_arrays(open_trace(path))``, column by column and bit for bit, and the same ``TraceError``
for a file that cannot be read.  Only a BLF file (``.blf``, also ``.blf.gz``) takes the fast path;
every other format, and stdin, goes through python-can's reader and ``frame_arrays``.

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
from decimal import Decimal

import numpy as np
from can.io import blf
from can.util import dlc2len

from hil.timing import KIND_DATA, KIND_ERROR, KIND_REMOTE, FrameArrays, frame_arrays
from hil.traceio import STDIN, Trace, open_trace

__all__ = ["BlfColumnReader", "NotFast", "read_blf_columns", "read_columns", "read_trace_columns"]

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
                 fd: tuple | None, error: bool, fd_dlc: bool) -> None:
        head = _fields(HEADER[version])
        start = BASE_SIZE + HEADER[version].size
        fields = _fields(body)
        self.size = start + body.size  # an object shorter than this is not read here
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
# flag and the FD flag in each body struct, as python-can unpacks them.
_FRAME_TYPES = {
    blf.CAN_MESSAGE: dict(body=blf.CAN_MSG_STRUCT, ident=3, dlc=2, remote=(1, blf.REMOTE_FLAG), fd=None,
                          error=False, fd_dlc=False),
    blf.CAN_MESSAGE2: dict(body=blf.CAN_MSG_STRUCT, ident=3, dlc=2, remote=(1, blf.REMOTE_FLAG), fd=None,
                           error=False, fd_dlc=False),
    blf.CAN_ERROR_EXT: dict(body=blf.CAN_ERROR_EXT_STRUCT, ident=7, dlc=5, remote=None, fd=None,
                            error=True, fd_dlc=False),
    blf.CAN_FD_MESSAGE: dict(body=blf.CAN_FD_MSG_STRUCT, ident=3, dlc=2, remote=(1, blf.REMOTE_FLAG),
                             fd=(6, blf.EDL), error=False, fd_dlc=True),
    blf.CAN_FD_MESSAGE_64: dict(body=blf.CAN_FD_MSG_64_STRUCT, ident=4, dlc=1, remote=(6, FD64_REMOTE),
                                fd=(6, FD64_FD), error=False, fd_dlc=True),
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

    def __init__(self, reader: blf.BLFReader, batch_bytes: int = BATCH_BYTES) -> None:
        self.batch_bytes = batch_bytes  # read the container payloads in batches of this many bytes
        self.file = reader.file
        self.start_timestamp = reader.start_timestamp
        self.chunks: list[dict[str, np.ndarray]] = []
        self.tail = b""
        self.viewed = 0  # frame objects read through one strided numpy view (equally spaced, one type)
        self.gathered = 0  # frame objects whose fields were gathered by their offsets
        self.steps = 0  # python-level steps of the object chain (see _chain)

    def read(self) -> FrameArrays:
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
        return FrameArrays(**{c: np.concatenate([ch[c] for ch in self.chunks]).astype(DTYPES[c], copy=False)
                              for c in COLUMNS})

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
            out = {c: np.empty(int(frames.sum()), dtype=DTYPES[c]) for c in COLUMNS}
            for layout, of_kind in layouts:
                cols = self._read(data, u8, at[of_kind], layout)
                where = of_kind[frames]
                for c in COLUMNS:
                    out[c][where] = cols[c]
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
        return _columns(layout, raw, self.start_timestamp)


def read_blf_columns(reader: blf.BLFReader) -> FrameArrays:
    """The columns of an open python-can BLFReader's file, read to its end (the reader is not closed).

    Raises ``NotFast`` where python-can would warn or the file has no frame, and whatever the data
    makes python-can's struct/zlib code raise; ``read_columns`` turns both into python-can's result.
    """
    return BlfColumnReader(reader).read()


def _is_blf(path: str | pathlib.Path) -> bool:
    if str(path) == STDIN:
        return False
    suffixes = [s.lower() for s in pathlib.Path(path).suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    return bool(suffixes) and suffixes[-1] == ".blf"


def read_trace_columns(path: str | pathlib.Path) -> tuple[FrameArrays, Trace]:
    """The columns of a trace, and its ``Trace`` (for ``skipped``/``name``, as after iterating it).

    Equal to ``frame_arrays(open_trace(path))``; raises the same ``TraceError``."""
    trace = open_trace(path)
    if _is_blf(path) and isinstance(trace.reader, blf.BLFReader):
        try:
            arrays = read_blf_columns(trace.reader)
        except Exception:  # NotFast, or a broken file: python-can's reader gives the result or the error
            arrays = None
        finally:
            trace.close()
        if arrays is not None:
            trace.count = len(arrays)
            return arrays, trace
        trace = open_trace(path)
    return frame_arrays(trace), trace


def read_columns(path: str | pathlib.Path) -> FrameArrays:
    """``frame_arrays(open_trace(path))``, fast for BLF files (see the module docstring)."""
    return read_trace_columns(path)[0]
