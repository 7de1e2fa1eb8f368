"""MF4 (ASAM MDF 4 bus logging): writing, reading the frames and decoding the signals, railhil against
python-can's MF4 reader and writer and against asammdf's own reading, on the same files, in one run.

The frames: the first 200,000 of bench_trace's synthetic bus (dbc/train_brake.dbc, 8 cars, every cyclic
message at its cycle time with jitter), written as MF4 by railhil's batched writer
(hil.trace.writers.Mf4Writer).  The figures:

(a) writing: railhil's Mf4Writer against python-can's MF4Writer (one asammdf append per frame; timed
    on its first 5,000 frames, it takes about 0.6 ms a frame);
(b) reading the frames into columns: ``hil.trace.columns.read_columns`` (each CAN channel group in one
    asammdf call) against python-can's ``can.LogReader`` + ``frame_arrays`` (a Message per frame; the
    columns are checked equal) and against asammdf's own reading of the frame records
    (``MDF(path).get("CAN_DataFrame")``, the structured records and their timestamps, no columns made);
(c) decoding every signal with the DBC: ``hil.trace.decoded.DecodedTrace`` (every message's table)
    against asammdf's own bus-logging extraction (``MDF.extract_bus_logging`` with the DBC).

    python bench/bench_mf4.py
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import can
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_trace import DBC, best, rate, synthesise  # noqa: E402

from hil.can.codec import Codec  # noqa: E402
from hil.can.dbc import load_dbc  # noqa: E402
from hil.trace.columns import read_columns  # noqa: E402
from hil.trace.decoded import DecodedTrace  # noqa: E402
from hil.trace.readers import open_trace  # noqa: E402
from hil.trace.timing import frame_arrays  # noqa: E402
from hil.trace.writers import Mf4Writer  # noqa: E402

FRAMES = 200_000
PYTHON_CAN_WRITE_FRAMES = 5_000


def _messages(t, ids, payloads, n=None):
    return [can.Message(timestamp=ts, arbitration_id=arb, is_extended_id=False, data=data, channel=0)
            for ts, arb, data in list(zip(t.tolist(), ids.tolist(), payloads, strict=True))[:n]]


def _write(writer, messages) -> float:
    t0 = time.perf_counter()
    for m in messages:
        writer.on_message_received(m)
    writer.stop()
    return time.perf_counter() - t0


def _best(fn, repeat: int = 3) -> float:
    return best(fn, repeat)


def run() -> list[tuple[str, str]]:
    import asammdf

    rows = []
    t, ids, payloads = synthesise(FRAMES)
    messages = _messages(t, ids, payloads)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bus.mf4"
        w_ours = _write(Mf4Writer(str(path), start_time_s=0.0), messages)
        w_theirs = _write(can.io.MF4Writer(str(Path(tmp) / "pc.mf4")), messages[:PYTHON_CAN_WRITE_FRAMES])
        per_ours, per_theirs = w_ours / len(messages), w_theirs / PYTHON_CAN_WRITE_FRAMES
        rows.append(("(a) MF4 write 200k: railhil Mf4Writer", rate(len(messages), w_ours)))
        rows.append(("(a) MF4 write: python-can MF4Writer (first 5k frames)",
                     rate(PYTHON_CAN_WRITE_FRAMES, w_theirs)))
        rows.append(("(a) ratio railhil / python-can writer", f"{per_theirs / per_ours:.0f}x"))

        fast, slow = read_columns(path), frame_arrays(open_trace(path))
        assert all(np.array_equal(getattr(fast, f), getattr(slow, f)) for f in ("t", "arbitration_id", "dlc"))
        t_ours = _best(lambda: read_columns(path))
        t_pc = _best(lambda: frame_arrays(open_trace(path)), repeat=1)

        def asammdf_records():
            mdf = asammdf.MDF(str(path))
            sig = mdf.get("CAN_DataFrame")
            assert len(sig.samples) == len(messages)
            mdf.close()

        t_am = _best(asammdf_records)
        rows.append(("(b) MF4 200k to columns: railhil read_columns (best of 3)",
                     rate(len(messages), t_ours)))
        rows.append(("(b) MF4 200k: python-can LogReader + frame_arrays", rate(len(messages), t_pc)))
        rows.append(("(b) MF4 200k: asammdf get('CAN_DataFrame') records (best of 3)",
                     rate(len(messages), t_am)))
        rows.append(("(b) ratio railhil / python-can", f"{t_pc / t_ours:.1f}x"))
        rows.append(("(b) ratio railhil / asammdf's own reading", f"{t_am / t_ours:.2f}x"))

        db = load_dbc(DBC)
        codec = Codec(db)

        def ours_decode():
            decoded = DecodedTrace.read(path, db, codec)
            return sum(len(tb.columns) for tb in decoded.tables())

        def asammdf_decode():
            mdf = asammdf.MDF(str(path))
            out = mdf.extract_bus_logging({"CAN": [(str(DBC), 0)]})
            n = sum(len(g.channels) for g in out.groups)
            mdf.close()
            out.close()
            return n

        t_dec = _best(ours_decode)
        t_ext = _best(asammdf_decode, repeat=1)
        rows.append(("(c) MF4 200k decode every signal: railhil DecodedTrace (best of 3)",
                     rate(len(messages), t_dec)))
        rows.append(("(c) MF4 200k decode: asammdf extract_bus_logging with the DBC",
                     rate(len(messages), t_ext)))
        rows.append(("(c) ratio railhil / asammdf's own decoding", f"{t_ext / t_dec:.1f}x"))
    return rows


if __name__ == "__main__":
    for label, figure in run():
        print(f"{label:<66} {figure}")
