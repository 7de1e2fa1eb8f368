"""BlfWriter (hil.trace.writers): `write_frame` writes, byte for byte, the BLF file python-can's BLFWriter
writes for the same frames as can.Message objects (as the lockstep runner builds them), alone and mixed
with python-can's own path (remote, error, FD frames, markers), across many containers, with its
containers compressed in this thread or beside it; can.LogReader reads the frames back."""

from __future__ import annotations

import random
import struct
from pathlib import Path

import can
import pytest

from hil.trace.writers import BLF_BATCH, BlfWriter, Mf4Writer, open_writer

FRAMES = 20_000
UNIX_T0 = 1_700_000_000.123456      # s: wall-clock timestamps (the header holds a date)
THREADS = [0, 1, 2]                 # compress_threads: in the writing thread, beside it (one, two)


def frames(n: int, seed: int, t0: float = UNIX_T0) -> list[tuple]:
    """`n` data frames (timestamp_s, arbitration_id, is_extended_id, data): standard and extended ids,
    0..8 bytes, timestamps that repeat, step by ns to ms, and a few that go back before the first."""
    rng = random.Random(seed)
    rows, t = [], t0
    for _ in range(n):
        t += rng.choice((0.0, 1e-9, 2.5e-7, 1e-4, 1.234e-3, -3e-3 * (rng.random() < 0.01)))
        extended = rng.random() < 0.3
        arb_id = rng.randrange(1 << 29) if extended else rng.randrange(1 << 11)
        rows.append((t, arb_id, extended, rng.randbytes(rng.randrange(9))))
    return rows


def lockstep_frames(n: int, seed: int) -> list[tuple]:
    """Frames timed as the lockstep runner times them: integer ns from 0, then t_ns / 1e9."""
    rng = random.Random(seed)
    t_ns, rows = 0, []
    for _ in range(n):
        t_ns += rng.choice((0, 1_000, 250_000, 1_000_000, 10_000_000))
        rows.append((t_ns / 1e9, rng.randrange(0x800), False, rng.randbytes(rng.choice((0, 2, 8)))))
    return rows


def message(row: tuple) -> can.Message:
    """A frame as the lockstep runner hands it to python-can today (hil/runtime/lockstep.py)."""
    t, arb_id, extended, data = row
    return can.Message(timestamp=t, arbitration_id=arb_id, is_extended_id=extended, data=data,
                       dlc=len(data), channel=0, check=False)


def python_can(path: Path, items: list, **kwargs) -> bytes:
    """python-can's BLFWriter: every frame as a can.Message, markers as log_event."""
    with can.BLFWriter(str(path), **kwargs) as writer:
        for item in items:
            if isinstance(item, can.Message):
                writer.on_message_received(item)
            elif isinstance(item, str):
                writer.log_event(item, timestamp=UNIX_T0)
            else:
                writer.on_message_received(message(item))
    return path.read_bytes()


def railhil(path: Path, items: list, **kwargs) -> bytes:
    """BlfWriter: frames through write_frame, Messages through on_message_received, markers as log_event."""
    with BlfWriter(str(path), **kwargs) as writer:
        for item in items:
            if isinstance(item, can.Message):
                writer.on_message_received(item)
            elif isinstance(item, str):
                writer.log_event(item, timestamp=UNIX_T0)
            else:
                writer.write_frame(*item)
    return path.read_bytes()


def read_back(path: Path) -> list[tuple]:
    with can.LogReader(str(path)) as reader:
        return [(m.timestamp, m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.is_error_frame,
                 m.is_fd, m.dlc, bytes(m.data), m.channel) for m in reader]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> tuple[list[tuple], bytes]:
    rows = frames(FRAMES, seed=1)
    return rows, python_can(tmp_path_factory.mktemp("blf") / "python-can.blf", rows)


@pytest.mark.parametrize("threads", THREADS)
def test_frames_are_python_cans_file(reference, tmp_path, monkeypatch, threads):
    rows, expected = reference
    monkeypatch.setattr(BlfWriter, "_add_rows", None)   # in bulk: not python-can's path frame by frame
    assert len(expected) > 5 * can.io.BLFWriter.max_container_size // 4    # several containers
    assert railhil(tmp_path / "railhil.blf", rows, compress_threads=threads) == expected


