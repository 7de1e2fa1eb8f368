"""The machine's own timer lateness during a real-time run, and whose each deadline miss is.

During every real-time run one more process per CPU (`probe_process`, pinned to its CPU) runs a bare
loop: sleep to absolute deadlines PROBE_PERIOD_US apart on CLOCK_MONOTONIC, record how late each sleep
returned, nothing else; the CPUs' probes are staggered over the period.  They run with the nodes'
scheduling (SCHED_FIFO one priority step above them where the OS permits, so that the bench's own CPU use
never shows as the machine's), so what delays them is the machine: the kernel, the hypervisor taking a
virtual CPU away, other tenants.  A stall of one virtual CPU does not delay a process on the other, hence
one probe per CPU.  Before the run the first probe also calibrates the hosts' precise wait
(hil.runtime.rtos.sleep_lateness).

A node's cycle released more than `late_threshold_us(period)` after its deadline is a deadline miss.  A
miss whose interval [deadline, release] overlaps an interval in which a probe was late too (a probe
stall: [its deadline, its release] with the probe more than PROBE_STALL_US late) is the machine's; any
other miss is the bench's (`classify_misses`).  Each probe samples every 10 ms: a stall that falls between
its deadlines is not seen by it; the host it kept from running sees it (hil.runtime.host.StallWatch: time
neither given to it as CPU time nor spent waiting for another process, beyond the sleep it asked for), and
a miss that would have been on time without the time its host lost is the machine's too
(`machine_cycles`).  A stall seen by neither counts as the bench's — the verdict errs against the bench,
never for it.
"""

from __future__ import annotations

import signal
import time
from array import array
from dataclasses import dataclass

import numpy as np

from hil.runtime.host import orphaned as _orphaned
from hil.runtime.rtos import make_realtime, sleep_lateness

PROBE_PERIOD_US = 10_000      # the probe's period [µs] (issue #17: a bare loop at 10 ms deadlines)
PROBE_STALL_US = 500          # the probe more than this late: the machine stalled [µs] (the miss bound
#                               of a 10 ms cycle, late_threshold_us)
MISS_MIN_US = 500             # a cycle later than max(MISS_MIN_US, MISS_PERIOD_FRACTION · period) is a
MISS_PERIOD_FRACTION = 0.05   # deadline miss (issue #17)


def late_threshold_us(period_us: int, min_us: int = MISS_MIN_US,
                      fraction: float = MISS_PERIOD_FRACTION) -> int:
    """The lateness above which a cycle of this period is a deadline miss [µs]."""
    return max(min_us, round(fraction * period_us))


@dataclass
class Misses:
    """A node's deadline misses: each one's deadline [µs since t0] and lateness [µs]."""

    deadline_us: np.ndarray
    lateness_us: np.ndarray


def stall_intervals(probe_deadlines_us, probe_lateness_us, stall_us: int = PROBE_STALL_US) -> np.ndarray:
    """The probe's stalls as [start, end] rows [µs since t0], merged where they overlap."""
    d = np.asarray(probe_deadlines_us, dtype=np.int64)
    late = np.asarray(probe_lateness_us, dtype=np.int64)
    k = late > stall_us
    rows = np.stack([d[k], d[k] + late[k]], axis=1) if k.any() else np.zeros((0, 2), dtype=np.int64)
    return merge_intervals(rows)


def merge_intervals(rows: np.ndarray) -> np.ndarray:
    """[start, end] rows sorted by start, those that overlap merged into one."""
    rows = np.asarray(rows, dtype=np.int64).reshape(-1, 2)
    merged: list[list[int]] = []
    for start, end in rows[np.argsort(rows[:, 0])] if len(rows) else rows:
        if merged and start <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], int(end))
        else:
            merged.append([int(start), int(end)])
    return np.asarray(merged, dtype=np.int64).reshape(-1, 2)


def classify_misses(misses: Misses, stalls: np.ndarray) -> np.ndarray:
    """True for each miss that is the machine's: its [deadline, release] overlaps a probe stall."""
    if not len(misses.deadline_us):
        return np.zeros(0, dtype=bool)
    if not len(stalls):
        return np.zeros(len(misses.deadline_us), dtype=bool)
    start, end = misses.deadline_us, misses.deadline_us + misses.lateness_us
    # the last stall that starts at or before the miss's release, and whether it ends after its deadline
    k = np.searchsorted(stalls[:, 0], end, side="right") - 1
    ok = k >= 0
    hit = np.zeros(len(start), dtype=bool)
    hit[ok] = stalls[k[ok], 1] >= start[ok]
    return hit


