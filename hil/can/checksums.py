"""A plain rolling counter and/or one-byte checksum: the protection of many supplier CAN matrices.

Not an AUTOSAR profile: no data id, no CRC.  ``CounterChecksumConfig`` describes where a frame
carries either or both, and protects and checks by the same contract as hil.can.e2e's profiles
(``hil.can.e2e.protect`` / ``check`` hand it its own ``protect`` / ``check``), so a Node carries
it in place of a P01Config.

Counter
    ``counter_bits`` (1..8) at bit ``counter_offset`` in AUTOSAR numbering (bit k is bit k % 8 of
    byte k // 8), inside one byte; it counts 0..counter_modulo-1 (default 2**bits).  The sender
    writes it, then increments it (its first frame carries 0).
Checksum
    One byte at ``checksum_offset`` (bits, byte-aligned) over every other protected byte, the
    counter's byte included (the sender writes the counter first): "xor" XORs them, "sum" adds them
    modulo 256.  Both detect any single-bit error.  Neither detects two flips of one bit position in
    two bytes (XOR: always; SUM: where one flip sets and the other clears the bit, and any two flips
    of bit 7), nor bytes swapped, nor a frame of another message with the same layout (no data id).

Receiver: the state machine of AUTOSAR's E2E_P05Check / E2E_P11Check (``hil.can.e2e.counter_check``):
ERROR for a wrong length, a wrong checksum or a counter at or above the modulo (the state unchanged),
NONEWDATA for no frame, else the counter delta: OK (1), OKSOMELOST (2..max_delta_counter), REPEATED
(0), WRONGSEQUENCE (more); the first frame is judged against counter_modulo - 1, one step before 0.
Without a counter a right checksum is OK; without a checksum the counter alone decides.
"""

from __future__ import annotations

import functools
import operator
from dataclasses import dataclass, field

# _check_int: the validator of every E2E configuration, for one message format
from hil.can.e2e import CheckState, E2EConfigError, ProtectState, Status, _check_int, counter_check

__all__ = ["CHECKSUMS", "CounterChecksumConfig", "checksum_sum", "checksum_xor"]

MAX_LENGTH = 64                   # bytes: a CAN FD frame


def checksum_xor(data: bytes) -> int:
    """XOR of the bytes (0 for none)."""
    return functools.reduce(operator.xor, data, 0)


def checksum_sum(data: bytes) -> int:
    """Sum of the bytes modulo 256."""
    return sum(data) & 0xFF


CHECKSUMS = {"xor": checksum_xor, "sum": checksum_sum}