@pytest.mark.parametrize("threads", [0, 1])
def test_lockstep_timestamps(tmp_path, threads):
    rows = lockstep_frames(3 * BLF_BATCH + 5, seed=2)
    assert railhil(tmp_path / "r.blf", rows, compress_threads=threads) == python_can(tmp_path / "p.blf", rows)


def test_log_reader_reads_the_frames_back(reference, tmp_path):
    rows, _ = reference
    path = tmp_path / "railhil.blf"
    railhil(path, rows, compress_threads=1)
    back = read_back(path)
    assert len(back) == len(rows)
    first_ms = int(rows[0][0] * 1000) / 1000      # python-can: times count from the first, to the ms below
    for (t, arb_id, extended, data), got in zip(rows, back, strict=True):
        assert got[1:] == (arb_id, extended, False, False, False, len(data), data, 0)
        assert got[0] == pytest.approx(max(t, first_ms), abs=1e-6)


def interleaved(n: int, seed: int) -> list:
    """Data frames with python-can's own path mixed in: remote, error, FD and data Messages, markers."""
    rng = random.Random(seed)
    items: list = []
    for row in frames(n, seed):
        items.append(row)
        r = rng.random()
        t = row[0]
        if r < 0.01:
            items.append(can.Message(timestamp=t, arbitration_id=row[1], is_extended_id=row[2],
                                     is_remote_frame=True, dlc=rng.randrange(9), channel=0))
        elif r < 0.02:
            items.append(can.Message(timestamp=t, is_error_frame=True, arbitration_id=0x20000004,
                                     is_extended_id=True, dlc=8, data=bytes(8), channel=0))
        elif r < 0.025:
            items.append(can.Message(timestamp=t, arbitration_id=0x18DAF110, is_extended_id=True, is_fd=True,
                                     bitrate_switch=True, data=rng.randbytes(64), channel=1))
        elif r < 0.03:
            items.append(message(row))             # a data frame the slow way, between fast ones
        elif r < 0.031:
            items.append(f"marker {len(items)}")
    return items


