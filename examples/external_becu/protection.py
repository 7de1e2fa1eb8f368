"""E2E protection and SecOC authentication of the train brake CAN, written from the wire contract alone
(docs/external-ecu.md), with cantools for the DBC and `cryptography` for AES-CMAC: no railhil import.

What is protected and how comes from the DBC's message attributes:

- `E2EProfile` = P01: AUTOSAR E2E profile 1, data-id mode BOTH, data id `E2EDataID`; CRC-8 SAE J1850
  (polynomial 0x1D) in byte 0, alive counter 0..14 in the low nibble of byte 1.  As AUTOSAR chains it
  (Crc_CalculateCRC8 with start 0xFF, not the first call, result XORed with 0xFF), the register starts at
  0x00 and no final XOR is left: the CRC runs over the data id's low byte, its high byte, then the
  protected bytes after byte 0.
- `E2EProfile` = P02: AUTOSAR E2E profile 2: CRC-8H2F (polynomial 0x2F, init 0xFF, final XOR 0xFF) over
  bytes 1.. of the protected part, then `E2EDataIDList`[counter] (16 bytes given as 32 hex digits);
  counter 0..15 in the low nibble of byte 1, incremented before it is written (the first frame has 1).
- `SecOCDataID` > 0: SecOC profile 1 style.  The last 4 bytes of the frame are the 8 low bits of a
  64-bit freshness counter and the 24 high bits of the AES-128 CMAC over
  data id (2 bytes, big-endian) || the bytes before the trailer || freshness (8 bytes, big-endian).
  E2E protects only the bytes before the trailer (its length is the frame's minus 4), and the MAC is
  computed over the E2E-protected bytes.

Receivers verify the MAC first (a frame that fails is dropped without touching the E2E state), then run
the E2E check; only the statuses OK, OKSOMELOST and SYNC are usable.  A cycle of the message without a
frame is checked as "no new data" (`Receiver.tick`), which is what lets the counter step over a lost
frame.
"""

from __future__ import annotations

import enum
import hmac
from dataclasses import dataclass
from typing import NamedTuple

from cryptography.hazmat.primitives import cmac
from cryptography.hazmat.primitives.ciphers import algorithms

DEV_SECOC_KEY_HEX = "2b7e151628aed2a6abf7158809cf4f3c"   # railhil's public development key (AES-128)
AUTH_BYTES = 4                    # SecOC trailer: 1 freshness byte + 3 MAC bytes
MAC_BYTES = 3                     # the 24 most significant bits of the CMAC
P01_COUNTER_MODULO = 15           # profile 1's counter runs 0..14; 15 is never sent
P02_COUNTER_MODULO = 16
NO_NEW_CAP = 14                   # AUTOSAR's NoNewOrRepeatedDataCounter saturates here
MAX_NO_NEW_OR_REPEATED = 14       # cycles without new data before the receiver resynchronises (SYNC)
MAX_DELTA_INIT = 1                # counter steps allowed between two frames, + one per cycle since


class ProtectionError(ValueError):
    """A DBC message whose protection attributes this program cannot use (names the message)."""


# --- CRCs -----------------------------------------------------------------------------------------

def _crc8_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_J1850 = _crc8_table(0x1D)
_H2F = _crc8_table(0x2F)


def _crc8(table: tuple[int, ...], data: bytes, crc: int) -> int:
    for byte in data:
        crc = table[crc ^ byte]
    return crc


def p01_crc(data_id: int, protected: bytes) -> int:
    """Profile 1 CRC (data-id mode BOTH, CRC in byte 0) of the protected bytes."""
    return _crc8(_J1850, bytes((data_id & 0xFF, data_id >> 8)) + protected[1:], 0x00)


def p02_crc(data_id_list: tuple[int, ...], protected: bytes, counter: int) -> int:
    """Profile 2 CRC (CRC-8H2F) of the protected bytes with the counter's data id byte."""
    return _crc8(_H2F, protected[1:] + bytes((data_id_list[counter],)), 0xFF) ^ 0xFF


# --- E2E ------------------------------------------------------------------------------------------

class Status(enum.Enum):
    """The E2E receiver's status for one cycle (AUTOSAR E2E_P0xCheckStatusType; WRONGCRC = ERROR)."""

    OK = "OK"
    NONEWDATA = "NONEWDATA"
    ERROR = "ERROR"
    SYNC = "SYNC"
    INITIAL = "INITIAL"
    REPEATED = "REPEATED"
    OKSOMELOST = "OKSOMELOST"
    WRONGSEQUENCE = "WRONGSEQUENCE"


USABLE = frozenset({Status.OK, Status.OKSOMELOST, Status.SYNC})   # E2E_P0xMapStatusToSM, R4.2.2+


@dataclass(frozen=True)
class E2EConfig:
    profile: str                  # "P01" | "P02"
    length: int                   # protected bytes (the frame's, less a SecOC trailer)
    data_id: int = 0              # P01
    data_id_list: tuple[int, ...] = ()   # P02: 16 bytes, one per counter value

    @property
    def modulo(self) -> int:
        return P01_COUNTER_MODULO if self.profile == "P01" else P02_COUNTER_MODULO