def _column(cycle: dict, key: str, fallback: np.ndarray) -> np.ndarray:
    """A node's per-cycle record `key`, or `fallback` where it was not recorded for every cycle."""
    a = np.asarray(cycle.get(key, ()), dtype=np.int64)
    return a if len(a) == len(fallback) else fallback


PROBE_SAMPLE_CPU_US = 150     # a probe's CPU time a sample, at most (0.3-0.4 CPU s for 2,940 samples,
#                               start-up included): what the probes may take from a host in a window
BENCH_HOLD_US = 100           # what else of the bench may hold a CPU a window: its processes below the
#                               hosts' priority (the recorder, the runner) inside a system call, where a
#                               real-time task cannot preempt them (this VM's kernel: "Dynamic Preempt:
#                               none"), a system call's length, tens of µs; the kernel's network processing
#                               of the bench's frames (softirq, in no process's CPU time: 0.14 % of this
#                               machine's CPU time since boot, /proc/stat, ~14 µs a 10 ms) (chosen, generous)


HOST_SEEN = ("wait_lost_us", "cycle_lost_us", "wait_cpu_us", "cycle_cpu_us", "wait_delay_us",
             "cycle_delay_us")
# machine_cycles' rows of a host's cycles: release, deadline, lateness, end, node, cycle, miss, threshold
# [0..7], then HOST_SEEN; the column of each of those
_COL = {key: 8 + k for k, key in enumerate(HOST_SEEN)}


