"""CRC-15 and bit stuffing of a classic CAN frame, a byte at a time: the tables, and the numba kernel that
runs them over a frame's payload.

The CRC-15 of the CAN 2.0 specification (polynomial 0x4599, over SOF..data) and the transmitter's bit
stuffing (a complement bit after every 5 equal bits, from SOF to the end of the CRC sequence; stuff bits
count towards the next run) as tables:

* ``CRC_TABLE[b]``: the CRC register's change for the byte ``b`` (a 256-entry table, the usual byte-wise CRC).
* ``STUFF_TABLES[w][(state << w) | chunk]``: the stuffing state machine over a chunk of ``w`` bits (1..8),
  as (state after it, stuff bits inserted).  A state is ``last * 6 + run`` (last bit, run length 0..5;
  run 0 only before the first bit).

`hil.can.bustiming` runs them over a frame's head in Python (`crc15`, `stuff_bits`, `FrameBits`) and, per
frame, over its payload and CRC here (`payload_bits`).  This module is apart because numba compiles it:
mypyc, which compiles bustiming, cannot compile a module that uses numba.
"""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np

__all__ = ["CRC15_POLY", "CRC_TABLE", "STUFF_TABLES", "payload_bits"]

CRC15_POLY = 0x4599          # x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1 (CAN 2.0 spec, §3.1.1)


def _crc15_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 7
        for _ in range(8):
            crc = ((crc << 1) ^ CRC15_POLY) if crc & 0x4000 else (crc << 1)
        table.append(crc & 0x7FFF)
    return table


def _stuff_tables() -> list[list[tuple[int, int]]]:
    tables: list[list[tuple[int, int]]] = [[]]
    for width in range(1, 9):
        table = []
        for state in range(12):
            for chunk in range(1 << width):
                last, run = divmod(state, 6)
                stuffs = 0
                for i in range(width - 1, -1, -1):
                    bit = (chunk >> i) & 1
                    if run and bit == last:
                        run += 1
                    else:
                        last, run = bit, 1
                    if run == 5:            # five equal bits: a complement bit follows
                        stuffs += 1
                        last, run = 1 - last, 1
                table.append((last * 6 + run, stuffs))
        tables.append(table)
    return tables


CRC_TABLE = _crc15_table()
STUFF_TABLES = _stuff_tables()
# the tables as arrays, for the kernel: numba takes a global array as a constant of the compiled code
# (passing the five as arguments costs ~180 ns each a call, measured, against ~0.3 µs for the kernel)
_CRC_NP = np.array(CRC_TABLE, dtype=np.int64)
_STUFF8_STATE, _STUFF8_N = (np.array(col, dtype=np.int64) for col in zip(*STUFF_TABLES[8], strict=True))
_STUFF7_STATE, _STUFF7_N = (np.array(col, dtype=np.int64) for col in zip(*STUFF_TABLES[7], strict=True))


def _payload_bits(crc: int, state: int, total: int, fixed: int, payload: bytes) -> int:
    """The CRC-15 and the stuffing state machine over the payload a byte at a time, then over the 15 CRC
    bits (7, then 8), from the CRC register `crc`, stuffing state `state` and `total` stuff bits after
    the frame's head: `fixed` (the frame's bits without stuffing) + every stuff bit of the frame."""
    for byte in payload:
        crc = ((crc << 8) & 0x7FFF) ^ _CRC_NP[((crc >> 7) ^ byte) & 0xFF]
        k = (state << 8) | byte
        state, total = _STUFF8_STATE[k], total + _STUFF8_N[k]
    k = (state << 7) | (crc >> 8)
    state, total = _STUFF7_STATE[k], total + _STUFF7_N[k]
    # int(): interpreted (NUMBA_DISABLE_JIT) the sum is a numpy.int64, which compiled bustiming refuses
    return int(fixed + total + _STUFF8_N[(state << 8) | (crc & 0xFF)])


#: `_payload_bits` compiled by numba: ~0.3 µs a frame against ~2.5 µs interpreted.  The lockstep bus
#: sizes every frame with it (payloads rarely repeat: alive counters and MACs).
payload_bits: Callable[[int, int, int, int, bytes], int] = numba.njit(cache=True)(_payload_bits)


def load_payload_bits() -> None:
    """Load `payload_bits`'s machine code (from numba's cache, else compiled) now, not in the middle of
    a run; nothing when numba is off (NUMBA_DISABLE_JIT: a plain function)."""
    if not getattr(payload_bits, "signatures", True):
        payload_bits(0, 0, 0, 0, b"")
