"""A device's own frame protections: AUTOSAR E2E Profiles 5 and 11 (hil/can/e2e.py, computed by the PyPI
package autosar-e2e) and the plain counter/checksum (hil/can/checksums.py).  The library's published
vectors, round trips across the counter's wrap, what each protection detects, the receiver state machine
as keyword tables, hypothesis properties, a Node carrying them; and railhil's own Profile 1 and 2 CRCs
cross-checked against autosar-e2e's, an implementation railhil does not share a line with.

Every vector names its source.
"""

from __future__ import annotations

import random

import cantools
import e2e.p01 as autosar_p01  # the PyPI package autosar-e2e (top-level package "e2e"), not hil.can.e2e
import e2e.p02 as autosar_p02
import e2e.p11 as autosar_p11
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.can.checksums import CounterChecksumConfig, checksum_sum, checksum_xor
from hil.can.codec import Codec
from hil.can.e2e import (
    CheckState,
    DataIdMode,
    E2EConfigError,
    P01Config,
    P02Config,
    P05Config,
    P11Config,
    ProtectState,
    Status,
    check,
    protect,
)
from hil.errors import RailhilError
from hil.runtime.node import Binding, Node

S = Status
BOTH, NIBBLE = DataIdMode.BOTH, DataIdMode.NIBBLE


# --- autosar-e2e's published vectors ----------------------------------------------------------------
# autosar-e2e 1.0.0 as published on PyPI (sdist autosar_e2e-1.0.0.tar.gz, test/test_p05.py and
# test/test_p11.py; the P05 ones also in zariiii9003/autosar-e2e test/test_p05.py @ 4289fec7 with the
# older signature).  Its "offset" is in bytes, ours in bits; its "length" 0 means the whole buffer.

P05_VECTORS = [
    # (length, offset [bits], frames with counter 0, 1): data id 0x1234, zero payload
    (8, 0, ["1cca000000000000", "cf8d010000000000"]),
    (16, 64, ["0000000000000000" "2891000000000000", "0000000000000000" "fbd6010000000000"]),  # SOME/IP-like
]


def assert_library_vectors(config, length: int, frames: list[str]) -> None:
    """Protecting zero payloads gives the library's frames one by one, and checking them gives OK, OK."""
    sender, state, statuses = ProtectState(), CheckState(), []
    for frame in frames:
        assert protect(config, sender, bytes(length)).hex() == frame
        state, status = check(config, state, bytes.fromhex(frame))
        statuses.append(status)
    assert statuses == [S.OK, S.OK] and sender.counter == 2


@pytest.mark.parametrize(("length", "offset", "frames"), P05_VECTORS, ids=["short", "long"])
def test_p05_library_vectors(length, offset, frames):
    assert_library_vectors(P05Config(0x1234, length=length, offset=offset), length, frames)


@pytest.mark.parametrize(("length", "offset", "frame"), [
    (8, 0, "1cca010000000000"),                                  # the counter changed under the CRC
    (16, 64, "0000000000000000" "2891010000000000"),
])
def test_p05_library_bad_frames_are_errors(length, offset, frame):
    assert check(P05Config(0x1234, length=length, offset=offset), CheckState(), bytes.fromhex(frame))[1] \
        is S.ERROR


def test_p05_bytes_past_the_protected_length_are_kept_but_a_longer_frame_is_an_error():
    # the library's "length argument" vector: 10 bytes, 8 protected
    config = P05Config(0x1234, length=8)
    assert protect(config, ProtectState(), bytes(10)).hex() == "1cca0000000000000000"
    # its check accepts "1cca000000000000ff" (length=8 of 9 bytes); railhil's receivers want the exact length
    assert check(config, CheckState(), bytes.fromhex("1cca000000000000ff"))[1] is S.ERROR


P11_VECTORS = [
    # (mode, length, offset [bits], frames with counter 0, 1): data id 0x123, zero payload.  At offset 0
    # these are also the PRS's Profile 1 protocol examples (tests/can/test_e2e.py P01_EXAMPLES, BOTH and
    # NIBBLE)
    (BOTH, 8, 0, ["cc00000000000000", "9101000000000000"]),
    (NIBBLE, 8, 0, ["2a10000000000000", "7711000000000000"]),
    (NIBBLE, 16, 64, ["0000000000000000" "7d10000000000000", "0000000000000000" "2011000000000000"]),
]


