"""CAN frame lengths and the static bus load of a DBC's cyclic frames.

Frame length: Davis, Burns, Bril, Lukkien, "Controller Area Network (CAN) schedulability analysis:
refuted, revisited and revised", Real-Time Systems 35(3), 2007, eq. (15):

    C = (g + 8s + 13 + floor((g + 8s - 1) / 4)) bit times

with s data bytes and g = 34 (11-bit identifier) or 54 (29-bit identifier) bits of the frame
subject to bit stuffing; the 13 bits that are not (CRC delimiter, ACK slot, ACK delimiter, 7 bits of
end of frame) include the 3-bit interframe space, as in Davis et al.  So an 8-byte frame occupies
the bus for 135 bit times (11-bit) or 160 (29-bit) at worst, 111 or 131 without stuffing.  The worst
case is 55 + 10s (11-bit) and 80 + 10s (29-bit).

Static load: every cyclic frame (DBC ``GenMsgCycleTime`` > 0) sent once per cycle, at its
worst-case length, over the bus bitrate (DBC ``Baudrate``).  It is the figure a CAN engineer
checks first; it says nothing about queuing, jitter or errors.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass

from cantools.database.can import Database

from hil.errors import DbcError

__all__ = ["BusLoad", "FrameLoad", "frame_bits", "static_load", "train_frame_ids"]

_STUFFED_BITS = {False: 34, True: 54}  # g of Davis et al. 2007: 11-bit / 29-bit identifier
_UNSTUFFED_BITS = 13  # CRC delimiter, ACK slot, ACK delimiter, EOF (7), interframe space (3)


def frame_bits(dlc: int, extended: bool, worst_case_stuffing: bool = True) -> int:
    """Length in bit times of a classic CAN data frame with `dlc` data bytes, interframe space
    included (Davis et al. 2007, eq. 15); without stuffing if `worst_case_stuffing` is False.

    A DLC of 9..15 means 8 data bytes on classic CAN (ISO 11898-1).

    >>> frame_bits(8, extended=False), frame_bits(8, extended=True)
    (135, 160)
    """
    if not 0 <= dlc <= 15:
        raise ValueError(f"DLC must be 0..15, got {dlc}")
    s = min(dlc, 8)
    g = _STUFFED_BITS[bool(extended)]
    bits = g + 8 * s + _UNSTUFFED_BITS
    if worst_case_stuffing:
        bits += (g + 8 * s - 1) // 4
    return bits


def arbitration_key(frame_id: int, extended: bool) -> int:
    """An int that orders frames as arbitration does: smaller wins.  The 11 base-id bits first, then an
    11-bit frame's RTR/IDE (dominant) beat a 29-bit frame's SRR/IDE (recessive), then the 18 extension
    bits (hil.can.bustiming, which arbitrates by it; here so that the response-time analysis, hil.can.rta,
    orders frames alike without the bus model and its compiled parts)."""
    if extended:
        return ((frame_id >> 18) << 19) | (1 << 18) | (frame_id & 0x3FFFF)
    return frame_id << 19


@dataclass(frozen=True)
class FrameLoad:
    name: str
    frame_id: int
    dlc: int
    cycle_ms: float
    bits: int  # bit times per frame
    bits_per_s: float
    load: float  # fraction of the bitrate this frame takes
    share: float  # fraction of the total load (all rows sum to 1)


@dataclass(frozen=True)
class BusLoad:
    bitrate_bps: int
    bits_per_s: float
    total: float  # fraction of the bitrate, 0.40 = 40 %
    worst_case_stuffing: bool
    rows: tuple[FrameLoad, ...]  # by frame id

    def table(self) -> str:
        """The rows as a short text table, then the total."""
        lines = [f"{'frame':<24} {'id':>10} {'dlc':>3} {'cycle ms':>8} {'bits':>5} {'load %':>7}"]
        for r in self.rows:
            lines.append(
                f"{r.name:<24} {r.frame_id:>#10x} {r.dlc:>3} {r.cycle_ms:>8g} {r.bits:>5}"
                f" {100 * r.load:>7.2f}"
            )
        stuffing = "worst-case stuffing" if self.worst_case_stuffing else "no stuffing"
        lines.append(
            f"total {100 * self.total:.1f} % of {self.bitrate_bps} bit/s "
            f"({self.bits_per_s:.0f} bit/s, {len(self.rows)} cyclic frames, {stuffing})"
        )
        return "\n".join(lines)


def declared_bitrate(db: Database) -> int | None:
    """The DBC's ``Baudrate`` attribute (its BA_ value, else its BA_DEF_DEF_ default), or None."""
    dbc = getattr(db, "dbc", None)
    if dbc is None:
        return None
    attribute = dbc.attributes.get("Baudrate")
    if attribute is not None:
        return int(attribute.value)
    definition = (dbc.attribute_definitions or {}).get("Baudrate")
    if definition is not None and definition.default_value is not None:
        return int(definition.default_value)
    return None