def e2e_protect(cfg: E2EConfig, counter: int, payload: bytes) -> tuple[bytes, int]:
    """(the payload with counter and CRC written, the sender's next counter).  P01 writes `counter` and
    then steps it; P02 steps it first and writes the stepped value (AUTOSAR)."""
    data = bytearray(payload)
    if cfg.profile == "P02":
        counter = (counter + 1) % P02_COUNTER_MODULO
        data[1] = (data[1] & 0xF0) | counter
        data[0] = p02_crc(cfg.data_id_list, bytes(data[:cfg.length]), counter)
        return bytes(data), counter
    data[1] = (data[1] & 0xF0) | counter
    data[0] = p01_crc(cfg.data_id, bytes(data[:cfg.length]))
    return bytes(data), (counter + 1) % P01_COUNTER_MODULO


class CheckState(NamedTuple):
    """AUTOSAR's receiver state; the default is E2E_P0xCheckInit."""

    last_counter: int = 0
    max_delta: int = 0
    wait_for_first: bool = True
    no_new: int = 0


def e2e_check(cfg: E2EConfig, state: CheckState, payload: bytes | None) -> tuple[CheckState, Status]:
    """One receiver cycle: the newest frame since the last call, or None when none came (pure)."""
    last, max_delta, wait, no_new = state
    max_delta = min(max_delta + 1, cfg.modulo - 1)
    if payload is None:
        return CheckState(last, max_delta, wait, min(no_new + 1, NO_NEW_CAP)), Status.NONEWDATA
    if len(payload) != cfg.length:
        return CheckState(last, max_delta, wait, no_new), Status.ERROR
    received = payload[1] & 0x0F
    if cfg.profile == "P01":
        good = received != 0x0F and payload[0] == p01_crc(cfg.data_id, payload)
    else:
        good = payload[0] == p02_crc(cfg.data_id_list, payload, received)
    if not good:
        return CheckState(last, max_delta, wait, no_new), Status.ERROR
    if wait:
        return CheckState(received, MAX_DELTA_INIT, False, no_new), Status.INITIAL
    delta = (received - last) % cfg.modulo
    if delta == 0:
        return CheckState(last, max_delta, False, min(no_new + 1, NO_NEW_CAP)), Status.REPEATED
    if delta > max_delta:
        return CheckState(last, max_delta, False, 0), Status.WRONGSEQUENCE
    if no_new > MAX_NO_NEW_OR_REPEATED:
        return CheckState(received, MAX_DELTA_INIT, False, 0), Status.SYNC
    return CheckState(received, MAX_DELTA_INIT, False, 0), Status.OK if delta == 1 else Status.OKSOMELOST


# --- SecOC ----------------------------------------------------------------------------------------

def key_from_hex(text: str) -> bytes:
    """A 16-byte AES-128 key from 32 hex digits (the error does not show the text: it is a secret)."""
    try:
        key = bytes.fromhex(text.strip())
    except ValueError:
        key = b""
    if len(key) != 16:
        raise ValueError(f"expected an AES-128 key as 32 hex digits, got {len(text.strip())} characters")
    return key


def authenticator(key: bytes, data_id: int, freshness: int, payload: bytes) -> bytes:
    """The 4-byte trailer: freshness & 0xFF, then the 3 most significant bytes of the AES-128 CMAC over
    data id (2 bytes, big-endian) || payload || freshness (8 bytes, big-endian)."""
    mac = cmac.CMAC(algorithms.AES(key))
    mac.update(data_id.to_bytes(2, "big") + payload + freshness.to_bytes(8, "big"))
    return bytes((freshness & 0xFF,)) + mac.finalize()[:MAC_BYTES]


class SecOcVerdict(enum.Enum):
    ACCEPTED = "accepted"
    STALE = "stale freshness"      # the rebuilt freshness is not in last+1 .. last+window: a replay
    MAC = "MAC mismatch"
    SHORT = "frame too short"


def rebuild_freshness(last: int, received: int) -> int:
    """The full freshness value from its 8 transmitted bits and the last accepted value."""
    upper = (last >> 8) + (received <= (last & 0xFF))
    return (upper << 8) | received


# --- one protected DBC message, both directions -----------------------------------------------------

def _attribute(message, name: str):
    attrs = getattr(getattr(message, "dbc", None), "attributes", None) or {}
    attr = attrs.get(name)
    if attr is None:
        return None
    choices = getattr(attr.definition, "choices", None)
    if choices and isinstance(attr.value, int):
        return choices[attr.value]
    return attr.value


def secoc_data_id(message) -> int | None:
    """The message's SecOCDataID (> 0), or None: the message is not authenticated."""
    value = _attribute(message, "SecOCDataID")
    return int(value) if value else None


