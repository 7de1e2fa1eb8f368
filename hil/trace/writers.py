"""Writing traces: python-can's writers, chosen by the file's suffix (.blf .mf4 .asc .log).

ASC and candump .log go through `can.Logger` as they are.

BLF goes through python-can's `BLFWriter` as `BlfWriter`, which adds `write_frame(timestamp_s,
arbitration_id, is_extended_id, data, channel=0)` for plain data frames, without a `can.Message`:

* **packed in bulk**: the frames are kept (in one flat list: no object a frame for the garbage
  collector) and packed `BLF_BATCH` at a time as one numpy array of CAN_MESSAGE objects (python-can's
  object header and `CAN_MSG_STRUCT`, python-can's timestamp arithmetic) into python-can's container
  buffer; the containers are cut from it as python-can's `_flush` cuts them.  Everything else
  (`on_message_received`, `log_event`) is python-can's own path, after the frames kept before it.
* **compressed beside the writer** (`compress_threads`, `open_writer`: `BLF_COMPRESS_THREADS`): zlib at
  python-can's level is most of what a frame costs once the Message is gone, so each 128 kB container
  is compressed by a thread while the writer goes on (zlib lets go of the GIL), and written in order.

The file is byte for byte the one python-can writes for the same frames as ``can.Message(timestamp=
timestamp_s, arbitration_id=..., is_extended_id=..., data=data, dlc=len(data), channel=channel,
check=False)`` (tests/trace/test_blf_writer.py; figures in bench/bench_trace.py).

MF4 (ASAM MDF 4 bus logging) goes through python-can's `MF4Writer` with two changes that a recording
of simulated time needs:

* **batched**: python-can's writer appends every frame to the file on its own (asammdf `MDF.extend`
  with one record), about 0.6 ms a frame — 30 s for the default run's 47,000 frames; `Mf4Writer` keeps
  the data frames and appends them in blocks of `BATCH` records through the same call, with the same
  record layout (python-can's `STD_DTYPE`).  Remote and error frames go through python-can's own path.
* **its epoch**: python-can stamps the file with the wall-clock time it was opened and stores every
  timestamp relative to it, so a lockstep trace (timestamps in simulated seconds from 0) came out with
  timestamps near -1.7e9 s (0.2 µs steps) and a new start time in every file.  `Mf4Writer` takes the
  epoch the timestamps count from (`start_time_s`; 0.0 for lockstep): the timestamps are stored as
  they are, and the same run writes the same file (the file history's time is the epoch too).

Every reader of python-can (can.LogReader) and asammdf reads the result as python-can's own file.
"""

from __future__ import annotations

import zlib
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from datetime import UTC, datetime
from pathlib import Path

import can
import numpy as np
from can.io import blf
from can.util import channel2int

MF4_SUFFIXES = (".mf4",)
BATCH = 4096                 # data frames per MDF.extend call (chosen: 4096 records ≈ 140 kB)
BLF_SUFFIXES = (".blf",)
BLF_BATCH = 4096             # data frames packed at once (chosen: 4096 objects ≈ 1.5 containers of 128 kB;
                             # any number writes the same file)
BLF_COMPRESS_THREADS = 1     # open_writer's: containers compressed beside the writing thread (0: in it)
BLF_IN_FLIGHT = 4            # containers being compressed at once, at most (4 × 128 kB)

# one CAN_MESSAGE object as python-can's BLFWriter lays it out: object header (base + version 1,
# timestamps in ns) then CAN_MSG_STRUCT (channel, flags, dlc, id, 8 data bytes); 48 bytes, no padding
_BLF_HEADER_SIZE = blf.OBJ_HEADER_BASE_STRUCT.size + blf.OBJ_HEADER_V1_STRUCT.size
_BLF_OBJECT_SIZE = _BLF_HEADER_SIZE + blf.CAN_MSG_STRUCT.size
_BLF_HEAD = (blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", _BLF_HEADER_SIZE, 1, _BLF_OBJECT_SIZE, blf.CAN_MESSAGE)
             + blf.OBJ_HEADER_V1_STRUCT.pack(blf.TIME_ONE_NANS, 0, 0, 0)[:-8])   # all but the timestamp