@dataclass(frozen=True, slots=True)
class CounterChecksumConfig:
    """A rolling counter and/or a one-byte checksum in one frame (at least one of the two)."""

    length: int = 8                                # payload bytes protected
    counter_offset: int | None = None              # bits (AUTOSAR numbering); None: no counter
    counter_bits: int = 4                          # 1..8, inside one byte
    counter_modulo: int | None = None              # counts 0..modulo-1; None: 2**counter_bits
    max_delta_counter: int = 1                     # counter steps allowed between two valid frames
    checksum: str | None = None                    # "xor", "sum"; None: no checksum
    checksum_offset: int = 0                       # bits, multiple of 8; with a checksum only
    name: str = "counter/checksum"                 # frame name, used in error messages only
    _counter_byte: int = field(init=False, repr=False, compare=False)
    _counter_shift: int = field(init=False, repr=False, compare=False)
    _counter_mask: int = field(init=False, repr=False, compare=False)   # in its byte, shifted
    _checksum_byte: int = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        w = self.name
        _check_int(w, "length", self.length, 1, MAX_LENGTH, " bytes")
        if self.counter_offset is None and self.checksum is None:
            raise E2EConfigError(f"{w}: neither counter_offset nor checksum given, expected one or both")
        if self.checksum is not None and not (isinstance(self.checksum, str) and self.checksum in CHECKSUMS):
            raise E2EConfigError(f"{w}: checksum = {self.checksum!r}, expected one of "
                                 f"{', '.join(map(repr, CHECKSUMS))} or None")
        counter_byte = checksum_byte = -1                  # -1: none
        shift = mask = 0
        if self.counter_offset is not None:
            bits = _check_int(w, "counter_bits", self.counter_bits, 1, 8)
            _check_int(w, "counter_offset", self.counter_offset, 0, self.length * 8 - bits, " bits")
            if self.counter_offset % 8 + bits > 8:
                raise E2EConfigError(f"{w}: counter_offset {self.counter_offset} + counter_bits {bits} "
                                     "crosses a byte boundary, expected the counter inside one byte")
            if self.counter_modulo is None:
                object.__setattr__(self, "counter_modulo", 1 << bits)
            _check_int(w, "counter_modulo", self.counter_modulo, 2, 1 << bits)
            _check_int(w, "max_delta_counter", self.max_delta_counter, 1, self.counter_modulo - 1)
            counter_byte, shift = self.counter_offset >> 3, self.counter_offset & 7
            mask = ((1 << bits) - 1) << shift
        if self.checksum is not None:
            _check_int(w, "length", self.length, 2, MAX_LENGTH, " bytes (a checksum and a byte it covers)")
            _check_int(w, "checksum_offset", self.checksum_offset, 0, (self.length - 1) * 8, " bits")
            if self.checksum_offset % 8:
                raise E2EConfigError(f"{w}: checksum_offset = {self.checksum_offset}, "
                                     "expected a multiple of 8 bits")
            checksum_byte = self.checksum_offset >> 3
            if checksum_byte == counter_byte:
                raise E2EConfigError(f"{w}: counter_offset {self.counter_offset} lies in the checksum byte "
                                     f"(checksum_offset {self.checksum_offset})")
        object.__setattr__(self, "_counter_byte", counter_byte)
        object.__setattr__(self, "_counter_shift", shift)
        object.__setattr__(self, "_counter_mask", mask)
        object.__setattr__(self, "_checksum_byte", checksum_byte)

    def describe(self) -> str:
        """One line for reports, e.g. "counter (4 bits) + XOR checksum"."""
        parts = []
        if self.counter_offset is not None:
            full = self.counter_modulo == 1 << self.counter_bits
            parts.append(f"counter ({self.counter_bits} bits"
                         + ("" if full else f", 0..{self.counter_modulo - 1}") + ")")
        if self.checksum is not None:
            parts.append(f"{self.checksum.upper()} checksum")
        return " + ".join(parts)

    def _checksum_of(self, data: bytes) -> int:
        """The checksum over the protected bytes but the checksum byte."""
        i = self._checksum_byte
        return CHECKSUMS[self.checksum](data[:i] + data[i + 1:self.length])

    def protect(self, state: ProtectState, payload: bytes) -> bytes:
        """``payload`` with the counter ``state.counter`` and then the checksum written; the counter
        advanced (modulo - 1 -> 0).  Bytes past ``length`` are returned unchanged.  A payload that is too
        short or a counter out of range is a programming error of the sender: ``E2EConfigError``."""
        if len(payload) < self.length:
            raise E2EConfigError(f"{self.name}: payload of {len(payload)} bytes, expected {self.length}")
        data = bytearray(payload)
        if self._counter_byte >= 0:
            counter = state.counter
            if not 0 <= counter < self.counter_modulo:
                raise E2EConfigError(f"{self.name}: sender counter {counter!r}, "
                                     f"expected 0..{self.counter_modulo - 1}")
            i = self._counter_byte
            data[i] = (data[i] & ~self._counter_mask & 0xFF) | (counter << self._counter_shift)
            state.counter = (counter + 1) % self.counter_modulo
        if self._checksum_byte >= 0:
            data[self._checksum_byte] = self._checksum_of(data)
        return bytes(data)

    def check(self, state: CheckState, payload: bytes | None) -> tuple[CheckState, Status]:
        """(new state, status) for one receiver cycle, as ``hil.can.e2e.check`` (module docstring).
        Never raises on the payload."""
        if payload is None:
            return state, Status.NONEWDATA
        if len(payload) != self.length:
            return state, Status.ERROR
        if self._checksum_byte >= 0 and payload[self._checksum_byte] != self._checksum_of(payload):
            return state, Status.ERROR
        if self._counter_byte < 0:
            return state, Status.OK
        received = (payload[self._counter_byte] & self._counter_mask) >> self._counter_shift
        if received >= self.counter_modulo:
            return state, Status.ERROR
        return counter_check(state, received, self.counter_modulo, self.max_delta_counter)