def static_load(
    db: Database,
    bitrate_bps: int | None = None,
    frame_ids: Iterable[int] | None = None,
    worst_case_stuffing: bool = True,
) -> BusLoad:
    """Static load of the cyclic frames of `db` (or of those among `frame_ids`).

    The bitrate is `bitrate_bps` if given, else the DBC's ``Baudrate`` attribute; a DBC without one
    needs `bitrate_bps`.  Frames with no cycle time (event frames) do not count.  CAN FD frames are
    not modelled and raise.
    """
    if bitrate_bps is None:
        bitrate_bps = declared_bitrate(db)
        if bitrate_bps is None:
            raise DbcError(
                "the DBC has no 'Baudrate' attribute, so the bus bitrate is unknown: "
                "pass bitrate_bps, e.g. static_load(db, bitrate_bps=500_000)"
            )
    if bitrate_bps <= 0:
        raise ValueError(f"bitrate must be positive, got {bitrate_bps} bit/s")
    messages = db.messages
    if frame_ids is not None:
        wanted = set(frame_ids)
        unknown = wanted - {m.frame_id for m in messages}
        if unknown:
            raise DbcError(f"frame ids not in the DBC: {', '.join(hex(i) for i in sorted(unknown))}")
        messages = [m for m in messages if m.frame_id in wanted]
    rows = []
    for m in sorted(messages, key=lambda m: m.frame_id):
        if not m.cycle_time or m.cycle_time <= 0:
            continue
        if m.is_fd or m.length > 8:
            raise DbcError(f"frame {m.name} (0x{m.frame_id:x}) is CAN FD: its length is not modelled")
        bits = frame_bits(m.length, m.is_extended_frame, worst_case_stuffing)
        rate = bits * 1000.0 / m.cycle_time
        rows.append((m, bits, rate))
    total_rate = sum(rate for _, _, rate in rows)
    return BusLoad(
        bitrate_bps=bitrate_bps,
        bits_per_s=total_rate,
        total=total_rate / bitrate_bps,
        worst_case_stuffing=worst_case_stuffing,
        rows=tuple(
            FrameLoad(
                name=m.name,
                frame_id=m.frame_id,
                dlc=m.length,
                cycle_ms=float(m.cycle_time),
                bits=bits,
                bits_per_s=rate,
                load=rate / bitrate_bps,
                share=rate / total_rate,
            )
            for m, bits, rate in rows
        ),
    )


_PER_CAR = re.compile(r"^(?:BECU|PLANT_CAR)(\d+)_")
FUNCTION_ATTRIBUTE = "RailhilFunction"   # DBC message attribute: the optional function a frame belongs to


def optional_function(msg) -> str:
    """The optional function a message belongs to (its DBC attribute RailhilFunction, e.g.
    "consensus"), or "" for a frame of the train's base functions."""
    attrs = msg.dbc.attributes if msg.dbc is not None else {}
    attr = attrs.get(FUNCTION_ATTRIBUTE)
    return str(attr.value) if attr is not None and attr.value else ""


def functions_of(db: Database) -> list[str]:
    """The optional functions the DBC's frames belong to (attribute RailhilFunction), sorted."""
    return sorted({f for f in map(optional_function, db.messages) if f})


def with_functions(db: Database, functions: list[str] | tuple[str, ...]) -> Database:
    """`db` with the frames of the train's base functions and of the optional `functions` only ("all":
    every frame).  A DBC without RailhilFunction attributes comes back whole.  An unknown function is a
    DbcError naming the known ones."""
    known = functions_of(db)
    if not known or "all" in functions:
        return db
    for f in functions:
        if f not in known:
            raise DbcError(f"--function {f!r}: no frame of the DBC belongs to it; its optional functions are "
                           f"{', '.join(known)} (or 'all')")
    keep = [m for m in db.messages if optional_function(m) in ("", *functions)]
    return Database(messages=keep, nodes=db.nodes, buses=db.buses, version=db.version,
                    dbc_specifics=db.dbc, strict=False)


def train_frame_ids(db: Database, n_cars: int) -> list[int]:
    """The frame ids on the bus in a run of train_brake.dbc with `n_cars` cars, sorted.

    Rule: a per-car frame -- ``BECU<k>_...`` or ``PLANT_CAR<k>_...`` -- is kept only if k <= n_cars; a
    frame of an optional function (DBC attribute ``RailhilFunction``: the anti-collision device and its
    radio, the studies' frames, precise stopping, balises) is left out, since the default run has none of
    them; every other frame (BCU, DESK, ...) is kept.
    """
    cars = {int(m.group(1)) for m in map(_PER_CAR.match, (msg.name for msg in db.messages)) if m}
    if not cars:
        raise DbcError("the DBC has no per-car frames (BECU<k>_* or PLANT_CAR<k>_*)")
    if not 1 <= n_cars <= max(cars):
        raise ValueError(f"n_cars must be 1..{max(cars)} for this DBC, got {n_cars}")
    ids = []
    for msg in db.messages:
        if optional_function(msg):
            continue
        car = _PER_CAR.match(msg.name)
        if car and int(car.group(1)) > n_cars:
            continue
        ids.append(msg.frame_id)
    return sorted(ids)
