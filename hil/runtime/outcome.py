"""What a run produced, in either mode, and whether a real-time run held real time."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hil.runtime.probe import (
    HOST_SEEN,
    behind_cycles,
    late_threshold_us,
    machine_cycles,
    merge_intervals,
    stall_intervals,
)
from hil.runtime.truth import Truth


@dataclass
class RunOutcome:
    """What a run produced, in either mode; the results module turns it into files and KPIs."""

    mode: str
    end_us: int
    reason: str                               # "standstill" | "max_duration" | "interrupted"
    truth: Truth                              # TruthLog, or a study's own
    frames_by_node: dict[str, int]
    node_stats: dict[str, dict] = field(default_factory=dict)
    wall_s: float = 0.0
    bus: dict | None = None                   # bit-timed lockstep bus: load and per-message timing
    frames_in_flight: int = 0                 # sent, but queued or on the wire when the run ended
    frames_overwritten: int = 0               # replaced in a transmit queue by a newer instance
    frames_faulted: int = 0                   # frames added (+) or removed (-) by injected faults
    faults: dict | None = None                # what the fault injector did: counts and events
    lateness_us: dict = field(default_factory=dict)   # real time: node -> each cycle's release lateness [µs]
    realtime: dict | None = None              # real time: hosting, OS set-up, calibration, probe, cycles
    devices: dict = field(default_factory=dict)   # by replaced node: its bus, gateway, device (hil.devices)


#: the edges of the lateness histograms in kpis.json [µs] (the last bin is everything above 100 ms)
HISTOGRAM_EDGES_US = (0, 50, 100, 200, 500, 1_000, 2_000, 5_000, 10_000, 20_000, 50_000, 100_000)


def histogram(lateness_us) -> list[int]:
    """Counts of lateness per bin of HISTOGRAM_EDGES_US (below 0: in the first; above the last edge: in
    the last bin)."""
    a = np.asarray(lateness_us, dtype=np.int64)
    k = np.clip(np.searchsorted(HISTOGRAM_EDGES_US, a, side="right") - 1, 0, len(HISTOGRAM_EDGES_US) - 1)
    return np.bincount(k, minlength=len(HISTOGRAM_EDGES_US)).tolist()


def _pct(a: np.ndarray, q: float) -> float | None:
    return round(float(np.percentile(a, q))) if a.size else None


def lateness_figures(lateness_us) -> dict:
    """p50 / p99 / max [µs] of a series of release lateness, and its length."""
    a = np.asarray(lateness_us, dtype=np.int64)
    return {"cycles": int(a.size), "p50_us": _pct(a, 50), "p99_us": _pct(a, 99),
            "max_us": int(a.max()) if a.size else None}


def realtime_verdict(outcome: RunOutcome) -> dict:
    """Did the run hold real time?  Every simulated node's cycles (the plant's steps: its wakes) are judged
    against the scenario's [realtime.deadline] budget: a cycle released more than max(miss_min_us,
    miss_period_pct % of the period) after its deadline is a miss; a miss at an instant the machine probe
    was late too is the machine's (hil.runtime.probe), as is one that would have been on time but for the
    time the machine kept its host from running (hil.runtime.host.StallWatch); any other the bench's; a
    miss behind a late cycle of the same host inherits that cycle's verdict
    (hil.runtime.probe.machine_cycles).  The run held when no node's bench misses exceed budget_pct % of
    its cycles and none is later than max_late_periods periods.  The machine's misses and its worst stall
    are reported beside, so that a reader sees whether the bench or the host failed, and of each node's
    bench misses how many were released behind another cycle of its host (a grouped host's knock-ons,
    hil.runtime.probe.behind_cycles)."""
    rt = outcome.realtime or {}
    budget = rt.get("deadline") or {"miss_min_us": 500, "miss_period_pct": 5.0, "budget_pct": 0.1,
                                    "max_late_periods": 1.0}
    probes = rt.get("probes") or {}
    if probes:
        rows = [stall_intervals(p["deadline_us"], p["lateness_us"]) for p in probes.values()]
        stalls = merge_intervals(np.concatenate(rows))
        pl = np.concatenate([np.asarray(p["lateness_us"], dtype=np.int64) for p in probes.values()])
        machine = {**lateness_figures(pl), "histogram": histogram(pl), "probes": len(probes),
                   "stalls": int(len(stalls)),
                   "worst_stall_us": int((stalls[:, 1] - stalls[:, 0]).max()) if len(stalls) else 0,
                   "stalls_by_probe": {n: int(len(r)) for n, r in zip(probes, rows, strict=True)}}
        if rt.get("probe_errors"):
            machine["errors"] = rt["probe_errors"]
    else:
        stalls = np.zeros((0, 2), dtype=np.int64)
        machine = {"error": "; ".join(f"{n}: {e}" for n, e in (rt.get("probe_errors") or {}).items())
                   or "no probe reported"}
    seen = {h: merge_intervals(v["stalls_us"]) for h, v in (rt.get("host_stalls") or {}).items()}
    counted = {h: a for h, a in seen.items() if rt["host_stalls"][h]["not_counted"] is None}
    if seen:
        machine["host_stalls"] = {
            h: {"stalls": int(len(a)), "worst_us": int((a[:, 1] - a[:, 0]).max()) if len(a) else 0,
                "counted": h in counted,
                **({} if h in counted else {"why": rt["host_stalls"][h]["not_counted"]})}
            for h, a in seen.items()}
    nodes: dict[str, dict] = {}
    cycles_of = rt.get("cycles") or {}
    thresholds = {n: late_threshold_us(int(c["period_us"]), budget["miss_min_us"],
                                       budget["miss_period_pct"] / 100) for n, c in cycles_of.items()}
    machines = machine_cycles(cycles_of, thresholds, stalls, max(1, len(probes)))
    behind = behind_cycles(cycles_of, thresholds)
    no_host = {n: {k: v for k, v in c.items() if k not in HOST_SEEN} for n, c in cycles_of.items()}
    by_probes = machine_cycles(no_host, thresholds, stalls)
    probes_alone = sum(int((by_probes[n] & (np.asarray(c["lateness_us"]) > thresholds[n])).sum())
                       for n, c in cycles_of.items())
    for name, c in cycles_of.items():
        period = int(c["period_us"])
        threshold = thresholds[name]
        late_all = np.asarray(c["lateness_us"], dtype=np.int64)
        miss = late_all > threshold
        machine_hit = machines[name][miss]
        bench_late = late_all[miss][~machine_hit]
        knock_on = int(behind[name][miss][~machine_hit].sum())
        cycles = len(c["lateness_us"])
        allowed = int(budget["budget_pct"] / 100 * cycles)
        too_late = int((bench_late > budget["max_late_periods"] * period).sum())
        skipped = int((outcome.node_stats.get(name) or {}).get("missed_cycles") or 0)
        nodes[name] = {
            "period_us": period, "judged_in": c.get("judged_in", "cycles"),
            **lateness_figures(c["lateness_us"]), "miss_threshold_us": threshold,
            "misses_bench": int(bench_late.size), "misses_machine": int(machine_hit.sum()),
            # of the bench misses, those released behind the cycle before them on the node's host
            "misses_bench_behind": knock_on,
            "misses_allowed": allowed, "bench_misses_over_a_period": too_late,
            "worst_bench_miss_us": int(bench_late.max()) if bench_late.size else 0,
            "skipped": skipped, "held": bool(bench_late.size <= allowed and too_late == 0),
            "histogram": histogram(c["lateness_us"]),
        }
    held = bool(nodes) and all(v["held"] for v in nodes.values())
    ten = [np.asarray(c["lateness_us"]) for n, c in (rt.get("cycles") or {}).items()
           if int(c["period_us"]) == 10_000]
    pooled = np.concatenate(ten) if ten else np.zeros(0)
    failing = [n for n, v in nodes.items() if not v["held"]]
    worst = (max(failing, key=lambda n: nodes[n]["worst_bench_miss_us"]) if failing else
             max(nodes, key=lambda n: nodes[n]["p99_us"] or 0, default=None))
    return {
        "held": held,
        "budget": budget,
        "worst_node": worst,
        "p99_10ms_us": _pct(pooled, 99), "p50_10ms_us": _pct(pooled, 50),
        "misses_bench": sum(v["misses_bench"] for v in nodes.values()),
        "misses_bench_behind": sum(v["misses_bench_behind"] for v in nodes.values()),
        "misses_machine": sum(v["misses_machine"] for v in nodes.values()),
        # of those, at a probe's stall (or behind one): what a verdict from the probes alone would say
        "misses_machine_probes": probes_alone,
        "machine": machine,
        "nodes": nodes,
        "histogram_edges_us": list(HISTOGRAM_EDGES_US),
        # the figures of earlier releases, kept for readers of kpis.json
        "missed_cycles": {n: v["skipped"] for n, v in nodes.items()},
        "max_lag_ms": {n: round(v["max_us"] / 1e3, 1) if v["max_us"] is not None else None
                       for n, v in nodes.items()},
        "lateness_us": {n: {"p50": v["p50_us"], "p99": v["p99_us"], "max": v["max_us"], "cycles": v["cycles"]}
                        for n, v in nodes.items()},
        "external": list(rt.get("external") or []),
    }
