"""hil.trace.columns: ``read_columns(p)`` equals ``frame_arrays(open_trace(p))`` column by column, on
every BLF of the corpus, on BLFs written by python-can's BLFWriter (standard, extended, remote, error
and CAN FD frames, objects split across containers, padded objects, v2 object headers, 10 µs
timestamps), and gives the same one-line TraceError on a broken file.

The corpus lives outside the repository; RAILHIL_CORPUS points to it (default ../shared/corpus).
"""

from __future__ import annotations

import io
import sys
from pathlib import Path

import can
import numpy as np
import pytest
from can.io import blf
from conftest import CORPUS
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.trace.columns import (
    BATCH_BYTES,
    BLOCK_FRAMES,
    BlfColumnReader,
    BlockReader,
    NotFast,
    parse_candump,
    read_blf_columns,
    read_columns,
    read_trace_columns,
)
from hil.trace.readers import CandumpReader, TraceError, open_trace
from hil.trace.timing import FrameArrays, frame_arrays

CORPUS_BLFS = sorted(p for p in (CORPUS.rglob("*") if CORPUS.is_dir() else ())
                     if p.is_file() and p.name.lower().endswith((".blf", ".blf.gz")))
NO_CORPUS = f"no BLF in a trace corpus at {CORPUS} (set RAILHIL_CORPUS)"
BLF_PARAMS = [pytest.param(p, id=str(p.relative_to(CORPUS))) for p in CORPUS_BLFS] or [
    pytest.param(None, marks=pytest.mark.skip(reason=NO_CORPUS))]
COLUMNS = ("t", "arbitration_id", "extended", "dlc", "kind", "fd")


def assert_same(ours: FrameArrays, theirs: FrameArrays) -> None:
    for c in COLUMNS:
        a, b = getattr(ours, c), getattr(theirs, c)
        assert a.dtype == b.dtype, (c, a.dtype, b.dtype)
        assert a.shape == b.shape, (c, a.shape, b.shape)
        assert np.array_equal(a, b), (c, a[a != b][:5], b[a != b][:5])


def generic(path) -> FrameArrays:
    return frame_arrays(open_trace(path))


def fast(path, batch_bytes: int = BATCH_BYTES) -> BlfColumnReader:
    """The fast path itself, read to the end (must not decline): the reader with its counters.

    With `batch_bytes` 1 every container payload is read on its own after the tail of the one before,
    exactly as python-can does; by default several are joined first."""
    reader = can.BLFReader(str(path))
    try:
        columns = BlfColumnReader(reader, batch_bytes)
        columns.arrays = columns.read()
    finally:
        reader.stop()
    return columns


def fast_both(path) -> BlfColumnReader:
    """The fast path, container by container and batched: equal columns; the batched reader."""
    one_by_one = fast(path, 1).arrays
    batched = fast(path)
    assert_same(batched.arrays, one_by_one)
    return batched


def read_both(path) -> None:
    """read_columns and the generic path agree: equal columns, or the same TraceError message."""
    try:
        theirs = generic(path)
    except TraceError as exc:
        with pytest.raises(TraceError) as ours:
            read_columns(path)
        assert str(ours.value) == str(exc)
        assert len(str(exc).splitlines()) == 1 and str(exc).startswith(str(path))
        return
    assert_same(read_columns(path), theirs)


def add_object(writer: can.BLFWriter, obj_type: int, body: bytes, timestamp: float, version: int = 1,
               time_flags: int = blf.TIME_ONE_NANS) -> None:
    """An object appended to the writer's container buffer as BLFWriter._add_object does, with the
    object header version and timestamp unit chosen (python-can's writer only writes v1, in ns)."""
    if writer.start_timestamp is None:
        writer.start_timestamp = int(timestamp * 1000) / 1000
    writer.stop_timestamp = timestamp
    unit = 1e5 if time_flags == blf.TIME_TEN_MICS else 1e9
    ticks = max(int((timestamp - writer.start_timestamp) * unit), 0)
    if version == 1:
        header = blf.OBJ_HEADER_V1_STRUCT.pack(time_flags, 0, 0, ticks)
    else:
        header = blf.OBJ_HEADER_V2_STRUCT.pack(time_flags, 0, 0, ticks)
    header_size = blf.OBJ_HEADER_BASE_STRUCT.size + len(header)
    obj_size = header_size + len(body)
    writer._buffer += [blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", header_size, version, obj_size, obj_type),
                       header, body, b"\x00" * (len(body) % 4)]
    writer._buffer_size += obj_size + len(body) % 4
    writer.object_count += 1
    if writer._buffer_size >= writer.max_container_size:
        writer._flush()