@pytest.mark.parametrize(("mode", "length", "offset", "frames"), P11_VECTORS, ids=["both", "nibble", "long"])
def test_p11_library_vectors(mode, length, offset, frames):
    assert_library_vectors(P11Config(0x123, mode, length=length, offset=offset), length, frames)


@pytest.mark.parametrize(("mode", "length", "offset", "frame"), [
    (BOTH, 8, 0, "cc10000000000000"),                            # a data bit in the counter's byte
    (NIBBLE, 8, 0, "7721000000000000"),                          # data-id nibble 2, configured 1
    (NIBBLE, 16, 64, "0000000000000000" "7d11000000000000"),     # the counter changed under the CRC
])
def test_p11_library_bad_frames_are_errors(mode, length, offset, frame):
    assert check(P11Config(0x123, mode, length=length, offset=offset), CheckState(),
                 bytes.fromhex(frame))[1] is S.ERROR


def test_p11_wrong_data_id_nibble_with_a_right_crc_is_an_error():
    """In NIBBLE mode the CRC covers only the data id's low byte: a frame of data id 0x223 has a right
    CRC for a receiver of 0x123, and only the nibble check tells them apart (as PRS Profile 11 checks)."""
    frame = protect(P11Config(0x223, NIBBLE), ProtectState(), bytes(8))
    assert check(P11Config(0x223, NIBBLE), CheckState(), frame)[1] is S.OK
    assert check(P11Config(0x123, NIBBLE), CheckState(), frame)[1] is S.ERROR


def test_p11_counter_15_is_an_error_even_with_a_right_crc():
    frame = bytearray(8)
    frame[1] = 0x0F
    autosar_p11.e2e_p11_protect(frame, 0x123, increment_counter=False)   # a CRC over counter 15
    assert frame.hex() == "900f000000000000"
    assert check(P11Config(0x123), CheckState(), bytes(frame))[1] is S.ERROR


# --- railhil's Profile 1 and 2 against autosar-e2e ----------------------------------------------------
# Two implementations that share no code: railhil's (fastcrc, the data-id CRC precomputed) and
# autosar-e2e's (C, AUTOSAR's chained Crc_CalculateCRC8 calls).  autosar-e2e puts the P01 header at a
# byte offset k: CRC in byte k, counter in the low nibble of byte k+1, data-id nibble in its high nibble.

_AUTOSAR_P01_MODES = {DataIdMode.BOTH: autosar_p01.E2E_P01_DATAID_BOTH,
                      DataIdMode.ALT: autosar_p01.E2E_P01_DATAID_ALT,
                      DataIdMode.LOW: autosar_p01.E2E_P01_DATAID_LOW,
                      DataIdMode.NIBBLE: autosar_p01.E2E_P01_DATAID_NIBBLE}


@given(st.sampled_from(DataIdMode), st.integers(0, 0xFFFF), st.data())
@settings(max_examples=300, deadline=None)
def test_railhil_p01_equals_autosar_e2e(mode, data_id, data):
    data_id &= 0x0FFF if mode is NIBBLE else 0xFFFF
    length = data.draw(st.integers(2, 30))
    k = data.draw(st.integers(0, length - 2))
    counter = data.draw(st.integers(0, 14))
    payload = data.draw(st.binary(min_size=length, max_size=length))
    ours = protect(P01Config(data_id, mode, length=length, crc_offset=8 * k, counter_offset=8 * k + 8,
                             data_id_nibble_offset=8 * k + 12), ProtectState(counter), payload)
    theirs = bytearray(payload)
    theirs[k + 1] = (theirs[k + 1] & 0xF0) | counter
    autosar_p01.e2e_p01_protect(theirs, data_id, data_id_mode=_AUTOSAR_P01_MODES[mode], length=length,
                                offset=k, increment_counter=False)
    assert ours == bytes(theirs)
    assert autosar_p01.e2e_p01_check(bytearray(ours), data_id, data_id_mode=_AUTOSAR_P01_MODES[mode],
                                     length=length, offset=k)