def e2e_config(message) -> E2EConfig | None:
    """The message's E2E profile from its attributes, or None: not protected."""
    profile = _attribute(message, "E2EProfile")
    if profile in (None, "NONE"):
        return None
    length = message.length - (AUTH_BYTES if secoc_data_id(message) else 0)
    if profile == "P01":
        data_id = _attribute(message, "E2EDataID")
        if data_id is None:
            raise ProtectionError(f"message {message.name}: E2EProfile P01 without E2EDataID")
        return E2EConfig("P01", length, data_id=int(data_id))
    if profile == "P02":
        try:
            ids = tuple(bytes.fromhex(str(_attribute(message, "E2EDataIDList"))))
        except ValueError:
            ids = ()
        if len(ids) != 16:
            raise ProtectionError(f"message {message.name}: E2EProfile P02 needs E2EDataIDList, 16 bytes")
        return E2EConfig("P02", length, data_id_list=ids)
    raise ProtectionError(f"message {message.name}: E2EProfile {profile!r} is not NONE, P01 or P02")


def _clamped(message, values: dict[str, float]) -> dict[str, float]:
    """Every signal of the message, saturated to its DBC range; a signal not given (and NaN) is raw 0."""
    out = {}
    for sig in message.signals:
        v = values.get(sig.name)
        if v is None or v != v:
            v = sig.offset
        if sig.minimum is not None and v < sig.minimum:
            v = sig.minimum
        if sig.maximum is not None and v > sig.maximum:
            v = sig.maximum
        out[sig.name] = v
    return out


class Sender:
    """One message this ECU sends: encode (cantools), then E2E (counter, CRC), then SecOC (freshness, MAC)."""

    def __init__(self, message, key: bytes) -> None:
        self.message = message
        self.e2e = e2e_config(message)
        self.data_id = secoc_data_id(message)
        self.key = key
        self.counter = 0              # E2E: the next P01 counter / the last P02 counter
        self.freshness = 0            # SecOC: the last freshness used (the first frame carries 1)

    def frame(self, values: dict[str, float]) -> bytes:
        data = self.message.encode(_clamped(self.message, values), scaling=True, padding=False, strict=True)
        if self.data_id is not None:
            data = data[:self.message.length - AUTH_BYTES]
        if self.e2e is not None:
            data, self.counter = e2e_protect(self.e2e, self.counter, data)
        if self.data_id is not None:
            self.freshness += 1
            data += authenticator(self.key, self.data_id, self.freshness, data)
        return data


class Receiver:
    """One message this ECU receives: SecOC first, then the E2E check; values only from usable frames.

    `receive(data, t_us)` -> the decoded values or None (dropped: `last` says why); `tick(now_us)`, once
    per ECU cycle, checks each message cycle that passed without a frame (after 1.5 cycles)."""

    def __init__(self, message, key: bytes, window: int = 255, start_us: int = 0) -> None:
        self.message = message
        self.e2e = e2e_config(message)
        self.data_id = secoc_data_id(message)
        self.key = key
        self.window = window
        self.freshness = 0            # the last accepted freshness value
        self.state = CheckState()
        self.cycle_us = int(message.cycle_time or 10) * 1000
        self.grace_us = (3 * self.cycle_us + 1) // 2
        self.checked_us = start_us    # time of the last E2E check (a frame, or a cycle without one)
        self.last: Status | SecOcVerdict | None = None
        self.e2e_rejects = 0          # frames whose E2E status was not usable
        self.secoc_rejects = 0        # frames whose freshness or MAC failed

    def verify(self, data: bytes) -> tuple[SecOcVerdict, bytes]:
        if len(data) < AUTH_BYTES:
            return SecOcVerdict.SHORT, b""
        end = len(data) - AUTH_BYTES
        freshness = rebuild_freshness(self.freshness, data[end])
        if freshness - self.freshness > self.window:
            return SecOcVerdict.STALE, b""
        payload = bytes(data[:end])
        expected = authenticator(self.key, self.data_id, freshness, payload)
        if not hmac.compare_digest(expected[1:], bytes(data[end + 1:])):
            return SecOcVerdict.MAC, b""
        self.freshness = freshness
        return SecOcVerdict.ACCEPTED, payload

    def receive(self, data: bytes, t_us: int) -> dict[str, float] | None:
        data = bytes(data)
        if len(data) < self.message.length:
            self.last = None
            return None
        payload = data
        if self.data_id is not None:
            verdict, payload = self.verify(data)
            self.last = verdict
            if verdict is not SecOcVerdict.ACCEPTED:
                self.secoc_rejects += 1
                return None
        if self.e2e is not None:
            self.state, status = e2e_check(self.e2e, self.state, payload[:self.e2e.length])
            self.checked_us = t_us
            self.last = status
            if status not in USABLE:
                self.e2e_rejects += 1
                return None
        values = self.message.decode(data[:self.message.length], decode_choices=False, scaling=True)
        return {name: float(v) for name, v in values.items()}

    def tick(self, now_us: int) -> None:
        if self.e2e is None:
            return
        while now_us >= self.checked_us + self.grace_us:
            self.state, self.last = e2e_check(self.e2e, self.state, None)
            self.checked_us += self.cycle_us