@pytest.mark.parametrize("threads", [0, 1])
def test_interleaved_keeps_the_order(tmp_path, threads):
    items = interleaved(FRAMES // 2, seed=3)
    assert sum(isinstance(i, can.Message) for i in items) > 200
    expected = python_can(tmp_path / "p.blf", items)
    assert railhil(tmp_path / "r.blf", items, compress_threads=threads) == expected
    back = read_back(tmp_path / "r.blf")
    assert back == read_back(tmp_path / "p.blf")
    assert sum(m[3] for m in back) and sum(m[4] for m in back) and sum(m[5] for m in back)


def test_a_message_first(tmp_path):
    """python-can's path sets the start timestamp; the kept frames count from it."""
    rows = frames(100, seed=4)
    items = [can.Message(timestamp=rows[0][0] - 2.5, arbitration_id=1, is_remote_frame=True, channel=0),
             *rows]
    assert railhil(tmp_path / "r.blf", items) == python_can(tmp_path / "p.blf", items)


def test_the_last_frame_not_the_latest(tmp_path):
    """python-can's header stops at the last frame's time, not the latest one's."""
    rows = frames(100, seed=10)
    rows.append((rows[-1][0] - 2.0, 0x7FF, False, b"late"))
    assert railhil(tmp_path / "r.blf", rows) == python_can(tmp_path / "p.blf", rows)


@pytest.mark.parametrize("threads", [0, 1])
def test_empty_file(tmp_path, threads):
    assert railhil(tmp_path / "r.blf", [], compress_threads=threads) == python_can(tmp_path / "p.blf", [])
    assert read_back(tmp_path / "r.blf") == []


@pytest.mark.parametrize("threads", THREADS)
@pytest.mark.parametrize("container", [1000, 48 * 20, 4096])   # bytes: not a multiple of 48, a multiple
def test_many_small_containers(tmp_path, threads, container):
    """Containers far smaller than a batch, cut across objects, and (48 × 20) ending on a boundary."""
    rows = frames(2000, seed=5)
    expected = python_can(tmp_path / "p.blf", rows, max_container_size=container)
    assert expected.count(b"LOBJ") >= 2000 * 48 // container
    ours = railhil(tmp_path / "r.blf", rows, compress_threads=threads, max_container_size=container)
    assert ours == expected


@pytest.mark.parametrize("level", [0, 1, 9])
def test_compression_levels(tmp_path, level):
    rows = frames(5000, seed=6)
    expected = python_can(tmp_path / "p.blf", rows, compression_level=level)
    for threads in (0, 1):
        assert railhil(tmp_path / f"r{threads}.blf", rows, compression_level=level,
                       compress_threads=threads) == expected


def test_data_is_copied(tmp_path):
    rows = frames(10, seed=7)
    with BlfWriter(str(tmp_path / "r.blf")) as writer:
        for t, arb_id, extended, data in rows:
            buffer = bytearray(data)
            writer.write_frame(t, arb_id, extended, buffer)
            buffer[:] = b"\xff" * len(buffer)          # the caller's buffer, reused
    assert (tmp_path / "r.blf").read_bytes() == python_can(tmp_path / "p.blf", rows)


def test_other_channels(tmp_path):
    rows = frames(300, seed=8)
    channels = [i % 3 for i in range(len(rows))]
    with BlfWriter(str(tmp_path / "r.blf")) as writer:
        for row, channel in zip(rows, channels, strict=True):
            writer.write_frame(*row, channel=channel)
    with can.BLFWriter(str(tmp_path / "p.blf")) as writer:
        for row, channel in zip(rows, channels, strict=True):
            msg = message(row)
            msg.channel = channel
            writer.on_message_received(msg)
    assert (tmp_path / "r.blf").read_bytes() == (tmp_path / "p.blf").read_bytes()
    assert [m[-1] for m in read_back(tmp_path / "r.blf")] == channels


@pytest.mark.parametrize("threads", [0, 1])
def test_a_frame_python_can_refuses(tmp_path, threads):
    """python-can's error for a frame it cannot write (here: an id of 33 bits), at the next flush; the
    frames before and after it are written, in order, as python-can writes them without it."""
    rows = frames(500, seed=9)
    writer = BlfWriter(str(tmp_path / "r.blf"), compress_threads=threads, max_container_size=1000)
    for i, row in enumerate(rows):
        writer.write_frame(*row)
        if i == 200:
            writer.write_frame(row[0], 1 << 33, False, b"")
    with pytest.raises(struct.error):
        writer.stop()
    writer.stop()
    assert (tmp_path / "r.blf").read_bytes() == python_can(tmp_path / "p.blf", rows, max_container_size=1000)


@pytest.mark.parametrize("name", ["trace.blf", "TRACE.BLF"])
def test_open_writer_blf(tmp_path, name):
    """A trace of simulated time (start 0.0) keeps its times, its first frame 0.5 s in included: python-can
    counts a BLF from its first frame's ms and stores no start before 1990, which would read 0.5 back as 0.0
    (a device's own bus in lockstep, whose first frame comes a few ms in, read back that early)."""
    with open_writer(tmp_path / name, start_time_s=0.0) as writer:
        assert isinstance(writer, BlfWriter) and callable(getattr(writer, "write_frame", None))
        writer.write_frame(0.5, 0x123, False, b"\x01\x02")
    assert read_back(tmp_path / name) == [(0.5, 0x123, False, False, False, False, 2, b"\x01\x02", 0)]


def test_open_writer_other_suffixes(tmp_path):
    for name, kind in (("t.asc", can.ASCWriter), ("t.log", can.CanutilsLogWriter), ("t.csv", can.CSVWriter)):
        writer = open_writer(tmp_path / name)
        try:
            assert not isinstance(writer, BlfWriter) and getattr(writer, "write_frame", None) is None
            assert isinstance(writer, kind)
        finally:
            writer.stop()
    pytest.importorskip("asammdf")
    writer = open_writer(tmp_path / "t.mf4", start_time_s=0.0)
    assert isinstance(writer, Mf4Writer)
    writer.stop()
