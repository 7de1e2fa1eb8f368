"""SecOC profile 1 style authentication (hil/can/secoc.py): the AES-CMAC against the published RFC 4493 /
NIST SP 800-38B examples, the frame layout, freshness rebuild edge cases, replay and rogue frames."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.can import secoc
from hil.can.secoc import (
    AUTH_BYTES,
    Reason,
    SecOcError,
    SecOcReceiver,
    SecOcSender,
    authenticate,
    cmac_aes128,
    data_to_authenticate,
    key_from_hex,
    rebuild_freshness,
)
from hil.errors import RailhilError

# RFC 4493 "The AES-CMAC Algorithm" §4 test vectors = NIST SP 800-38B Appendix D.1 (AES-128) examples.
RFC4493_KEY = bytes.fromhex("2b7e151628aed2a6abf7158809cf4f3c")
RFC4493_M = bytes.fromhex(
    "6bc1bee22e409f96e93d7e117393172a"
    "ae2d8a571e03ac9c9eb76fac45af8e51"
    "30c81c46a35ce411e5fbc1191a0a52ef"
    "f69f2445df4f9b17ad2b417be66c3710")
RFC4493_EXAMPLES = [   # (message length in bytes, AES-CMAC)
    (0, "bb1d6929e95937287fa37d129b756746"),
    (16, "070a16b46b4d4144f79bdd9dd04a287c"),
    (40, "dfa66747de9ae63030ca32611497c827"),
    (64, "51f0bebf7e3b9d92fc49741779363cfe"),
]

COMPILED = not secoc.__file__.endswith(".py")          # hil.can.secoc built by mypyc
KEY = bytes(range(16))
OTHER_KEY = bytes(range(1, 17))
DEMAND, RELEASE = 0x0028, 0x0029            # two data ids, as two frame types would have


@pytest.mark.parametrize(("length", "tag"), RFC4493_EXAMPLES, ids=[f"len{n}" for n, _ in RFC4493_EXAMPLES])
def test_cmac_matches_rfc4493(length, tag):
    assert cmac_aes128(RFC4493_KEY, RFC4493_M[:length]).hex() == tag


@pytest.mark.parametrize(("length", "tag"), RFC4493_EXAMPLES[1:],
                         ids=[f"len{n}" for n, _ in RFC4493_EXAMPLES[1:]])
def test_authenticate_layout_on_rfc4493_messages(length, tag):
    """Split an RFC 4493 message into data id (2 bytes) | payload | freshness (8 bytes): authenticate()
    must return the freshness' low byte and the 24 MSB of the published MAC -- so the CMAC and the
    documented big-endian layout are both right."""
    message = RFC4493_M[:length]
    data_id, freshness = int.from_bytes(message[:2], "big"), int.from_bytes(message[-8:], "big")
    payload = message[2:-8]
    assert data_to_authenticate(data_id, freshness, payload) == message
    auth = authenticate(RFC4493_KEY, data_id, freshness, payload)
    assert auth == bytes((message[-1],)) + bytes.fromhex(tag)[:3]
    receiver = SecOcReceiver(RFC4493_KEY, data_id, last=freshness - 1)
    verdict = receiver.verify(payload + auth)
    assert verdict.accepted and verdict.freshness == freshness and verdict.payload == payload


def test_sender_receiver_round_trip():
    sender, receiver = SecOcSender(KEY, DEMAND), SecOcReceiver(KEY, DEMAND)
    for i in range(1, 600):                           # past two wraps of the 8 transmitted bits
        payload = bytes((i & 0xFF, 0x55, i >> 8))
        frame = sender.secure(payload)
        assert len(frame) == len(payload) + AUTH_BYTES
        assert frame[:len(payload)] == payload
        assert frame[len(payload):] == authenticate(KEY, DEMAND, i, payload)
        verdict = receiver.verify(frame)
        assert verdict.accepted and verdict.freshness == i and verdict.payload == payload
    assert receiver.counts[Reason.ACCEPTED] == 599 and receiver.rejected == 0


# --- freshness rebuild: (last accepted, received 8 bits) -> candidate ---------------------------------

@pytest.mark.parametrize(("last", "received", "expected"), [
    (0x000, 0x01, 0x001),        # next value
    (0x000, 0xFF, 0x0FF),        # larger jump, same upper bits
    (0x0FF, 0x00, 0x100),        # wrap of the 8 LSB: upper bits + 1
    (0x1FE, 0xFF, 0x1FF),
    (0x1FF, 0x03, 0x203),        # wrap with 3 lost
    (0x105, 0x05, 0x205),        # same LSB as last (a replay): upper + 1, i.e. last + 256
    (0x105, 0x04, 0x204),        # older LSB (reordered/stale): upper + 1
    (0xFFFF_FFFF_FFFF_FFFE, 0xFF, 0xFFFF_FFFF_FFFF_FFFF),
])
def test_rebuild_freshness(last, received, expected):
    assert rebuild_freshness(last, received) == expected


@given(st.integers(0, 2**64 - 1), st.integers(0, 255))
def test_rebuild_is_within_one_wrap(last, received):
    candidate = rebuild_freshness(last, received)
    assert last < candidate <= last + 256 and candidate & 0xFF == received


# --- receiver behaviour -------------------------------------------------------------------------------

def _sent(n, data_id=DEMAND, key=KEY):
    sender = SecOcSender(key, data_id)
    return [sender.secure(bytes((i, 0xA5))) for i in range(1, n + 1)]


def test_replay_of_the_last_frame_is_rejected():
    frames, receiver = _sent(3), SecOcReceiver(KEY, DEMAND)
    assert receiver.verify(frames[0]).accepted
    verdict = receiver.verify(frames[0])
    assert not verdict.accepted and verdict.reason is Reason.STALE_FRESHNESS and verdict.freshness == 257
    assert receiver.last == 1 and receiver.counts[Reason.STALE_FRESHNESS] == 1


def test_replay_of_an_older_frame_is_rejected():
    frames, receiver = _sent(5), SecOcReceiver(KEY, DEMAND)
    for frame in frames:
        assert receiver.verify(frame).accepted
    assert receiver.verify(frames[1]).reason is Reason.STALE_FRESHNESS
    assert receiver.last == 5


def test_reordered_frames_only_the_newer_counts():
    frames, receiver = _sent(3), SecOcReceiver(KEY, DEMAND)
    assert receiver.verify(frames[0]).accepted
    assert receiver.verify(frames[2]).accepted            # frame 2 lost or late: within the window
    assert receiver.verify(frames[1]).reason is Reason.STALE_FRESHNESS
    assert receiver.last == 3


def test_window_edges():
    frames = _sent(20)
    receiver = SecOcReceiver(KEY, DEMAND, window=4)
    assert receiver.verify(frames[3]).accepted             # freshness 4 = last (0) + window
    receiver = SecOcReceiver(KEY, DEMAND, window=4)
    verdict = receiver.verify(frames[4])                   # freshness 5 = last + window + 1
    assert verdict.reason is Reason.STALE_FRESHNESS and receiver.last == 0


def test_wrap_of_the_transmitted_byte_is_followed():
    sender = SecOcSender(KEY, DEMAND, freshness=250)
    receiver = SecOcReceiver(KEY, DEMAND, last=250)
    for expected in range(251, 262):
        verdict = receiver.verify(sender.secure(b"\x01"))
        assert verdict.accepted and verdict.freshness == expected


def test_losses_across_the_wrap_within_the_window():
    sender = SecOcSender(KEY, DEMAND, freshness=252)
    receiver = SecOcReceiver(KEY, DEMAND, window=16, last=252)
    frames = [sender.secure(b"\x02") for _ in range(10)]   # freshness 253 .. 262
    assert receiver.verify(frames[8]).freshness == 261     # 253..260 lost, transmitted byte 0x05
    assert receiver.last == 261


@pytest.mark.parametrize(("tamper", "reason"), [
    (lambda f: bytes((f[0] ^ 1,)) + f[1:], Reason.MAC_MISMATCH),          # payload bit
    (lambda f: f[:-1] + bytes((f[-1] ^ 0x80,)), Reason.MAC_MISMATCH),    # MAC bit
    (lambda f: f[:-4] + bytes((f[-4] ^ 0x01,)) + f[-3:], Reason.MAC_MISMATCH),   # freshness byte 2 -> 3
    (lambda f: f[-3:], Reason.MALFORMED),
    (lambda f: b"", Reason.MALFORMED),
])
def test_tampered_frames_are_dropped_and_counted(tamper, reason):
    frame = _sent(2)[1]                                     # freshness 2
    receiver = SecOcReceiver(KEY, DEMAND, last=1)
    verdict = receiver.verify(tamper(frame))
    assert not verdict.accepted and verdict.payload is None
    assert verdict.reason is reason
    assert receiver.last == 1 and receiver.counts[reason] == 1 and receiver.rejected == 1
    assert receiver.verify(frame).accepted                  # the genuine frame still passes afterwards


def test_wrong_key_and_wrong_data_id_fail_the_mac():
    demand = _sent(1)[0]
    assert SecOcReceiver(OTHER_KEY, DEMAND).verify(demand).reason is Reason.MAC_MISMATCH
    # a MAC made for a brake demand never verifies as a brake release, even with the same key
    assert SecOcReceiver(KEY, RELEASE).verify(demand).reason is Reason.MAC_MISMATCH


def test_rogue_node_cannot_release_brakes():
    """A rogue node without the key tries every freshness byte with random MACs, then replays a genuine
    release frame it recorded earlier: nothing is accepted, everything is counted."""
    genuine = SecOcSender(KEY, RELEASE)
    receiver = SecOcReceiver(KEY, RELEASE)
    recorded = [genuine.secure(b"\x01")]                    # release request, freshness 1
    assert receiver.verify(recorded[0]).accepted
    for _ in range(5):
        assert receiver.verify(genuine.secure(b"\x00")).accepted
    rng = random.Random(7)
    for fv in range(256):
        for _ in range(8):
            assert not receiver.verify(b"\x01" + bytes((fv,)) + rng.randbytes(3)).accepted
    assert not receiver.verify(recorded[0]).accepted        # replay
    assert receiver.counts[Reason.MAC_MISMATCH] + receiver.counts[Reason.STALE_FRESHNESS] == 256 * 8 + 1
    assert receiver.counts[Reason.MAC_MISMATCH] == receiver.window * 8    # only in-window bytes reach the MAC
    assert receiver.verify(genuine.secure(b"\x00")).accepted               # the genuine sender still passes


@given(st.integers(1, 40), st.lists(st.integers(0, 39), max_size=80), st.integers(1, 32))
@settings(max_examples=200, deadline=None)
def test_replay_is_never_accepted(n, deliveries, window):
    """Any delivery schedule of the sent frames (losses, duplicates, reordering): the accepted freshness
    values strictly increase, so no frame is accepted twice, and each accepted payload is the one sent
    with that freshness."""
    sender, receiver = SecOcSender(KEY, DEMAND), SecOcReceiver(KEY, DEMAND, window=window)
    frames = [sender.secure(bytes((i, i ^ 0x5A))) for i in range(1, n + 1)]
    accepted = []
    for index in deliveries:
        if index < n:
            verdict = receiver.verify(frames[index])
            if verdict.accepted:
                accepted.append(verdict.freshness)
                assert verdict.payload == frames[index][:-AUTH_BYTES] and verdict.freshness == index + 1
    assert accepted == sorted(set(accepted))
    assert receiver.counts[Reason.ACCEPTED] == len(accepted)


@given(st.binary(max_size=40))
@settings(max_examples=200, deadline=None)
def test_verify_never_raises(frame):
    receiver = SecOcReceiver(KEY, DEMAND)
    assert receiver.verify(frame).reason in Reason


# --- bad configuration: one line, a RailhilError with exit code 2 --------------------------------------

@pytest.mark.parametrize(("build", "words"), [
    (lambda: SecOcSender(bytes(15), DEMAND), "must be 16 bytes, got 15 bytes"),
    (lambda: SecOcReceiver(bytes(17), DEMAND), "must be 16 bytes, got 17 bytes"),
    (lambda: authenticate(bytes(8), DEMAND, 1, b""), "authenticate data id 40"),
    (lambda: cmac_aes128(b"", b""), "must be 16 bytes"),
    (lambda: SecOcSender(KEY, 0x10000), "data id"),
    (lambda: SecOcReceiver(KEY, DEMAND, window=0), "acceptance window"),
    (lambda: SecOcReceiver(KEY, DEMAND, window=256), "acceptance window"),
    (lambda: authenticate(KEY, DEMAND, -1, b""), "freshness value"),
    (lambda: key_from_hex("0011", "scenarios/x.toml: secoc.keys.BCU_DEMAND"), "32 hex digits, got 4"),
    (lambda: key_from_hex("zz" * 16, "scenarios/x.toml: secoc.keys.BCU_DEMAND"), "secoc.keys.BCU_DEMAND"),
    (lambda: key_from_hex(123), "got int"),
])
def test_bad_keys_and_settings_are_one_line_errors(build, words):
    with pytest.raises(SecOcError) as info:
        build()
    assert isinstance(info.value, RailhilError) and info.value.exit_code == 2
    assert words in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize(("build", "words"), [
    (lambda: SecOcSender("00" * 16, DEMAND), "got str"),
    (lambda: SecOcReceiver(bytes(16), "40"), "data id '40'"),
    (lambda: SecOcReceiver(bytes(16), DEMAND, window=1.0), "acceptance window 1.0"),
    (lambda: authenticate(bytes(16), DEMAND, 1.0, b""), "freshness value 1.0"),
])
def test_a_value_of_the_wrong_type_is_a_type_error(build, words):
    """A programming error, not a configuration's: compiled, the annotations refuse it (mypyc checks them on
    every call, in its own words); interpreted, the module's own checks, in words that name it."""
    with pytest.raises(TypeError) as info:
        build()
    assert COMPILED or words in str(info.value)


