"""The summary a run prints: the foundation's lines, then each study's (hil/studies/<name>/kpis.py
`summary_lines(k)` on its kpis.json entry), the files written, and last the verdict of the checks that
gate `railhil run`'s exit code (hil.report.gate)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from hil.report.gate import gates, verdict_line
from hil.scenario import registry


def summary_lines(kpis: dict, files: Iterable[Path]) -> list[str]:
    def per_car(values, fmt):
        return " ".join(fmt.format(v) for v in values)

    lines = [
        f"stopping distance       {kpis['stopping_distance_m']:.2f} m"
        + ("" if kpis["stopped"] else "  (train did not stop)"),
        f"time to stop            {kpis['time_to_stop_s']:.2f} s" if kpis["time_to_stop_s"] is not None
        else "time to stop            —",
        f"max slip speed per car  {per_car(kpis['max_slip_speed_mps'], '{:.3f}')} m/s",
        f"max slip ratio per car  {per_car(kpis['max_slip_ratio'], '{:.3f}')}",
        f"WSP activations per car {per_car(kpis['wsp_activations'], '{:d}')}",
        "mean |decel error|      " + (f"{kpis['mean_abs_decel_error_mps2']:.3f} m/s²"
                                      if kpis["mean_abs_decel_error_mps2"] is not None else "—"),
        f"frames sent             {kpis['frames_sent']} ({kpis['frames_lost']} not in the trace"
        + (f", {kpis['frames_in_flight']} still queued at the end" if kpis.get("frames_in_flight") else "")
        + (f", {kpis['frames_overwritten']} overwritten in a transmit queue"
           if kpis.get("frames_overwritten") else "") + ")",
    ]
    if kpis.get("faults_injected") is not None or kpis.get("protection_events"):
        injected = ", ".join(f"{k} {v}" for k, v in (kpis.get("faults_injected") or {}).items()) or "none"
        seen = ", ".join(f"{k} {v}" + (" (frames 1.5 cycles late)" if k == "NONEWDATA" else "")
                         for k, v in kpis.get("protection_events", {}).items()) or "nothing"
        lines.append(f"faults injected         {injected}; receivers reported {seen}")
    flags = kpis.get("plausibility_flags")
    if flags:                         # first time [s] each sensor fault / implausible car was flagged
        shown = "; ".join(f"{flag} " + ", ".join(f"{car} {t:.2f} s" for car, t in cars.items())
                          for flag, cars in sorted(flags.items()))
        lines.append(f"sensor flags            {shown}")
    for study in registry.studies():
        if study.name in kpis:
            lines += study.part("kpis").summary_lines(kpis[study.name])
    bus = kpis.get("bus")
    if bus:
        lines.append(bus_line(bus))
    rt = kpis.get("realtime")
    if rt and "budget" in rt:
        lines += realtime_lines(rt)
        lines += external_lines(rt.get("conduct") or {})
    lines += device_lines(kpis.get("devices") or {})
    lines.append("files: " + ", ".join(str(f) for f in files))
    lines.append(verdict_line(gates(kpis)))
    return lines


def bus_line(bus: dict) -> str:
    """The bus line (kpis.json `bus`): the load measured (each frame with its real stuff bits) and at
    worst-case stuffing (each frame at its longest, as `railhil timing` and the response-time analysis
    count it), the worst response -- the bus model's, or in real time the one estimated from the trace --
    and the bus model's deadline misses."""
    load = "load —" if bus.get("load") is None else f"load {100 * bus['load']:.1f} % measured"
    if bus.get("load_worst_case") is not None:
        load += f", {100 * bus['load_worst_case']:.1f} % at worst-case stuffing"
    where = ", estimated from the trace" if bus.get("source") == "trace" else ""
    misses = f", {bus['deadline_misses']} deadline misses" if "deadline_misses" in bus else ""
    return (f"bus ({bus['bitrate_bps'] // 1000} kbit/s)       {load}; worst response "
            f"{bus['worst_response_us']:.0f} us ({bus['worst_response_message']}{where}){misses}")


def host_stalls_text(machine: dict) -> str:
    """The stalls the hosts saw themselves ('' for a run that did not watch them)."""
    seen = machine.get("host_stalls") or {}
    if not seen:
        return ""
    parts = [f"{h} {v['stalls']}" + ("" if v["counted"] else f" (not counted: {v.get('why')})")
             for h, v in seen.items()]
    return "stalls the hosts saw themselves: " + ", ".join(parts)