def can_message2(arb: int, ext: bool, dlc: int, remote: bool = False, extra: int = 0) -> bytes:
    """A CAN_MESSAGE2 body (python-can reads its first CAN_MSG_STRUCT bytes), `extra` bytes longer."""
    flags = blf.REMOTE_FLAG if remote else 0
    ident = arb | (blf.CAN_MSG_EXT if ext else 0)
    return blf.CAN_MSG_STRUCT.pack(1, flags, dlc, ident, bytes(8)) + bytes(extra)


# --- frames as python-can writes them ------------------------------------------------------------

frame = st.one_of(
    st.builds(lambda i, d: dict(arbitration_id=i, dlc=d, data=bytes(d)),
              st.integers(0, 0x7FF), st.integers(0, 8)),
    st.builds(lambda i, d: dict(arbitration_id=i, is_extended_id=True, dlc=d, data=bytes(d)),
              st.integers(0, 0x1FFFFFFF), st.integers(0, 8)),
    st.builds(lambda i, d, e: dict(arbitration_id=i, is_extended_id=e, is_remote_frame=True, dlc=d),
              st.integers(0, 0x7FF), st.integers(0, 8), st.booleans()),
    st.builds(lambda i, e: dict(arbitration_id=i, is_extended_id=e, is_error_frame=True, dlc=8,
                                data=bytes(8)),
              st.integers(0, 0x7FF), st.booleans()),
    st.builds(lambda i, n, b, e, r: dict(arbitration_id=i, is_fd=True, bitrate_switch=b,
                                         error_state_indicator=e, is_remote_frame=r, dlc=n, data=bytes(n)),
              st.integers(0, 0x7FF), st.sampled_from([0, 5, 8, 12, 16, 20, 24, 32, 48, 64]), st.booleans(),
              st.booleans(), st.booleans()),
)


def write_blf(path: Path, frames: list[dict], t0: float = 1_700_000_000.0, dt: float = 0.001,
              container: int = 128 * 1024, compression: int = -1) -> Path:
    with can.BLFWriter(str(path), max_container_size=container, compression_level=compression) as writer:
        for i, kw in enumerate(frames):
            writer.on_message_received(can.Message(timestamp=t0 + i * dt, **kw))
    return path


@pytest.mark.parametrize("path", BLF_PARAMS)
def test_every_corpus_blf(path):
    theirs = generic(path)
    assert len(theirs) > 0
    assert_same(fast_both(path).arrays, theirs)
    assert_same(read_columns(path), theirs)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=st.lists(frame, min_size=1, max_size=120),
       container=st.sampled_from([40, 100, 333, 4096, 131072]),
       compression=st.sampled_from([0, 1, -1]), t0=st.sampled_from([0.0, 12.5, 1_700_000_000.123456]),
       dt=st.sampled_from([0.0, 1e-6, 0.001, 0.37]))
def test_python_can_blfwriter_frames(tmp_path_factory, frames, container, compression, t0, dt):
    """Containers of 40 and 100 bytes split most objects in two; python-can's writer then loses the
    frames it still buffers at stop (it flushes one container only), as its reader shows."""
    path = write_blf(tmp_path_factory.mktemp("blf") / "t.blf", frames, t0, dt, container, compression)
    try:
        theirs = generic(path)
    except TraceError:  # every frame lost by the writer: "no CAN frames found"
        assert container < 128
        read_both(path)
        return
    kinds = [2 if f.get("is_error_frame") else 1 if f.get("is_remote_frame") else 0 for f in frames]
    assert list(theirs.kind) == kinds[:len(theirs)]
    assert len(theirs) == len(frames) or container < 128
    assert_same(fast_both(path).arrays, theirs)
    assert_same(read_columns(path), theirs)


