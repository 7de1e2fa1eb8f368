"""Writing traces: python-can's writers, chosen by the file's suffix (.blf .mf4 .asc .log).

BLF, ASC and candump .log go through `can.Logger` as they are.  MF4 (ASAM MDF 4 bus logging) goes
through python-can's `MF4Writer` with two changes that a recording of simulated time needs:

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

from datetime import UTC, datetime
from pathlib import Path

import can
import numpy as np

MF4_SUFFIXES = (".mf4",)
BATCH = 4096                 # data frames per MDF.extend call (chosen: 4096 records ≈ 140 kB)


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
    """A trace writer for `path`, by its suffix (python-can's choice; MF4: `Mf4Writer`).  `start_time_s`:
    the epoch of the frames' timestamps (0.0 for a lockstep run's simulated time; None: python-can's
    default, the time the file is opened, for wall-clock timestamps)."""
    path = Path(path)
    if path.suffix.lower() in MF4_SUFFIXES:
        return Mf4Writer(str(path), start_time_s=start_time_s)
    return can.Logger(str(path))
