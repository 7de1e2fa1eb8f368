"""Worst-case response times of the cyclic messages of a classic CAN bus, from the DBC alone, and an
estimate of the response times a trace actually shows.  Pure analysis; nothing here prints.

Analysis: Davis, Burns, Bril, Lukkien, "Controller Area Network (CAN) schedulability analysis:
refuted, revisited and revised", Real-Time Systems 35(3):239-272, 2007, Sect. 3.3, the revised
analysis for fixed-priority non-preemptive arbitration.  Model (the paper's Sect. 2-3): every node
queues its ready frames in priority order and always offers its highest-priority one to arbitration;
message m is sent periodically (or sporadically, at least T_m apart) with queuing jitter J_m; no
errors on the bus; every frame has its worst-case number of stuff bits.  Symbols (times in µs):

* C_m    transmission time: ``hil.can.busload.frame_bits(dlc, extended)`` bit times (worst-case stuffing,
         3-bit interframe space included, the paper's frame-length equation) x τ_bit = 1 / bitrate
* B_m    blocking: the longest frame of lower priority, which may just have started        (eq. 5)
* t_m    priority level-m busy period:  t = B_m + Σ_{k ∈ hep(m)} ⌈(t + J_k) / T_k⌉ C_k,
         iterated from t = C_m                                                              (eq. 7)
* Q_m    instances of m queued in that busy period: ⌈(t_m + J_m) / T_m⌉                      (eq. 8)
* w_m(q) queuing delay of instance q = 0 .. Q_m - 1:
         w = B_m + q C_m + Σ_{k ∈ hp(m)} ⌈(w + J_k + τ_bit) / T_k⌉ C_k                       (eq. 9)
* R_m(q) = J_m + w_m(q) - q T_m + C_m                                                        (eq. 10)
* R_m    = max_q R_m(q); schedulable when R_m <= D_m (D_m = T_m unless given)               (eq. 11)

(Equation numbers as we read them in the paper; the notation and every formula above are the
paper's, so the numbers only help to find them.)  hp(m) / hep(m): messages of higher / higher or
equal priority than m.  The busy period and the queuing delays converge when the utilisation of
hep(m), Σ C_k / T_k, is below 1; at 1 or above, or when the busy period exceeds BUSY_PERIOD_LIMIT_US,
R_m is unbounded: ``math.inf``, not schedulable.  Arithmetic is exact: times are integers in units of
1 / (bitrate x 10^6) s (1 µs = bitrate units, one bit time = 10^6 units), so no ceiling is ever off
by a rounding error.

Priority: the arbitration field as the bus compares it (``hil.can.busload.arbitration_key``): the 11
base id bits first, then an 11-bit data frame's dominant RTR/IDE bits beat a 29-bit frame's
recessive SRR/IDE bits, then the 18 extension bits.  So 0x100 (11-bit) beats every 29-bit id whose
11 base bits are 0x100, and 29-bit 0x00CC0001 (base 0x033) beats 11-bit 0x123.  Two messages with
the same arbitration field cannot share a bus: an error.

Measured response (``measured_response``): see its docstring.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np
from cantools.database.can import Database

from hil.can.busload import arbitration_key, frame_bits
from hil.can.dbc import closest
from hil.errors import DbcError, RailhilError

__all__ = [
    "BUSY_PERIOD_LIMIT_US", "MeasuredResponse", "RtaError", "RtaMessage", "RtaReport", "RtaResult",
    "analyse", "measured_response", "messages_from_dbc", "priority_key",
]

BUSY_PERIOD_LIMIT_US = 60_000_000  # a level-m busy period longer than 60 s is reported unbounded (chosen)
BIT_UNITS = 1_000_000  # one bit time in the exact time unit 1 / (bitrate·10^6) s


class RtaError(RailhilError, ValueError):
    """A message set or option the response-time analysis cannot take (bad period, duplicate id...)."""


@dataclass(frozen=True)
class RtaMessage:
    """One periodic (or sporadic, at least `period_us` apart) classic CAN message.

    period_us T, deadline_us D (relative to the release), jitter_us J (queuing jitter: the latest
    queuing after the release), all in µs; dlc 0..15 (9..15 mean 8 bytes); sender is informative.
    """

    name: str
    frame_id: int
    extended: bool
    dlc: int
    period_us: int
    deadline_us: int
    jitter_us: int = 0
    sender: str = ""


@dataclass(frozen=True)
class RtaResult:
    """The analysis of one message; times in µs (``math.inf`` where unbounded).

    c_us C_m; blocking_us B_m; busy_period_us t_m; instances Q_m (0 when the busy period is
    unbounded); response_us the worst-case response time R_m from release to the end of the frame
    (interframe space included); schedulable R_m <= D_m.
    """

    message: RtaMessage
    c_us: float
    blocking_us: float
    busy_period_us: float
    instances: int
    response_us: float  # worst case, math.inf when unbounded
    schedulable: bool

    @property
    def unbounded(self) -> bool:
        return math.isinf(self.response_us)


@dataclass(frozen=True)
class RtaReport:
    """All messages, highest priority first; utilisation Σ C_m / T_m over all of them (0.52 = 52 %)."""

    bitrate_bps: int
    utilisation: float
    results: tuple[RtaResult, ...]  # by priority (id order)

    @property
    def ok(self) -> bool:
        return all(r.schedulable for r in self.results)

    def by_name(self) -> dict[str, RtaResult]:
        return {r.message.name: r for r in self.results}


def priority_key(frame_id: int, extended: bool) -> int:
    """Smaller wins arbitration (the module docstring)."""
    return arbitration_key(frame_id, extended)


def _check(m: RtaMessage) -> None:
    if not isinstance(m.period_us, int) or m.period_us <= 0:
        raise RtaError(f"message {m.name}: period must be a positive whole number of µs, got {m.period_us!r}")
    if not isinstance(m.deadline_us, int) or m.deadline_us <= 0:
        raise RtaError(f"message {m.name}: deadline must be a positive whole number of µs, "
                       f"got {m.deadline_us!r}")
    if not isinstance(m.jitter_us, int) or m.jitter_us < 0:
        raise RtaError(f"message {m.name}: jitter must be a whole number of µs >= 0, got {m.jitter_us!r}")
    if not 0 <= m.dlc <= 15:
        raise RtaError(f"message {m.name}: DLC must be 0..15, got {m.dlc}")
    if not 0 <= m.frame_id <= (0x1FFFFFFF if m.extended else 0x7FF):
        raise RtaError(f"message {m.name}: id 0x{m.frame_id:x} does not fit a "
                       f"{'29' if m.extended else '11'}-bit identifier")


def _ceil_div(a: int, b: int) -> int:
    return -(-a // b)


def analyse(messages: Sequence[RtaMessage], bitrate_bps: int) -> RtaReport:
    """Worst-case response time of every message on a bus at `bitrate_bps` (module docstring)."""
    if not isinstance(bitrate_bps, int) or bitrate_bps <= 0:
        raise RtaError(f"bitrate must be a positive whole number of bit/s, got {bitrate_bps!r}")
    for m in messages:
        _check(m)
    ordered = sorted(messages, key=lambda m: priority_key(m.frame_id, m.extended))
    for a, b in zip(ordered, ordered[1:], strict=False):
        if priority_key(a.frame_id, a.extended) == priority_key(b.frame_id, b.extended):
            raise RtaError(f"messages {a.name} and {b.name} have the same identifier 0x{a.frame_id:x}: "
                           f"they cannot share a bus")
    unit = bitrate_bps  # exact time units per µs
    c = [frame_bits(m.dlc, m.extended) * BIT_UNITS for m in ordered]
    t = [m.period_us * unit for m in ordered]
    j = [m.jitter_us * unit for m in ordered]
    d = [m.deadline_us * unit for m in ordered]
    tau = BIT_UNITS
    limit = BUSY_PERIOD_LIMIT_US * unit
    n = len(ordered)
    blocking = [max(c[i + 1:], default=0) for i in range(n)]  # eq. (5)
    results = []
    u_hep = Fraction(0)

    def us(x: int) -> float:
        return x / unit

    for i, m in enumerate(ordered):
        u_hep += Fraction(c[i], t[i])
        busy = _busy_period(i, c, t, j, blocking[i], limit) if u_hep < 1 else None
        if busy is None:
            results.append(RtaResult(m, us(c[i]), us(blocking[i]), math.inf, 0, math.inf, False))
            continue
        q_count = _ceil_div(busy + j[i], t[i])  # eq. (8)
        worst: int | None = None
        w: int | None = blocking[i]
        for q in range(q_count):
            # eq. (9) iterated from B_m for q = 0, from w_m(q-1) + C_m after: w_m(q) >= w_m(q-1) + C_m,
            # so the iteration still ends at the least fixed point
            w = _queuing_delay(i, q, c, t, j, blocking[i], tau, w + c[i] if q else blocking[i], limit)
            if w is None:
                break
            r = j[i] + w - q * t[i] + c[i]  # eq. (10)
            worst = r if worst is None else max(worst, r)  # eq. (11)
        if w is None or worst is None:
            results.append(RtaResult(m, us(c[i]), us(blocking[i]), us(busy), q_count, math.inf, False))
            continue
        results.append(RtaResult(m, us(c[i]), us(blocking[i]), us(busy), q_count, us(worst), worst <= d[i]))
    utilisation = float(sum((Fraction(ci, ti) for ci, ti in zip(c, t, strict=True)), Fraction(0)))
    return RtaReport(bitrate_bps, utilisation, tuple(results))


def _busy_period(i: int, c: list[int], t: list[int], j: list[int], b: int, limit: int) -> int | None:
    """Length of the priority level-i busy period (eq. 7), None beyond `limit`."""
    busy = c[i]
    while True:
        nxt = b + sum(_ceil_div(busy + j[k], t[k]) * c[k] for k in range(i + 1))
        if nxt == busy:
            return busy
        if nxt > limit:
            return None
        busy = nxt


def _queuing_delay(i: int, q: int, c: list[int], t: list[int], j: list[int], b: int, tau: int, start: int,
                   limit: int) -> int | None:
    """w_i(q) of eq. (9) iterated from `start`, None beyond `limit`."""
    w = start
    while True:
        nxt = b + q * c[i] + sum(_ceil_div(w + j[k] + tau, t[k]) * c[k] for k in range(i))
        if nxt == w:
            return w
        if nxt > limit:
            return None
        w = nxt


def _node_attr(db: Database, node_name: str, attr: str) -> float | None:
    node = next((n for n in db.nodes if n.name == node_name), None)
    attrs = getattr(getattr(node, "dbc", None), "attributes", None) or {}
    a = attrs.get(attr)
    return None if a is None else float(a.value)


def messages_from_dbc(db: Database, jitter_us: Mapping[str, int] | None = None) -> list[RtaMessage]:
    """The cyclic messages of `db` (``GenMsgCycleTime`` > 0) as RtaMessages, in DBC order.

    T = the cycle time, D = T.  Queuing jitter J of a message: `jitter_us[name]` when given (µs); else
    from its (first) sender node's CANdb++ attributes ``CANoeJitterMin`` / ``CANoeJitterMax`` when
    the node has both: J = (max - min) / 100 x T, rounded to the µs.  CANoe gives these in percent of
    the timer interval (the same reading as hil.runtime.release), and the interval of a message's timer is
    its cycle time; the width of the interval is what delays a release beyond its earliest time.
    Else J = 0.  CAN FD messages are not modelled: an error.  A name in `jitter_us` that is not a
    cyclic message of the DBC is an error (a typo would otherwise be silently ignored).
    """
    jitter_us = dict(jitter_us or {})
    names = [m.name for m in db.messages]
    cyclic = [m for m in db.messages if m.cycle_time and m.cycle_time > 0]
    cyclic_names = {m.name for m in cyclic}
    for name, value in jitter_us.items():
        if name not in names:
            raise RtaError(f"--jitter {name}: no message named {name!r} in the DBC (closest: "
                           f"{closest(name, names)})")
        if name not in cyclic_names:
            raise RtaError(f"--jitter {name}: message {name} has no GenMsgCycleTime: it is not analysed")
        if not isinstance(value, int) or value < 0:
            raise RtaError(f"--jitter {name}={value}: expected a whole number of µs >= 0")
    out = []
    for m in cyclic:
        if m.is_fd or m.length > 8:
            raise DbcError(f"frame {m.name} (0x{m.frame_id:x}) is CAN FD: its response time is not modelled")
        period = round(m.cycle_time * 1000)
        sender = m.senders[0] if m.senders else ""
        if m.name in jitter_us:
            jitter = jitter_us[m.name]
        else:
            jmin = _node_attr(db, sender, "CANoeJitterMin") if sender else None
            jmax = _node_attr(db, sender, "CANoeJitterMax") if sender else None
            jitter = 0
            if jmin is not None and jmax is not None:
                if jmax < jmin:
                    raise DbcError(f"node {sender}: CANoeJitterMax {jmax:g} is below CANoeJitterMin {jmin:g}")
                jitter = round((jmax - jmin) / 100 * period)
        out.append(RtaMessage(m.name, m.frame_id, bool(m.is_extended_frame), m.length, period, period,
                              jitter, sender))
    return out


@dataclass(frozen=True)
class MeasuredResponse:
    """Response times of one message estimated from its frames' timestamps (``measured_response``)."""

    frames: int  # frames used
    cycles: int  # cycles spanned, first to last frame
    missed: int  # cycles of that span without a frame
    period_us: float  # fitted period (the sender's clock as the trace's clock sees it)
    drift_ppm: float  # fitted period / nominal period - 1, in parts per million
    p50_us: float
    p99_us: float
    max_us: float
    responses_us: np.ndarray = field(repr=False)  # per frame, in time order