def test_many_frames_across_container_boundaries(tmp_path):
    """20 000 frames, mostly of one type, broken by error, remote, FD and extended frames, some with
    'LOBJ' in their data (candidates the object chain must step over), in containers of 1000 bytes
    that split objects in two; read container by container and in batches."""
    frames = []
    for i in range(20_000):
        if i % 997 == 0:
            frames.append(dict(arbitration_id=0x55, is_error_frame=True, dlc=8, data=bytes(8)))
        elif i % 1499 == 0:
            frames.append(dict(arbitration_id=0x123, is_remote_frame=True, dlc=4))
        elif i % 2003 == 0:
            frames.append(dict(arbitration_id=0x7A0, is_fd=True, bitrate_switch=True, dlc=64,
                               data=b"LOBJ" * 16))
        elif i % 3001 == 0:
            frames.append(dict(arbitration_id=0x18FF0001, is_extended_id=True, dlc=8, data=bytes(8)))
        elif i % 101 == 0:
            frames.append(dict(arbitration_id=0x4C, dlc=8, data=b"xxLOBJ\x20\x00"[: 8]))
        else:
            frames.append(dict(arbitration_id=0x100 + i % 32, dlc=8, data=i.to_bytes(8, "little")))
    for compression in (0, -1):
        path = write_blf(tmp_path / f"many{compression}.blf", frames, container=1000, compression=compression)
        theirs = generic(path)
        assert len(theirs) == len(frames)
        single, batched = fast(path, 1), fast(path)
        assert_same(single.arrays, theirs)
        assert_same(batched.arrays, theirs)
        assert single.viewed > 10_000 and single.gathered > 100, (single.viewed, single.gathered)
        assert batched.gathered > 15_000 and batched.steps > 200, (batched.gathered, batched.steps)
        assert_same(read_columns(path), theirs)


def test_one_frame_type_is_read_through_views(tmp_path):
    frames = [dict(arbitration_id=i % 50, dlc=8, data=bytes(8)) for i in range(30_000)]
    path = write_blf(tmp_path / "uniform.blf", frames)
    reader = fast_both(path)
    assert reader.viewed == 30_000 and reader.gathered == 0
    assert_same(reader.arrays, generic(path))


@pytest.mark.parametrize("version", [1, 2])
@pytest.mark.parametrize("time_flags", [blf.TIME_ONE_NANS, blf.TIME_TEN_MICS])
@pytest.mark.parametrize("extra", [0, 1, 2, 3])
def test_padded_objects_v2_headers_and_10us_timestamps(tmp_path, version, time_flags, extra):
    """CAN_MESSAGE2 objects `extra` bytes longer than python-can's struct, so padded by `extra` bytes
    before the next 'LOBJ', with markers and other frame types between them."""
    path = tmp_path / "padded.blf"
    with can.BLFWriter(str(path), max_container_size=700) as writer:
        t = 50.0
        for i in range(600):
            t += 0.000731
            body = can_message2(0x200 + i % 3, i % 7 == 0, 8, i % 11 == 0, extra)
            add_object(writer, blf.CAN_MESSAGE2, body, t, version, time_flags)
            if i % 150 == 149:
                writer.log_event(f"marker {i}", t)  # GLOBAL_MARKER: python-can skips it
                writer.on_message_received(can.Message(timestamp=t, arbitration_id=0x7, is_error_frame=True))
    theirs = generic(path)
    assert len(theirs) == 604
    single = fast(path, 1)  # containers of about 13 objects: most of them equally spaced
    assert_same(single.arrays, theirs)
    assert single.viewed > 300
    assert_same(fast(path).arrays, theirs)
    assert_same(read_columns(path), theirs)


fd64 = st.tuples(st.integers(0, 15), st.integers(0, 0x1FFFFFFF) | st.integers(0x80000000, 0x9FFFFFFF),
                 st.integers(0, 0xFFFF), st.sampled_from([0, 8, 12, 64]), st.integers(0, 1))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(objects=st.lists(fd64, min_size=1, max_size=80), repeat=st.integers(1, 30),
       container=st.sampled_from([150, 1000, 131072]))