_BLF_OBJECT = np.dtype([("head", f"V{len(_BLF_HEAD)}"), ("timestamp", "<u8"), ("channel", "<u2"),
                        ("flags", "u1"), ("dlc", "u1"), ("id", "<u4"), ("data", "S8")])
assert _BLF_OBJECT.itemsize == _BLF_OBJECT_SIZE and _BLF_OBJECT_SIZE % 4 == 0
_BLF_ROW = 4                 # values kept a frame: timestamp_s, id (with the extended flag), data, channel
_BLF_CONTAINER_HEAD = blf.OBJ_HEADER_BASE_STRUCT.size + blf.LOG_CONTAINER_STRUCT.size


class BlfWriter(can.io.BLFWriter):
    """python-can's BLFWriter with `write_frame` for plain data frames, packed in bulk, and, with
    `compress_threads`, its containers compressed beside the writing thread (module docstring).

    The file is python-can's for the same frames as `can.Message`s, as long as `max_container_size` is
    no smaller than the largest object written (python-can's 128 kB always is)."""

    def __init__(self, file, *args, compress_threads: int = 0, **kwargs) -> None:
        self._rows: list = []        # flat: timestamp_s, id | python-can's extended flag, data, channel, ...
        self._compress_threads = compress_threads
        self._pool: ThreadPoolExecutor | None = None
        self._compressing: deque[tuple[int, Future]] = deque()   # (uncompressed size, zlib.compress)
        super().__init__(file, *args, **kwargs)

    def write_frame(self, timestamp_s: float, arbitration_id: int, is_extended_id: bool, data: bytes,
                    channel: int = 0) -> None:
        """A received data frame (not remote, not error, not FD), as python-can writes
        ``can.Message(timestamp=timestamp_s, arbitration_id=arbitration_id, is_extended_id=is_extended_id,
        data=data, dlc=len(data), channel=channel, check=False)``; in the file's order with every other
        write.  `data` is copied unless it is `bytes`.  A frame python-can could not write (an id that
        does not fit 32 bits, a non-finite timestamp, ...) raises python-can's error at the next flush."""
        if type(data) is not bytes:
            data = bytes(data)
        rows = self._rows            # flat, not a tuple a frame: nothing for the garbage collector to walk
        rows += (timestamp_s, arbitration_id | blf.CAN_MSG_EXT if is_extended_id else arbitration_id, data,
                 channel)
        if len(rows) >= _BLF_ROW * BLF_BATCH:
            self._pack_rows()

    def _pack_rows(self) -> None:
        """The kept frames into python-can's container buffer, as its `_add_object` would add them one by
        one: the same start/stop timestamps, object count, and a container written each time the buffer
        reaches `max_container_size` (`_flush`)."""
        rows, self._rows = self._rows, []
        if not rows:
            return
        t, ids, data, channels = (rows[i::_BLF_ROW] for i in range(_BLF_ROW))
        n = len(t)
        try:
            start = self.start_timestamp
            if start is None:
                start = int(t[0] * 1000) / 1000        # python-can's: the first timestamp, to the ms below
            stamps, arb_ids, chans = np.array(t), np.array(ids), np.array(channels)
            sizes = np.fromiter(map(len, data), np.int64, n)
        except (TypeError, ValueError, OverflowError):
            stamps = None                              # a timestamp python-can refuses too, a huge int, ...
        # anything but finite times and ints in their fields' ranges: python-can's arithmetic, one by one
        if (stamps is None or stamps.dtype.kind not in "if" or arb_ids.dtype.kind != "i"
                or chans.dtype.kind != "i" or self.max_container_size < _BLF_OBJECT_SIZE):
            self._add_rows(t, ids, data, channels)
            return
        offsets = (stamps - start) * 1e9
        chans = chans + 1                              # python-can's: interfaces count channels from 0
        if (not (np.isfinite(offsets).all() and offsets.max() < 2.0 ** 63) or arb_ids.min() < 0
                or arb_ids.max() > 0xFFFF_FFFF or sizes.max() > 0xFF or chans.min() < 0
                or chans.max() > 0xFFFF):
            self._add_rows(t, ids, data, channels)
            return
        objects = np.empty(n, _BLF_OBJECT)
        objects["head"] = np.void(_BLF_HEAD)
        objects["timestamp"] = np.maximum(offsets, 0.0).astype(np.int64)   # python-can: max(int(...), 0)
        objects["channel"] = chans
        objects["flags"] = 0                           # received, not remote
        objects["dlc"] = sizes
        objects["id"] = arb_ids
        objects["data"] = np.array(data, dtype="S8")   # zero-padded (and cut) to 8 bytes, as "8s" packs
        packed = objects.tobytes()
        self.start_timestamp = start
        self.stop_timestamp = t[-1]
        self.object_count += n
        self._buffer.append(packed)
        self._buffer_size += len(packed)
        while self._buffer_size >= self.max_container_size and not self.file.closed:
            self._flush()                              # python-can's: one container, the buffer's head

    def _add_rows(self, t: list, ids: list, data: list, channels: list) -> None:
        """Kept frames through python-can's own `on_message_received` arithmetic and `_add_object`."""
        for i, (timestamp, arb_id, payload, channel) in enumerate(zip(t, ids, data, channels, strict=True)):
            try:
                ch = channel2int(channel)
                ch = self.channel if ch is None else ch + 1
                super()._add_object(blf.CAN_MESSAGE, blf.CAN_MSG_STRUCT.pack(ch, 0, len(payload), arb_id,
                                                                             payload), timestamp)
            except BaseException:                      # the frames after the refused one stay, in order
                rest = zip(t[i + 1:], ids[i + 1:], data[i + 1:], channels[i + 1:], strict=True)
                self._rows[:0] = [x for row in rest for x in row]
                raise

    def _add_object(self, obj_type: int, data: bytes, timestamp: float | None = None) -> None:
        self._pack_rows()                              # every other object after the frames before it
        super()._add_object(obj_type, data, timestamp)

    def _flush(self) -> None:
        """python-can's `_flush`: the buffer's first `max_container_size` bytes as one container; with
        `compress_threads`, compressed by a thread beside this one and written, in order, when done."""
        if not (self._compress_threads and self.compression_level):
            self._write_compressed(wait=True)
            super()._flush()
            return
        if self.file.closed:
            return
        buffer = b"".join(self._buffer)
        if not buffer:
            return
        size = self.max_container_size
        chunk = buffer[:size]
        self._buffer = [buffer[size:]]
        self._buffer_size = len(buffer) - len(chunk)
        self.uncompressed_size += _BLF_CONTAINER_HEAD + len(chunk)
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self._compress_threads, thread_name_prefix="railhil-blf")
        compressed = self._pool.submit(zlib.compress, chunk, self.compression_level)
        self._compressing.append((len(chunk), compressed))
        self._write_compressed(wait=False)

    def _write_compressed(self, wait: bool) -> None:
        """The compressed containers that are done, in order (`wait`: all of them), as python-can writes
        one; the oldest waited for while more than `BLF_IN_FLIGHT` are being compressed."""
        pending = self._compressing
        while pending and (wait or len(pending) > BLF_IN_FLIGHT or pending[0][1].done()):
            size, compressed = pending.popleft()
            data = compressed.result()
            obj_size = _BLF_CONTAINER_HEAD + len(data)
            self.file.write(blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", blf.OBJ_HEADER_BASE_STRUCT.size, 1,
                                                            obj_size, blf.LOG_CONTAINER))
            self.file.write(blf.LOG_CONTAINER_STRUCT.pack(blf.ZLIB_DEFLATE, size))
            self.file.write(data)
            self.file.write(b"\x00" * (obj_size % 4))  # python-can's padding

    def file_size(self) -> int:
        kept = _BLF_OBJECT_SIZE * len(self._rows) // _BLF_ROW + sum(size for size, _ in self._compressing)
        return super().file_size() + kept

    def stop(self) -> None:
        self._pack_rows()            # python-can's error for a frame it refuses: the writer stays open
        self._flush()
        try:
            self._write_compressed(wait=True)
        finally:
            if self._pool is not None:
                self._pool.shutdown()
                self._pool = None
        super().stop()                                 # the header, now that every container is written