def realtime_lines(rt: dict) -> list[str]:
    """The verdict of a real-time run against its budget, the lateness and the machine's own floor
    (hil.runtime.outcome.realtime_verdict)."""
    b = rt["budget"]
    budget = (f"budget: bench misses ≤ {b['budget_pct']:g} % of each node's cycles, none over "
              f"{b['max_late_periods']:g} period late; a miss is > max({b['miss_min_us']} us, "
              f"{b['miss_period_pct']:g} % of the period) late")
    nodes = rt["nodes"]
    if rt["held"]:
        head = f"real time               held: {rt['misses_bench']} bench misses ({budget})"
    else:
        bad = [n for n, v in nodes.items() if not v["held"]]
        what = ", ".join(f"{n} {nodes[n]['misses_bench']} misses (allowed {nodes[n]['misses_allowed']}), "
                         f"worst {nodes[n]['worst_bench_miss_us'] / 1e3:.1f} ms late" for n in bad)
        head = f"real time               NOT HELD: {what} ({budget})"
    m = rt["machine"]
    floor = "machine floor: probe " + (f"p99 {m['p99_us']} us, worst stall {m['worst_stall_us'] / 1e3:.1f} "
                                       "ms" if "error" not in m else f"failed ({m['error']})")
    plant = nodes.get("PLANT")
    seen = host_stalls_text(m)
    lateness = (f"  lateness              10 ms nodes p50 {rt['p50_10ms_us']} / p99 {rt['p99_10ms_us']} us"
                + (f"; PLANT p99 {plant['p99_us']} us" if plant else "")
                + f"; {floor}" + (f"; {seen}" if seen else "")
                + f"; {rt['misses_machine']} misses at machine stalls"
                + (f" ({rt['misses_machine_probes']} at the probes' alone)" if seen else "")
                + (f"; {rt['misses_bench_behind']} of the {rt['misses_bench']} bench misses behind another "
                   "cycle of their host" if rt.get("misses_bench_behind") else ""))
    per_node = [f"  {name:<21} p50 {v['p50_us']} / p99 {v['p99_us']} / max {v['max_us']} us over "
                f"{_judged(v)}; misses {v['misses_bench']} bench{_behind(v)} / "
                f"{v['misses_machine']} machine (> {v['miss_threshold_us']} us); {v['skipped']} skipped"
                for name, v in nodes.items()]
    return [head, lateness, *per_node]


def _behind(v: dict) -> str:
    """Of a node's bench misses, those released behind another cycle of its host (kpis.json of earlier
    releases have no such count)."""
    n = v.get("misses_bench_behind") or 0
    return f" ({n} behind another cycle of its host)" if n else ""


def _judged(v: dict) -> str:
    """What a node's lateness is counted over: its cycles, or, for the plant woken on its frames (its 1 ms
    steps computed at each wake), its wakes."""
    if v.get("judged_in") == "wakes":
        return f"{v['cycles']} wakes at most {v['period_us'] / 1e3:g} ms apart"
    return f"{v['cycles']} cycles of {v['period_us'] / 1e3:g} ms"


def _way(f: dict) -> str:
    if not f["frames"]:
        return "no frame"
    return f"p50 {f['p50_us']:.0f} / p99 {f['p99_us']:.0f} / max {f['max_us']:.0f} us"


