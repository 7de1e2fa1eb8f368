"""What each KPI of kpis.json is: its display name, its unit, a one-line meaning and whether it is per car.

kpis.json holds the foundation's KPIs (hil.report.kpis.compute_kpis and hil.report.run.finish_run) at its
top level, two groups of them (`bus`, `realtime`) and each study's under the study's name.  The table of
the foundation's is `FOUNDATION` below (a group's members by their dotted path, `bus.load`); each study
keeps its own as `KPI_INFO` at the end of hil/studies/<name>/kpis.py, in the same shape, and the report
finds it through the study registry.

An entry is a tuple `(display name, unit, meaning)` or `(display name, unit, meaning, True)` for a KPI
that is a list of one value per car (car 1 first).  Units are SI as the key's suffix says (`_m`, `_s`,
`_mps`, `_mps2`); the study KPIs the papers give in g say g (9.81 m/s²).  For what has no physical unit:
`1` a ratio or fraction, `count` a number of things, `yes/no` a flag, `text` a name or a choice, `id`
an identifier (the seed).

`groups(kpis)` sorts a kpis.json into the tables the report shows (the train's KPIs from the plant's truth,
the run's and its frames, the bus, real time, each study), each KPI with its entry or None;
`undescribed(kpis)` lists the dotted paths that have no entry (tests/report/test_html.py fails on any,
so a KPI added without a description is caught).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from hil.scenario import registry


class KpiInfo(NamedTuple):
    name: str               # display name
    unit: str               # SI unit, or 1 / count / yes/no / text / id
    meaning: str            # one line
    per_car: bool = False   # a list of one value per car


PER_CAR = True

# (display name, unit, meaning[, per car]); the order is the report's
FOUNDATION: dict[str, tuple] = {
    "stopped": ("train stopped", "yes/no",
                "every car below the plant's standstill speed (0.01 m/s) at a truth sample after the brake "
                "command"),
    "stopping_distance_m": ("stopping distance", "m",
                            "car 1's travel from the first brake command to the standstill (to the end of "
                            "the run when the train did not stop)"),
    "time_to_stop_s": ("time to stop", "s",
                       "from the first brake command to the standstill; none when the train did not stop"),
    "brake_start_s": ("brake command", "s",
                      "simulated time of the desk's first brake command (the start of the run without one)"),
    "mean_abs_decel_error_mps2": ("mean |deceleration error|", "m/s²",
                                  "mean |r⁰ − train deceleration| after the brake command while a car moves "
                                  "(> 0.5 m/s); r⁰ = BCU_DEMAND.TargetDecel from the trace, the train's "
                                  "deceleration mass-weighted from the truth; none without BCU_DEMAND"),
    "max_slip_speed_mps": ("max slip speed", "m/s",
                           "largest slip speed v − rω of the car at the 10 ms truth samples while it moves "
                           "(> 0.5 m/s)", PER_CAR),
    "max_slip_ratio": ("max slip ratio", "1",
                       "largest slip ratio σ = (v − rω)/v of the car at the 10 ms truth samples while it "
                       "moves (> 0.5 m/s)", PER_CAR),
    "wsp_activations": ("WSP activations", "count",
                        "times the car's applied WSP valve went to VENT (from FILL or HOLD; a VENT at the "
                        "first sample counts)", PER_CAR),
    "wsp_time_s": ("WSP time", "s",
                   "time the car's applied WSP valve was not FILL (HOLD or VENT), at the truth samples",
                   PER_CAR),
    "max_abs_coupler_dl_m": ("max |coupler displacement|", "m",
                             "largest |Δl| of any coupler at the truth samples (trains of more than one "
                             "car)"),
    "frames_sent": ("frames sent", "count", "CAN frames every node handed to the bus"),
    "frames_recorded": ("frames recorded", "count", "frames in the run's trace"),
    "frames_in_flight": ("frames in flight", "count",
                         "frames still queued or on the wire when the run ended"),
    "frames_overwritten": ("frames overwritten", "count",
                           "frames replaced by a newer one of the same message in a full transmit queue"),
    "frames_faulted": ("frames added/removed by faults", "count",
                       "frames injected faults added (+) or deleted (−); 0 without faults"),
    "frames_lost": ("frames lost", "count",
                    "sent + faulted − recorded − in flight − overwritten: frames that went nowhere (0 "
                    "expected)"),
    "frames_sent_by_node": ("frames sent by node", "count", "frames each node handed to the bus"),
    "protection_events": ("E2E / SecOC reports", "count",
                          "what the receivers' E2E and SecOC checks reported (every status but INITIAL), by "
                          "status; NONEWDATA = a frame 1.5 of its cycles late"),
    "faults_injected": ("faults injected", "count",
                        "injections of the scenario's [[faults]], by kind (only in runs with faults)"),
    "plausibility_flags": ("first plausibility flags", "s",
                           "simulated time each ECU flag (SpeedSensorFault, AccelSensorFault, "
                           "CarsImplausible) was first set in the trace, by flag and car (runs with faults "
                           "or flags)"),
    "mode": ("mode", "text", "lockstep (simulated time, bit-timed bus) or realtime (OS processes on a "
                             "python-can bus)"),
    "seed": ("seed", "id", "the scenario's seed (release jitter, sensor noise, faults)"),
    "simulated_s": ("simulated time", "s", "simulated time at the end of the run"),
    "end_reason": ("ended by", "text",
                   "standstill, max_duration, interrupted, failed or observed (a real-time node died)"),
    # the bus: the bit-timed lockstep bus's figures, or a real-time run's from its trace (hil.report.bus)
    "bus.bitrate_bps": ("bitrate", "bit/s", "the bus's bit rate (the DBC's Baudrate unless the scenario sets "
                                            "one)"),
    "bus.load": ("bus load", "1", "fraction of the run's time its frames took on the bus, each frame with "
                                  "its real stuff bits (0 to 1); the bits on the wire"),
    "bus.load_worst_case": ("bus load at worst-case stuffing", "1",
                            "the same frames, each at its worst-case stuffed length (Davis 2007): how "
                            "railhil timing's average and the response-time analysis count them, so a few "
                            "points above bus load"),
    "bus.worst_response_us": ("worst response time", "µs",
                              "largest response of any message: end of the frame − start of its release "
                              "window (real time: estimated from the trace, each frame against its cycle's "
                              "grid; a lower estimate)"),
    "bus.worst_response_message": ("worst-response message", "text", "the message with that response"),
    "bus.deadline_misses": ("deadline misses", "count",
                            "frames whose response was longer than their message's cycle time, all messages"),
    "bus.source": ("bus figures from", "text",
                   "bus model: the bit-timed lockstep bus, release by release; trace: a real-time run's "
                   "recorded frames"),
    # a real-time run (hil.runtime.outcome.realtime_verdict)
    "realtime.held": ("real time held", "yes/no",
                      "every simulated node's deadline misses that were the bench's (not the machine's) "
                      "stayed within the budget: at most budget_pct % of its cycles, none later than "
                      "max_late_periods periods"),
    "realtime.budget": ("budget", "text",
                        "a cycle more than max(miss_min_us, miss_period_pct % of its period) late is a miss; "
                        "the bench's misses allowed per node ([realtime.deadline])"),
    "realtime.worst_node": ("worst node", "text",
                            "the node that broke the budget with the latest miss, else the one with the "
                            "largest p99 lateness"),
    "realtime.p99_10ms_us": ("p99 lateness, 10 ms nodes", "µs",
                             "99th percentile of the release lateness of every 10 ms node's cycles, pooled"),
    "realtime.p50_10ms_us": ("p50 lateness, 10 ms nodes", "µs", "median of the same"),
    "realtime.misses_bench": ("deadline misses, the bench's", "count",
                              "misses at instants neither the machine probe nor the node's host saw a "
                              "stall, all nodes"),
    "realtime.misses_bench_behind": ("the bench's misses behind another cycle of their host", "count",
                                     "of the bench's misses, those whose deadline came while their host "
                                     "still ran the cycle before (a grouped host runs its nodes one after "
                                     "another), all nodes; per node in nodes"),
    "realtime.misses_machine": ("deadline misses, the machine's", "count",
                                "misses that coincide with a stall of the machine probe or one the node's "
                                "host saw itself, all nodes"),
    "realtime.misses_machine_probes": ("deadline misses at the probes' stalls", "count",
                                       "of the machine's misses, those a verdict from the probes alone "
                                       "would give the machine, all nodes"),
    "realtime.machine": ("machine floor (probe)", "µs",
                         "lateness of a bare loop per CPU sleeping to absolute 10 ms deadlines during the "
                         "run, at the nodes' priority: p50, p99, max, its stalls (> 500 µs late), the worst; "
                         "host_stalls: the stalls each host saw itself (kept from running > 500 µs)"),
    "realtime.nodes": ("per node", "µs",
                       "period, lateness p50/p99/max, the miss threshold, misses (bench, of them behind "
                       "another cycle of the host / machine / allowed), the worst bench miss, cycles "
                       "skipped, held, the lateness histogram"),
    "realtime.histogram_edges_us": ("histogram bins", "µs",
                                    "lower edges of the lateness histograms' bins (the last: all above)"),
    "realtime.missed_cycles": ("skipped cycles by node", "count",
                               "cycles each node skipped after falling more than 5 periods behind"),
    "realtime.max_lag_ms": ("max lateness by node", "ms", "the latest each node's cycle was released"),
    "realtime.lateness_us": ("cycle release lateness by node", "µs",
                             "p50, p99 and max of how late each cycle's wait returned after its absolute "
                             "deadline (its frames follow right after), and the cycles counted"),
    "realtime.conduct": ("each node on the bus", "text",
                         "per node: frames in the trace, their cycle-time verdicts (mean period ±10 %, "
                         "none missed), what the receivers' E2E / SecOC checks reported, first and last "
                         "frame [s]"),
    "realtime.external": ("external nodes", "text",
                          "nodes not simulated: their frames came from the bus (a device under test)"),
}

#: the train's KPIs, from the plant's truth: what a run is about, equal in a lockstep run and its real-time
#: twin; the foundation's other top-level KPIs are the run's (frames, mode, seed, ...)
TRAIN = ("stopped", "stopping_distance_m", "time_to_stop_s", "brake_start_s", "mean_abs_decel_error_mps2",
         "max_slip_speed_mps", "max_slip_ratio", "wsp_activations", "wsp_time_s", "max_abs_coupler_dl_m")
#: the foundation's groups of KPIs (a dict in kpis.json) and their titles
GROUPS = {"bus": "CAN bus", "realtime": "Real time"}
#: members of a group that the report shows in a section of their own, not in the KPI tables: a real-time
#: run's per-node lateness, the machine probe and each node's conduct on the bus (report.html's "Real time")
OWN_SECTION_PATHS = ("realtime.nodes", "realtime.conduct", "realtime.machine", "realtime.histogram_edges_us",
                     "realtime.lateness_us", "realtime.max_lag_ms", "realtime.missed_cycles")
#: kpis.json keys the report shows in a section of their own, not in the KPI tables: each device on its own
#: CAN matrix (hil.report.devices; report.html's "Devices")
OWN_SECTION = ("devices",)


def info_of(entry: tuple | None) -> KpiInfo | None:
    return None if entry is None else KpiInfo(*entry)


def study_info(name: str) -> tuple[str, dict[str, tuple]] | None:
    """(title, KPI_INFO) of the study called `name` (None: no such study)."""
    for study in registry.studies():
        if study.name == name:
            return study.title, getattr(study.part("kpis"), "KPI_INFO", {})
    return None


@dataclass(frozen=True)
class Kpi:
    path: str                   # dotted path in kpis.json: "stopping_distance_m", "bus.load", "wheel_slip.x"
    key: str                    # its key in its group
    value: object
    info: KpiInfo | None        # None: no entry (undescribed)

    @property
    def per_car(self) -> bool:
        return self.info is not None and self.info.per_car and isinstance(self.value, list)


@dataclass(frozen=True)
class Group:
    key: str                    # "" (the foundation's top level), "bus", "realtime" or a study's name
    title: str
    kpis: list[Kpi]


def _ordered(values: dict, table: dict[str, tuple], prefix: str = "") -> list[str]:
    """The keys of `values`: those of `table` in its order, then the rest as they come."""
    known = [k[len(prefix):] for k in table if k.startswith(prefix) and k[len(prefix):] in values]
    return known + [k for k in values if k not in known]


def groups(kpis: dict) -> list[Group]:
    """kpis.json as the report's tables: the foundation's top level, then `bus`, `realtime`, then each study
    (registry order), then any other group; each KPI with its entry (None when there is none)."""
    top = [k for k in _ordered(kpis, {k: v for k, v in FOUNDATION.items() if "." not in k})
           if k not in OWN_SECTION
           and not (isinstance(kpis[k], dict) and (k in GROUPS or study_info(k) is not None))]
    out = [Group("", "Train (from the plant's truth)",
                 [Kpi(k, k, kpis[k], info_of(FOUNDATION.get(k))) for k in top if k in TRAIN]),
           Group("run", "Run and frames",
                 [Kpi(k, k, kpis[k], info_of(FOUNDATION.get(k))) for k in top if k not in TRAIN])]
    for key, title in GROUPS.items():
        if isinstance(kpis.get(key), dict):
            members = kpis[key]
            out.append(Group(key, title, [Kpi(f"{key}.{k}", k, members[k],
                                              info_of(FOUNDATION.get(f"{key}.{k}")))
                                          for k in _ordered(members, FOUNDATION, f"{key}.")]))
    for study in registry.studies():
        if isinstance(kpis.get(study.name), dict):
            title, table = study_info(study.name)
            members = kpis[study.name]
            out.append(Group(study.name, f"{title} ({study.name})",
                             [Kpi(f"{study.name}.{k}", k, members[k], info_of(table.get(k)))
                              for k in _ordered(members, table)]))
    return out


def undescribed(kpis: dict) -> list[str]:
    """The dotted paths of the KPIs in `kpis` that have no entry."""
    return [k.path for g in groups(kpis) for k in g.kpis if k.info is None]