class Mf4Writer(can.io.MF4Writer):
    """python-can's MF4Writer, batched and with a given epoch (module docstring)."""

    def __init__(self, file, start_time_s: float | None = None, **kwargs) -> None:
        super().__init__(file, **kwargs)
        self._epoch_ns = None if start_time_s is None else round(start_time_s * 1e9)
        if start_time_s is not None:
            self._mdf.header.start_time = datetime.fromtimestamp(start_time_s, UTC)
            self.last_timestamp = self._start_time = start_time_s
        self._rows: list[tuple] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_remote_frame or msg.is_error_frame or msg.is_fd:
            self._flush()                         # python-can's own path for these (rare) frames
            super().on_message_received(msg)
            return
        timestamp = msg.timestamp
        if timestamp is None:
            timestamp = self.last_timestamp
        else:
            self.last_timestamp = max(self.last_timestamp, timestamp)
        channel = can.io.mf4.channel2int(msg.channel)
        self._rows.append((timestamp - self._start_time, 0 if channel is None else channel,
                           msg.arbitration_id, int(msg.is_extended_id), 0 if msg.is_rx else 1, msg.dlc,
                           bytes(msg.data)))
        if len(self._rows) >= BATCH:
            self._flush()

    def _flush(self) -> None:
        if not self._rows:
            return
        rows, self._rows = self._rows, []
        records = np.zeros(len(rows), dtype=can.io.mf4.STD_DTYPE)
        t, channel, ident, ide, direction, dlc, data = zip(*rows, strict=True)
        records["CAN_DataFrame.BusChannel"] = channel
        records["CAN_DataFrame.ID"] = ident
        records["CAN_DataFrame.IDE"] = ide
        records["CAN_DataFrame.Dir"] = direction
        records["CAN_DataFrame.DLC"] = dlc
        sizes = np.fromiter((len(d) for d in data), dtype=np.int64, count=len(data))
        records["CAN_DataFrame.DataLength"] = sizes
        width = records["CAN_DataFrame.DataBytes"].shape[1]
        payload = np.zeros((len(data), width), dtype=np.uint8)
        flat = np.frombuffer(b"".join(data), dtype=np.uint8)
        rows_idx = np.repeat(np.arange(len(data)), sizes)
        cols_idx = np.arange(flat.size) - np.repeat(np.cumsum(sizes) - sizes, sizes)
        payload[rows_idx, cols_idx] = flat
        records["CAN_DataFrame.DataBytes"] = payload
        self._mdf.extend(0, [(np.asarray(t, dtype="<f8"), None), (records, None)])

    def stop(self) -> None:
        self._flush()
        if self._epoch_ns is None:
            super().stop()
            return
        # python-can's stop() saves with a file-history entry stamped "now": the same save here, with the
        # entry stamped with the epoch, then what MF4Writer.stop does after its save
        from asammdf.blocks.v4_blocks import FileHistory

        entry = FileHistory()
        entry.comment = ("<FHcomment>\n    <TX>created</TX>\n    <tool_id>railhil</tool_id>\n"
                         "    <tool_vendor>railhil</tool_vendor>\n</FHcomment>")
        entry.abs_time = self._epoch_ns
        self._mdf.file_history.append(entry)
        self._mdf.save(self.file, compression=self._compression_level, add_history_block=False)
        self._mdf.close()
        super(can.io.MF4Writer, self).stop()          # BinaryIOMessageWriter: closes the file


def open_writer(path: str | Path, start_time_s: float | None = None) -> can.Listener:
    """A trace writer for `path`, by its suffix (python-can's choice; MF4: `Mf4Writer`; BLF: `BlfWriter`,
    which has `write_frame`).  `start_time_s`: the epoch of the frames' timestamps (0.0 for a lockstep
    run's simulated time; None: python-can's default, the time the file is opened, for wall-clock
    timestamps; a BLF file then counts from its first frame's ms, as python-can's does)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in MF4_SUFFIXES:
        return Mf4Writer(str(path), start_time_s=start_time_s)
    if suffix in BLF_SUFFIXES:
        writer = BlfWriter(str(path), compress_threads=BLF_COMPRESS_THREADS)
        if start_time_s is not None:
            # the file's start at the epoch (to the ms below, as python-can's): python-can counts a BLF from
            # its first frame's ms and stores no start before 1990, so a trace of simulated time whose
            # first frame comes after 1 ms would read back that many ms early
            writer.start_timestamp = int(start_time_s * 1000) / 1000
        return writer
    return can.Logger(str(path))
