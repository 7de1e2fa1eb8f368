"""Cycle-time conformance of a recorded CAN trace against the DBC's ``GenMsgCycleTime``, and the
bus load the trace really put on the bus.  Pure analysis with numpy; nothing here prints.

Periods.  For every data frame id (11-bit and 29-bit ids apart; remote and error frames never
count) the periods are the differences of its successive timestamps, in time order.  Per id:
count, and mean / σ (numpy's std, ddof=0) / p50 / p99 (numpy's linear percentile) / min / max of
the periods, in ms.  ``measure_periods(arrays)`` gives these without a DBC.

Verdict of a message with cycle time T (ms, DBC ``GenMsgCycleTime`` > 0) and tolerance tol
(``--tolerance``, or ``--override NAME=FRACTION`` for one message), on its periods p:

* ``late``   = number of periods p > (1 + tol)·T            (reported; does not fail by itself)
* ``bursts`` = number of periods p < (1 - tol)·T            (reported; does not fail by itself)
* ``missed`` = Σ max(0, round(s_i/T)) over the periods p_i ≥ 1.5·T, where s_i is the smallest
  schedule slip Σ_(k=i..j) (p_k - T) over the CATCH_UP_PERIODS periods from i on: late frames that
  the sender catches up on within them (17 ms + 3 ms, or 17.7 + 14.4 + 0.2 + 7.2 ms at T = 10 ms)
  are late, not missed; a dropped frame (20 ms, then 10 ms periods) is one missed frame; a steadily
  slow sender fails on its mean.
  Gaps ending in the last STOP_GRACE_S of the trace (the teardown of a run) are not counted
* ``jitter`` = p - T per period; ``jitter_max_ms`` = max |p - T|

PASS when all of: at least 2 frames; |mean(p) - T| ≤ tol·T; missed == 0; and the message did not
stop: the time from its last frame to the end of the trace (the last frame of any id) is below
1.5·T + STOP_GRACE_S (``stopped``; the grace covers the teardown of a run, whose nodes stop a few
tens of ms apart).  Otherwise FAIL, with the first failing reason.  A cyclic DBC message with
no data frame in the trace is MISSING.  Ids in the trace that the DBC does not have get no verdict:
they are counted (``unknown``).

Bus load.  Each data frame takes ``frame_bits(dlc, extended)`` bit times with worst-case stuffing
(Davis et al. 2007, see hil.can.busload); a remote frame takes the length of a 0-byte data frame;
error frames are not counted (their length is unknown); CAN FD frames are counted as classic
frames of at most 8 bytes (an underestimate; ``fd_frames`` says how many).  Average load = all
bits / (last - first timestamp) / bitrate.  Peak load = the most bits in any sliding window
[t, t + window) that starts at a frame, / window / bitrate.

Period histogram (``period_histogram``): the periods of a message counted in bins of tol·T/5 (at
least T/100) around T, the middle bin centred on T, over T ± T/2; shorter and longer ones counted
apart.

Latency chains (``parse_chain``, ``analyse_chains``): cause -> effect latencies between signal
changes on different messages, e.g. wheel speed received -> pressure command sent -> cylinder
pressure responding; definitions in ``analyse_chains``.

Response-time analysis against a trace (``rta_against_trace``): hil.can.rta's worst-case bound of each
cyclic message next to the response the trace shows (hil.can.rta.measured_response); FAIL when the
measurement exceeds the bound.
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import can
import numpy as np
from cantools.database.can import Database, Message

from hil.can.busload import frame_bits
from hil.can.codec import FrameCodec
from hil.can.dbc import closest
from hil.can.rta import MeasuredResponse, RtaReport, RtaResult, measured_response
from hil.errors import RailhilError

__all__ = [
    "BusLoadMeasured", "Chain", "ChainLink", "ChainResult", "FrameArrays", "LatencyStats", "MessageTiming",
    "PeriodHistogram", "PeriodStats", "RtaCheck", "TimingArgError", "TimingReport", "analyse",
    "analyse_chains", "bus_load", "chain_frame_keys", "frame_arrays", "measure_periods", "parse_chain",
    "period_histogram", "rta_against_trace", "rta_check",
]

KIND_DATA, KIND_REMOTE, KIND_ERROR = 0, 1, 2
MISSED_AT = 1.5  # a gap of 1.5 cycles (not made up) is a missed frame; silent as long at the end: stopped
STOP_GRACE_S = 0.2  # teardown: the nodes of a run stop a few tens of ms apart (chosen)
CATCH_UP_PERIODS = 10  # a late sender that is back on schedule within this many periods missed nothing


class TimingArgError(RailhilError, ValueError):
    """A timing option that is out of range or names something the DBC does not have."""


@dataclass(frozen=True)
class FrameArrays:
    """A trace as columns, in file order: timestamp [s], id, 29-bit?, DLC, kind, CAN FD?"""

    t: np.ndarray  # float64
    arbitration_id: np.ndarray  # int64
    extended: np.ndarray  # bool
    dlc: np.ndarray  # int64
    kind: np.ndarray  # int8: KIND_DATA, KIND_REMOTE, KIND_ERROR
    fd: np.ndarray  # bool

    def __len__(self) -> int:
        return len(self.t)

    @property
    def key(self) -> np.ndarray:
        """One int per (id, 11/29-bit): id·2 + extended."""
        return self.arbitration_id * 2 + self.extended


def frame_arrays(frames: Iterable[can.Message]) -> FrameArrays:
    """Columns of the frames, read once (the only per-frame Python loop of this module)."""
    t: list[float] = []
    ids: list[int] = []
    ext: list[bool] = []
    dlc: list[int] = []
    kind: list[int] = []
    fd: list[bool] = []
    for msg in frames:
        t.append(msg.timestamp)
        ids.append(msg.arbitration_id)
        ext.append(msg.is_extended_id)
        dlc.append(msg.dlc)
        kind.append(KIND_ERROR if msg.is_error_frame else KIND_REMOTE if msg.is_remote_frame else KIND_DATA)
        fd.append(msg.is_fd)
    return FrameArrays(
        t=np.asarray(t, dtype=np.float64),
        arbitration_id=np.asarray(ids, dtype=np.int64),
        extended=np.asarray(ext, dtype=bool),
        dlc=np.asarray(dlc, dtype=np.int64),
        kind=np.asarray(kind, dtype=np.int8),
        fd=np.asarray(fd, dtype=bool),
    )


@dataclass(frozen=True)
class PeriodStats:
    """The periods of one id (data frames only), in ms; the figures are None with fewer than 2 frames."""

    arbitration_id: int
    extended: bool
    count: int
    first_s: float
    last_s: float
    periods_ms: np.ndarray = field(repr=False)
    mean_ms: float | None = None
    sigma_ms: float | None = None
    p50_ms: float | None = None
    p99_ms: float | None = None
    min_ms: float | None = None
    max_ms: float | None = None


def _period_stats(arbitration_id: int, extended: bool, t: np.ndarray) -> PeriodStats:
    periods = np.diff(t) * 1e3
    if len(periods) == 0:
        return PeriodStats(arbitration_id, extended, len(t), float(t[0]), float(t[-1]), periods)
    p50, p99 = np.percentile(periods, [50, 99])
    return PeriodStats(
        arbitration_id, extended, len(t), float(t[0]), float(t[-1]), periods,
        mean_ms=float(periods.mean()), sigma_ms=float(periods.std()), p50_ms=float(p50),
        p99_ms=float(p99), min_ms=float(periods.min()), max_ms=float(periods.max()),
    )


def measure_periods(arrays: FrameArrays) -> dict[tuple[int, bool], PeriodStats]:
    """Period statistics per data-frame id, keyed (id, extended), sorted 11-bit first then by id.

    No DBC needed: this is what a trace of unknown origin says about its cyclic ids.
    """
    data = arrays.kind == KIND_DATA
    key = arrays.key[data]
    t = arrays.t[data]
    order = np.lexsort((t, key))  # by id, then by time within an id
    key, t = key[order], t[order]
    if not len(key):  # no data frame at all (an empty trace, or error frames only)
        return {}
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    ends = np.r_[starts[1:], len(key)]
    out = {}
    for s, e in sorted(zip(starts, ends, strict=True), key=lambda se: (int(key[se[0]]) & 1, int(key[se[0]]))):
        k = int(key[s])
        out[(k >> 1, bool(k & 1))] = _period_stats(k >> 1, bool(k & 1), t[s:e])
    return out


@dataclass(frozen=True)
class MessageTiming:
    """One cyclic DBC message against the trace."""

    name: str
    arbitration_id: int
    extended: bool
    cycle_ms: float
    tolerance: float
    verdict: str  # PASS, FAIL, MISSING
    reason: str  # why not PASS; "" for PASS
    stats: PeriodStats | None  # None when MISSING
    late: int = 0
    missed: int = 0
    bursts: int = 0
    jitter_max_ms: float | None = None
    tail_ms: float | None = None  # last frame of this id to the end of the trace
    stopped: bool = False


def judge(name: str, arbitration_id: int, extended: bool, cycle_ms: float, tol: float,
          stats: PeriodStats | None, trace_end_s: float) -> MessageTiming:
    """The verdict of one message (see the module docstring)."""
    common = (name, arbitration_id, extended, float(cycle_ms), tol)
    if stats is None:
        return MessageTiming(*common, "MISSING", "no frame in the trace", None)
    T = float(cycle_ms)
    p = stats.periods_ms
    late = int(np.count_nonzero(p > (1 + tol) * T))
    bursts = int(np.count_nonzero(p < (1 - tol) * T))
    missed = 0
    ends_s = stats.first_s + np.cumsum(p) * 1e-3                # time of the frame closing each period
    judged = ends_s < trace_end_s - STOP_GRACE_S
    for i in np.flatnonzero((p >= MISSED_AT * T) & judged).tolist():   # rare: only the long gaps
        slip = float(np.cumsum(p[i:i + CATCH_UP_PERIODS] - T).min())   # what catching up leaves
        missed += max(0, math.floor(slip / T + 0.5))
    jitter = float(np.abs(p - T).max()) if len(p) else None
    tail_ms = (trace_end_s - stats.last_s) * 1e3
    stopped = tail_ms >= MISSED_AT * T + STOP_GRACE_S * 1e3
    reasons = []
    if stats.count < 2:
        reasons.append("a single frame: no period")
    elif abs(stats.mean_ms - T) > tol * T:
        reasons.append(f"mean period {stats.mean_ms:.3f} ms outside {T:g} ms ± {100 * tol:g} %")
    if missed:
        reasons.append(f"{missed} frame{'s' if missed > 1 else ''} missed "
                       f"(longest period {stats.max_ms:.3f} ms)")
    if stopped:
        reasons.append(f"stopped: last frame {tail_ms:.3f} ms before the end of the trace")
    return MessageTiming(*common, "FAIL" if reasons else "PASS", "; ".join(reasons), stats,
                         late=late, missed=missed, bursts=bursts, jitter_max_ms=jitter,
                         tail_ms=tail_ms, stopped=stopped)


@dataclass(frozen=True)
class BusLoadMeasured:
    bitrate_bps: int
    frames: int  # frames counted (data and remote)
    bits: int
    duration_s: float
    average: float  # fraction of the bitrate; nan for a trace of less than 2 distinct times
    window_s: float
    peak: float  # fraction of the bitrate in the busiest window
    peak_at_s: float  # start of that window
    error_frames: int
    fd_frames: int


def bus_load(arrays: FrameArrays, bitrate_bps: int, window_s: float = 0.1) -> BusLoadMeasured:
    """Average and sliding-window peak bus load of the trace (see the module docstring)."""
    if bitrate_bps <= 0:
        raise TimingArgError(f"bitrate must be positive, got {bitrate_bps} bit/s")
    if not window_s > 0 or not math.isfinite(window_s):
        raise TimingArgError(f"window must be a positive number of seconds, got {window_s}")
    table = np.array([[frame_bits(d, ext) for d in range(16)] for ext in (False, True)], dtype=np.int64)
    counted = arrays.kind != KIND_ERROR
    dlc = np.where(arrays.kind == KIND_REMOTE, 0, np.minimum(arrays.dlc, 8))[counted]
    bits = table[arrays.extended[counted].astype(np.int64), dlc]
    t = arrays.t[counted]
    order = np.argsort(t, kind="stable")
    t, bits = t[order], bits[order]
    total = int(bits.sum())
    duration = float(t[-1] - t[0]) if len(t) else 0.0
    average = total / duration / bitrate_bps if duration > 0 else math.nan
    if len(t):
        cum = np.r_[0, np.cumsum(bits)]
        stop = np.searchsorted(t, t + window_s, side="left")
        in_window = cum[stop] - cum[:-1]
        i = int(np.argmax(in_window))
        peak, peak_at = float(in_window[i]) / window_s / bitrate_bps, float(t[i])
    else:
        peak, peak_at = 0.0, math.nan
    return BusLoadMeasured(
        bitrate_bps=int(bitrate_bps), frames=len(t), bits=total, duration_s=duration, average=average,
        window_s=float(window_s), peak=peak, peak_at_s=peak_at,
        error_frames=int(np.count_nonzero(arrays.kind == KIND_ERROR)),
        fd_frames=int(np.count_nonzero(arrays.fd & counted)),
    )


@dataclass(frozen=True)
class TimingReport:
    messages: tuple[MessageTiming, ...]  # cyclic DBC messages, by (extended, id)
    unknown: dict[tuple[int, bool], int]  # (id, extended) -> frames, ids the DBC does not have
    non_cyclic: int  # data frames of DBC messages without a cycle time (not judged)
    frames: int
    duration_s: float
    load: BusLoadMeasured | None

    @property
    def ok(self) -> bool:
        return all(m.verdict == "PASS" for m in self.messages)

    def counts(self) -> dict[str, int]:
        out = {"PASS": 0, "FAIL": 0, "MISSING": 0}
        for m in self.messages:
            out[m.verdict] += 1
        return out


def check_tolerance(value: float, what: str) -> float:
    if not (math.isfinite(value) and 0 <= value < 1):
        raise TimingArgError(f"{what}: tolerance must be a fraction in [0, 1), e.g. 0.10, got {value}")
    return float(value)


def analyse(arrays: FrameArrays, db: Database, tolerance: float = 0.10,
            overrides: Mapping[str, float] | None = None, bitrate_bps: int | None = None,
            window_s: float = 0.1, ignore: Sequence[str] = ()) -> TimingReport:
    """Judge every cyclic message of `db` on the trace; bus load too when `bitrate_bps` is given.

    Messages whose name matches one of the `ignore` shell patterns (fnmatch, e.g. ``RADIO_*``) are not
    judged: frames of the DBC that a run does not send by design.  A pattern matching no message of
    the DBC is an error (a typo would otherwise silently judge everything)."""
    tolerance = check_tolerance(tolerance, "--tolerance")
    overrides = dict(overrides or {})
    names = {m.name for m in db.messages}
    unknown_names = sorted(set(overrides) - names)
    if unknown_names:
        raise TimingArgError(f"--override: no message named {', '.join(map(repr, unknown_names))} in the DBC")
    for name, value in overrides.items():
        check_tolerance(value, f"--override {name}")
    for pattern in ignore:
        if not fnmatch.filter(names, pattern):
            raise TimingArgError(f"--ignore {pattern!r} matches no message of the DBC")
    periods = measure_periods(arrays)
    end = float(arrays.t.max()) if len(arrays) else 0.0
    start = float(arrays.t.min()) if len(arrays) else 0.0
    results, known = [], set()
    for m in sorted(db.messages, key=lambda m: (bool(m.is_extended_frame), m.frame_id)):
        key = (m.frame_id, bool(m.is_extended_frame))
        known.add(key)
        if not m.cycle_time or m.cycle_time <= 0 or any(fnmatch.fnmatchcase(m.name, g) for g in ignore):
            continue
        tol = overrides.get(m.name, tolerance)
        results.append(judge(m.name, m.frame_id, key[1], m.cycle_time, tol, periods.get(key), end))
    non_cyclic = sum(s.count for k, s in periods.items() if k in known) - sum(
        m.stats.count for m in results if m.stats is not None)
    unknown = {k: s.count for k, s in periods.items() if k not in known}
    load = bus_load(arrays, bitrate_bps, window_s) if bitrate_bps is not None else None
    return TimingReport(tuple(results), unknown, non_cyclic, len(arrays), end - start, load)


# --- period histograms -------------------------------------------------------------------------------

HISTOGRAM_BINS_PER_TOLERANCE = 5  # bin width = tolerance·T / 5 (chosen: five bins inside the tolerance)
HISTOGRAM_MIN_BIN = 0.01  # ... but at least T / 100, so a tight tolerance does not make thousands of bins
HISTOGRAM_HALF_SPAN = 0.5  # bins cover T ± T/2; shorter and longer periods are counted below / above


@dataclass(frozen=True)
class PeriodHistogram:
    """Counts of the periods of one message in bins around its cycle time T (all in ms).

    Bin width w = max(tolerance·T / 5, T / 100); the middle bin is centred on T; the 2N + 1 bins,
    N = ceil((T / 2) / w), cover [T - (N + ½)w, T + (N + ½)w).  Bin i holds edges[i] <= p < edges[i + 1];
    ``below`` / ``above`` count the periods outside (bursts, missed frames).
    """

    cycle_ms: float
    bin_ms: float
    edges_ms: np.ndarray  # len(counts) + 1
    counts: np.ndarray  # int64
    below: int
    above: int

    @property
    def total(self) -> int:
        return int(self.counts.sum()) + self.below + self.above


def period_histogram(periods_ms: np.ndarray, cycle_ms: float, tolerance: float) -> PeriodHistogram:
    """The histogram of `periods_ms` around `cycle_ms` (see PeriodHistogram)."""
    if not cycle_ms > 0:
        raise TimingArgError(f"cycle time must be positive, got {cycle_ms} ms")
    width = max(tolerance * cycle_ms / HISTOGRAM_BINS_PER_TOLERANCE, HISTOGRAM_MIN_BIN * cycle_ms)
    half = math.ceil(HISTOGRAM_HALF_SPAN * cycle_ms / width - 1e-9)
    edges = cycle_ms + width * (np.arange(2 * half + 2) - half - 0.5)
    p = np.asarray(periods_ms, dtype=np.float64)
    index = np.searchsorted(edges, p, side="right") - 1
    below = int(np.count_nonzero(index < 0))
    above = int(np.count_nonzero(index >= len(edges) - 1))
    inside = index[(index >= 0) & (index < len(edges) - 1)]
    counts = np.bincount(inside, minlength=len(edges) - 1).astype(np.int64)
    return PeriodHistogram(float(cycle_ms), float(width), edges, counts, below, above)


# --- cause -> effect latency chains ---------------------------------------------------------------------


@dataclass(frozen=True)
class ChainLink:
    """One link of a chain: a DBC signal (its changes are the events) or a whole message (every frame)."""

    message: str
    signal: str | None
    frame_id: int
    extended: bool
    db_message: Message = field(compare=False, repr=False)  # cantools' message, to decode with

    @property
    def key(self) -> tuple[int, bool]:
        return (self.frame_id, self.extended)

    def __str__(self) -> str:
        return self.message if self.signal is None else f"{self.message}.{self.signal}"


@dataclass(frozen=True)
class Chain:
    text: str  # as given
    links: tuple[ChainLink, ...]

    def __str__(self) -> str:
        return " -> ".join(map(str, self.links))


def parse_chain(text: str, db: Database) -> Chain:
    """``'A.sig -> B.sig -> C'`` → Chain; a link is MESSAGE.SIGNAL or a bare MESSAGE (every frame).

    Errors name the option, the link and the closest DBC names."""
    parts = [p.strip() for p in text.split("->")]
    if len(parts) < 2 or not all(parts):
        raise TimingArgError(f"--chain {text!r}: expected at least two links 'MESSAGE.SIGNAL -> "
                             f"MESSAGE.SIGNAL' (a link may be a bare MESSAGE)")
    names = [m.name for m in db.messages]
    links = []
    for part in parts:
        message_name, _, signal = part.partition(".")
        message_name, signal = message_name.strip(), signal.strip()
        try:
            message = db.get_message_by_name(message_name)
        except KeyError:
            raise TimingArgError(f"--chain {text!r}: no message named {message_name!r} in the DBC "
                                 f"(closest: {closest(message_name, names)})") from None
        if "." in part and not signal:
            raise TimingArgError(f"--chain {text!r}: link {part!r} has no signal name after the '.'")
        if signal:
            signals = [s.name for s in message.signals]
            if signal not in signals:
                raise TimingArgError(f"--chain {text!r}: message {message_name} has no signal {signal!r} "
                                     f"(closest: {closest(signal, signals)})")
        links.append(ChainLink(message.name, signal or None, message.frame_id,
                               bool(message.is_extended_frame), message))
    return Chain(text, tuple(links))


def chain_frame_keys(chains: Iterable[Chain]) -> set[tuple[int, bool]]:
    """The (id, extended) of every message the chains need: the only frames to keep and decode."""
    return {link.key for chain in chains for link in chain.links}


@dataclass(frozen=True)
class LatencyStats:
    """Latencies in ms: count, and p50 / p99 (numpy's linear percentile) / max, None when count is 0."""

    count: int
    p50_ms: float | None = None
    p99_ms: float | None = None
    max_ms: float | None = None


def latency_stats(latencies_s: np.ndarray) -> LatencyStats:
    if len(latencies_s) == 0:
        return LatencyStats(0)
    ms = np.asarray(latencies_s) * 1e3
    p50, p99 = np.percentile(ms, [50, 99])
    return LatencyStats(len(ms), float(p50), float(p99), float(ms.max()))


@dataclass(frozen=True)
class ChainResult:
    """One chain on one trace (definitions in ``analyse_chains``)."""

    chain: Chain
    instances: int  # events of the first link
    completed: int
    incomplete: int  # instances that never reached the last link before the trace ended
    links: tuple[LatencyStats, ...]  # link j -> link j + 1, for the instances that got that far
    end_to_end: LatencyStats  # first -> last link, completed instances
    max_ms: float | None  # the chain's limit (--chain-max-ms), None: no verdict
    overdue: int  # incomplete instances that began more than max_ms before the end of the trace
    verdict: str | None  # PASS / FAIL, None without max_ms
    reason: str  # why FAIL; "" otherwise
    undecodable: int  # frames of the chain's messages that did not decode (too short...): no event


@dataclass
class _Events:
    t: np.ndarray  # float64 seconds, ascending
    seq: np.ndarray  # int64: position of the frame among the kept frames in time order


def _link_events(link: ChainLink, frames: list[tuple[int, float, bytes]], codec) -> tuple[_Events, int]:
    """Events of one link over its message's frames [(seq, t, data)]: every frame for a bare message,
    else the frames whose decoded signal differs from its last decoded value (the first value is no
    change; a frame in which the signal is absent — multiplexing — leaves it unchanged)."""
    if link.signal is None:
        return _Events(np.array([f[1] for f in frames], dtype=np.float64),
                       np.array([f[0] for f in frames], dtype=np.int64)), 0
    t, seq, bad = [], [], 0
    last = None
    for s, ts, data in frames:
        try:
            value = codec.decode(data).get(link.signal)
        except RailhilError:
            bad += 1
            continue
        if value is None:
            continue
        if last is not None and value != last and not (math.isnan(value) and math.isnan(last)):
            t.append(ts)
            seq.append(s)
        last = value
    return _Events(np.array(t, dtype=np.float64), np.array(seq, dtype=np.int64)), bad


def analyse_chains(frames: Iterable[can.Message], chains: Sequence[Chain], end_s: float,
                   max_ms: float | None = None) -> tuple[ChainResult, ...]:
    """Cause -> effect latencies of `chains` over the data frames `frames` (any others are ignored).

    Event of a link: a data frame of its message (id and 11/29-bit kind) in which its signal's
    decoded value differs from its value in the previous frame of that message that carried it;
    for a bare-message link, every frame of the message.  Frames are taken in time order (ties in
    file order).

    Instance: each event of the first link starts one.  From the event e_j matched for link j, the
    event of link j + 1 is the first one after e_j: strictly later in time when the two links are
    different messages; at or after e_j's frame when they are the same message (a signal may respond
    in the very frame of its cause: latency 0).  Latency of link j -> j + 1 = t(e_(j+1)) - t(e_j);
    of the instance = t(last event) - t(first event).  An instance for which some link has no event
    left before the end of the trace is incomplete.

    With `max_ms` a chain PASSes when at least one instance completed, none took longer than
    max_ms, and no incomplete instance began more than max_ms before `end_s` (the end of the trace:
    such an effect is overdue); else FAIL.  Without it there is no verdict.
    """
    keys = chain_frame_keys(chains)
    kept = sorted(((float(m.timestamp), i, m) for i, m in enumerate(frames)
                   if not m.is_error_frame and not m.is_remote_frame
                   and (m.arbitration_id, bool(m.is_extended_id)) in keys), key=lambda x: (x[0], x[1]))
    by_key: dict[tuple[int, bool], list[tuple[int, float, bytes]]] = {k: [] for k in keys}
    for seq, (t, _, m) in enumerate(kept):
        by_key[(m.arbitration_id, bool(m.is_extended_id))].append((seq, t, bytes(m.data)))
    codecs: dict[str, FrameCodec] = {}
    results = []
    for chain in chains:
        events, undecodable = [], 0
        for link in chain.links:
            codec = None
            if link.signal is not None:
                codec = codecs.get(link.message)
                if codec is None:
                    codec = codecs[link.message] = FrameCodec(link.db_message)
            ev, bad = _link_events(link, by_key[link.key], codec)
            events.append(ev)
            undecodable = max(undecodable, bad)
        results.append(_follow(chain, events, end_s, max_ms, undecodable))
    return tuple(results)


def _follow(chain: Chain, events: list[_Events], end_s: float, max_ms: float | None,
            undecodable: int) -> ChainResult:
    """Walk every instance along the links (vectorised over the instances)."""
    first = events[0]
    start_t = first.t
    alive = np.arange(len(start_t))  # instance numbers still on their way
    t_prev, seq_prev = first.t, first.seq
    link_stats = []
    for j in range(1, len(chain.links)):
        ev = events[j]
        if chain.links[j].key == chain.links[j - 1].key:
            nxt = np.searchsorted(ev.seq, seq_prev, side="left")  # at or after the same frame
        else:
            nxt = np.searchsorted(ev.t, t_prev, side="right")  # strictly later
        ok = nxt < len(ev.t)
        alive, nxt, t_old = alive[ok], nxt[ok], t_prev[ok]
        t_prev, seq_prev = ev.t[nxt], ev.seq[nxt]
        link_stats.append(latency_stats(t_prev - t_old))
    end_to_end = t_prev - start_t[alive]
    e2e = latency_stats(end_to_end)
    instances, completed = len(start_t), len(alive)
    incomplete = instances - completed
    overdue, verdict, reasons = 0, None, []
    if max_ms is not None:
        done = np.zeros(instances, dtype=bool)
        done[alive] = True
        overdue = int(np.count_nonzero(~done & (start_t < end_s - max_ms / 1e3)))
        slow = int(np.count_nonzero(end_to_end * 1e3 > max_ms))
        if completed == 0:
            reasons.append("no instance completed" if instances else "no event of the first link "
                           f"({chain.links[0]} never changed)")
        if slow:
            reasons.append(f"{slow} instance{'s' if slow > 1 else ''} over {max_ms:g} ms "
                           f"(max {e2e.max_ms:.3f} ms)")
        if overdue:
            reasons.append(f"{overdue} instance{'s' if overdue > 1 else ''} not completed within "
                           f"{max_ms:g} ms before the end of the trace")
        verdict = "FAIL" if reasons else "PASS"
    return ChainResult(chain, instances, completed, incomplete, tuple(link_stats), e2e, max_ms, overdue,
                       verdict, "; ".join(reasons), undecodable)


# --- response-time analysis against a trace --------------------------------------------------------------

MEASURE_SLACK_US = 1.0  # measured may exceed the bound by this much: the µs resolution of ASC/candump times


@dataclass(frozen=True)
class RtaCheck:
    """One message's worst-case response-time bound, and what a trace measured (None without one)."""

    result: RtaResult
    measured: MeasuredResponse | None
    verdict: str  # PASS / FAIL
    reason: str  # why FAIL; "" for PASS


def rta_check(result: RtaResult, measured: MeasuredResponse | None = None) -> RtaCheck:
    """FAIL when the bound is unbounded or above the deadline, or when the measured maximum exceeds
    the bound by more than MEASURE_SLACK_US; else PASS."""
    m = result.message
    reasons = []
    if result.unbounded:
        reasons.append("unbounded: the messages of its priority and above use 100 % of the bus or more"
                       if math.isinf(result.busy_period_us) else "unbounded: busy period over 60 s")
    elif not result.schedulable:
        reasons.append(f"worst-case response {result.response_us / 1e3:.3f} ms > deadline "
                       f"{m.deadline_us / 1e3:g} ms")
    if measured is not None and measured.max_us > result.response_us + MEASURE_SLACK_US:
        reasons.append(f"measured response {measured.max_us / 1e3:.3f} ms > bound "
                       f"{result.response_us / 1e3:.3f} ms (release jitter not declared? --jitter)")
    return RtaCheck(result, measured, "FAIL" if reasons else "PASS", "; ".join(reasons))


def rta_against_trace(arrays: FrameArrays, report: RtaReport) -> tuple[RtaCheck, ...]:
    """Every message of `report` with its measured response (hil.can.rta.measured_response) on the data
    frames of its id in `arrays`; None where the trace has fewer than two of them."""
    data = arrays.kind == KIND_DATA
    out = []
    for r in report.results:
        m = r.message
        t = arrays.t[data & (arrays.arbitration_id == m.frame_id) & (arrays.extended == m.extended)]
        out.append(rta_check(r, measured_response(t, m.period_us, r.c_us)))
    return tuple(out)