def _windows(order: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A host's waits and cycles in time order as (starts, ends, cumulative CPU [µs]): the wait before each
    cycle from the end of the one before, then the cycle."""
    rel, ended = order[:, 0], order[:, 3]
    starts = np.empty(2 * len(order), dtype=np.int64)
    ends = np.empty_like(starts)
    starts[0::2] = np.concatenate([[0], ended[:-1]])
    ends[0::2] = rel
    starts[1::2], ends[1::2] = rel, ended
    cpu = np.empty_like(starts)
    cpu[0::2], cpu[1::2] = order[:, _COL["wait_cpu_us"]], order[:, _COL["cycle_cpu_us"]]
    return starts, ends, np.concatenate([[0], np.cumsum(cpu)])


def _window_cpu(window: tuple, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The CPU time another host's windows overlapping [a, b] had, in all (the whole of each)."""
    starts, ends, cum = window
    lo = np.searchsorted(np.maximum.accumulate(ends), a, side="right")
    hi = np.searchsorted(starts, b, side="left")
    return np.where(hi > lo, cum[np.maximum(hi, lo)] - cum[lo], 0)


def bench_wait_bound(others: list, a: np.ndarray, b: np.ndarray, probes: int, cpus: int) -> np.ndarray:
    """The most a host at SCHED_FIFO that may run on `cpus` CPUs could have waited for a CPU in each of its
    windows [a, b] because of the bench [µs].

    A task at SCHED_FIFO waits for a CPU only while every CPU it may run on runs a task of its priority or
    above: the kernel's real-time balancing moves it to a CPU that runs anything less.  Of the bench those
    are the other hosts (`others`: their windows) and the probes, one step above.  The time in which all
    `cpus` CPUs ran one of them is at most their CPU time in the window less that of the cpus − 1 busiest
    (at every such instant one of the others runs), each counted as the whole CPU time of its windows that
    overlap [a, b] (it may have fallen anywhere in them) but at most the window's length (one thread), a
    probe as PROBE_SAMPLE_CPU_US a sample.  Plus BENCH_HOLD_US: a process below the hosts' priority in a
    system call holds its CPU until it returns, and the kernel's network processing of the bench's frames
    is in no process's CPU time.  Bounds, never estimates: what they leave is the machine's (the
    hypervisor ran another virtual CPU while the host was queued on this one)."""
    span = b - a
    each = [np.minimum(span, _window_cpu(w, a, b)) for w in others]
    each += [np.minimum(span, PROBE_SAMPLE_CPU_US * (span // PROBE_PERIOD_US + 1))] * probes
    if not each:
        return np.full(len(a), BENCH_HOLD_US, dtype=np.int64)
    ranked = np.sort(np.stack(each), axis=0)
    return ranked[:max(len(each) - (cpus - 1), 0)].sum(axis=0) + BENCH_HOLD_US


def _host_orders(cycles: dict[str, dict], thresholds: dict[str, int]) -> tuple[dict, dict, dict]:
    """Per host: its nodes' names, the CPUs it could run on (its records' `cpus`, None: all) and its cycles
    as it ran them (machine_cycles' rows, in order of release)."""
    by_host: dict[object, list[str]] = {}
    cpus: dict[object, int | None] = {}
    for name, c in cycles.items():
        by_host.setdefault(c.get("host") or name, []).append(name)
        cpus[c.get("host") or name] = c.get("cpus")
    orders = {}
    for host, names in by_host.items():
        rows = []
        for k, name in enumerate(names):
            c = cycles[name]
            d = np.asarray(c["deadline_us"], dtype=np.int64)
            late = np.asarray(c["lateness_us"], dtype=np.int64)
            n = len(d)
            ended = _column(c, "ended_us", d + late)        # no record of the cycles' ends: their releases
            zero = np.zeros(n, dtype=np.int64)
            host_seen = [_column(c, key, zero) for key in HOST_SEEN]
            rows.append(np.stack([d + late, d, late, ended, np.full(n, k), np.arange(n),
                                  late > thresholds[name], np.full(n, thresholds[name]), *host_seen], axis=1))
        if rows:
            order = np.concatenate(rows)
            orders[host] = order[np.argsort(order[:, 0], kind="stable")]   # the host's cycles as it ran them
    return by_host, cpus, orders


def behind_cycles(cycles: dict[str, dict], thresholds: dict[str, int]) -> dict[str, np.ndarray]:
    """Per node, True for each cycle whose deadline came while its host was still running the cycle before
    it (another node's, in a grouped host): it could not be released on time whatever the machine did, and
    a miss of it is a knock-on of that cycle's lateness or length.  Reported beside the verdict (how many of
    a node's bench misses are knock-ons); it changes no verdict."""
    by_host, _, orders = _host_orders(cycles, thresholds)
    out = {name: np.zeros(len(c["lateness_us"]), dtype=bool) for name, c in cycles.items()}
    for host, order in orders.items():
        ended = order[:, 3]
        blocked = np.concatenate([[False], ended[:-1] > order[1:, 1]])
        for k, name in enumerate(by_host[host]):
            mine = order[:, 4] == k
            out[name][order[mine, 5]] = blocked[mine]
    return out


def machine_cycles(cycles: dict[str, dict], thresholds: dict[str, int],
                   stalls: np.ndarray, probes: int = 2) -> dict[str, np.ndarray]:
    """Per node, True for each cycle that is a deadline miss of the machine's.

    Seen by a probe: a miss whose [deadline, release] overlaps a probe stall is the machine's.  The nodes
    of one host run one after another: a miss whose deadline came while the host was still busy with a
    late cycle (the one before it ended after this deadline) inherits that cycle's verdict — a stall that
    delays one cycle of a grouped host delays the cycles due behind it too.

    Seen by the host (hil.runtime.host.StallWatch): in the wait before a cycle and in the cycle, the time
    the machine took from it (`wait_lost_us`, `cycle_lost_us`), and the time it waited for a CPU
    (`wait_delay_us`, `cycle_delay_us`, recorded only for a host at SCHED_FIFO, which only the other hosts
    and the probes above it could keep waiting).  Of that wait, at most `bench_wait_bound` may have been
    the bench's: on a host's `cpus` CPUs (its record's, else one per probe), the time all of them ran
    another host or a probe; the rest was the machine's (its virtual CPU taken while the host queued).  A
    miss is the machine's when, without the machine's time, it would not have been one: its release would
    have come that much earlier, and, if it waited behind the cycle before it, as much earlier as that
    cycle's end would have, never before its deadline."""
    by_host, cpus, orders = _host_orders(cycles, thresholds)
    out = {name: np.zeros(len(c["lateness_us"]), dtype=bool) for name, c in cycles.items()}
    windows = {host: _windows(order) for host, order in orders.items()}
    for host, order in orders.items():
        names = by_host[host]
        others = [w for h, w in windows.items() if h != host]
        starts, ends, _ = windows[host]
        allowed = bench_wait_bound(others, starts, ends, probes, cpus.get(host) or probes)
        delays = order[:, [_COL["wait_delay_us"], _COL["cycle_delay_us"]]].reshape(-1)   # window by window
        machine_wait = np.maximum(0, delays - allowed)          # the machine's, added to what it took
        order[:, _COL["wait_lost_us"]] += machine_wait[0::2]
        order[:, _COL["cycle_lost_us"]] += machine_wait[1::2]
        misses = order[order[:, 6] == 1]
        if not len(misses):
            continue
        alone = classify_misses(Misses(misses[:, 1], misses[:, 2]), stalls)
        verdict = dict(zip(map(tuple, misses[:, 4:6].tolist()), alone.tolist(), strict=True))
        prev_end, prev_verdict, prev_gain = -1, None, 0
        for row in order.tolist():
            _, deadline, late, ended, k, i, miss, threshold, wait_lost, cycle_lost = row[:10]
            blocked = prev_end > deadline
            # without the machine's time, released this much earlier (never before the deadline)
            gain = min(late, wait_lost + (prev_gain if blocked else 0)) if late > 0 else 0
            if miss:
                if prev_verdict is not None and blocked:          # behind a late cycle: its verdict
                    verdict[(k, i)] = prev_verdict
                if late - gain <= threshold:                     # on time but for the machine's time
                    verdict[(k, i)] = True
                prev_verdict = verdict[(k, i)]
                out[names[k]][i] = prev_verdict
            else:
                prev_verdict = None
            prev_end, prev_gain = ended, gain + cycle_lost
    return out


def probe_process(name: str, cpu: int | None, phase_us: int, t0_ns, go, stop, results, setup_args: dict,
                  calibrate_s: float) -> None:
    """One probe's process, on `cpu` (None: not pinned): real-time setup, with `calibrate_s` > 0 the sleep
    calibration (put as ("calibrated", name, ...)), else ("ready", name, ...); then the bare loop at
    deadlines t0 + phase + k·period until `stop`; puts ("result", name, {...})."""

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        rt = make_realtime(cpus=(cpu,) if cpu is not None else None, **setup_args)
        if calibrate_s > 0:
            cal = sleep_lateness(calibrate_s)
            results.put(("calibrated", name, {"calibration": cal.as_dict(), "rt": rt.as_dict()}))
        else:
            results.put(("ready", name, rt.as_dict()))
        while not go.wait(0.5):
            if _orphaned():
                return
        t0 = t0_ns.value + phase_us * 1000
        deadlines, late = array("q"), array("q")
        period = PROBE_PERIOD_US * 1000
        k = 1
        now = time.monotonic_ns
        while not stop.is_set():
            deadline = t0 + k * period
            remaining = deadline - now()
            if remaining > 0:
                time.sleep(remaining / 1e9)
            lateness = now() - deadline
            deadlines.append(phase_us + k * PROBE_PERIOD_US)
            late.append(lateness // 1000)
            k = max(k + 1, (now() - t0) // period + 1)      # a stall longer than a period: next slot
            if k % ORPHAN_CHECK_CYCLES == 0 and _orphaned():   # the runner was killed (-9): stop too
                return
        import resource

        r = resource.getrusage(resource.RUSAGE_SELF)
        results.put(("result", name, {"deadline_us": deadlines, "lateness_us": late, "cpu": cpu,
                                      "cpu_s": round(r.ru_utime + r.ru_stime, 3)}))
    except BaseException as exc:   # noqa: BLE001 - the run goes on without this probe, and says so
        results.put(("probe_error", name, f"{type(exc).__name__}: {exc}"))


ORPHAN_CHECK_CYCLES = 50      # a probe checks every 50 cycles (0.5 s) that its runner still lives


def probe_cpus() -> list[int | None]:
    """The CPUs to probe: every CPU this process may run on (one unpinned probe where that is unknown)."""
    import os

    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return [None]