def test_can_fd_message_64_objects(tmp_path_factory, objects, repeat, container):
    """CAN_FD_MESSAGE_64 objects (python-can reads them, its writer does not write them): any DLC,
    11/29-bit ids, the remote/FD/BRS/ESI flag bits and others, data of several lengths (so objects of
    several sizes and paddings), each repeated `repeat` times (runs)."""
    path = tmp_path_factory.mktemp("fd64") / "fd64.blf"
    with can.BLFWriter(str(path), max_container_size=container) as writer:
        t = 3.25
        for dlc, arb, flags, length, direction in objects:
            body = blf.CAN_FD_MSG_64_STRUCT.pack(2, dlc, length, 0, arb, 0, flags, 0, 0, 0, 0, 0, direction,
                                                 0, 0) + bytes(range(length))
            for _ in range(repeat):
                t += 0.0001
                add_object(writer, blf.CAN_FD_MESSAGE_64, body, t)
    theirs = generic(path)
    assert len(theirs) == len(objects) * repeat
    assert_same(fast_both(path).arrays, theirs)


def test_timestamps_beyond_float_exact_integers(tmp_path):
    """Object timestamps of 2**53 ticks and more are converted with python-can's Decimal arithmetic."""
    path = tmp_path / "late.blf"
    with can.BLFWriter(str(path)) as writer:
        for i in range(40):
            add_object(writer, blf.CAN_MESSAGE, can_message2(0x10, False, 8), 0.0)
            writer._buffer[-3] = blf.OBJ_HEADER_V1_STRUCT.pack(blf.TIME_ONE_NANS, 0, 0, 2 ** 53 - 20 + 7 * i)
    theirs = generic(path)
    assert theirs.t.max() > 2 ** 53 / 1e9
    assert_same(fast_both(path).arrays, theirs)


def test_blf_gz(tmp_path):
    import gzip
    frames = [dict(arbitration_id=i % 50, dlc=8, data=bytes(8)) for i in range(3000)]
    plain = write_blf(tmp_path / "a.blf", frames)
    packed = tmp_path / "a.blf.gz"
    packed.write_bytes(gzip.compress(plain.read_bytes()))
    assert_same(read_columns(packed), generic(plain))
    assert_same(read_columns(packed), generic(packed))


# --- what the fast path leaves to python-can ------------------------------------------------------


def test_unknown_compression_method_falls_back_with_python_cans_warning_counted(tmp_path):
    # containers of 50 whole objects of 48 bytes: skipping one leaves the others readable
    path = write_blf(tmp_path / "c.blf", [dict(arbitration_id=1, dlc=8, data=bytes(8))] * 500, container=2400)
    raw = bytearray(path.read_bytes())
    first = blf.FILE_HEADER_SIZE + blf.OBJ_HEADER_BASE_STRUCT.size  # the first container's method
    raw[first:first + 2] = (7).to_bytes(2, "little")
    path.write_bytes(bytes(raw))
    with pytest.raises(NotFast):
        fast(path)
    trace = open_trace(path)
    theirs = frame_arrays(trace)
    assert trace.skipped == 1 and len(theirs) == 450
    ours, info = read_trace_columns(path)
    assert_same(ours, theirs)
    assert info.skipped == 1 and "compression" in info.first_skipped


@pytest.mark.parametrize("gap", range(9))
@pytest.mark.parametrize("compression", [0, -1])
def test_bytes_between_objects(tmp_path, gap, compression):
    """python-can finds the next object up to 4 bytes after the end of the last one, and fails on a
    longer gap (BLFParseError) unless the container ends there."""
    path = tmp_path / "gap.blf"
    with can.BLFWriter(str(path), compression_level=compression) as writer:
        for i in range(30):
            add_object(writer, blf.CAN_MESSAGE, can_message2(0x100 + i, False, 8), 1.0 + i / 100)
            if i == 14:
                writer._buffer.append(b"\x00" * gap)
                writer._buffer_size += gap
    read_both(path)
    if gap <= 4:
        assert_same(fast_both(path).arrays, generic(path))
    else:
        with pytest.raises(TraceError, match="BLFParseError: Could not find next object"):
            read_columns(path)


@pytest.mark.parametrize("short", [1, 4, 8])
@pytest.mark.parametrize("last", [False, True])
def test_objects_shorter_than_their_struct_are_left_to_python_can(tmp_path, short, last):
    """python-can reads such an object's fields from the bytes after it; as the last object of the
    data it fails to unpack it and drops it silently."""
    path = tmp_path / "short.blf"
    with can.BLFWriter(str(path)) as writer:
        for i in range(20):
            body = can_message2(0x100 + i, False, 8)
            if i == (19 if last else 7):
                body = body[:-short]
            add_object(writer, blf.CAN_MESSAGE, body, 1.0 + i / 100)
    with pytest.raises(NotFast):
        fast(path)
    if last and short % 4 == 0:  # no padding after it: nothing to read the missing bytes from
        assert len(generic(path)) == 19
    read_both(path)


