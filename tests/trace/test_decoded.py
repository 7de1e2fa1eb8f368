"""hil.trace.decoded.DecodedTrace decodes a message's frames all at once with numpy where the codec takes
the shift-and-mask path: its values equal the codec's (cantools' own, tests/can/test_codec.py) frame by
frame, bit for bit, on every message of every corpus DBC and of dbc/train_brake.dbc — random payloads,
frames shorter than their message, longer ones — and its undecodable count is the codec's FrameErrors.

The corpus lives outside the repository; RAILHIL_CORPUS points to it (default ../shared/corpus).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import CORPUS

from hil.can.codec import Codec, FrameError
from hil.can.dbc import load_dbc
from hil.errors import DbcError
from hil.trace.columns import FrameBlock
from hil.trace.decoded import DecodedTrace

ROOT = Path(__file__).resolve().parents[2]


def dbcs() -> list:
    out = [pytest.param(ROOT / "dbc" / "train_brake.dbc", id="train_brake.dbc")]
    for p in sorted(CORPUS.rglob("*.dbc")) if CORPUS.is_dir() else []:
        try:
            load_dbc(p)
        except DbcError:        # cantools rejects it (tesla_can, vw_mqb): nothing to decode with
            continue
        out.append(pytest.param(p, id=str(p.relative_to(CORPUS))))
    return out


def random_frames(db, rng: np.random.Generator, per_message: int = 300) -> FrameBlock:
    """Random payloads of every message: mostly its own length, some shorter (they fail to decode),
    some longer; all-zero and all-one payloads among them (the extremes of every signal)."""
    ids, ext, lengths, payloads = [], [], [], []
    width = max([m.length for m in db.messages] + [8]) + 4
    for m in db.messages:
        n = per_message
        length = np.full(n, m.length)
        length[: n // 10] = rng.integers(0, max(m.length, 1), n // 10)          # short
        length[n // 10: n // 5] = np.minimum(m.length + rng.integers(1, 5, n // 10), width)   # long
        data = rng.integers(0, 256, (n, width), dtype=np.uint8)
        data[-1], data[-2] = 0, 255
        length[-2:] = m.length
        data[np.arange(width)[None, :] >= length[:, None]] = 0
        ids.append(np.full(n, m.frame_id))
        ext.append(np.full(n, bool(m.is_extended_frame)))
        lengths.append(length)
        payloads.append(data)
    n = sum(len(i) for i in ids)
    z = np.zeros(n, dtype=bool)
    length = np.concatenate(lengths)
    return FrameBlock(np.arange(n) * 1e-3, np.concatenate(ids).astype(np.int64), np.concatenate(ext), z,
                      z.copy(), length.astype(np.int64), length.astype(np.int64), np.concatenate(payloads))


@pytest.mark.parametrize("dbc", dbcs())
def test_decoded_tables_equal_the_codec_frame_by_frame(dbc):
    db = load_dbc(dbc)
    codec = Codec(db)
    frames = random_frames(db, np.random.default_rng(20))
    decoded = DecodedTrace(dbc, db, frames, codec)
    failed = 0
    columnar = 0
    for m in db.messages:
        if m.is_container:
            continue
        table = decoded.table(m.name)
        fc = codec[m.frame_id]
        columnar += fc.fallback_reason is None
        rows = np.flatnonzero(frames.arbitration_id == m.frame_id)
        expected: dict[str, list[float]] = {s.name: [] for s in m.signals}
        times = []
        for i in rows.tolist():
            try:
                values = fc.decode(frames.payload[i, : frames.length[i]].tobytes())
            except FrameError:
                failed += 1
                continue
            times.append(frames.t[i])
            for s in m.signals:
                expected[s.name].append(values.get(s.name, np.nan))
        assert np.array_equal(table.t, times), m.name
        for name, want in expected.items():
            got = table.columns[name]
            assert got.dtype == np.float64
            assert np.array_equal(got.view(np.int64), np.asarray(want, dtype=np.float64).view(np.int64)) \
                or np.array_equal(got, want, equal_nan=True), f"{m.name}.{name}"
    assert decoded.undecodable == failed
    if dbc.name == "train_brake.dbc":
        assert columnar == len(db.messages)              # the train's messages all take the numpy path
