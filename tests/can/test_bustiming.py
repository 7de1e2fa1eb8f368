"""The bit-timed lockstep bus: frame lengths, CRC, stuffing, arbitration, transmit queues, overload."""

import can
import pytest
from conftest import DEFAULT
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.can.bustiming import (
    BitTimedBus,
    Pending,
    arbitration_key,
    crc15,
    exact_frame_bits,
    frame_duration_bits,
    stuff_bits,
)
from hil.report.run import run_scenario_lockstep
from hil.scenario import load_scenario

std_ids = st.integers(0, 0x7FF)
ext_ids = st.integers(0, 0x1FFFFFFF)
payloads = st.binary(min_size=0, max_size=8)


def reference_bits(frame_id: int, extended: bool, data: bytes) -> int:
    """The frame spelled out bit by bit as ISO 11898-1 draws it, stuffed the slow, obvious way."""
    def bits(value, n):
        return [(value >> i) & 1 for i in range(n - 1, -1, -1)]

    if extended:
        head = [0] + bits(frame_id >> 18, 11) + [1, 1] + bits(frame_id & 0x3FFFF, 18) + [0, 0, 0]
    else:
        head = [0] + bits(frame_id, 11) + [0, 0, 0]
    stream = head + bits(len(data), 4) + [b for byte in data for b in bits(byte, 8)]
    crc = 0
    for b in stream:                                        # CAN 2.0 spec §3.1.1 pseudocode
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    stream += bits(crc, 15)
    out, run, last = [], 0, None
    for b in stream:
        out.append(b)
        run = run + 1 if b == last else 1
        last = b
        if run == 5:
            out.append(1 - b)
            last, run = 1 - b, 1
    return len(out) + 13


def test_crc15_check_value_of_the_crc_catalogue():
    # CRC-15/CAN: width 15, poly 0x4599, init 0, check = 0x059E over ASCII "123456789"
    assert crc15(int.from_bytes(b"123456789", "big"), 72) == 0x059E


def test_all_zero_frame_by_hand():
    # id 0, DLC 0: SOF..DLC are 19 dominant bits and their CRC is 0, so 34 zeros -> a stuff bit after
    # every 5th (6 of them), + 13 unstuffed bits
    assert exact_frame_bits(0, False, b"") == 34 + 6 + 13


def test_davis_bounds_for_8_bytes_at_500k():
    bus = BitTimedBus(500_000, 1, "exact")
    assert bus.duration_ns(frame_duration_bits(0x123, False, bytes(8), "none")) == 222_000
    assert bus.duration_ns(frame_duration_bits(0x123, False, bytes(8), "worst")) == 270_000
    assert frame_duration_bits(0x123, True, bytes(8), "none") == 67 + 64
    assert frame_duration_bits(0x123, True, bytes(8), "worst") == 80 + 80


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.tuples(std_ids, st.just(False)), st.tuples(ext_ids, st.just(True))), payloads)
def test_exact_length_matches_the_bit_by_bit_reference_and_lies_within_davis(idx, data):
    frame_id, extended = idx
    bits = exact_frame_bits(frame_id, extended, data)
    assert bits == reference_bits(frame_id, extended, data)
    assert frame_duration_bits(frame_id, extended, data, "none") <= bits
    assert bits <= frame_duration_bits(frame_id, extended, data, "worst")
    if len(data) == 8 and not extended:
        assert 222_000 <= BitTimedBus(500_000, 1).duration_ns(bits) <= 270_000


@given(st.integers(0, (1 << 40) - 1), st.integers(1, 40))
def test_table_stuffing_equals_bitwise_stuffing(value, n):
    value &= (1 << n) - 1
    run, last, count = 0, None, 0
    for i in range(n - 1, -1, -1):
        b = (value >> i) & 1
        run = run + 1 if b == last else 1
        last = b
        if run == 5:
            count += 1
            last, run = 1 - b, 1
    assert stuff_bits(value, n) == count


def test_11_bit_frame_beats_29_bit_frame_with_the_same_base_id():
    assert arbitration_key(0x100, False) < arbitration_key(0x100 << 18, True)
    assert arbitration_key(0x0FF, False) < arbitration_key(0x100 << 18, True) < arbitration_key(0x101, False)


frames = st.lists(st.tuples(st.integers(0, 3), st.one_of(st.tuples(std_ids, st.just(False)),
                                                         st.tuples(ext_ids, st.just(True))),
                            st.integers(0, 2_000_000), payloads), min_size=1, max_size=40)


@settings(max_examples=200, deadline=None)
@given(frames)
def test_under_saturation_the_lowest_pending_identifier_always_wins(spec):
    """Frames released at random times onto a 125 kbit/s bus (saturated: up to 40 frames in 2 ms,
    about 5 ms of frames): every arbitration is won by the lowest arbitration field waiting in any
    node's queue at that instant, and the bus never idles while a frame waits."""
    bus = BitTimedBus(125_000, 4, "exact")
    releases = sorted((t, k, fid, ext, data) for k, (fid, ext), t, data in spec)
    waiting: dict[tuple, int] = {}          # (node, id, ext) -> key, mirroring the one-buffer rule
    i, now, sent = 0, 0, 0
    while i < len(releases) or bus.pending():
        if not bus.pending():
            now = max(now, releases[i][0])
        while i < len(releases) and releases[i][0] <= now:
            t, k, fid, ext, data = releases[i]
            bus.enqueue(Pending(k, fid, ext, data, t, t))
            waiting[(k, fid, ext)] = arbitration_key(fid, ext)
            i += 1
        lowest = min(waiting.values())
        frame, _, idle = bus.arbitrate(now)
        assert frame.key == lowest
        del waiting[(frame.node, frame.frame_id, frame.extended)]
        sent += 1
        now = idle
    overwritten = sum(s.overwritten for s in bus.stats.values())
    assert sent + overwritten == len(releases)