def test_key_from_hex():
    assert key_from_hex(" 2B7E151628AED2A6ABF7158809CF4F3C ") == RFC4493_KEY


def test_sender_counter_exhausted():
    sender = SecOcSender(KEY, DEMAND, freshness=2**64 - 1)
    with pytest.raises(SecOcError, match="exhausted"):
        sender.secure(b"")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([KEY, OTHER_KEY]), st.sampled_from([DEMAND, RELEASE]),
                          st.binary(min_size=0, max_size=8), st.sampled_from([True, False])),
                min_size=1, max_size=12))
def test_the_shared_mac_of_senders_and_receivers_is_always_the_fresh_cmac(frames):
    """Senders and receivers of one (key, data id) share the last MAC they computed (hil.can.secoc): whatever
    the interleaving of keys, data ids and payloads, every trailer is the one a fresh CMAC gives, and a
    receiver with another key never takes the memo of the sender's."""
    senders: dict[tuple[bytes, int], SecOcSender] = {}
    for key, data_id, payload, tamper in frames:
        sender = senders.setdefault((key, data_id), SecOcSender(key, data_id))
        frame = sender.secure(payload)
        assert frame == payload + authenticate(key, data_id, sender.freshness, payload)
        receiver = SecOcReceiver(key, data_id, last=sender.freshness - 1)
        other = SecOcReceiver(OTHER_KEY if key == KEY else KEY, data_id, last=sender.freshness - 1)
        assert other.verify(frame).reason is Reason.MAC_MISMATCH
        if tamper:
            frame = frame[:-1] + bytes((frame[-1] ^ 1,))
        assert receiver.verify(frame).accepted is not tamper