@given(st.lists(st.integers(0, 255), min_size=16, max_size=16), st.integers(0, 15), st.data())
@settings(max_examples=300, deadline=None)
def test_railhil_p02_equals_autosar_e2e(ids, counter, data):
    length = data.draw(st.integers(2, 64))
    payload = data.draw(st.binary(min_size=length, max_size=length))
    # Profile 2's sender increments, then writes: the state before frame `counter` holds counter - 1
    ours = protect(P02Config(tuple(ids), length=length), ProtectState((counter - 1) % 16), payload)
    theirs = bytearray(payload)
    theirs[1] = (theirs[1] & 0xF0) | counter
    autosar_p02.e2e_p02_protect(theirs, bytes(ids), length=length, increment_counter=False)
    assert ours == bytes(theirs)
    assert autosar_p02.e2e_p02_check(ours, bytes(ids), length=length)


@given(st.sampled_from([BOTH, NIBBLE]), st.integers(0, 0xFFFF), st.integers(0, 14),
       st.binary(min_size=2, max_size=30))
@settings(max_examples=200, deadline=None)
def test_profile_11_on_can_is_railhil_profile_1(mode, data_id, counter, payload):
    """Profile 11 in BOTH and NIBBLE mode with its default offsets makes Profile 1's frames (PRS R19-11
    "fixed interoperability issues between P01 and P11")."""
    data_id &= 0x0FFF if mode is NIBBLE else 0xFFFF
    length = len(payload)
    assert protect(P11Config(data_id, mode, length=length), ProtectState(counter), payload) == \
        protect(P01Config(data_id, mode, length=length), ProtectState(counter), payload)


# --- configurations for the properties --------------------------------------------------------------

p05_configs = st.builds(
    lambda data_id, length, k, delta: P05Config(data_id, length=length, offset=8 * min(k, length - 3),
                                                max_delta_counter=delta),
    st.integers(0, 0xFFFF), st.integers(3, 64), st.integers(0, 61), st.integers(1, 255))
p11_configs = st.builds(
    lambda mode, data_id, length, k, delta: P11Config(data_id & (0x0FFF if mode is NIBBLE else 0xFFFF), mode,
                                                      length=length, offset=8 * min(k, length - 2),
                                                      max_delta_counter=delta),
    st.sampled_from([BOTH, NIBBLE]), st.integers(0, 0xFFFF), st.integers(2, 30), st.integers(0, 28),
    st.integers(1, 14))


@st.composite
def counter_checksum_configs(draw, kinds=("counter", "checksum", "both")):
    kind = draw(st.sampled_from(kinds))
    length = draw(st.integers(2, 16))
    checksum_byte = draw(st.integers(0, length - 1))
    counter_byte = draw(st.integers(0, length - 1).filter(lambda b: kind == "counter" or b != checksum_byte))
    bits = draw(st.integers(1, 8))
    shift = draw(st.integers(0, 8 - bits))
    modulo = draw(st.integers(2, 1 << bits))
    return CounterChecksumConfig(
        length=length, counter_offset=None if kind == "checksum" else 8 * counter_byte + shift,
        counter_bits=bits, counter_modulo=modulo, max_delta_counter=draw(st.integers(1, modulo - 1)),
        checksum=None if kind == "counter" else draw(st.sampled_from(["xor", "sum"])),
        checksum_offset=8 * checksum_byte)


configs = st.one_of(p05_configs, p11_configs, counter_checksum_configs())


def modulo_of(config) -> int | None:
    """How many counter values a sender of ``config`` cycles through (None: no counter)."""
    if isinstance(config, P05Config):
        return 256
    if isinstance(config, P11Config):
        return 15
    return config.counter_modulo if config.counter_offset is not None else None


