"""Which of a run's verdicts gate `railhil run`'s exit code, from its kpis.json.

A run exits 1 when one of these failed (`railhil run --exit-zero` turns that off):

* real time held (a real-time run: kpis.json `realtime.held`, hil.runtime.outcome.realtime_verdict: the
  bench's deadline misses within the [realtime.deadline] budget); its figure names each node over budget
  with its bench misses and the misses allowed;
* each external node PASS (a device under test, `railhil run --external NAME`: kpis.json
  `realtime.conduct.NAME`, hil.report.conduct): its timing PASS (each cyclic message it sent at its DBC
  cycle time, none stopped) and its protection clean (no E2E / SecOC status but NONEWDATA reported about
  its frames);
* each device on its own CAN matrix PASS (hil.devices, `railhil run --device`: kpis.json `devices.NAME`,
  hil.report.devices): its frames' timing against its own DBC, their protection clean, and the gateway's
  frames on the bench PASS;
* each study's own PASS / FAIL checks (hil/studies/<name>/kpis.py `verdicts(k)`, e.g. the governor's slip
  bound, no collision with the train ahead); a check without a verdict (None) does not gate.

The other verdicts of report.html (hil.report.html.run_verdicts) are informational for the exit code:
the run ended by itself, the train stopped, frames lost, bus deadline misses, controller step errors, the
simulated nodes' E2E / SecOC reports, frames 1.5 cycles late, the machine's own misses.  report.html still
judges them.

`gates(kpis)` lists every gating verdict of a run, passed or failed, as `Gate`s; a caller that judges
more (a device under test on its own CAN matrix) appends its own and hands the list to `verdict_line`.
"""

from __future__ import annotations

from dataclasses import dataclass

from hil.scenario import registry


@dataclass(frozen=True)
class Gate:
    """One verdict that gates the exit code."""

    kind: str         # what the PASS line counts it as: "real time", "external node", "study check"
    what: str         # "real time", "external BECU3", "wheel_slip: slip ≤ s̄ at every plant step"
    passed: bool
    figure: str       # what stands behind it: "held", "NOT HELD (BCU 12 bench misses, allowed 2)", ...


def gates(kpis: dict) -> list[Gate]:
    """Every gating verdict of a run (module docstring) from its kpis.json: real time, then each external
    node, then each study's checks. A lockstep run has no real-time or external verdict."""
    rt = kpis.get("realtime") or {}
    out = [realtime_gate(rt)] if "held" in rt else []
    out += external_gates(rt.get("conduct") or {})
    out += device_gates(kpis.get("devices") or {})
    out += [Gate("study check", f"{study}: {check}", passed,
                 "PASS" if passed else f"FAIL ({value}; expected {criterion})")
            for study, (check, value, criterion, passed) in study_checks(kpis) if passed is not None]
    return out


def realtime_gate(rt: dict) -> Gate:
    """Real time held, or the nodes over budget: their bench misses, the misses allowed and those later
    than max_late_periods of their period."""
    if rt["held"]:
        return Gate("real time", "real time", True, "held")
    over = [(n, v) for n, v in (rt.get("nodes") or {}).items() if not v["held"]]
    figure = ", ".join(f"{n} {v['misses_bench']} bench misses, allowed {v['misses_allowed']}"
                       + (f", {v['bench_misses_over_a_period']} over a period late"
                          if v.get("bench_misses_over_a_period") else "") for n, v in over)
    return Gate("real time", "real time", False, f"NOT HELD ({figure or rt.get('worst_node')})")


def external_gates(conduct: dict) -> list[Gate]:
    """Each external node PASS: timing PASS and no E2E / SecOC status but NONEWDATA (a frame 1.5 cycles
    late: timing, judged by the timing) reported about its frames (hil.report.conduct)."""
    out = []
    for name, c in conduct.items():
        if not c.get("external"):
            continue
        bad = {k: v for k, v in (c.get("protection") or {}).items() if k != "NONEWDATA"}
        failed = ([f"timing {c['timing']}"] if c["timing"] != "PASS" else []) + \
                 (["E2E/SecOC " + ", ".join(f"{k} {v}" for k, v in bad.items())] if bad else [])
        out.append(Gate("external node", f"external {name}", not failed, ", ".join(failed) or "PASS"))
    return out


def device_gates(devices: dict) -> list[Gate]:
    """Each device PASS: its own frames' timing PASS and protection clean, the gateway's bench frames'
    timing PASS (hil.report.devices)."""
    out = []
    for name, d in devices.items():
        if d.get("transport") == "opcua":          # a PLC over OPC UA: its writes' timing
            failed = [] if d["plc"]["timing"] == "PASS" else [f"its writes' timing FAIL: {d['plc']['why']}"]
            if d["bench"]["timing"] != "PASS":
                failed.append(f"the gateway's bench frames' timing {d['bench']['timing']}")
            out.append(Gate("device", f"device {name}", not failed, ", ".join(failed) or "PASS"))
            continue
        own, bench = d["device"], d["bench"]
        bad = {k: v for k, v in own["protection"].items() if k != "NONEWDATA"}
        failed = ([f"its frames' timing {own['timing']}"] if own["timing"] != "PASS" else [])
        failed += ["its protection " + ", ".join(f"{k} {v}" for k, v in bad.items())] if bad else []
        if bench["timing"] != "PASS":
            failed.append(f"the gateway's bench frames' timing {bench['timing']}")
        out.append(Gate("device", f"device {name}", not failed, ", ".join(failed) or "PASS"))
    return out


def study_checks(kpis: dict) -> list[tuple[str, tuple]]:
    """(study, (check, value, criterion, passed)) for each check of each study in the run, in registry
    order: the study's `verdicts(k)` on its kpis.json entry (a study without checks has none)."""
    out = []
    for study in registry.studies():
        hook = getattr(study.part("kpis"), "verdicts", None) if study.name in kpis else None
        if hook is not None:
            out += [(study.name, tuple(v)) for v in hook(kpis[study.name])]
    return out


def verdict_line(checks: list[Gate]) -> str:
    """The last line of a run's summary: the gating verdicts that failed, each with its figure, or what
    passed, counted by kind."""
    failed = [g for g in checks if not g.passed]
    if failed:
        return "verdict: FAIL — " + "; ".join(f"{g.what} {g.figure}" for g in failed)
    if not checks:
        return "verdict: PASS (no real-time, external-node, device or study check in this run)"
    by_kind: dict[str, list[Gate]] = {}
    for g in checks:
        by_kind.setdefault(g.kind, []).append(g)
    parts = []
    for kind, group in by_kind.items():
        if len(group) == 1 and group[0].what == kind:        # a verdict of its own: "real time held"
            parts.append(f"{kind} {group[0].figure}")
        else:
            parts.append(f"{len(group)} {kind}{'s' if len(group) > 1 else ''} PASS")
    return f"verdict: PASS ({', '.join(parts)})"
