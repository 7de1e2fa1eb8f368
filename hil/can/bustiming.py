"""The bit-timed CAN bus of lockstep mode: frame durations, arbitration and per-node transmit queues.

Pure logic, no I/O: `hil.runtime.lockstep` drives it from its event schedule.  Times are integer nanoseconds.

Frame duration (classic CAN, ISO 11898-1 frame layout), in bit times, interframe space included:

* ``exact``  — the frame's real bits: SOF, arbitration and control fields, data, CRC-15 (polynomial
  0x4599 of the CAN 2.0 specification, over SOF..data) are built, and a stuff bit is counted after
  every 5 equal bits from SOF to the end of the CRC sequence (stuff bits count towards the next run);
  plus the 13 unstuffed bits (CRC delimiter, ACK slot and delimiter, 7 EOF bits, 3 interframe bits).
* ``worst``  — Davis et al. 2007 eq. (15): 55 + 10 s bits (11-bit id), 80 + 10 s (29-bit), s bytes.
* ``none``   — no stuff bits: 47 + 8 s (11-bit), 67 + 8 s (29-bit).

An 8-byte 11-bit frame at 500 kbit/s therefore occupies the bus 222 µs (no stuffing) to 270 µs
(worst case).  A frame is delivered to its receivers (and the trace) at the end of its EOF, 3 bit
times before the bus is idle again.

Arbitration (`BitTimedBus.arbitrate`): when the bus is idle, the head of every node's transmit queue
competes; the lowest arbitration field wins, compared bit by bit as on the wire: 11 base-id bits,
then an 11-bit frame's RTR/IDE (dominant) beat a 29-bit frame's SRR/IDE (recessive), then the 18
extension bits.  Each node's queue is ordered by that same priority (the queue Davis et al. assume);
a frame released while an older frame of the same id still waits in that node's queue replaces it
(one transmit buffer per message, as AUTOSAR CanIf buffers a PDU): the older one is *overwritten*,
counted, and is a deadline miss.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

from hil.can.busload import arbitration_key, frame_bits
from hil.can.stuffing import CRC15_POLY, CRC_TABLE, STUFF_TABLES, load_payload_bits, payload_bits

__all__ = ["STUFFING_MODES", "BitTimedBus", "FrameBits", "Pending", "arbitration_key", "crc15",
           "exact_frame_bits", "frame_duration_bits", "stuff_bits"]

STUFFING_MODES = ("exact", "worst", "none")
UNSTUFFED_TAIL_BITS = 13     # CRC delimiter, ACK slot, ACK delimiter, EOF (7), interframe space (3)
IFS_BITS = 3                 # interframe space: after delivery, before the bus is idle


def crc15(value: int, nbits: int) -> int:
    """CRC-15/CAN of the `nbits`-bit stream `value` (most significant bit first).

    A generic CRC library works on whole bytes; the CAN CRC runs over 19 + 8s (11-bit) or 39 + 8s
    (29-bit) bits, so the leading nbits mod 8 bits go one at a time and the rest by table.
    """
    crc = 0
    lead = nbits % 8
    for i in range(nbits - 1, nbits - 1 - lead, -1):
        bit = (value >> i) & 1
        top = (crc >> 14) & 1
        crc = (crc << 1) & 0x7FFF
        if top ^ bit:
            crc ^= CRC15_POLY
    for shift in range(nbits - lead - 8, -1, -8):
        crc = ((crc << 8) & 0x7FFF) ^ CRC_TABLE[((crc >> 7) ^ (value >> shift)) & 0xFF]
    return crc


def _stuff_run(state: int, value: int, nbits: int) -> tuple[int, int]:
    """Run the stuffing state machine from `state` over the `nbits`-bit stream `value` (MSB first):
    (state after it, stuff bits inserted)."""
    total = 0
    lead = nbits % 8
    if lead:
        state, total = STUFF_TABLES[lead][(state << lead) | (value >> (nbits - lead))]
    table = STUFF_TABLES[8]
    for shift in range(nbits - lead - 8, -1, -8):
        state, n = table[(state << 8) | ((value >> shift) & 0xFF)]
        total += n
    return state, total


def stuff_bits(value: int, nbits: int) -> int:
    """Number of stuff bits a transmitter inserts into the `nbits`-bit stream `value` (MSB first)."""
    return _stuff_run(0, value, nbits)[1]


class FrameBits:
    """Exact bit times of the data frames of one (identifier, format, DLC, payload length).

    The head of such a frame (SOF, arbitration and control fields) never changes, so its CRC register
    and stuffing state are computed once; `bits(payload)` then runs the CRC-15 and the stuffing state
    machine over the payload a byte at a time, and over the 15 CRC bits.  The same bits as stuffing the
    whole frame at once (`exact_frame_bits`, which is built on this), in about a fifth of the time: the
    lockstep bus sizes every frame this way (payloads rarely repeat: alive counters and MACs), by
    `hil.can.stuffing.payload_bits`, which numba compiles.
    """

    __slots__ = ("payload_bytes", "_crc", "_state", "_stuffs", "_fixed")
    payload_bytes: int
    _crc: int           # the CRC register after the head
    _state: int         # the stuffing state after the head
    _stuffs: int        # stuff bits in the head
    _fixed: int         # the frame's bits without stuffing

    def __init__(self, frame_id: int, extended: bool, dlc: int, payload_bytes: int,
                 remote: bool = False) -> None:
        rtr = 1 if remote else 0
        if extended:
            base, ext = frame_id >> 18, frame_id & 0x3FFFF
            # SOF, 11 base bits, SRR=1, IDE=1, 18 extension bits, RTR, r1=0, r0=0, DLC
            head = (((((base << 2) | 0b11) << 18 | ext) << 3 | rtr << 2) << 4) | (dlc & 0xF)
            head_bits = 1 + 11 + 2 + 18 + 3 + 4
        else:
            # SOF, 11 id bits, RTR, IDE=0, r0=0, DLC
            head = ((frame_id << 3 | rtr << 2) << 4) | (dlc & 0xF)
            head_bits = 1 + 11 + 3 + 4
        self.payload_bytes = payload_bytes
        self._crc = crc15(head, head_bits)
        self._state, self._stuffs = _stuff_run(0, head, head_bits)
        self._fixed = head_bits + 8 * payload_bytes + 15 + UNSTUFFED_TAIL_BITS

    def bits(self, payload: bytes) -> int:
        """Bit times of the frame with this payload (`payload_bytes` long), interframe space included."""
        return payload_bits(self._crc, self._state, self._stuffs, self._fixed, payload)


def exact_frame_bits(frame_id: int, extended: bool, data: bytes, remote: bool = False,
                     dlc: int | None = None) -> int:
    """Bit times of one classic CAN frame with its real stuff bits, interframe space included."""
    dlc = len(data) if dlc is None else dlc
    payload = b"" if remote else bytes(data[:8])
    return FrameBits(frame_id, extended, dlc, len(payload), remote).bits(payload)


def frame_duration_bits(frame_id: int, extended: bool, data: bytes, stuffing: str = "exact") -> int:
    """Bit times one data frame occupies the bus, by the chosen stuffing model (module docstring)."""
    if stuffing == "exact":
        return exact_frame_bits(frame_id, extended, data)
    if stuffing == "worst":
        return frame_bits(len(data), extended)
    if stuffing == "none":
        return frame_bits(len(data), extended, worst_case_stuffing=False)
    raise ValueError(f"stuffing must be one of {', '.join(STUFFING_MODES)}, got {stuffing!r}")


@dataclass(slots=True)
class Pending:
    """A frame in a node's transmit queue."""

    node: int
    frame_id: int
    extended: bool
    data: bytes
    released_ns: int          # entered the transmit queue
    window_ns: int            # start of its release window (nominal release - max early jitter)
    # what the runner needs at delivery (the frame's codec); `object | None`, not `object`, which mypyc's
    # dataclass support cannot name at import (KeyError: 'object', mypyc 2.4)
    item: object | None = None
    key: int = 0
    overwritten: bool = False


