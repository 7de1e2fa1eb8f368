"""SecOC-style authentication of CAN frames, AUTOSAR SecOC "profile 1" (24Bit-CMAC-8Bit-FV).

Reference: AUTOSAR "Specification of Secure Onboard Communication" (SWS_SecOC) and its profile 1:
AES-128 CMAC (NIST SP 800-38B, RFC 4493) computed by the ``cryptography`` package, the 24 most
significant bits of the MAC and the 8 least significant bits of a 64-bit freshness counter sent in
the frame, the full freshness value rebuilt by the receiver.  Pure protocol layer: no I/O, no clock.

Data to authenticate (SecOC's DataToAuthenticator: Data Identifier | secured part of the Authentic
I-PDU | Complete Freshness Value)::

    data_id (2 bytes, big-endian) || payload (all of the authentic payload) || freshness (8 bytes, big-endian)

The data id binds a MAC to one frame type, so a MAC computed for a brake *demand* never verifies as
a brake *release*; the full 64-bit freshness value (not only its 8 transmitted bits) makes a MAC valid
for exactly one counter value, so a recorded frame replayed later fails either the freshness check or
the MAC.  Big-endian ("network order") serialisation of the data id and freshness follows SecOC.

Secured frame (SecOC's Secured I-PDU: Authentic I-PDU | Freshness Value | Authenticator)::

    payload || freshness & 0xFF (1 byte) || MAC[0:3] (the 24 MSB of the 16-byte CMAC)

Freshness at the receiver (SecOC's rebuild of a counter-based freshness value):
with ``last`` the last *accepted* freshness value and ``r`` the received 8 bits, the candidate keeps
the upper 56 bits of ``last`` if ``r`` > ``last`` & 0xFF, else takes them + 1.  The candidate is
accepted only if it is strictly greater than ``last`` and at most ``last + window`` (the acceptance
window, 1..255 frames), and only then is the MAC checked.  The candidate is always in
``last + 1 .. last + 256``, so an exact replay of the last frame (``r`` == ``last`` & 0xFF) gives
``last + 256``: always out of the window.  A frame that fails is dropped and counted by reason.
Resynchronising a sender whose counter was reset is out of scope: counters persist for a run.
"""

from __future__ import annotations

import enum
import hmac
import re
from typing import NamedTuple

from cryptography.hazmat.primitives import cmac
from cryptography.hazmat.primitives.ciphers import algorithms

from hil.errors import RailhilError

__all__ = [
    "AUTH_BYTES",
    "DEFAULT_WINDOW",
    "KEY_BYTES",
    "Reason",
    "SecOcError",
    "SecOcReceiver",
    "SecOcSender",
    "Verdict",
    "authenticate",
    "cmac_aes128",
    "data_to_authenticate",
    "key_from_hex",
    "rebuild_freshness",
]

KEY_BYTES = 16                 # AES-128 key
MAC_TX_BITS = 24               # SecOC profile 1: SecOCAuthInfoTxLength = 24 bits (MSB of the MAC)
FV_TX_BITS = 8                 # SecOC profile 1: SecOCFreshnessValueTxLength = 8 bits (LSB of the FV)
FV_BITS = 64                   # complete freshness value: a 64-bit counter
MAC_TX_BYTES = MAC_TX_BITS // 8
AUTH_BYTES = FV_TX_BITS // 8 + MAC_TX_BYTES    # bytes appended to a payload: 4
FV_MAX = (1 << FV_BITS) - 1
FV_TX_MASK = (1 << FV_TX_BITS) - 1
DATA_ID_MAX = 0xFFFF           # SecOCDataId is 16 bits
DEFAULT_WINDOW = 16            # frames: 15 consecutive losses tolerated, 150 ms at a 10 ms cycle
_HEX_KEY = re.compile(r"[0-9a-fA-F]{32}")


class SecOcError(RailhilError, ValueError):
    """A SecOC key, data id, freshness value or window that is not allowed (one line, names it)."""


# A value of the wrong type is a TypeError, as the compiled build's annotations make it before these checks
# run (mypyc checks them on every call); a value out of range a SecOcError.  A bool is an int, as to mypy
# (compiled, an int argument takes True as 1).

def _key(key: bytes | bytearray, where: str) -> bytes:
    if not isinstance(key, (bytes, bytearray)):
        raise TypeError(f"{where}: AES-128 key must be {KEY_BYTES} bytes, got {type(key).__name__}")
    if len(key) != KEY_BYTES:
        raise SecOcError(f"{where}: AES-128 key must be {KEY_BYTES} bytes, got {len(key)} bytes")
    return bytes(key)