def test_a_newer_instance_overwrites_the_waiting_one_and_counts_a_deadline_miss():
    bus = BitTimedBus(500_000, 2, "worst", deadlines_ns={0x200: 1_000_000})
    bus.enqueue(Pending(0, 0x100, False, bytes(8), 0, 0))
    bus.arbitrate(0)                                          # 0x100 holds the bus for 270 us
    bus.enqueue(Pending(1, 0x200, False, b"\x01", 10_000, 10_000))
    bus.enqueue(Pending(1, 0x200, False, b"\x02", 20_000, 20_000))
    frame, deliver, idle = bus.arbitrate(270_000)
    assert frame.data == b"\x02" and not bus.pending()
    assert deliver == 270_000 + (55 + 10 - 3) * 2_000 and idle == 270_000 + 65 * 2_000
    s = bus.stats[0x200]
    assert (s.frames, s.overwritten, s.deadline_misses) == (1, 1, 1)
    assert s.response_max_ns == idle - 20_000 and s.queued_max_ns == 250_000


def test_arbitration_while_busy_is_refused():
    bus = BitTimedBus(500_000, 1)
    bus.enqueue(Pending(0, 0x100, False, bytes(8), 0, 0))
    bus.enqueue(Pending(0, 0x101, False, bytes(8), 0, 0))
    bus.arbitrate(0)
    with pytest.raises(ValueError, match="busy"):
        bus.arbitrate(1_000)


def _trace(path):
    with can.LogReader(str(path)) as reader:
        return [(m.timestamp, m.arbitration_id) for m in reader]


def test_lockstep_trace_is_serial_and_frames_arrive_after_their_length(tmp_path):
    """On the bit-timed bus no two frames overlap: successive trace timestamps are at least one
    frame length apart (every frame of the DBC has 8 bytes: 222 us at 500 kbit/s, 0 stuff bits)."""
    scenario = load_scenario(DEFAULT).model_copy(update={"max_duration_s": 1.0})
    report = run_scenario_lockstep(scenario, tmp_path / "run")
    rows = _trace(tmp_path / "run" / "trace.blf")
    gaps = [b[0] - a[0] for a, b in zip(rows, rows[1:], strict=False)]
    assert min(gaps) >= 222e-6 - 1e-9
    # PLANT sends its 6 sensor frames at the same instant: they leave in id order, one frame apart
    first = [fid for _, fid in rows if 0x101 <= fid <= 0x106][:6]
    assert first == sorted(first)
    assert report.kpis["bus"]["deadline_misses"] == 0
    assert 0.2 < report.kpis["bus"]["load"] < 0.5


def test_ideal_bus_delivers_at_send_time(tmp_path):
    scenario = load_scenario(DEFAULT).model_copy(update={"max_duration_s": 0.2})
    ideal = scenario.model_copy(update={"bus": scenario.bus.model_copy(update={"timing": "ideal"})})
    report = run_scenario_lockstep(ideal, tmp_path / "run")
    stamps = {round(t * 1e6) % 500 for t, _ in _trace(tmp_path / "run" / "trace.blf")}
    assert stamps == {0}                                  # every frame on its node's 0.5 ms phase grid
    assert report.kpis["frames_lost"] == 0 and "bus" not in report.kpis


def test_above_full_load_low_priorities_miss_deadlines_and_the_emergency_frame_gets_through(tmp_path):
    """The default scenario's frames at 62.5 kbit/s need ~290 % of the bus: the lowest-priority frames
    wait, are overwritten by their next instance and miss deadlines; the highest-priority frame
    (BCU_EMERGENCY, 0x010) still goes out every cycle."""
    scenario = load_scenario(DEFAULT).model_copy(update={"max_duration_s": 2.0})
    slow = scenario.model_copy(update={"bus": scenario.bus.model_copy(update={"bitrate": 62_500})})
    report = run_scenario_lockstep(slow, tmp_path / "run")
    bus = report.outcome.bus
    assert bus["load"] > 0.95
    msgs = bus["messages"]
    assert msgs["BCU_EMERGENCY"]["deadline_misses"] == 0
    assert msgs["BCU_EMERGENCY"]["frames"] >= 2.0 / 0.020 - 1
    assert report.kpis["bus"]["deadline_misses"] > 100
    assert report.kpis["frames_overwritten"] > 100
    served = [m["frame_id"] for m in msgs.values() if not m["overwritten"]]
    starved = [m["frame_id"] for m in msgs.values() if m["overwritten"]]
    assert starved and min(starved) > max(served)      # priority order decides who loses frames
    assert {0x010, 0x018, 0x028} <= set(served)


@settings(max_examples=100, deadline=None)
@given(st.one_of(st.tuples(std_ids, st.just(False)), st.tuples(ext_ids, st.just(True))),
       st.lists(payloads, min_size=1, max_size=6))
def test_the_bus_sizes_every_frame_of_an_id_as_the_bit_by_bit_reference(idx, datas):
    """The bus keeps one FrameBits per (id, format, length) and runs only the payload through it."""
    frame_id, extended = idx
    bus = BitTimedBus(500_000, 1, "exact")
    for data in datas:
        p = Pending(0, frame_id, extended, data, 0, 0)
        assert bus.frame_bits(p) == reference_bits(frame_id, extended, data)
