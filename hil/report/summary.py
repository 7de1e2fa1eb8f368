"""The summary a run prints: the foundation's lines, then each study's (hil/studies/<name>/kpis.py
`summary_lines(k)` on its kpis.json entry)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

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
        lines.append(f"bus ({bus['bitrate_bps'] // 1000} kbit/s)       load {100 * bus['load']:.1f} %, "
                     f"worst response {bus['worst_response_us']:.0f} us ({bus['worst_response_message']}), "
                     f"{bus['deadline_misses']} deadline misses")
    rt = kpis.get("realtime")
    if rt:
        worst = rt["worst_node"]
        skipped = ", ".join(f"{n} {k}" for n, k in rt["missed_cycles"].items() if k)
        lines.append(f"real time               held: no cycle more than {rt['limit_ms']:g} ms late (worst "
                     f"{worst} {rt['max_lag_ms'][worst]:g} ms)" if rt["held"] else
                     f"real time               NOT HELD: {worst} up to {rt['max_lag_ms'][worst]:g} ms late"
                     + (f", cycles skipped: {skipped}" if skipped else "")
                     + " - the machine was short of CPU; this run's figures are not the controllers' at "
                       "their cycle times")
    lines.append("files: " + ", ".join(str(f) for f in files))
    return lines