def _in_range(value: int, low: int, high: int, message: str) -> int:
    if not isinstance(value, int):
        raise TypeError(message)
    if not low <= value <= high:
        raise SecOcError(message)
    return value


def _data_id(data_id: int, where: str) -> int:
    return _in_range(data_id, 0, DATA_ID_MAX,
                     f"{where}: data id {data_id!r}, expected an integer 0..{DATA_ID_MAX}")


def _freshness(value: int, where: str) -> int:
    return _in_range(value, 0, FV_MAX, f"{where}: freshness value {value!r}, expected an integer 0..2**64-1")


def key_from_hex(text: object, where: str = "key") -> bytes:
    """A 16-byte key from 32 hex digits (as a scenario file holds it); ``where`` names the key in
    the one-line error, e.g. ``"scenario.toml: secoc.keys.BCU_DEMAND"``."""
    if not isinstance(text, str) or not _HEX_KEY.fullmatch(text.strip()):
        shown = f"{len(text.strip())} characters" if isinstance(text, str) else type(text).__name__
        raise SecOcError(f"{where}: expected an AES-128 key as 32 hex digits, got {shown}")
    return bytes.fromhex(text.strip())


def cmac_aes128(key: bytes | bytearray, message: bytes, where: str = "CMAC") -> bytes:
    """The full 16-byte AES-128 CMAC of ``message`` (NIST SP 800-38B), via ``cryptography``;
    ``where`` names the key in the error for a key that is not 16 bytes."""
    mac = cmac.CMAC(algorithms.AES(_key(key, where)))
    mac.update(message)
    return mac.finalize()


def data_to_authenticate(data_id: int, freshness: int, payload: bytes) -> bytes:
    """``data_id`` (2 bytes) || ``payload`` || ``freshness`` (8 bytes), both numbers big-endian."""
    return data_id.to_bytes(2, "big") + payload + freshness.to_bytes(8, "big")


def authenticate(key: bytes | bytearray, data_id: int, freshness: int, payload: bytes) -> bytes:
    """The 4 bytes a sender appends to ``payload``: freshness & 0xFF, then the 24 MSB of the CMAC
    over ``data_to_authenticate(data_id, freshness, payload)``."""
    data_id = _data_id(data_id, "authenticate")
    freshness = _freshness(freshness, "authenticate")
    tag = cmac_aes128(key, data_to_authenticate(data_id, freshness, payload),
                      f"authenticate data id {data_id}")
    return bytes((freshness & FV_TX_MASK,)) + tag[:MAC_TX_BYTES]


def rebuild_freshness(last: int, received: int) -> int:
    """The complete freshness value from the 8 bits ``received`` and the last accepted value ``last``:
    ``last``'s upper 56 bits if ``received`` > ``last`` & 0xFF, else those + 1 (always in
    ``last + 1 .. last + 256``)."""
    upper = last >> FV_TX_BITS
    if received <= last & FV_TX_MASK:
        upper += 1
    return (upper << FV_TX_BITS) | received


class _SharedCmac:
    """The AES-128 CMAC of one (key, data id), shared by every sender and receiver of that frame type in
    a process, remembering the last frame a sender secured with it.

    The MAC is a pure function of the key and the message, and in lockstep the receivers of a frame
    authenticate the very bytes its sender did: a receiver handed the sender's last frame (``sent``: the
    secured frame, its freshness, its payload) at the sender's freshness accepts it without rebuilding the
    message and computing its MAC again (`SecOcReceiver.verify`).  ``cryptography``'s keyed prototype is
    copied per computation (no AES key schedule per frame; a new CMAC object costs 4x a copy, measured)."""

    __slots__ = ("_proto", "sent")
    _proto: cmac.CMAC
    sent: tuple[bytes, int, bytes]          # the sender's last frame, its freshness, its payload

    def __init__(self, key: bytes) -> None:
        self._proto = cmac.CMAC(algorithms.AES(key))
        self.sent = (b"", -1, b"")

    def tag(self, message: bytes) -> bytes:
        """The 16-byte CMAC of ``message``."""
        mac = self._proto.copy()
        mac.update(message)
        return mac.finalize()


_SHARED: dict[tuple[bytes, int], _SharedCmac] = {}


def _shared_cmac(key: bytes, data_id: int) -> _SharedCmac:
    shared = _SHARED.get((key, data_id))
    if shared is None:
        shared = _SHARED[(key, data_id)] = _SharedCmac(key)
    return shared


