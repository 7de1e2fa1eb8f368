"""The real-time verdict (hil.runtime.outcome.realtime_verdict) on made-up cycle records: what a deadline
miss is, whose it is (the bench's or the machine's, from the probe), the budget, and how the summary and
the report say it.  Pure: no process, no bus."""

import numpy as np
import pytest

from hil.report.html import run_verdicts
from hil.report.summary import realtime_lines
from hil.runtime.outcome import HISTOGRAM_EDGES_US, RunOutcome, histogram, realtime_verdict
from hil.runtime.probe import (
    PROBE_PERIOD_US,
    Misses,
    classify_misses,
    late_threshold_us,
    stall_intervals,
)

BUDGET = {"miss_min_us": 500, "miss_period_pct": 5.0, "budget_pct": 0.1, "max_late_periods": 1.0}


def cycles(period_us: int, n: int, late: dict[int, int] | None = None) -> dict:
    """n cycles of one node on time (lateness 20 µs), but cycle k `late[k]` µs late."""
    lateness = np.full(n, 20, dtype=np.int64)
    for k, v in (late or {}).items():
        lateness[k] = v
    return {"period_us": period_us, "deadline_us": np.arange(n, dtype=np.int64) * period_us + 3_000,
            "lateness_us": lateness}


def probe(n: int, stalls: dict[int, int] | None = None) -> dict:
    """A probe at PROBE_PERIOD_US on time (lateness 60 µs) but its cycle k `stalls[k]` µs late."""
    lateness = np.full(n, 60, dtype=np.int64)
    for k, v in (stalls or {}).items():
        lateness[k] = v
    return {"deadline_us": np.arange(1, n + 1, dtype=np.int64) * PROBE_PERIOD_US, "lateness_us": lateness}


def outcome(nodes: dict, probes: dict | None = None, stats: dict | None = None) -> RunOutcome:
    rt = {"cycles": nodes, "probes": probes if probes is not None else {"PROBE0": probe(3_000)},
          "probe_errors": {}, "deadline": dict(BUDGET), "external": []}
    return RunOutcome(mode="realtime", end_us=30_000_000, reason="standstill", truth=None, frames_by_node={},
                      node_stats=stats or {}, realtime=rt)


@pytest.mark.parametrize(("period_us", "threshold_us"), [(1_000, 500), (10_000, 500), (100_000, 5_000)])
def test_a_miss_is_later_than_500_us_or_5_percent_of_the_period(period_us, threshold_us):
    assert late_threshold_us(period_us) == threshold_us


def test_a_miss_is_the_machines_when_its_window_overlaps_a_probe_stall():
    stalls = stall_intervals([10_000, 20_000, 90_000], [3_000, 700, 200])     # the third is no stall (200 µs)
    assert stalls.tolist() == [[10_000, 13_000], [20_000, 20_700]]
    misses = Misses(np.array([9_000, 14_000, 19_500, 50_000]), np.array([1_500, 800, 600, 900]))
    # [9.0, 10.5] ms overlaps the first stall; [14.0, 14.8] does not; [19.5, 20.1] overlaps the second;
    # [50.0, 50.9] overlaps nothing
    assert classify_misses(misses, stalls).tolist() == [True, False, True, False]
    assert classify_misses(misses, np.zeros((0, 2), dtype=np.int64)).tolist() == [False] * 4


def test_overlapping_stalls_of_two_probes_merge():
    rows = stall_intervals([1_000, 1_500, 9_000], [2_000, 3_000, 600])
    assert rows.tolist() == [[1_000, 4_500], [9_000, 9_600]]


def test_held_within_the_budget_and_the_machines_misses_beside():
    # 3,000 cycles of 10 ms: 0.1 % allows 3 misses of the bench; two here, one more at a machine stall
    nodes = {"BECU1": cycles(10_000, 3_000, {100: 900, 200: 2_000, 1_000: 4_000}),
             "PLANT": cycles(1_000, 30_000)}
    stall_at = (1_000 * 10_000 + 3_000) // PROBE_PERIOD_US               # the probe cycle at that instant
    v = realtime_verdict(outcome(nodes, {"PROBE0": probe(3_000, {stall_at - 1: 5_000})}))
    becu = v["nodes"]["BECU1"]
    assert (becu["misses_bench"], becu["misses_machine"], becu["misses_allowed"]) == (2, 1, 3)
    assert becu["held"] and v["held"] and becu["worst_bench_miss_us"] == 2_000
    assert v["machine"]["stalls"] == 1 and v["machine"]["worst_stall_us"] == 5_000
    assert v["p99_10ms_us"] == 20 and v["nodes"]["PLANT"]["misses_bench"] == 0