@dataclass
class MessageBusStats:
    """What the bus did to one message: frames carried, response times, losses."""

    frames: int = 0
    overwritten: int = 0       # a newer instance replaced it in the queue before it was sent
    deadline_misses: int = 0   # response > deadline, plus the overwritten ones
    response_max_ns: int = 0   # end of frame (with interframe space) - start of its release window
    response_sum_ns: int = 0
    queued_max_ns: int = 0     # start of transmission - release into the queue
    bits: int = 0


class BitTimedBus:
    """Transmit queues, arbitration and frame timing; `hil.runtime.lockstep` calls enqueue/arbitrate."""

    bitrate_bps: int
    n_nodes: int
    stuffing: str                                  # one of STUFFING_MODES (module docstring)
    deadlines_ns: dict[int, int]                   # frame id -> deadline (its cycle)
    idle_at_ns: int                                # the bus is busy until then
    busy_ns: int                                   # time the bus has carried frames so far
    stats: dict[int, MessageBusStats]              # frame id -> what the bus did to its frames
    # Every node's queue is ordered by priority, so the head that wins arbitration is the lowest key among
    # all waiting frames: one heap of them all (key, sequence, frame) gives the same winner in O(log n).
    _heap: list[tuple[int, int, Pending]]
    _waiting: dict[tuple[int, int, bool], Pending]  # (node, frame id, extended) -> its frame in the queue
    _seq: int                                      # frames enqueued so far
    _worst: dict[tuple[int, bool], int]            # (length, extended) -> bits, the "worst"/"none" models
    _exact: dict[tuple[int, bool, int], FrameBits]  # (frame id, extended, length) -> its FrameBits

    def __init__(self, bitrate_bps: int, n_nodes: int, stuffing: str = "exact",
                 deadlines_ns: dict[int, int] | None = None) -> None:
        if stuffing not in STUFFING_MODES:
            raise ValueError(f"stuffing must be one of {', '.join(STUFFING_MODES)}, got {stuffing!r}")
        if bitrate_bps <= 0:
            raise ValueError(f"bitrate must be positive, got {bitrate_bps}")
        self.bitrate_bps = bitrate_bps
        self.n_nodes = n_nodes
        self.stuffing = stuffing
        self.deadlines_ns = {} if deadlines_ns is None else deadlines_ns
        self.idle_at_ns = 0
        self.busy_ns = 0
        self.stats = {}
        self._heap = []
        self._waiting = {}
        self._seq = 0
        self._worst = {}
        self._exact = {}
        load_payload_bits()

    def duration_ns(self, bits: int) -> int:
        """Bit times -> ns at the bitrate, rounded to the nearest ns."""
        return (bits * 1_000_000_000 + self.bitrate_bps // 2) // self.bitrate_bps

    def frame_bits(self, p: Pending) -> int:
        """Bit times of the frame `p` by the bus's stuffing model, interframe space included; the exact
        model keeps one FrameBits per (identifier, format, length) and runs only the payload through it."""
        data = p.data
        if self.stuffing != "exact":
            size = (len(data), p.extended)
            bits = self._worst.get(size)
            if bits is None:
                bits = self._worst[size] = frame_duration_bits(p.frame_id, p.extended, data, self.stuffing)
            return bits
        if len(data) > 8:
            return exact_frame_bits(p.frame_id, p.extended, data)
        shape = (p.frame_id, p.extended, len(data))
        plan = self._exact.get(shape)
        if plan is None:
            plan = self._exact[shape] = FrameBits(p.frame_id, p.extended, len(data), len(data))
        return plan.bits(data)

    def _stats(self, frame_id: int) -> MessageBusStats:
        s = self.stats.get(frame_id)
        if s is None:
            s = self.stats[frame_id] = MessageBusStats()
        return s

    def enqueue(self, p: Pending) -> None:
        """Put a released frame into its node's transmit queue (replacing a waiting older instance)."""
        p.key = arbitration_key(p.frame_id, p.extended)
        slot = (p.node, p.frame_id, p.extended)
        old = self._waiting.get(slot)
        if old is not None:
            old.overwritten = True          # lazily dropped from the queue heap
            s = self._stats(p.frame_id)
            s.overwritten += 1
            s.deadline_misses += 1
        self._waiting[slot] = p
        self._seq += 1
        heapq.heappush(self._heap, (p.key, self._seq, p))

    def pending(self) -> bool:
        return bool(self._waiting)

    def is_waiting(self, node: int, frame_id: int, extended: bool) -> bool:
        """Does `node` have a frame of this id in its transmit queue?"""
        return (node, frame_id, extended) in self._waiting

    def waiting(self) -> int:
        """Frames in the transmit queues."""
        return len(self._waiting)

    def arbitrate(self, now_ns: int) -> tuple[Pending, int, int] | None:
        """Start the winning frame at `now_ns` (bus idle): (frame, delivery time, bus idle again)."""
        if now_ns < self.idle_at_ns:
            raise ValueError(f"arbitration at {now_ns} ns while the bus is busy until {self.idle_at_ns} ns")
        heap = self._heap
        while heap and heap[0][2].overwritten:
            heapq.heappop(heap)
        if not heap:
            return None
        best = heapq.heappop(heap)[2]
        del self._waiting[(best.node, best.frame_id, best.extended)]
        bits = self.frame_bits(best)
        deliver = now_ns + self.duration_ns(bits - IFS_BITS)
        end = now_ns + self.duration_ns(bits)
        self.idle_at_ns = end
        self.busy_ns += end - now_ns
        s = self._stats(best.frame_id)
        s.frames += 1
        s.bits += bits
        response = end - best.window_ns
        s.response_max_ns = max(s.response_max_ns, response)
        s.response_sum_ns += response
        s.queued_max_ns = max(s.queued_max_ns, now_ns - best.released_ns)
        deadline = self.deadlines_ns.get(best.frame_id)
        if deadline is not None and response > deadline:
            s.deadline_misses += 1
        return best, deliver, end