class SecOcSender:
    """One sending frame type: key, data id and its freshness counter (last value used).

    ``secure(payload)`` increments the counter and returns ``payload`` + 4 authentication bytes, so
    the first frame carries freshness ``freshness + 1``.
    """

    __slots__ = ("data_id", "freshness", "_mac", "_id_bytes")
    data_id: int
    freshness: int                       # the last value used
    _mac: _SharedCmac
    _id_bytes: bytes                     # the data id as it enters the MAC

    def __init__(self, key: bytes | bytearray, data_id: int, freshness: int = 0) -> None:
        self.data_id = _data_id(data_id, "SecOC sender")
        self.freshness = _freshness(freshness, "SecOC sender")
        self._mac = _shared_cmac(_key(key, f"SecOC sender of data id {data_id}"), self.data_id)
        self._id_bytes = self.data_id.to_bytes(2, "big")

    def secure(self, payload: bytes) -> bytes:
        """The secured frame for ``payload``; advances the freshness counter."""
        freshness = self.freshness + 1
        if freshness > FV_MAX:
            raise SecOcError(f"SecOC sender of data id {self.data_id}: freshness counter exhausted")
        self.freshness = freshness
        tag = self._mac.tag(self._id_bytes + payload + freshness.to_bytes(8, "big"))   # data_to_authenticate
        frame = payload + bytes((freshness & FV_TX_MASK,)) + tag[:MAC_TX_BYTES]
        self._mac.sent = (frame, freshness, payload)
        return frame


class Reason(enum.Enum):
    """Why a secured frame was accepted or dropped."""

    ACCEPTED = "accepted"
    MAC_MISMATCH = "MAC mismatch"
    STALE_FRESHNESS = "replay/stale freshness"     # rebuilt freshness not in last+1 .. last+window
    MALFORMED = "frame shorter than the 4 authentication bytes"


class Verdict(NamedTuple):
    """Outcome of ``SecOcReceiver.verify``: the authentic payload only when accepted (immutable)."""

    accepted: bool
    reason: Reason
    freshness: int | None = None                   # the rebuilt complete freshness value, if any
    payload: bytes | None = None


class SecOcReceiver:
    """One receiving frame type: key, data id, acceptance window, last accepted freshness, counts.

    ``verify(frame)`` never raises on the frame: any bytes give a ``Verdict``.  ``counts`` holds the
    number of frames per ``Reason`` since construction.
    """

    __slots__ = ("data_id", "window", "last", "counts", "_mac", "_id_bytes")
    data_id: int
    window: int                          # frames: the acceptance window
    last: int                            # the last accepted freshness value
    counts: dict[Reason, int]            # frames per Reason
    _mac: _SharedCmac
    _id_bytes: bytes                     # the data id as it enters the MAC

    def __init__(self, key: bytes | bytearray, data_id: int, window: int = DEFAULT_WINDOW,
                 last: int = 0) -> None:
        self.data_id = _data_id(data_id, "SecOC receiver")
        self.window = _in_range(window, 1, FV_TX_MASK, f"SecOC receiver of data id {data_id}: acceptance "
                                f"window {window!r}, expected an integer 1..{FV_TX_MASK} frames")
        self.last = _freshness(last, "SecOC receiver")
        self.counts = dict.fromkeys(Reason, 0)
        self._mac = _shared_cmac(_key(key, f"SecOC receiver of data id {data_id}"), self.data_id)
        self._id_bytes = self.data_id.to_bytes(2, "big")

    @property
    def rejected(self) -> int:
        """Frames dropped so far, all reasons."""
        return sum(n for reason, n in self.counts.items() if reason is not Reason.ACCEPTED)

    def verify(self, frame: bytes | bytearray) -> Verdict:
        """Check a secured frame; on success the freshness value is remembered as the last accepted."""
        if len(frame) < AUTH_BYTES:
            return self._drop(Reason.MALFORMED, None)
        end = len(frame) - AUTH_BYTES
        freshness = rebuild_freshness(self.last, frame[end])
        if freshness - self.last > self.window or freshness > FV_MAX:
            return self._drop(Reason.STALE_FRESHNESS, freshness)
        sent, sent_freshness, payload = self._mac.sent
        if freshness != sent_freshness or frame != sent:     # not the sender's own frame: check its MAC
            payload = bytes(frame[:end])
            message = self._id_bytes + payload + freshness.to_bytes(8, "big")      # data_to_authenticate
            if not hmac.compare_digest(self._mac.tag(message)[:MAC_TX_BYTES], bytes(frame[end + 1:])):
                return self._drop(Reason.MAC_MISMATCH, freshness)
        self.last = freshness
        self.counts[Reason.ACCEPTED] += 1
        return Verdict(True, Reason.ACCEPTED, freshness, payload)

    def _drop(self, reason: Reason, freshness: int | None) -> Verdict:
        self.counts[reason] += 1
        return Verdict(False, reason, freshness)