def test_unknown_object_header_version_falls_back(tmp_path):
    path = tmp_path / "v3.blf"
    with can.BLFWriter(str(path)) as writer:
        for i in range(100):
            add_object(writer, blf.CAN_MESSAGE, can_message2(i, False, 8), 1.0 + i / 100, version=1)
        writer._buffer[-4] = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 32, 3, 48, blf.CAN_MESSAGE)
    with pytest.raises(NotFast):
        fast(path)
    theirs = generic(path)
    assert len(theirs) == 99
    assert_same(read_columns(path), theirs)


def test_other_formats_and_stdin_take_python_cans_reader(tmp_path, monkeypatch):
    frames = [can.Message(timestamp=10 + i / 7, arbitration_id=0x100 + i % 5, data=bytes([i % 256] * 8))
              for i in range(300)]
    for suffix in (".log", ".asc", ".csv", ".trc"):
        path = tmp_path / f"t{suffix}"
        with can.Logger(str(path)) as writer:
            for m in frames:
                writer.on_message_received(m)
        assert_same(read_columns(path), generic(path))
    text = (tmp_path / "t.log").read_text()
    monkeypatch.setattr(sys, "stdin", io.StringIO(text))
    ours = read_columns("-")
    monkeypatch.setattr(sys, "stdin", io.StringIO(text))
    assert_same(ours, generic("-"))
    assert len(ours) == 300


# --- broken files: python-can's error, as open_trace gives it -------------------------------------


def test_missing_empty_and_not_blf(tmp_path):
    for path in (tmp_path / "missing.blf", tmp_path / "dir.blf"):
        if path.name == "dir.blf":
            path.mkdir()
        with pytest.raises(TraceError) as exc:
            generic(path)
        with pytest.raises(TraceError) as ours:
            read_columns(path)
        assert str(ours.value) == str(exc.value) and str(path) in str(exc.value)
    empty = tmp_path / "empty.blf"
    empty.write_bytes(b"")
    read_both(empty)
    garbage = tmp_path / "garbage.blf"
    garbage.write_bytes(bytes(range(256)) * 8)
    read_both(garbage)
    header_only = write_blf(tmp_path / "header.blf", [])
    with pytest.raises(TraceError, match="no CAN frames found"):
        read_columns(header_only)
    read_both(header_only)