def test_the_senders_own_frame_is_taken_on_trust_only_at_the_senders_freshness():
    """A receiver handed the very frame its sender just secured accepts it without recomputing the MAC
    (hil.can.secoc: `_SharedCmac.sent`), but only when the freshness it rebuilds is the sender's: the same
    bytes read at another freshness are another message, and its MAC fails."""
    sender = SecOcSender(KEY, DEMAND, freshness=299)
    frame = sender.secure(b"\x01\x02")                   # freshness 300: its transmitted byte is 44
    behind = SecOcReceiver(KEY, DEMAND, window=255, last=0)          # rebuilds 44, not 300
    verdict = behind.verify(frame)
    assert (verdict.accepted, verdict.reason, verdict.freshness) == (False, Reason.MAC_MISMATCH, 44)
    in_step = SecOcReceiver(KEY, DEMAND, last=299)
    verdict = in_step.verify(frame)
    assert (verdict.accepted, verdict.freshness, verdict.payload) == (True, 300, b"\x01\x02")
    assert in_step.verify(frame).reason is Reason.STALE_FRESHNESS            # and a replay of it is not
    copy = bytearray(frame)                                                  # equal bytes, another object
    assert SecOcReceiver(KEY, DEMAND, last=299).verify(copy).payload == b"\x01\x02"