def test_not_held_over_the_budget_or_with_a_bench_miss_later_than_a_period():
    over = {"BECU1": cycles(10_000, 1_000, {k: 800 for k in (10, 20)})}        # 1,000 cycles: 1 allowed
    v = realtime_verdict(outcome(over))
    assert not v["held"] and v["worst_node"] == "BECU1" and v["nodes"]["BECU1"]["misses_allowed"] == 1
    long = {"BECU1": cycles(10_000, 100_000, {5: 12_000})}                     # 100 allowed, but > 1 period
    v = realtime_verdict(outcome(long))
    assert not v["held"] and v["nodes"]["BECU1"]["bench_misses_over_a_period"] == 1
    lines = realtime_lines(v)
    assert lines[0].startswith("real time               NOT HELD: BECU1 1 misses (allowed 100), worst "
                               "12.0 ms")
    assert "machine floor: probe p99 60 us" in lines[1]
    checks = {c.check: c for c in run_verdicts({"realtime": v}, {"mode": "realtime"})}
    assert checks["real time held (the bench's deadline misses)"].passed is False
    assert checks["the machine's own misses (stalls of a probe or seen by a host)"].passed is None


def test_no_probe_is_said_not_hidden():
    v = realtime_verdict(outcome({"BCU": cycles(10_000, 100)}, probes={}))
    assert "error" in v["machine"] and v["held"]
    assert "machine floor: probe failed" in realtime_lines(v)[1]


def test_histograms_count_every_cycle_in_fixed_bins():
    counts = histogram([-3, 0, 49, 50, 450, 600, 250_000])
    assert len(counts) == len(HISTOGRAM_EDGES_US) and sum(counts) == 7
    assert counts[0] == 3 and counts[1] == 1 and counts[HISTOGRAM_EDGES_US.index(200)] == 1
    assert counts[HISTOGRAM_EDGES_US.index(500)] == 1 and counts[-1] == 1


def test_a_miss_behind_a_late_cycle_of_the_same_host_inherits_its_verdict():
    """A grouped host runs its nodes one after another: BECU1's cycle at 3 ms released 2 ms late by a stall
    the probe saw ([3.2, 4.7] ms) ends at 5.1 ms and delays BECU2's, due at 4.8 ms, to 5.4 ms: a miss that
    does not overlap the stall itself but is its doing.  In another host (no stall) the same chain is the
    bench's, both misses."""
    def node(host, deadline, late, ended):
        return {"period_us": 10_000, "host": host, "deadline_us": np.array([deadline]),
                "lateness_us": np.array([late]), "ended_us": np.array([ended])}

    nodes = {"BECU1": node("ECUS", 3_000, 2_000, 5_100), "BECU2": node("ECUS", 4_800, 600, 5_500),
             "BECU3": node("OTHER", 53_000, 2_000, 55_100), "BECU4": node("OTHER", 54_800, 600, 55_500)}
    stall = {"deadline_us": np.array([3_200]), "lateness_us": np.array([1_500])}     # [3.2, 4.7] ms
    v = realtime_verdict(outcome(nodes, {"PROBE0": stall}))
    assert [(v["nodes"][n]["misses_machine"], v["nodes"][n]["misses_bench"]) for n in nodes] == \
        [(1, 0), (1, 0), (0, 1), (0, 1)]


def test_the_plant_woken_on_its_frames_is_said_to_be_judged_in_its_wakes():
    """The plant woken on its frames computes its 1 ms steps at each wake: its lateness is counted over
    its wakes (at most 5 ms apart), and the summary and the report say wakes, not cycles of 5 ms."""
    plant = {**cycles(5_000, 200), "judged_in": "wakes"}
    v = realtime_verdict(outcome({"PLANT": plant, "BCU": cycles(10_000, 100)}))
    assert v["nodes"]["PLANT"]["judged_in"] == "wakes" and v["nodes"]["BCU"]["judged_in"] == "cycles"
    lines = {line.split()[0]: line for line in realtime_lines(v)[2:]}
    assert "over 200 wakes at most 5 ms apart;" in lines["PLANT"]
    assert "over 100 cycles of 10 ms;" in lines["BCU"]