@pytest.mark.parametrize("compression", [0, -1])
def test_truncated_and_corrupt_blf(tmp_path, compression):
    frames = [dict(arbitration_id=0x100 + i % 9, dlc=8, data=bytes(8)) if i % 13 else
              dict(arbitration_id=0x18DA00F1, is_extended_id=True, is_fd=True, dlc=12, data=bytes(12))
              for i in range(400)]
    path = write_blf(tmp_path / "whole.blf", frames, container=600, compression=compression)
    raw = path.read_bytes()
    errors = 0
    cut = tmp_path / "cut.blf"
    for size in sorted({*range(0, len(raw), max(1, len(raw) // 41)), *range(len(raw) - 40, len(raw), 3)}):
        cut.write_bytes(raw[:size])
        read_both(cut)
        try:
            generic(cut)
        except TraceError:
            errors += 1
    assert errors > 0  # some cuts end inside an object header: python-can's struct.error, one line
    bad = tmp_path / "bad.blf"
    for at in range(blf.FILE_HEADER_SIZE + 16, len(raw), max(1, len(raw) // 29)):
        broken = bytearray(raw)
        broken[at:at + 4] = b"\xa5\x5a\xff\x00"
        bad.write_bytes(bytes(broken))
        read_both(bad)
    if compression == 0:  # an object's 'LOBJ' overwritten in an uncompressed container
        broken = bytearray(raw)
        at = raw.index(b"LOBJ", blf.FILE_HEADER_SIZE + 64)
        broken[at:at + 4] = b"XXXX"
        bad.write_bytes(bytes(broken))
        with pytest.raises(TraceError, match=r"not readable as a Vector BLF binary trace .*BLFParseError"):
            read_columns(bad)
        read_both(bad)


def test_read_blf_columns_does_not_close_the_reader(tmp_path):
    path = write_blf(tmp_path / "open.blf", [dict(arbitration_id=1, dlc=1, data=b"\x01")] * 10)
    reader = can.BLFReader(str(path))
    arrays = read_blf_columns(reader)
    assert not reader.file.closed and len(arrays) == 10
    reader.stop()


# --- hil.trace.readers.CandumpReader: python-can's candump -L reader, common lines by one regex ----------


def message_fields(m: can.Message) -> tuple:
    return (m.timestamp, m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.is_error_frame, m.channel,
            type(m.channel), m.dlc, bytes(m.data), type(m.data), m.is_fd, m.is_rx, m.bitrate_switch,
            m.error_state_indicator)


def python_can_outcome(reader_class, text: str) -> list:
    """The messages (as field tuples) a reader yields from `text`, then the exception it raised if any."""
    out = []
    try:
        for m in reader_class(io.StringIO(text)):
            out.append(message_fields(m))
    except Exception as exc:
        out.append((type(exc), str(exc)))
    return out


hexdata = st.binary(max_size=8).map(lambda b: b.hex())
candump_line = st.one_of(
    # the common line, in all its variants
    st.builds(lambda t, ch, i, ext, d, up, rx: f"({t:.6f}) {ch} {i:0{8 if ext else 3}X}#"
                                               f"{d.upper() if up else d}{rx}",
              st.floats(0, 2e9), st.sampled_from(["can0", "vcan1", "0", "12", "any_bus"]),
              st.integers(0, 0x1FFFFFFF), st.booleans(), hexdata, st.booleans(),
              st.sampled_from(["", " R", " T", " r", " t"])),
    # what python-can parses itself: remote, FD, error flag, odd spacing, odd lengths, garbage
    st.sampled_from([
        "(1.000001) can0 123#R", "(1.000001) can0 123#R5", "(1.5) can0 12345678#r", "(2.0) can1 123##1A0B",
        "(2.0) can1 123##3", "(3.25) can0 20000080#0000000000000000", "(3.25) can0 20000001#00",
        "(4.0)  can0  123#0A0B", "(4.0)\tcan0\t123#0A", "(4.0) can0 1#0A", "(4.0) can0 1234#0A",
        "(4.0) can0 123#ABC",
        "(4.0) can0 123#GG", "(5) can0 123#00", "(1e3) can0 123#00", "(4.0) can0 123#0A x", "", "   ",
        "hello world", "(4.0) can0 123", "(4.0) ٣ 123#00", "(٣.٣) can0 123#00", "(4.0) can0 123#+f",
    ]),
)


@settings(max_examples=300, deadline=None)
@given(lines=st.lists(candump_line, min_size=1, max_size=12), newline=st.sampled_from(["\n", "\r\n"]))
def test_candump_reader_equals_python_can(lines, newline):
    text = newline.join(lines) + newline
    assert python_can_outcome(CandumpReader, text) == python_can_outcome(can.CanutilsLogReader, text)


@pytest.mark.skipif(not CORPUS.is_dir(), reason=f"no trace corpus at {CORPUS} (set RAILHIL_CORPUS)")
def test_candump_reader_on_the_corpus_logs():
    logs = sorted(CORPUS.rglob("*.log"))
    assert logs
    for path in logs:
        text = path.read_text(errors="replace")
        ours = python_can_outcome(CandumpReader, text)
        assert ours == python_can_outcome(can.CanutilsLogReader, text), path


# --- FrameBlocks: frames with their data bytes, for `trace decode` (hil.trace.fastdecode) ----------------


def frame_fields(m: can.Message) -> tuple:
    """What `trace decode` reads of a frame."""
    return (m.timestamp, type(m.timestamp), m.arbitration_id, m.is_extended_id, m.is_remote_frame,
            m.is_error_frame, m.dlc, bytes(m.data))


def block_outcome(path, max_frames: int = BLOCK_FRAMES) -> tuple[list, str | None, int]:
    """The frames BlockReader gives (each row as python-can's Message of it), the TraceError it
    raised if any, and its trace's frame count; each block checked on the way."""
    out, error = [], None
    reader = BlockReader(path, max_frames)
    try:
        for block in reader:
            assert 0 < len(block) <= max_frames
            for c in ("arbitration_id", "extended", "remote", "error", "dlc", "length", "payload"):
                assert len(getattr(block, c)) == len(block), c
            assert (block.payload[np.arange(block.payload.shape[1]) >= block.length[:, None]] == 0).all()
            if block.stamps is not None:  # the trace's text of the timestamp, where it is format(t, '.6f')
                for stamp, t in zip(block.stamps.tolist(), block.t.tolist(), strict=True):
                    assert stamp == b"" or stamp.decode() == f"{t:.6f}", (stamp, t)
            out += [frame_fields(block.message(i)) for i in range(len(block))]
    except TraceError as exc:
        error = str(exc)
    return out, error, reader.trace.count


def python_can_block_outcome(path) -> tuple[list, str | None, int]:
    """The same through python-can's reader (open_trace, one Message at a time)."""
    out, error = [], None
    trace = open_trace(path)
    try:
        for m in trace:
            out.append(frame_fields(m))
    except TraceError as exc:
        error = str(exc)
    return out, error, trace.count


def assert_blocks_like_python_can(path, max_frames: int = BLOCK_FRAMES) -> list:
    theirs = python_can_block_outcome(path)
    assert block_outcome(path, max_frames) == theirs
    return theirs[0]


seconds_text = st.one_of(
    st.floats(0, 5e9).map(lambda t: f"{t:.6f}"),
    st.builds(lambda i, f: f"{i}.{f}", st.from_regex(r"[0-9]{1,12}", fullmatch=True),
              st.from_regex(r"[0-9]{1,10}", fullmatch=True)),
    st.sampled_from(["0.000000", "0.000050", "0.000100", "00012.500000", "0.5", "4000000000.000001",
                     "9007199254.740993", "99999999999999999999.5", "3999999999.999999"]),
)
common_line = st.builds(lambda t, ch, i, ext, d, rx: f"({t}) {ch} {i:0{8 if ext else 3}X}#{d}{rx}",
                        seconds_text, st.sampled_from(["can0", "vcan1", "0", "x_1"]),
                        st.integers(0, 0x1FFFFFFF), st.booleans(), st.binary(max_size=12).map(bytes.hex),
                        st.sampled_from(["", " R", " T"]))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(lines=st.lists(st.one_of(common_line, common_line, candump_line), min_size=1, max_size=40),
       newline=st.sampled_from(["\n", "\r\n"]), end=st.sampled_from(["", "\n"]),
       max_frames=st.sampled_from([1, 3, 7, BLOCK_FRAMES]))
def test_frame_blocks_of_candump_text_equal_python_can(tmp_path_factory, lines, newline, end, max_frames):
    """parse_candump takes the common lines in bulk, python-can's parser every other one: the same
    frames in the same order, the same TraceError at the same line after the same frames, whatever
    the batches; the timestamps' texts kept are exactly format(t, '.6f')."""
    path = tmp_path_factory.mktemp("log") / "t.log"
    path.write_bytes((newline.join(lines) + end).encode())
    assert_blocks_like_python_can(path, max_frames)


def test_parse_candump_takes_the_common_lines_only():
    text = ("(100.001394) can0 123#0102\n(1.5) can0 12345678#\n(0100.000001) c 7FF#AB R\n"
            "(2.0) can0 123#R\n(3.0)  can0 123#00\n(1.000000) can0 20000080#00\n(4.0) can0 123#0g\n\n"
            "(5.000000) ca-n 123#00\n(6.000000) can0 123#000\n")
    block, ok = parse_candump(text)
    assert ok.tolist() == [True, True, True] + [False] * 7
    assert block.t[:3].tolist() == [100.001394, 1.5, 100.000001]
    assert block.arbitration_id[:3].tolist() == [0x123, 0x12345678, 0x7FF]
    assert block.extended[:3].tolist() == [False, True, False]
    assert block.length[:3].tolist() == [2, 0, 1] and block.payload[0, :2].tolist() == [1, 2]
    assert block.stamps[:3].tolist() == [b"100.001394", b"", b""]  # 1.5: not 6 decimals; 0100: a leading 0


def test_frame_blocks_of_the_corpus_logs_and_traces():
    suffixes = (".log", ".asc", ".trc", ".blf", ".gz")
    traces = sorted(p for p in CORPUS.rglob("*") if p.is_file() and p.suffix.lower() in suffixes)
    if not traces:
        pytest.skip(NO_CORPUS)
    for path in traces:
        assert assert_blocks_like_python_can(path), path
        assert_blocks_like_python_can(path, 5)


def test_frame_blocks_after_a_byte_the_text_cannot_decode(tmp_path):
    """A byte that is not UTF-8 after 30 000 lines: the frames of the lines read before it, then the
    TraceError that iterating the trace raises, naming the same line after the same frames."""
    path = tmp_path / "bad.log"
    good = b"".join(b"(%d.%06d) can0 %03X#0011223344556677\n" % (i // 1000, i % 1000, i % 0x7FF)
                    for i in range(30_000))
    path.write_bytes(good + b"(31.000000) can0 123#\xff\xfe\n" + good[:4000])
    frames = assert_blocks_like_python_can(path, 4096)
    assert 25_000 < len(frames) <= 30_000


blf_frame = st.one_of(
    st.builds(lambda i, e, d: dict(arbitration_id=i, is_extended_id=e, dlc=len(d), data=d),
              st.integers(0, 0x7FF), st.booleans(), st.binary(max_size=8)),
    st.builds(lambda i, d, n: dict(arbitration_id=i, dlc=n, data=d[:8]),  # a DLC above the data
              st.integers(0, 0x7FF), st.binary(min_size=8, max_size=8), st.integers(9, 15)),
    st.builds(lambda i, n: dict(arbitration_id=i, is_remote_frame=True, dlc=n), st.integers(0, 0x7FF),
              st.integers(0, 8)),
    st.builds(lambda i, d: dict(arbitration_id=i, is_error_frame=True, dlc=len(d), data=d),
              st.integers(0, 0x7FF), st.binary(max_size=8)),
    st.builds(lambda i, d, r: dict(arbitration_id=i, is_fd=True, is_remote_frame=r, dlc=len(d), data=d),
              st.integers(0, 0x7FF), st.sampled_from([0, 5, 8, 12, 16, 20, 24, 32, 48, 64]).map(
                  lambda n: bytes(range(n))), st.booleans()),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=st.lists(blf_frame, min_size=1, max_size=80), container=st.sampled_from([100, 4096, 131072]),
       max_frames=st.sampled_from([2, BLOCK_FRAMES]))
def test_frame_blocks_of_blf_hold_python_cans_data(tmp_path_factory, frames, container, max_frames):
    """BLF read by BlfColumnReader with the data bytes: python-can's data of every frame (DLC above 8,
    remote frames without data, error frames with it, CAN FD)."""
    path = write_blf(tmp_path_factory.mktemp("blf") / "t.blf", frames, container=container)
    assert reads_fast(path) or container < 128  # python-can's writer may lose every frame (see above)
    assert_blocks_like_python_can(path, max_frames)


def reads_fast(path) -> bool:
    """Whether BlfColumnReader reads the file with the data bytes (else it leaves it to python-can)."""
    reader = can.BLFReader(str(path))
    try:
        return bool(BlfColumnReader(reader, payload=True).read_chunks())
    except NotFast:
        return False
    finally:
        reader.stop()


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(objects=st.lists(st.tuples(st.integers(0, 15), st.integers(0, 0x7FF), st.sampled_from([0, 8, 12, 64]),
                                  st.integers(0, 80), st.sampled_from([0, 0x10, 0x1000])),
                        min_size=1, max_size=30))
def test_frame_blocks_of_can_fd_message_64_objects(tmp_path_factory, objects):
    """CAN_FD_MESSAGE_64: the data after the struct, valid_bytes of it (zero-padded where the object
    holds fewer), none for a remote frame -- python-can's data."""
    path = tmp_path_factory.mktemp("fd64") / "fd64.blf"
    with can.BLFWriter(str(path)) as writer:
        for k, (dlc, arb, length, valid, flags) in enumerate(objects):
            body = blf.CAN_FD_MSG_64_STRUCT.pack(1, dlc, valid, 0, arb, 0, flags, 0, 0, 0, 0, 0, 0, 0, 0)
            add_object(writer, blf.CAN_FD_MESSAGE_64, body + bytes(range(1, length + 1)), 1.0 + k / 100)
    assert reads_fast(path)
    assert_blocks_like_python_can(path)
