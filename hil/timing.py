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
(Davis et al. 2007, see hil.busload); a remote frame takes the length of a 0-byte data frame;
error frames are not counted (their length is unknown); CAN FD frames are counted as classic
frames of at most 8 bytes (an underestimate; ``fd_frames`` says how many).  Average load = all
bits / (last - first timestamp) / bitrate.  Peak load = the most bits in any sliding window
[t, t + window) that starts at a frame, / window / bitrate.
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import can
import numpy as np
from cantools.database.can import Database

from hil.busload import frame_bits
from hil.errors import RailhilError

__all__ = [
    "BusLoadMeasured", "FrameArrays", "MessageTiming", "PeriodStats", "TimingArgError", "TimingReport",
    "analyse", "bus_load", "frame_arrays", "measure_periods",
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
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.array([], dtype=int)
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