def test_a_miss_is_the_machines_when_without_the_time_the_machine_took_from_its_host_it_was_none():
    """A stall between the probe's 10 ms samples is not seen by the probe; the host it kept from running
    saw it (hil.runtime.host.StallWatch: `wait_lost_us` before a release, `cycle_lost_us` in a cycle).
    BECU1, 1.5 ms late, lost 1.2 ms in its wait: 0.3 ms late without it, the machine's.  BECU2, due
    behind it and blocked until its end, inherits that, and lost 0.4 ms more in BECU1's cycle.  BECU3 lost
    0.8 ms of 1.5: 0.7 ms late on its own, the bench's.  No time lost: the bench's, as before."""
    def node(deadline, late, ended, wait_lost, cycle_lost, host="ECUS"):
        return {"period_us": 10_000, "host": host, "deadline_us": np.array([deadline]),
                "lateness_us": np.array([late]), "ended_us": np.array([ended]),
                "wait_lost_us": np.array([wait_lost]), "cycle_lost_us": np.array([cycle_lost])}

    nodes = {"BECU1": node(3_000, 1_500, 5_100, 1_200, 400), "BECU2": node(3_500, 1_650, 5_400, 0, 0),
             "BECU3": node(13_000, 1_500, 14_700, 800, 0), "BECU4": node(23_000, 1_500, 24_700, 0, 0)}

    def split(v):
        return [(v["nodes"][n]["misses_machine"], v["nodes"][n]["misses_bench"]) for n in nodes]

    o = outcome(nodes)
    o.realtime["host_stalls"] = {"ECUS": {"stalls_us": [[3_300, 4_500]], "not_counted": None}}
    v = realtime_verdict(o)
    assert split(v) == [(1, 0), (1, 0), (0, 1), (0, 1)]
    assert v["misses_machine"] == 2 and v["misses_machine_probes"] == 0
    assert v["machine"]["host_stalls"]["ECUS"] == {"stalls": 1, "worst_us": 1_200, "counted": True}
    assert "stalls the hosts saw themselves: ECUS 1; 2 misses at machine stalls (0 at the probes' alone)" \
        in realtime_lines(v)[1]
    o.realtime["host_stalls"]["ECUS"]["not_counted"] = "/proc/thread-self/schedstat unreadable"
    assert realtime_verdict(o)["machine"]["host_stalls"]["ECUS"]["why"].startswith("/proc")


def test_cycles_due_after_the_plants_last_wake_are_not_the_runs():
    """The plant ends the run; a host releases a few more cycles before it hears so (the plant meanwhile
    hands its results over at the nodes' priority): those are not judged, nor the probes' samples then."""
    from array import array

    from hil.runtime.realtime import judged_until_the_end

    payloads = {"PLANT": {"deadline_us": array("q", [0, 5_000, 10_000])},
                "BCU": {"deadline_us": array("q", [2_000, 12_000, 22_000]),
                        "lateness_us": array("q", [0, 10_100, 30]),
                        "ended_us": array("q", [2_300, 22_400, 22_300]),
                        "wait_lost_us": array("q", [0, 0, 0]), "cycle_lost_us": array("q", [0, 0, 0])},
                "PROBE0": {"deadline_us": array("q", [10_000, 20_000]), "lateness_us": array("q", [60, 70])}}
    judged_until_the_end(payloads)
    assert list(payloads["PLANT"]["deadline_us"]) == [0, 5_000, 10_000]
    assert list(payloads["BCU"]["lateness_us"]) == [0] and len(payloads["BCU"]["cycle_lost_us"]) == 1
    assert list(payloads["PROBE0"]["deadline_us"]) == [10_000]


@pytest.mark.parametrize(("wait_delay", "plant_cpu", "machines"),
                         [(1_400, 100, 1), (1_400, 800, 0), (0, 100, 0)])
def test_a_wait_for_a_cpu_no_other_host_or_probe_could_fill_is_the_machines(wait_delay, plant_cpu, machines):
    """BECU1 waited 1.4 ms runnable for a CPU in the 4.5 ms before its release, 1.5 ms late.  The plant's
    windows beside it ran 0.1 ms, the probes may have run 0.3 ms (two probes, one period): 1 ms of the wait
    was the machine's (its virtual CPU taken while BECU1 queued), and 0.5 ms late is no miss.  Had the plant
    run 0.8 ms then, only 0.3 ms is the machine's and the miss the bench's; no wait recorded (a host below
    SCHED_FIFO), the bench's."""
    nodes = {"BECU1": {"period_us": 10_000, "host": "ECUS", "deadline_us": np.array([3_000]),
                       "lateness_us": np.array([1_500]), "ended_us": np.array([4_800]),
                       "wait_lost_us": np.array([0]), "cycle_lost_us": np.array([0]),
                       "wait_cpu_us": np.array([50]), "cycle_cpu_us": np.array([300]),
                       "wait_delay_us": np.array([wait_delay]), "cycle_delay_us": np.array([0])},
             "PLANT": {"period_us": 5_000, "judged_in": "wakes", "host": "PLANT",
                       "deadline_us": np.array([0]), "lateness_us": np.array([0]),
                       "ended_us": np.array([200]), "wait_cpu_us": np.array([0]),
                       "cycle_cpu_us": np.array([plant_cpu])}}
    v = realtime_verdict(outcome(nodes))
    becu1 = v["nodes"]["BECU1"]
    assert (becu1["misses_machine"], becu1["misses_bench"]) == (machines, 1 - machines)