def header_mask(config) -> bytes:
    """Per protected byte, the bits protect() may write (the rest is the sender's payload)."""
    mask = bytearray(config.length)
    if isinstance(config, P05Config):
        mask[config.offset // 8:config.offset // 8 + 3] = b"\xff\xff\xff"
    elif isinstance(config, P11Config):
        mask[config.offset // 8] = 0xFF
        mask[config.offset // 8 + 1] = 0xFF if config.data_id_mode is NIBBLE else 0x0F
    else:
        if config.counter_offset is not None:
            bits = (1 << config.counter_bits) - 1
            mask[config.counter_offset // 8] |= bits << (config.counter_offset % 8)
        if config.checksum is not None:
            mask[config.checksum_offset // 8] = 0xFF
    return bytes(mask)


# --- round trips and error detection ----------------------------------------------------------------

@given(configs, st.data())
@settings(max_examples=150, deadline=None)
def test_protect_then_check_round_trips_across_the_counter_wrap(config, data):
    """Any payloads, sent in order from a counter just before the wrap: OK every time but the first
    (whose status is the first-frame rule's, table-tested below); only the header bits change."""
    modulo = modulo_of(config)
    start = data.draw(st.integers(max(0, modulo - 3), modulo - 1)) if modulo else 0
    sender, state, statuses = ProtectState(start), CheckState(), []
    mask = header_mask(config)
    for _ in range(8):
        payload = data.draw(st.binary(min_size=config.length, max_size=config.length))
        frame = protect(config, sender, payload)
        assert all((f ^ p) & ~m == 0 for f, p, m in zip(frame, payload, mask, strict=True))
        state, status = check(config, state, frame)
        statuses.append(status)
    assert statuses[1:] == [S.OK] * 7
    assert statuses[0] is S.OK or start != 0
    if modulo:
        assert sender.counter == (start + 8) % modulo and state.last_valid_counter == (start + 7) % modulo


@given(st.one_of(p05_configs, p11_configs, counter_checksum_configs(kinds=("checksum", "both"))), st.data())
@settings(max_examples=150, deadline=None)
def test_every_single_bit_flip_is_an_error(config, data):
    """CRC-16 (P05) and CRC-8 SAE J1850 (P11) detect every single-bit error of the protected bytes, header
    included (the data id does not depend on the counter, unlike Profile 2's); so do XOR and SUM."""
    payload = data.draw(st.binary(min_size=config.length, max_size=config.length))
    frame = protect(config, ProtectState(data.draw(st.integers(0, (modulo_of(config) or 1) - 1))), payload)
    for bit in range(config.length * 8):
        flipped = bytearray(frame)
        flipped[bit // 8] ^= 1 << (bit % 8)
        assert check(config, CheckState(), bytes(flipped))[1] is S.ERROR, bit


def _flip(frame: bytes, *bits: int) -> bytes:
    out = bytearray(frame)
    for bit in bits:
        out[bit // 8] ^= 1 << (bit % 8)
    return bytes(out)


XOR = CounterChecksumConfig(checksum="xor")                  # checksum in byte 0 over bytes 1..7
SUM = CounterChecksumConfig(checksum="sum")


@pytest.mark.parametrize(("name", "payload", "bits", "xor_detects", "sum_detects"), [
    # name, payload (byte 0 is the checksum), bits flipped, detected by XOR, by SUM
    ("one bit", "0011223344556677", [8 + 3], True, True),
    ("bit 3 set in two bytes", "0000000000000000", [8 + 3, 16 + 3], False, True),        # +8 +8
    ("bit 3 set in one, cleared in another", "0000080000000000", [8 + 3, 16 + 3], False, False),   # +8 -8
    ("bit 7 in two bytes", "0000000000000000", [8 + 7, 16 + 7], False, False),          # +128 +128 = 256
    ("bits 0 and 1 in one byte", "0001000000000000", [8, 9], True, True),               # 0x01 -> 0x02
    ("two bits in three bytes", "0000000000000000", [8, 16, 24], True, True),
])
def test_what_xor_and_sum_detect(name, payload, bits, xor_detects, sum_detects):
    """XOR misses any error that flips each bit position an even number of times; SUM (mod 256) misses
    errors whose changes add up to a multiple of 256 -- a bit set in one byte and cleared in another,
    bit 7 flipped in two bytes.  Both detect every single-bit error."""
    for config, detects in ((XOR, xor_detects), (SUM, sum_detects)):
        frame = protect(config, ProtectState(), bytes.fromhex(payload))
        detected = check(config, CheckState(), _flip(frame, *bits))[1] is S.ERROR
        assert detected == detects, (name, config.checksum)


def test_neither_checksum_detects_swapped_bytes_or_a_masquerading_frame():
    """Both are symmetric in the bytes (a swap keeps them), and neither covers a data id: a frame of
    another message with the same layout checks."""
    for config in (XOR, SUM):
        frame = bytearray(protect(config, ProtectState(), bytes.fromhex("0011223344556677")))
        frame[2], frame[5] = frame[5], frame[2]
        assert check(config, CheckState(), bytes(frame))[1] is S.OK


def test_checksum_functions():
    assert checksum_xor(b"") == 0 and checksum_xor(bytes((0x0F, 0xF0, 0x01))) == 0xFE
    assert checksum_sum(bytes((0xFF, 0x02))) == 0x01


# --- receiver state machine: keyword tables ---------------------------------------------------------

PROFILES = {
    "P05": P05Config(0x1234, max_delta_counter=2),
    "P11": P11Config(0x123, max_delta_counter=2),
    "counter+XOR": CounterChecksumConfig(counter_offset=8, max_delta_counter=2, checksum="xor"),
    "counter": CounterChecksumConfig(counter_offset=12, counter_modulo=15, max_delta_counter=2),   # 0..14
}


def _run(config, steps):
    """Feed ``steps`` (a counter, ``None`` for no data, ``("corrupt", counter)`` for a frame with a data
    bit flipped) to a fresh receiver; (statuses, last state)."""
    state, statuses = CheckState(), []
    for step in steps:
        if step is None:
            frame = None
        elif isinstance(step, tuple):
            frame = _flip(protect(config, ProtectState(step[1]), bytes(range(8))), 5 * 8 + 4)
        else:
            frame = protect(config, ProtectState(step), bytes(range(8)))
        state, status = check(config, state, frame)
        statuses.append(status)
    return statuses, state


SEQUENCE_TABLE = [
    # name, steps, expected statuses -- MaxDeltaCounter 2 everywhere
    ("first frame, counter 0", [0], [S.OK]),
    ("first frame, counter 1: one lost before it", [1], [S.OKSOMELOST]),
    # a sender that counted before the receiver listened: its first frame anchors the count, not used
    ("first frame, counter 2: more than MaxDeltaCounter", [2, 3], [S.INITIAL, S.OK]),
    ("consecutive", [0, 1, 2], [S.OK, S.OK, S.OK]),
    ("repeated frame", [0, 1, 1], [S.OK, S.OK, S.REPEATED]),
    ("one lost", [0, 1, 3], [S.OK, S.OK, S.OKSOMELOST]),
    ("two lost, more than MaxDeltaCounter", [0, 1, 4], [S.OK, S.OK, S.WRONGSEQUENCE]),
    ("a wrong sequence re-anchors the counter", [0, 1, 6, 7], [S.OK, S.OK, S.WRONGSEQUENCE, S.OK]),
    ("no new data", [0, None], [S.OK, S.NONEWDATA]),
    ("no new data before the first frame", [None, 0], [S.NONEWDATA, S.OK]),
    ("a silent cycle does not widen the window", [0, None, 3], [S.OK, S.NONEWDATA, S.WRONGSEQUENCE]),
    ("corrupted frame", [0, ("corrupt", 1)], [S.OK, S.ERROR]),
    ("after an error, the next frame", [0, ("corrupt", 1), 2], [S.OK, S.ERROR, S.OKSOMELOST]),
    ("an error before the first frame leaves it first", [("corrupt", 0), 0], [S.ERROR, S.OK]),
]


@pytest.mark.parametrize("profile", [p for p in PROFILES if p != "counter"])
@pytest.mark.parametrize(("name", "steps", "expected"), SEQUENCE_TABLE, ids=[r[0] for r in SEQUENCE_TABLE])
def test_sequence_table(profile, name, steps, expected):
    statuses, _ = _run(PROFILES[profile], steps)
    assert statuses == expected


UNCORRUPTED_TABLE = [r for r in SEQUENCE_TABLE if not any(isinstance(step, tuple) for step in r[1])]


@pytest.mark.parametrize(("name", "steps", "expected"), UNCORRUPTED_TABLE,
                         ids=[r[0] for r in UNCORRUPTED_TABLE])
def test_sequence_table_counter_alone(name, steps, expected):
    """Without a checksum the counter alone decides: the same statuses as the CRC profiles'."""
    statuses, _ = _run(PROFILES["counter"], steps)
    assert statuses == expected


def test_a_counter_alone_does_not_see_a_data_bit_flip():
    assert _run(PROFILES["counter"], [0, ("corrupt", 1)])[0] == [S.OK, S.OK]


@pytest.mark.parametrize(("profile", "modulo"),
                         [("P05", 256), ("P11", 15), ("counter+XOR", 16), ("counter", 15)])
def test_counter_wraps_and_a_first_frame_at_the_top_is_initial(profile, modulo):
    """E2E_P05CheckInit / E2E_P11CheckInit leave the counter at modulo - 1 (0xFF, 0x0E): a first frame
    carrying it, or one further on, follows nothing the receiver knew: INITIAL (the PRS: REPEATED,
    WRONGSEQUENCE), not used; modulo - 1 -> 0 is one step."""
    statuses, state = _run(PROFILES[profile], [modulo - 2, modulo - 1, 0, 1])
    assert statuses == [S.INITIAL, S.OK, S.OK, S.OK] and state.last_valid_counter == 1
    assert _run(PROFILES[profile], [modulo - 1])[0] == [S.INITIAL]
    assert not S.INITIAL.usable


def test_state_fields_used():
    _, state = _run(PROFILES["P05"], [0, 1, 3])
    assert state == CheckState(last_valid_counter=3, wait_for_first_data=False, lost_data=1)
    _, state = _run(PROFILES["P05"], [0, 1, 3, 3])                # a repeat keeps the count of lost frames
    assert state.lost_data == 1


def test_counter_checksum_without_a_counter_is_ok_on_a_right_checksum():
    config = CounterChecksumConfig(checksum="sum", checksum_offset=56)
    frame = protect(config, ProtectState(), bytes(range(8)))
    assert frame[7] == sum(range(7))
    state, status = check(config, CheckState(), frame)
    assert (state, status) == (CheckState(), S.OK)
    assert check(config, state, frame)[1] is S.OK                     # the same frame again: no counter, OK


def test_a_counter_beyond_the_modulo_is_an_error():
    config = CounterChecksumConfig(counter_offset=8, counter_modulo=15, checksum="xor")
    frame = bytearray(8)
    frame[1] = 0x0F
    frame[0] = checksum_xor(frame[1:])
    assert check(config, CheckState(), bytes(frame))[1] is S.ERROR


@pytest.mark.parametrize("profile", sorted(PROFILES))
@pytest.mark.parametrize("payload", [b"", bytes(7), bytes(9)], ids=["empty", "short", "long"])
def test_wrong_length_is_an_error_and_changes_nothing(profile, payload):
    config = PROFILES[profile]
    _, state = _run(config, [0, 1])
    assert check(config, state, payload) == (state, S.ERROR)


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_check_is_pure(profile):
    config, state = PROFILES[profile], CheckState()
    frame = protect(config, ProtectState(3), bytes(8))
    assert check(config, state, frame) == check(config, state, frame) and state == CheckState()


@given(configs, st.lists(st.one_of(st.none(), st.binary(max_size=70)), max_size=30))
@settings(max_examples=150, deadline=None)
def test_check_never_raises_on_received_data(config, frames):
    state = CheckState()
    for frame in frames:
        state, status = check(config, state, frame)
        assert isinstance(status, Status) and isinstance(state, CheckState)


@given(configs, st.data())
@settings(max_examples=100, deadline=None)
def test_check_never_raises_on_frames_of_the_right_length(config, data):
    """Random frames of the configured length reach the CRC, nibble and counter reads."""
    state = CheckState()
    for frame in data.draw(st.lists(st.binary(min_size=config.length, max_size=config.length), max_size=20)):
        state, status = check(config, state, frame)
        assert isinstance(status, Status)


# --- configuration: validated when built, one line; describe() ----------------------------------------

@pytest.mark.parametrize(("build", "words"), [
    (lambda: P05Config(0x10000), "data_id = 65536"),
    (lambda: P05Config(1, length=2), "length = 2"),
    (lambda: P05Config(1, length=4097), "length = 4097"),
    (lambda: P05Config(1, offset=4), "offset = 4, expected a multiple of 8 bits"),
    (lambda: P05Config(1, offset=48), "offset = 48, expected an integer 0..40 bits"),
    (lambda: P05Config(1, max_delta_counter=0), "max_delta_counter"),
    (lambda: protect(P05Config(1), ProtectState(256), bytes(8)), "sender counter 256, expected 0..255"),
    (lambda: protect(P05Config(1), ProtectState(), bytes(7)), "payload of 7 bytes, expected 8"),
    (lambda: P11Config(1, DataIdMode.ALT), "expected BOTH or NIBBLE"),
    (lambda: P11Config(0x1123, NIBBLE), "12 bits"),
    (lambda: P11Config(1, length=31), "length = 31"),
    (lambda: P11Config(1, offset=56), "offset = 56"),
    (lambda: P11Config(1, max_delta_counter=15), "max_delta_counter = 15"),
    (lambda: protect(P11Config(1), ProtectState(15), bytes(8)), "sender counter 15, expected 0..14"),
    (lambda: CounterChecksumConfig(), "neither counter_offset nor checksum"),
    (lambda: CounterChecksumConfig(checksum="crc8"), "checksum = 'crc8', expected one of 'xor', 'sum'"),
    (lambda: CounterChecksumConfig(counter_offset=6), "crosses a byte boundary"),
    (lambda: CounterChecksumConfig(counter_offset=8, counter_bits=9), "counter_bits = 9"),
    (lambda: CounterChecksumConfig(counter_offset=8, counter_modulo=17), "counter_modulo = 17"),
    (lambda: CounterChecksumConfig(counter_offset=8, max_delta_counter=16), "max_delta_counter = 16"),
    (lambda: CounterChecksumConfig(counter_offset=64), "counter_offset = 64"),
    (lambda: CounterChecksumConfig(checksum="xor", checksum_offset=4), "checksum_offset = 4"),
    (lambda: CounterChecksumConfig(checksum="xor", counter_offset=3), "lies in the checksum byte"),
    (lambda: CounterChecksumConfig(length=65, checksum="sum"), "length = 65"),
    (lambda: CounterChecksumConfig(length=1, checksum="sum"), "length = 1"),
    (lambda: protect(CounterChecksumConfig(counter_offset=8, counter_modulo=10), ProtectState(10), bytes(8)),
     "sender counter 10, expected 0..9"),
])
def test_config_errors_are_one_line(build, words):
    with pytest.raises(E2EConfigError) as info:
        build()
    assert isinstance(info.value, RailhilError) and info.value.exit_code == 2
    assert words in str(info.value) and "\n" not in str(info.value)


def test_describe():
    assert P05Config(0x1234).describe() == "AUTOSAR E2E P05, data id 0x1234"
    assert P11Config(0x123, NIBBLE).describe() == "AUTOSAR E2E P11, data id 0x123 (NIBBLE)"
    assert P01Config(0x28).describe() == "AUTOSAR E2E P01, data id 0x28 (BOTH)"
    assert P02Config(tuple(range(16))).describe() == \
        "AUTOSAR E2E P02, DataIDList 000102030405060708090a0b0c0d0e0f"
    assert CounterChecksumConfig(counter_offset=8, checksum="xor").describe() == \
        "counter (4 bits) + XOR checksum"
    assert CounterChecksumConfig(counter_offset=8, counter_modulo=15).describe() == "counter (4 bits, 0..14)"
    assert CounterChecksumConfig(checksum="sum").describe() == "SUM checksum"


def test_protect_and_check_hand_other_configs_to_their_methods():
    for config in PROFILES.values():
        a, b = ProtectState(5), ProtectState(5)
        frame = protect(config, a, bytes(range(8)))
        assert frame == config.protect(b, bytes(range(8))) and a == b
        assert check(config, CheckState(), frame) == config.check(CheckState(), frame)


# --- a Node carrying them ---------------------------------------------------------------------------

DEVICE_DBC = """VERSION ""

BU_: DEV HIL

BO_ 1280 DEV_STATUS: 8 DEV
 SG_ Pressure : 24|16@1+ (0.01,0) [0|655.35] "bar" HIL

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 1280 10;
"""
# Header bytes 0..2 at most (P05 at offset 0), Pressure in bytes 3 and 4.
DEVICE_PROTECTIONS = {
    "P05": P05Config(0x0500, name="DEV_STATUS"),
    "P11": P11Config(0x500, NIBBLE, name="DEV_STATUS"),
    "counter+SUM": CounterChecksumConfig(counter_offset=8, checksum="sum", name="DEV_STATUS"),
}


class PressureSource:
    """A device controller: 1.00 bar, +0.01 bar a cycle."""

    def step(self, now_us, rx):
        return {"Pressure": 1.0 + 0.01 * (now_us // 10_000)}


class Sink:
    def step(self, now_us, rx):
        return {}


def device_node(monkeypatch, name, controller, db, config, inputs=(), outputs=(), rx=(), tx=()):
    """A Node whose protection of DEV_STATUS is ``config``, by Node's ``protection`` hook (hil.devices'
    way in)."""
    def protection(msg):
        return config if msg.name == "DEV_STATUS" else None

    binding = Binding.build(db, name, inputs, outputs, rx, tx)
    return Node(name, controller, binding, Codec(db), db, 10_000, protection=protection)


@pytest.mark.parametrize("kind", sorted(DEVICE_PROTECTIONS))
def test_a_node_protects_what_it_sends_and_drops_what_fails(monkeypatch, kind):
    config = DEVICE_PROTECTIONS[kind]
    db = cantools.database.load_string(DEVICE_DBC, "dbc")
    msg = db.get_message_by_name("DEV_STATUS")
    sender = device_node(monkeypatch, "DEV", PressureSource(), db, config, outputs=["Pressure"],
                         tx=["DEV_STATUS"])
    receiver = device_node(monkeypatch, "HIL", Sink(), db, config, inputs=["Pressure"], rx=["DEV_STATUS"])
    frames = [data for k in range(4) for fc, data in sender.cycle(10_000 * k) if fc.name == "DEV_STATUS"]
    assert len(frames) == 4

    state, seen = CheckState(), []                       # the sender protected them: an independent receiver
    for data in frames:
        state, status = config.check(state, data)
        seen.append(status)
    assert seen == [S.OK] * 4                            # counter 0 first: OK, and usable (no INITIAL here)

    for k, data in enumerate(frames[:3]):
        receiver.receive(msg.frame_id, data, 10_000 * k + 500)
        assert receiver.rx.e2e["DEV_STATUS"] is S.OK
        assert receiver.rx["Pressure"] == pytest.approx(1.0 + 0.01 * k)
    corrupt = _flip(frames[3], 3 * 8)                    # one bit of Pressure
    receiver.receive(msg.frame_id, corrupt, 30_500)
    assert receiver.rx.e2e["DEV_STATUS"] is S.ERROR
    assert receiver.rx["Pressure"] == pytest.approx(1.02)                   # kept the last good value
    receiver.receive(msg.frame_id, frames[1], 31_000)    # a replayed old frame
    assert receiver.rx.e2e["DEV_STATUS"] is S.WRONGSEQUENCE
    receiver.receive(msg.frame_id, frames[2], 32_000)    # re-anchored on frame 1: frame 2 is the next one
    assert receiver.rx.e2e["DEV_STATUS"] is S.OK
    assert receiver.stats.e2e_discarded == 2
    assert [s for _, _, s in receiver.stats.e2e_events] == ["ERROR", "WRONGSEQUENCE"]
    for k in range(5, 9):                                # the device falls silent
        receiver.cycle(10_000 * k)
    assert receiver.rx.e2e["DEV_STATUS"] is S.NONEWDATA


def test_device_frames_survive_random_bytes_in_a_node(monkeypatch):
    """Garbage on the device's identifier: counted, never raised, never used."""
    db = cantools.database.load_string(DEVICE_DBC, "dbc")
    rng = random.Random(11)
    for config in DEVICE_PROTECTIONS.values():
        receiver = device_node(monkeypatch, "HIL", Sink(), db, config, inputs=["Pressure"], rx=["DEV_STATUS"])
        for k in range(300):
            receiver.receive(1280, rng.randbytes(rng.choice((0, 3, 8, 8, 8, 12))), 1_000 * k)
        used = receiver.stats.frames_received - receiver.stats.e2e_discarded
        assert used <= 2 and receiver.stats.e2e_status.get("ERROR", 0) > 100