def _cycle_indices(t: np.ndarray, period_s: float) -> np.ndarray:
    """The cycle index k_i of each frame (see measured_response)."""
    gaps = np.diff(t)
    near = gaps[np.abs(gaps / period_s - 1) < 0.5]
    local = float(np.median(near)) if len(near) else period_s  # the period as the trace's clock sees it
    steps = np.rint(gaps / local).astype(np.int64)
    k = np.concatenate(([0], np.cumsum(steps)))
    for i in np.flatnonzero(steps == 0):  # two frames in one cycle: a frame late by more than T/2?
        if i > 0 and k[i - 1] < k[i] - 1:
            k[i] -= 1
    return k


def measured_response(t_s: np.ndarray, period_us: float, c_us: float) -> MeasuredResponse | None:
    """Estimated response times of the frames of one cyclic message, from their timestamps alone.

    A trace has the end of each frame, not its release.  Releases of a cyclic message lie on a grid
    φ + k·T' (T' the period the sender's clock really keeps, as the trace's clock sees it), so:

    1. Cycle index k_i of each frame t_i (seconds, any order; sorted here): successive gaps rounded
       to whole periods, k_i = k_(i-1) + round((t_i - t_(i-1)) / T_loc), T_loc the median of the gaps
       within ±50 % of the nominal period `period_us` (drift-corrected locally; a missed frame
       makes a gap of 2, so k counts it).  Two frames in one cycle (a gap rounding to 0) mean the
       earlier one was late by more than T/2: it moves to the cycle before when that has no frame.
    2. Drift-corrected fit: least squares t_i ≈ a + T'·k_i.  Residual r_i = t_i - (a + T'·k_i).
    3. The earliest frame relative to the grid, min r_i, is taken as not queued at all: it completed
       C after its release (C = `c_us`, the frame's worst-case transmission time).  So the release
       of cycle k is a + min r + T'·k - C, and the measured response of frame i is

           R_i = r_i - min_j r_j + C      [µs]

    R_i never exceeds the true response: the earliest frame may have waited too (blocking,
    interference), and frames shorter than C (fewer stuff bits) make it err by less than C - C_min.
    Release jitter of the sender shows up in R_i, as it does in the bound.  With fewer than two
    frames, all in one cycle, or a fitted period off the nominal one by more than 50 %, there is no
    cycle to fit: None.
    """
    t = np.sort(np.asarray(t_s, dtype=np.float64))
    if len(t) < 2 or not period_us > 0:
        return None
    t = t - t[0]
    k = _cycle_indices(t, period_us * 1e-6)
    if k[-1] == k[0]:
        return None
    slope, intercept = np.polyfit(k.astype(np.float64), t, 1)
    if abs(slope * 1e6 / period_us - 1) > 0.5:  # not a cycle of this period (a burst of frames)
        return None
    resid = t - (intercept + slope * k)
    responses = (resid - resid.min()) * 1e6 + c_us
    p50, p99 = np.percentile(responses, [50, 99])
    cycles = int(k[-1] - k[0] + 1)
    return MeasuredResponse(
        frames=len(t), cycles=cycles, missed=cycles - len(np.unique(k)), period_us=float(slope * 1e6),
        drift_ppm=float((slope * 1e6 / period_us - 1) * 1e6), p50_us=float(p50), p99_us=float(p99),
        max_us=float(responses.max()), responses_us=responses,
    )