@pytest.mark.parametrize(("pinned", "machines"), [(False, 1), (True, 0)])
def test_on_two_cpus_one_other_host_cannot_keep_an_unpinned_host_waiting(pinned, machines):
    """The same 1.4 ms wait, the plant running 0.8 ms beside it, on a machine of two CPUs (a probe each).
    ECUS may run on either: it waits only while both run another host or a probe, at most the probes' 0.3 ms
    here (the plant and a probe at once, or both probes), plus what a process below it may hold a CPU in a
    system call: 1 ms of the wait is the machine's, the miss too.  ECUS pinned to one CPU: the plant may
    have held that one all along, the miss is the bench's."""
    from hil.runtime.probe import BENCH_HOLD_US, PROBE_SAMPLE_CPU_US, bench_wait_bound

    becu1 = {"period_us": 10_000, "host": "ECUS", "deadline_us": np.array([3_000]),
             "lateness_us": np.array([1_500]), "ended_us": np.array([4_800]),
             "wait_lost_us": np.array([0]), "cycle_lost_us": np.array([0]),
             "wait_cpu_us": np.array([50]), "cycle_cpu_us": np.array([300]),
             "wait_delay_us": np.array([1_400]), "cycle_delay_us": np.array([0]),
             **({"cpus": 1} if pinned else {})}
    plant = {"period_us": 5_000, "judged_in": "wakes", "host": "PLANT", "deadline_us": np.array([0]),
             "lateness_us": np.array([0]), "ended_us": np.array([1_000]), "wait_cpu_us": np.array([0]),
             "cycle_cpu_us": np.array([800])}
    v = realtime_verdict(outcome({"BECU1": becu1, "PLANT": plant},
                                 probes={"PROBE0": probe(3_000), "PROBE1": probe(3_000)}))
    assert (v["nodes"]["BECU1"]["misses_machine"], v["nodes"]["BECU1"]["misses_bench"]) == (machines,
                                                                                           1 - machines)
    # the bound itself: the plant's 0.8 ms and two probes' 0.15 ms in a 4.5 ms window
    plant_window = (np.array([0, 0]), np.array([0, 1_000]), np.array([0, 0, 800]))
    a, b = np.array([0]), np.array([4_500])
    probes = 2 * PROBE_SAMPLE_CPU_US
    assert bench_wait_bound([plant_window], a, b, probes=2, cpus=2)[0] == probes + BENCH_HOLD_US
    assert bench_wait_bound([plant_window], a, b, probes=2, cpus=1)[0] == 800 + probes + BENCH_HOLD_US
    # no host's CPU time counts for more than the window's length: a 0.3 ms window beside 0.8 ms of plant
    assert bench_wait_bound([plant_window], a, np.array([300]), probes=0, cpus=1)[0] == 300 + BENCH_HOLD_US


def test_bench_misses_released_behind_another_cycle_of_the_host_are_counted_apart():
    """A grouped host runs its nodes one after another: BECU1's cycle, on time but 1.6 ms long (3.0 to 4.6
    ms), keeps BECU2 (due at 3.5 ms) and BECU3 (due at 4.0 ms, behind BECU2's cycle) from their
    deadlines.  No probe stalled: the misses are the bench's, two of them behind another cycle of
    the host; BECU4's own late release (nothing before it running) is not.  The count changes no verdict."""
    def node(deadline, late, ended):
        return {"period_us": 10_000, "host": "ECUS", "deadline_us": np.array([deadline]),
                "lateness_us": np.array([late]), "ended_us": np.array([ended])}

    nodes = {"BECU1": node(3_000, 0, 4_600), "BECU2": node(3_500, 1_100, 4_900),
             "BECU3": node(4_000, 900, 5_200), "BECU4": node(6_000, 700, 6_900)}
    v = realtime_verdict(outcome(nodes))
    assert [(v["nodes"][n]["misses_bench"], v["nodes"][n]["misses_bench_behind"]) for n in nodes] == \
        [(0, 0), (1, 1), (1, 1), (1, 0)]
    assert (v["misses_bench"], v["misses_bench_behind"]) == (3, 2)
    lines = realtime_lines(v)
    assert "2 of the 3 bench misses behind another cycle of their host" in lines[1]
    assert "misses 1 bench (1 behind another cycle of its host) / 0 machine" in next(
        line for line in lines if line.lstrip().startswith("BECU2"))
    assert "misses 1 bench / 0 machine" in next(line for line in lines if line.lstrip().startswith("BECU4"))