def device_lines(devices: dict) -> list[str]:
    """Two lines per device on its own CAN matrix (hil.report.devices): its frames against its own DBC
    and their protection, when it was heard; the gateway's latency each way and its frames on the
    bench."""
    lines = []
    for name, d in devices.items():
        if d.get("transport") == "opcua":
            lines += opcua_lines(name, d)
            continue
        own, bench = d["device"], d["bench"]
        judged = [v for v in own["messages"].values() if v["verdict"] != "MISSING"]
        passed = sum(v["verdict"] == "PASS" for v in judged)
        bad = {k: v for k, v in own["protection"].items() if k != "NONEWDATA"}
        prot = ("protection clean" if not bad else
                "protection " + ", ".join(f"{k} {v}" for k, v in bad.items()))
        heard = f"heard {own['first_s']:.2f}–{own['last_s']:.2f} s" if own["frames"] else "never heard"
        silent = (f"; the BCU reported it silent at {bench['reported_silent_s']:.2f} s"
                  if bench.get("reported_silent_s") is not None else "")
        lines.append(f"device {name:<16} {d['node']} ({Path(d['dbc']).name}, {d['mode']}): {own['frames']} "
                     f"frames, timing {own['timing']} ({passed} of {len(judged)} messages), {prot}; "
                     f"{heard}{silent}")
        lat = d["latency"]
        b_judged = [v for v in bench["messages"].values() if v["verdict"] != "MISSING"]
        b_passed = sum(v["verdict"] == "PASS" for v in b_judged)
        lines.append(f"  gateway               device→bench {_way(lat['device_to_bench'])}, bench→device "
                     f"{_way(lat['bench_to_device'])}; on the bench {bench['frames']} frames, timing "
                     f"{bench['timing']} ({b_passed} of {len(b_judged)} messages)")
    return lines


def _spread(f: dict) -> str:
    if not f["n"]:
        return "none measured"
    return f"p50 {f['p50_ms']:g} / p99 {f['p99_ms']:g} / max {f['max_ms']:g} ms"


def opcua_lines(name: str, d: dict) -> list[str]:
    """A device over OPC UA: its link (role, endpoint, security), its writes' cycle against the bound, the
    age of what it read and the round trip (with an echo), the bench's calls, refusals; the gateway's
    frames on the bench."""
    link, bench, plc = d["opcua"], d["bench"], d["plc"]
    security = link["security"] + (f", user {link['user']}" if link.get("user") else "")
    where = ("its model in lockstep, no link" if d["mode"] == "model" else
             f"the bench as {link['role']} at {link['endpoint']}, {security}")
    lines = [f"device {name:<16} {d['node']} over OPC UA ({Path(d['file']).name}; {where}): {link['writes']} "
             f"writes, timing {plc['timing']} ({plc['why']})",
             f"  PLC cycle             {_spread(link['cycle'])} (declared {link['cycle_ms_declared']:g} ms)"]
    if link.get("echo"):
        lines.append(f"  read age / round trip {_spread(link['read_age'])} / {_spread(link['round_trip'])} "
                     f"(by the echo {link['echo']})")
    else:
        lines.append("  read age / round trip not measured: the device file names no [opcua] stamp and echo")
    if link["calls"]["n"]:
        lines.append(f"  the bench's OPC UA calls {_spread(link['calls'])}")
    if link["refused"]:
        lines.append("  refused: " + ", ".join(f"{k} {v}" for k, v in link["refused"].items()))
    b_judged = [v for v in bench["messages"].values() if v["verdict"] != "MISSING"]
    b_passed = sum(v["verdict"] == "PASS" for v in b_judged)
    silent = (f"; the BCU reported it silent at {bench['reported_silent_s']:.2f} s"
              if bench.get("reported_silent_s") is not None else "")
    lines.append(f"  gateway on the bench  {bench['frames']} frames, timing {bench['timing']} ({b_passed} of "
                 f"{len(b_judged)} messages){silent}")
    return lines


def external_lines(conduct: dict) -> list[str]:
    """One line per external node (a device under test): its frames, their timing, the receivers' E2E /
    SecOC verdicts, when it was heard and, once it fell silent, when the BCU reported it."""
    lines = []
    for name, c in conduct.items():
        if not c.get("external"):
            continue
        judged = [v for v in c["messages"].values() if v["verdict"] != "MISSING"]
        passed = sum(v["verdict"] == "PASS" for v in judged)
        bad = {k: v for k, v in c["protection"].items() if k != "NONEWDATA"}
        prot = "E2E/SecOC clean" if not bad else "E2E/SecOC " + ", ".join(f"{k} {v}" for k, v in bad.items())
        heard = (f"heard {c['first_s']:.2f}–{c['last_s']:.2f} s" if c["frames"] else "never heard")
        silent = (f"; the BCU reported it silent at {c['reported_silent_s']:.2f} s"
                  if c.get("reported_silent_s") is not None else "")
        lines.append(f"external {name:<14} {c['frames']} frames, timing {c['timing']} ({passed} of "
                     f"{len(judged)} messages), {prot}; {heard}{silent}")
    return lines
