"""One self-contained HTML page per run folder (report.html), per campaign folder, and per comparison of
two run folders (report-vs-<other>.html).

A run's page is built from the files of its folder only — run.json, kpis.json, truth.csv and the PNG plots
— so `railhil report RUN_DIR` rebuilds it at any time and `hil.report.run.finish_run` writes it after
every run.  It needs nothing else: no network, no neighbouring file (the PNGs are embedded as base64,
plotly.js is inlined once per page).  It reads at a glance on a 1,280 px screen (tests/report/test_html.py
draws it in headless Chromium: no element wider than the page, the verdict and the KPIs on the first
screen, under 5,000 px), in this order:

* what the run ran, from its own resolved scenario (`describe_scenario`), the verdict and the key figures;
* the verdicts: each check of `run_verdicts` with its value, its criterion and pass / fail;
* every KPI of kpis.json with its name, value, unit and meaning (hil.report.kpi_info): the train's (from the
  plant's truth), the run's and its frames, the bus, each study, single values in one table and per-car
  values one column per car; a real-time run's KPIs folded (the Real time section has them per node); a
  KPI without a description is shown as such;
* the signals: an interactive plotly figure of the truth (speed, cylinder pressure and slip speed of
  every car over time, as plot.png), zoomable; at most MAX_POINTS samples a curve (min/max per bucket,
  so peaks survive the decimation);
* real time: one row per node -- cycles, lateness, misses (the bench's / the machine's), E2E start-up
  discards apart from the E2E / SecOC errors the verdict counts (`_e2e_by_node`), its frames' timing --
  and lateness.png; the rest folded;
* timing: per message on the bit-timed lockstep bus (folded), per node its frames and E2E / SecOC;
* faults injected and what the receivers' E2E / SecOC checks and the plausibility checks reported;
* folded: the static figures (plot.png and each study's), what reproduces the run (railhil and library
  versions, seed, DBC path and SHA-256, git commit), the resolved scenario.

A comparison page (`write_comparison`: `railhil report RUN --against REF`) puts two run folders side by
side the way a regression is reviewed: both runs' scenario (each described from its own), seed, mode and
versions, the scenario keys that differ, both runs' verdicts, every KPI both runs have with both values,
Δ = RUN − REF and Δ relative to |REF| (changed values highlighted; per group how many differ,
`comparison_summary`), those of one run only listed apart, and the two runs' signals overlaid (RUN solid,
REF dashed).

A campaign's page (`write_campaign_report`) holds the point counts, the results table (results.csv)
and the summary plots (plot_<key>.png) of the campaign folder.

What reproduces the run (versions, seed, DBC SHA-256, git commit) is in run.json, which the run wrote
(hil.runtime.provenance.run_metadata).
"""

from __future__ import annotations

import base64
import csv
import html
import json
import math
import re
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np

from hil.errors import RailhilError
from hil.report import kpi_info
from hil.report.gate import device_gates, external_gates, study_checks
from hil.report.kpi_info import Kpi
from hil.report.summary import host_stalls_text
from hil.runtime.truth import read_truth_csv
from hil.scenario import registry
from hil.scenario.params import KMH_PER_MPS

REPORT_NAME = "report.html"
MAX_FAULT_EVENTS = 200       # fault events listed in a report (run.json keeps them all)
MAX_TABLE_ROWS = 2000        # campaign rows shown in the page (results.csv keeps them all)
MAX_POINTS = 2000            # samples a curve of the interactive figures keeps at most (min/max decimation)
#: matplotlib's tab10, the colours of plot.png's cars, so both figures colour car i alike
CAR_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
               "#bcbd22", "#17becf")
#: the truth columns of the interactive figures: (column prefix, scale, y-axis title), as plot.png
SIGNALS = (("v_mps", KMH_PER_MPS, "speed [km/h]"), ("p_Pa", 1e-3, "cylinder pressure [kPa]"),
           ("slip_speed_mps", 1.0, "slip speed v − rω [m/s]"))
#: no plotly logo, no "Share chart" button (plotly.js 3 uploads the data to Plotly Cloud with it)
PLOTLY_CONFIG = {"displaylogo": False, "responsive": True, "showSendToCloud": False, "plotlyServerURL": ""}


class ReportError(RailhilError):
    """A folder that is not a run folder or a campaign folder, or whose files do not read (exit 2)."""


# --------------------------------------------------------------------------------------------- verdicts
@dataclass(frozen=True)
class Verdict:
    check: str
    value: str
    criterion: str
    passed: bool | None            # None: informational, no criterion applies to this run


def _sum_stat(meta: dict, key: str) -> int:
    return sum(int(s.get(key) or 0) for s in (meta.get("node_stats") or {}).values())


def run_verdicts(kpis: dict, meta: dict) -> list[Verdict]:
    """The checks every run is judged by, from its kpis.json and run.json:

    * the run ended by itself (standstill or max_duration), not interrupted or failed;
    * the train stopped (every car below the plant's standstill speed) before the run ended;
    * no frame lost: every frame sent is in the trace, still queued at the end, or overwritten;
    * no bus deadline miss (bit-timed lockstep bus: response time above the message's cycle time);
    * no node step error (an exception inside a controller's step, answered with safe values);
    * real time held (hil.runtime.outcome.realtime_verdict: the bench's deadline misses within the
      budget of [realtime.deadline]), with the machine's own misses beside (informational);
    * E2E / SecOC: without injected faults, nothing reported by the receivers; with faults, the
      detections are listed (informational); NONEWDATA (a frame 1.5 of its cycles late) is a verdict of
      its own: none in lockstep, informational in real time;
    * each external node (a device under test) on the bus: timing PASS, E2E / SecOC clean
      (hil.report.conduct);
    * each study's own checks (hil/studies/<name>/kpis.py `verdicts`), e.g. the governor's slip bound.

    Real time held, the external nodes and the studies' checks also gate `railhil run`'s exit code
    (hil.report.gate); the others are informational there."""
    out = [Verdict("run ended by itself", str(kpis.get("end_reason")), "standstill or max_duration",
                   kpis.get("end_reason") in ("standstill", "max_duration")),
           Verdict("train stopped", str(kpis.get("stopped")), "standstill before the run ended",
                   bool(kpis.get("stopped")))]
    if "frames_lost" in kpis:
        out.append(Verdict("frames lost", str(kpis["frames_lost"]), "= 0", kpis["frames_lost"] == 0))
    bus = kpis.get("bus")
    if bus and "deadline_misses" in bus:            # the bit-timed lockstep bus (real time: hil.report.bus)
        out.append(Verdict("bus deadline misses", str(bus.get("deadline_misses")), "= 0",
                           bus.get("deadline_misses") == 0))
    steps = _sum_stat(meta, "step_errors")
    out.append(Verdict("controller step errors", str(steps), "= 0", steps == 0))
    if meta.get("mode") == "realtime":
        rt = kpis.get("realtime")
        if rt and "budget" in rt:               # hil.runtime.outcome.realtime_verdict
            b = rt["budget"]
            bad = [n for n, v in rt["nodes"].items() if not v["held"]]
            value = (f"{rt['misses_bench']} bench misses; 10 ms nodes p99 {rt['p99_10ms_us']} µs"
                     if rt["held"] else
                     "; ".join(f"{n}: {rt['nodes'][n]['misses_bench']} misses (allowed "
                               f"{rt['nodes'][n]['misses_allowed']}), worst "
                               f"{rt['nodes'][n]['worst_bench_miss_us'] / 1e3:.1f} ms" for n in bad))
            out.append(Verdict("real time held (the bench's deadline misses)", value,
                               f"≤ {b['budget_pct']:g} % of each node's cycles, none over "
                               f"{b['max_late_periods']:g} period late; miss: > max({b['miss_min_us']} µs, "
                               f"{b['miss_period_pct']:g} % of the period)", rt["held"]))
            m = rt.get("machine") or {}
            seen = host_stalls_text(m)
            out.append(Verdict("the machine's own misses (stalls of a probe or seen by a host)",
                               (f"{rt['misses_machine']} misses; probe p99 {m.get('p99_us')} µs, worst stall "
                                f"{(m.get('worst_stall_us') or 0) / 1e3:.1f} ms" if "error" not in m
                                else f"no probe: {m['error']}") + (f"; {seen}" if seen else ""),
                               "(informational: the host, not the bench)", None))
            out += [Verdict(f"{g.what} on the bus", g.figure, "timing PASS (each cyclic message at its DBC "
                            "cycle time), E2E / SecOC clean (nothing but NONEWDATA reported)", g.passed)
                    for g in external_gates(rt.get("conduct") or {})]
        elif rt:                                  # a run folder of an earlier release
            out.append(Verdict("real time held", str(rt.get("worst_node")), "(earlier release's verdict)",
                               rt.get("held")))
        late = _sum_stat(meta, "late_cycles")
        out.append(Verdict("real-time cycles late", str(late), "(informational)", None))
    events = kpis.get("protection_events") or {}
    # NONEWDATA is timing, not protection: a receiver's cycle found no frame 1.5 cycles after the last one
    # (hil.runtime.node): on a real-time bus every late frame counts, so there it is informational
    late_frames = events.get("NONEWDATA", 0)
    seen = {k: v for k, v in events.items() if k != "NONEWDATA"}
    detected = ", ".join(f"{k} {v}" for k, v in seen.items()) or "none"
    if kpis.get("faults_injected") is None:
        out.append(Verdict("E2E / SecOC errors reported", detected, "none (no fault injected)", not seen))
        realtime = meta.get("mode") == "realtime"
        out.append(Verdict("frames 1.5 cycles late (E2E NONEWDATA)", str(late_frames),
                           "(real time: informational)" if realtime else "= 0 (no fault injected)",
                           None if realtime else late_frames == 0))
    else:
        if late_frames:
            detected = ", ".join(f"{k} {v}" for k, v in events.items())
        out.append(Verdict("E2E / SecOC errors reported", detected, "(faults injected: informational)", None))
    out += [Verdict(g.what, g.figure, "its frames' timing PASS against its own DBC, its protection clean, "
                    "the gateway's bench frames' timing PASS", g.passed)
            for g in device_gates(kpis.get("devices") or {})]      # each device on its own CAN matrix
    out += [Verdict(*v) for _, v in study_checks(kpis)]    # each study's own checks of its KPIs
    return out


# ----------------------------------------------------------------------------------------- HTML pieces
CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;margin:1.5em auto;max-width:1150px;
color:#1d1d1f;padding:0 1em}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.88em;margin:.4em 0}
th,td{border:1px solid #ddd;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#f4f4f6}td.num{text-align:right;font-variant-numeric:tabular-nums}
.pass{background:#dff5e1;color:#165c1e;font-weight:600}.fail{background:#fde2e1;color:#8a1c14;font-weight:600}
.info{color:#666}.banner{padding:.5em .8em;border-radius:4px;margin:.6em 0;font-weight:600}
img{max-width:100%;border:1px solid #eee}pre{background:#f7f7f9;padding:.6em;overflow:auto;font-size:.8em}
.scroll{max-height:32em;overflow:auto}
h3{font-size:1em;margin:1.2em 0 .2em}code.key{color:#777;font-size:.85em;display:block}
td.meaning{color:#444;max-width:36em}table.inner{margin:0;font-size:1em}
table.inner td,table.inner th{padding:.1em .4em}.note{background:#fff6c8;color:#5c4a00}
tr.undescribed td{background:#fff1d6}tr.changed td{background:#fff6c8}td.delta{white-space:nowrap}
table.runs td{overflow-wrap:anywhere}table.runs td:first-child{white-space:nowrap}
nav{font-size:.88em;color:#666}nav a{margin-right:.8em}.plot{width:100%;min-height:400px}
table.kpis{width:100%}table.kpis td.meaning{max-width:none;font-size:.92em}
details{margin:.4em 0}summary{cursor:pointer;color:#333}details>*:not(summary){margin-left:.6em}
.figures{display:flex;flex-wrap:wrap;gap:.4em 1.2em;margin:.4em 0;padding:.4em .8em;background:#f7f7f9;
border-radius:4px;font-size:.92em}.figures span{white-space:nowrap}
.figures b{font-variant-numeric:tabular-nums}p.describe{margin:.2em 0;color:#333}
.nowrap td{white-space:nowrap}
"""


def _e(x: object) -> str:
    return html.escape(str(x), quote=True)


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        return " ".join(_fmt(x) for x in v)
    if isinstance(v, dict):
        return ", ".join(f"{k} {_fmt(x)}" for k, x in v.items()) or "—"
    return "—" if v is None else str(v)


def _table(header: list[str], rows: list[list[object]], numeric: set[int] | frozenset = frozenset()) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td{' class=num' if i in numeric else ''}>{_e(_fmt(c))}</td>"
                                    for i, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _verdict_cell(passed: bool | None) -> str:
    if passed is None:
        return "<td class=info>info</td>"
    return "<td class=pass>pass</td>" if passed else "<td class=fail>FAIL</td>"


def _images(paths: list[Path]) -> str:
    parts = []
    for p in paths:
        data = base64.b64encode(p.read_bytes()).decode("ascii")
        parts.append(f"<figure><img alt=\"{_e(p.name)}\" src=\"data:image/png;base64,{data}\">"
                     f"<figcaption class=info>{_e(p.name)}</figcaption></figure>")
    return "".join(parts) or "<p class=info>no plot in this folder</p>"


def _page(title: str, body: str, plotly: bool = False) -> str:
    """The page; `plotly`: with plotly.js inlined (once, in the head) for the interactive figures."""
    script = (f"<script>window.PlotlyConfig = {{MathJaxConfig: 'local'}};</script>\n"
              f"<script>{_plotly_js()}</script>\n") if plotly else ""
    return (f"<!DOCTYPE html>\n<html lang=en><head><meta charset=utf-8>"
            f"<meta name=viewport content=\"width=device-width, initial-scale=1\">"
            f"<title>{_e(title)}</title><style>{CSS}</style>\n{script}</head><body>\n{body}\n</body></html>\n")


def _nav(sections: list[tuple[str, str]]) -> str:
    return "<nav>" + "".join(f"<a href=\"#{a}\">{_e(t)}</a>" for a, t in sections) + "</nav>"


def _read_json(path: Path, what: str) -> dict:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise ReportError(f"{path.parent}: not a run folder: no {path.name} ({what})") from None
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise ReportError(f"{path}: cannot read {what}: {' '.join(str(exc).split())[:160]}") from None


# ------------------------------------------------------------------------------------------------ KPIs
def _value_html(v: object) -> str:
    """A KPI's value for a table cell (escaped): yes/no, numbers, lists as "a, b", a mapping (frames by
    node, events by status, flags by car) as a small table of its own."""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, list):
        return ", ".join(_value_html(x) for x in v) or "—"
    if isinstance(v, dict):
        if not v:
            return "none"
        if all(isinstance(x, dict) for x in v.values()):          # {flag: {car: t}}
            return "<table class=inner>" + "".join(
                f"<tr><th>{_e(k)}</th><td>{_value_html(x)}</td></tr>" for k, x in v.items()) + "</table>"
        # {node: frames}, {status: count}: one line of "name value" pairs that wraps with the page
        return ", ".join(f"{_e(k)}&nbsp;{_value_html(x)}" for k, x in v.items())
    return _e(_fmt(v))


def _kpi_name(k: Kpi) -> str:
    name = k.info.name if k.info else k.key
    return f"{_e(name)} <code class=key>{_e(k.path)}</code>"


def _unit_meaning(k: Kpi) -> tuple[str, str]:
    if k.info is None:
        return "?", ("no description: add one to hil/report/kpi_info.py (the foundation's) or the study's "
                     "KPI_INFO (hil/studies/<name>/kpis.py)")
    return k.info.unit, k.info.meaning


def _kpi_row(k: Kpi) -> str:
    unit, meaning = _unit_meaning(k)
    cls = " class=undescribed" if k.info is None else ""
    num = " class=num" if isinstance(k.value, int | float) and not isinstance(k.value, bool) else ""
    return (f"<tr{cls}><td>{_kpi_name(k)}</td><td{num}>{_value_html(k.value)}</td><td>{_e(unit)}</td>"
            f"<td class=meaning>{_e(meaning)}</td></tr>")


def _car_cells(values: list, n: int) -> str:
    """One cell per car, n of them (a shorter list leaves the last ones empty)."""
    return "".join(f"<td class=num>{_value_html(v)}</td>" for v in values) + "<td></td>" * (n - len(values))


def _per_car_table(kpis: list[Kpi]) -> str:
    n = max(len(k.value) for k in kpis)
    head = "".join(f"<th>car {i}</th>" for i in range(1, n + 1))
    rows = []
    for k in kpis:
        unit, meaning = _unit_meaning(k)
        rows.append(f"<tr><td>{_kpi_name(k)}</td>{_car_cells(k.value, n)}<td>{_e(unit)}</td>"
                    f"<td class=meaning>{_e(meaning)}</td></tr>")
    return (f"<table class=kpis><thead><tr><th>per car</th>{head}<th>unit</th><th>meaning</th></tr></thead>"
            f"<tbody>{''.join(rows)}</tbody></table>")


def _kpi_section(kpis: dict) -> str:
    """The KPIs of kpis.json (hil.report.kpi_info.groups): per group a table name / value / unit /
    meaning and a table of the per-car values, one column per car; a real-time run's per-node figures
    (kpi_info.OWN_SECTION_PATHS) are in the Real time section instead."""
    parts = []
    for g in kpi_info.groups(kpis):
        shown = [k for k in g.kpis if k.path not in kpi_info.OWN_SECTION_PATHS]
        if not shown:
            continue
        single = [k for k in shown if not k.per_car]
        per_car = [k for k in shown if k.per_car]
        tables = []
        if single:
            tables.append("<table class=kpis><thead><tr><th>KPI</th><th>value</th><th>unit</th>"
                          f"<th>meaning</th></tr></thead><tbody>{''.join(_kpi_row(k) for k in single)}"
                          "</tbody></table>")
        if per_car:
            tables.append(_per_car_table(per_car))
        if g.key == "realtime":          # the Real time section has them per node, at a glance: folded here
            held = g.kpis and kpis["realtime"].get("held")
            parts.append(f"<h3>{_e(g.title)}</h3><details><summary>{'held' if held else 'NOT HELD'}: the "
                         f"{len(shown)} real-time KPIs of kpis.json (per node, the machine probe and each "
                         f"node on the bus: <a href=\"#realtime\">Real time</a>)</summary>{''.join(tables)}"
                         "</details>")
            continue
        parts.append(f"<h3>{_e(g.title)}</h3>" + "".join(tables))
    missing = kpi_info.undescribed(kpis)
    if missing:
        parts.insert(0, f"<p class=fail>{len(missing)} KPIs without a description: "
                        f"{_e(', '.join(missing))}</p>")
    return "".join(parts) or "<p class=info>no KPIs in kpis.json</p>"


# -------------------------------------------------------------------------------- interactive figures
@cache
def _plotly_js() -> str:
    from plotly.offline import get_plotlyjs

    return get_plotlyjs()


def decimate(t: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """At most about `max_points` samples of the curve (t, y): the smallest and the largest sample of each
    of max_points/2 equal buckets, in time order, and the first and last sample (a peak survives; a
    curve of max_points samples or fewer is kept whole)."""
    n = len(t)
    if n <= max_points:
        return t, y
    k = math.ceil(2 * n / max_points)
    m = n // k
    blocks = y[: m * k].reshape(m, k)
    base = np.arange(m) * k
    idx = np.unique(np.concatenate([base + np.argmin(blocks, axis=1), base + np.argmax(blocks, axis=1),
                                    np.arange(m * k, n), [0, n - 1]]))
    return t[idx], y[idx]


def _read_truth(run_dir: Path) -> tuple[dict[str, np.ndarray] | None, str]:
    """truth.csv of a run folder as columns, or None and why not."""
    path = run_dir / "truth.csv"
    if not path.is_file():
        return None, f"no {path.name} in the folder"
    try:
        cols = read_truth_csv(path)
    except (RailhilError, ValueError) as exc:
        return None, " ".join(str(exc).split())[:200]
    if "t_s" not in cols or len(np.atleast_1d(cols["t_s"])) < 2:
        return None, f"{path.name} holds no samples"
    return {k: np.atleast_1d(v) for k, v in cols.items()}, ""


def _cars(cols: dict[str, np.ndarray]) -> int:
    n = 0
    while f"v_mps_{n + 1}" in cols:
        n += 1
    return n


def _signals_figure(runs: list[tuple[str, dict[str, np.ndarray]]], title: str):
    """The truth's speed, cylinder pressure and slip speed of every car over time (SIGNALS), one row each
    with a shared time axis; one run: every car shown; several (a comparison): the first solid, the others
    dashed, car 1 shown and the other cars in the legend (a click shows them)."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    rows = [s for s in SIGNALS if any(f"{s[0]}_1" in cols for _, cols in runs)]
    fig = make_subplots(rows=len(rows), cols=1, shared_xaxes=True, vertical_spacing=0.04)
    compare = len(runs) > 1
    for r, (key, scale, label) in enumerate(rows, start=1):
        for j, (name, cols) in enumerate(runs):
            t = cols["t_s"]
            for i in range(1, _cars(cols) + 1):
                col = cols.get(f"{key}_{i}")
                if col is None:
                    continue
                x, y = decimate(t, col * scale)
                group = f"{name} · car {i}" if compare else f"car {i}"
                fig.add_trace(go.Scatter(
                    x=x.astype(np.float32), y=y.astype(np.float32), mode="lines", name=group,
                    legendgroup=group, showlegend=r == 1,
                    visible=True if not compare or i == 1 else "legendonly",
                    line={"color": CAR_COLOURS[(i - 1) % len(CAR_COLOURS)], "width": 1.2,
                          "dash": "solid" if j == 0 else "dash"}), row=r, col=1)
        fig.update_yaxes(title_text=label, row=r, col=1)
    fig.update_xaxes(title_text="time [s]", row=len(rows), col=1)
    legend = ({"orientation": "v", "x": 1.01, "y": 1.0, "yanchor": "top"} if compare
              else {"orientation": "h", "x": 0.0, "y": 1.01, "yanchor": "bottom"})
    fig.update_layout(title=title, template="plotly_white", height=160 + 260 * len(rows),
                      hovermode="x unified", legend=legend,
                      margin={"t": 100, "l": 70, "r": 190 if compare else 20, "b": 50})
    return fig


def _figure_html(fig, div_id: str) -> str:
    """A plotly figure as a <div> and its data as JSON in the page (plotly.js itself is in the head)."""
    import plotly.io as pio

    data = pio.to_json(fig, validate=False, pretty=False)      # escapes < > / : safe inside <script>
    return (f"<div id={div_id} class=plot></div>"
            f"<script type=application/json id={div_id}-data>{data}</script>"
            f"<script>(function(){{var f=JSON.parse(document.getElementById('{div_id}-data').textContent);"
            f"Plotly.newPlot('{div_id}',f.data,f.layout,{json.dumps(PLOTLY_CONFIG)});}})();</script>")


def _signals_section(runs: list[tuple[str, dict[str, np.ndarray] | None, str]],
                     title: str) -> tuple[str, bool]:
    """(HTML, whether it has a plotly figure) of the signals of `runs` = (name, truth columns or None, why
    not)."""
    missing = "".join(f"<p class=info>{_e(name)}: no signals ({_e(why)})</p>" for name, cols, why in runs
                      if cols is None)
    have = [(name, cols) for name, cols, _ in runs if cols is not None]
    if not have:
        return missing, False
    note = (f"<p class=info>the plant's truth (truth.csv, every 10 ms), at most {MAX_POINTS} samples a curve "
            f"(the smallest and largest of each bucket); drag to zoom, double-click to zoom out, click a "
            f"legend entry to hide or show it</p>")
    return missing + note + _figure_html(_signals_figure(have, title), "signals-plot"), True


# --------------------------------------------------------------------------------------------- run page
def _us(value) -> str:
    """A time in µs for a table cell: whole µs, or a dash when there is none (a message never sent)."""
    return "—" if value is None else f"{float(value):.0f}"


def _e2e_by_node(meta: dict) -> dict[str, dict[str, int]]:
    """What each node's E2E and SecOC checks reported about the frames it received (run.json node_stats'
    events), counted as the verdicts count them: `startup` the INITIAL ones (the first frame of each
    protected message, whose sequence cannot be judged yet: not used, by design, and no error), `errors`
    every other status but NONEWDATA (the verdict "E2E / SecOC errors reported"), `late` NONEWDATA (the
    verdict "frames 1.5 cycles late")."""
    out = {}
    for node, stats in (meta.get("node_stats") or {}).items():
        counts = {"startup": 0, "errors": 0, "late": 0}
        for _, _, status in stats.get("e2e_events") or ():
            counts["startup" if status == "INITIAL" else "late" if status == "NONEWDATA" else "errors"] += 1
        out[node] = counts
    return out


E2E_STARTUP = ("E2E start-up discards", "the first frame of each protected message a node receives: its "
               "counter follows nothing yet (E2E INITIAL), so it is not used; expected once per message and "
               "receiver, not an error, and not counted in the verdict")


def _lateness(us) -> str:
    """A lateness in whole µs for a cell; 0: within 1 µs of the deadline."""
    return "—" if us is None else "< 1" if us == 0 else f"{us}"


def _realtime_section(run_dir: Path, meta: dict, kpis: dict) -> str:
    """A real-time run at a glance: per node its cycles, release lateness, misses (the bench's / the
    machine's) and what its E2E / SecOC checks reported, as the verdict lines count them; lateness.png; the
    details folded: the processes' scheduling, the sleep calibration, each node's messages on the bus."""
    rt = kpis.get("realtime") or {}
    if "nodes" not in rt:
        return ""
    e2e = _e2e_by_node(meta)
    conduct = rt.get("conduct") or {}
    rows = []
    for n, v in rt["nodes"].items():
        c, b = e2e.get(n, {}), conduct.get(n) or {}
        judged = [m for m in (b.get("messages") or {}).values() if m.get("verdict") != "MISSING"]
        rows.append([n + (" (wakes)" if v.get("judged_in") == "wakes" else ""), v["cycles"],
                     f"{v['period_us'] / 1e3:g}", _lateness(v["p50_us"]), _lateness(v["p99_us"]),
                     _lateness(v["max_us"]), f"{v['misses_bench']} / {v['misses_machine']}",
                     v["misses_allowed"], c.get("startup", 0), c.get("errors", 0), c.get("late", 0),
                     (f"{b.get('timing')} ({sum(m['verdict'] == 'PASS' for m in judged)}/{len(judged)})"
                      if b else "—"), "held" if v["held"] else "NOT HELD"])
    m = rt.get("machine") or {}
    if "error" not in m:
        rows.append(["machine probe", m.get("cycles"), "10", _lateness(m.get("p50_us")),
                     _lateness(m.get("p99_us")), _lateness(m.get("max_us")), f"— / {m.get('stalls')} stalls",
                     "—", "—", "—", "—", "—", "(reference)"])
    header = ["node", "cycles", "period [ms]", "lateness p50 [µs]", "p99 [µs]", "max [µs]",
              "misses bench / machine", "bench misses allowed", E2E_STARTUP[0], "E2E / SecOC errors",
              "E2E NONEWDATA", "frames' timing", "verdict"]
    out = [f"<p>lateness: when a cycle's wait returned after its absolute deadline, in whole µs (&lt; 1: on "
           f"time to the µs); a miss: a cycle over the node's threshold, the machine's when the probe or the "
           f"node's host saw a stall then, else the bench's; {_e(E2E_STARTUP[0])}: {_e(E2E_STARTUP[1])}</p>",
           "<div class=nowrap>" + _table(header, rows, set(range(1, 12))) + "</div>"]
    late = run_dir / "lateness.png"
    if late.is_file():
        out.append(_images([late]))
    details = [_realtime_table(rt, meta)]
    messages = _conduct_tables(conduct)
    if messages:
        details.append(messages)
    out.append("<details><summary>per node in full: thresholds, the bench's misses behind another cycle, "
               "the processes' scheduling, the sleep calibration, each node's messages on the bus</summary>"
               + "".join(details) + "</details>")
    return "".join(out)


def _conduct_tables(conduct: dict) -> str:
    """Each node's cyclic messages on the bus against their cycle time (kpis.json realtime.conduct); the
    messages with no frame in the trace (in run folders that do not say what each node sends: other cars',
    other studies') folded apart."""
    rows, silent = [], []
    for node, c in conduct.items():
        for name, v in (c.get("messages") or {}).items():
            if v.get("verdict") == "MISSING":
                silent.append(f"{node}: {name}")
                continue
            rows.append([node, name, v.get("cycle_ms"), v.get("frames"), _ms(v.get("mean_ms")),
                         _ms(v.get("max_ms")), v.get("missed"), v.get("verdict")])
    if not rows and not silent:
        return ""
    out = ("<h3>Each node's messages on the bus</h3>"
           + _table(["node", "message", "cycle [ms]", "frames", "mean period [ms]", "max period [ms]",
                     "missed", "timing"], rows, {2, 3, 4, 5, 6}))
    if silent:
        out += (f"<details><summary>{len(silent)} messages the DBC gives these nodes with no frame in the "
                f"trace (frames of cars or studies this run does not have)</summary><p class=info>"
                f"{_e(', '.join(silent))}</p></details>")
    return out


def _realtime_table(rt: dict, meta: dict) -> str:
    """A real-time run's lateness per node against the budget, the machine probe beside, and what the OS
    granted each process (kpis.json realtime, run.json realtime)."""
    stats = meta.get("node_stats") or {}
    rows = [[f"{n} (wakes at most the period apart)" if v.get("judged_in") == "wakes" else n,
             stats.get(n, {}).get("host"), v["period_us"], v["cycles"], v["p50_us"], v["p99_us"],
             v["max_us"], v["miss_threshold_us"], v["misses_bench"], v.get("misses_bench_behind", "—"),
             v["misses_machine"], v["misses_allowed"], v["skipped"], "held" if v["held"] else "NOT HELD"]
            for n, v in rt["nodes"].items()]
    m = rt.get("machine") or {}
    if "error" not in m:
        rows.append(["machine probe", "PROBE", 10_000, m.get("cycles"), m.get("p50_us"), m.get("p99_us"),
                     m.get("max_us"), 500, "—", "—", f"{m.get('stalls')} stalls", "—", "—", "(reference)"])
    out = ("<p>release lateness = when a cycle's wait returned − its absolute deadline [µs]; a miss is the "
           "machine's when the probe (a bare loop at 10 ms deadlines, one priority above the nodes) was late "
           "at the same time, or its host saw the machine keep it from running then; of the bench's, "
           "'of them behind' counts those released behind another cycle of the same host (still running "
           "at the deadline: a grouped host runs its nodes one after another); "
           "lateness.png (below, with the static figures) has the histograms</p>"
           + _table(["node", "host", "period [µs]", "cycles", "p50 [µs]", "p99 [µs]", "max [µs]",
                     "miss threshold [µs]", "misses: bench", "of them behind", "misses: machine",
                     "bench misses allowed", "skipped", "verdict"], rows, set(range(2, 13))))
    info = meta.get("realtime") or {}
    os_rows = [[host, d.get("policy"), d.get("priority"), d.get("memory_locked"),
                d.get("cpus") or "not pinned", "; ".join(d.get("refused") or []) or "—"]
               for host, d in (info.get("os") or {}).items()]
    if os_rows:
        out += _table(["process", "scheduling", "priority / nice", "memory locked", "CPUs",
                       "refused by the OS"], os_rows)
    cal = info.get("calibration")
    if cal:
        out += (f"<p>precise wait {'on' if info.get('precise_wait') else 'off'}: margin "
                f"{int(info.get('margin_ns') or 0) / 1e3:.0f} µs (this machine's sleeps to absolute "
                f"deadlines returned p50 {cal['p50_us']} / p90 {cal['p90_us']} / p99 {cal['p99_us']} / max "
                f"{cal['max_us']} µs late over {cal['seconds']} s before the run)</p>")
    return out


def _timing_section(meta: dict, kpis: dict | None = None) -> str:
    parts = []
    bus = meta.get("bus_timing")
    if bus:
        load = bus.get("load")
        parts.append(f"<p>bit-timed bus at {_e(bus.get('bitrate_bps'))} bit/s, stuffing "
                     f"{_e(bus.get('stuffing'))}, load {'—' if load is None else f'{100 * load:.1f} %'}; "
                     f"response = end of frame − start of its release window; deadline = the message's "
                     f"cycle time</p>")
        rows = sorted((bus.get("messages") or {}).items(), key=lambda kv: kv[1].get("frame_id", 0))
        body = "".join(
            f"<tr><td>{_e(name)}</td><td class=num>0x{int(m.get('frame_id', 0)):03X}</td>"
            f"<td class=num>{_e(m.get('frames'))}</td>"
            f"<td class=num>{_us(m.get('response_max_us'))}</td>"
            f"<td class=num>{_us(m.get('response_mean_us'))}</td>"
            f"<td class=num>{_us(m.get('queued_max_us'))}</td>"
            f"<td class=num>{_e(m.get('overwritten'))}</td><td class=num>{_e(m.get('deadline_misses'))}</td>"
            f"{_verdict_cell(m.get('deadline_misses') == 0)}</tr>" for name, m in rows)
        parts.append(f"<details><summary>per message on the bit-timed bus ({len(rows)} messages)</summary>"
                     "<div class=scroll><table><thead><tr><th>message</th><th>id</th><th>frames</th>"
                     "<th>worst response [µs]</th><th>mean response [µs]</th><th>worst queued [µs]</th>"
                     "<th>overwritten</th><th>deadline misses</th><th>verdict</th></tr></thead><tbody>"
                     f"{body}</tbody></table></div></details>")
    stats = meta.get("node_stats") or {}
    if stats:
        realtime = meta.get("mode") == "realtime"
        e2e = _e2e_by_node(meta)
        header = ["node", "cycles", "frames sent", "frames received", "step errors", E2E_STARTUP[0],
                  "E2E / SecOC errors", "E2E NONEWDATA (late)"] + (["late cycles", "missed cycles"]
                                                                   if realtime else [])
        rows = [[n, s.get("cycles"), s.get("frames_sent"), s.get("frames_received"), s.get("step_errors"),
                 e2e[n]["startup"], e2e[n]["errors"], e2e[n]["late"]]
                + ([s.get("late_cycles"), s.get("missed_cycles")] if realtime else [])
                for n, s in stats.items()]
        table = (f"<p>per node: the frames it sent and received; what its E2E / SecOC checks reported "
                 f"about the frames it received, as the verdicts count them ({_e(E2E_STARTUP[0])}: "
                 f"{_e(E2E_STARTUP[1])})</p>" + _table(header, rows, set(range(1, len(header)))))
        parts.append(table if not realtime else
                     "<details><summary>per node: cycles, frames sent and received, step errors, E2E / "
                     "SecOC, late and missed cycles</summary>" + table + "</details>")
    return "".join(parts) or "<p class=info>no timing data in run.json</p>"


def _ms(value) -> str:
    return "—" if value is None else f"{float(value):.3f}"


def _counts(counts: dict, none: str) -> str:
    """`{"ERROR": 2, ...}` as "ERROR 2, ..." (`none` when empty)."""
    return ", ".join(f"{k} {v}" for k, v in counts.items()) or none


def _devices_section(kpis: dict) -> str:
    """Each device on its own CAN matrix (kpis.json devices, hil.report.devices): its frames against its own
    DBC and what the gateway's checks reported, the gateway's latency per message, its frames on the
    bench, what the translation substituted."""
    parts = []
    period_columns = ["message", "cycle [ms]", "frames", "mean period [ms]", "max period [ms]", "missed"]
    for name, d in (kpis.get("devices") or {}).items():
        if d.get("transport") == "opcua":
            parts.append(_opcua_device(name, d, period_columns))
            continue
        own, bench, lat = d["device"], d["bench"], d["latency"]
        mode = "its model (lockstep)" if d["mode"] == "model" else "the device (real time)"
        parts.append(f"<h3>{_e(name)}: {_e(d['node'])} of {_e(Path(d['dbc']).name)}, {_e(mode)} — "
                     f"{_e(d['verdict'])}</h3><p class=info>device file {_e(d['file'])}; its bus's frames in "
                     f"{_e(d['trace'])}; heard {_e(_fmt(own['first_s']))}–{_e(_fmt(own['last_s']))} s</p>")
        prot = d.get("protection") or {}
        rows = [[m, v["cycle_ms"], v["frames"], _ms(v["mean_ms"]), _ms(v["max_ms"]), v["missed"],
                 prot.get(m, "—"), v["verdict"]] for m, v in own["messages"].items()]
        rows += [[f"{m} (the gateway's)", v["cycle_ms"], v["frames"], _ms(v["mean_ms"]), _ms(v["max_ms"]),
                  v["missed"], prot.get(m, "—"), v["verdict"]] for m, v in (d.get("to_device") or {}).items()]
        parts.append("<p>the frames on the device's bus, against its own DBC's cycle times: the device's "
                     "(their protection checked by the gateway, which reported "
                     f"{_e(_counts(own['protection'], 'nothing but OK'))}), then the gateway's to it</p>"
                     + _table([*period_columns, "protection", "timing"], rows, {1, 2, 3, 4, 5}))
        rows = [[m, v["kind"], v["from"], "device → bench" if v["to"] == "bench" else "bench → device",
                 v["frames"], _us(v["p50_us"]), _us(v["p99_us"]), _us(v["max_us"])]
                for m, v in lat["messages"].items()]
        parts.append("<p>the gateway: a routed message goes out on each usable frame of the message it is "
                     "sent from (its latency: from that frame on one bus to this one on the other, by the "
                     "two traces); a cyclic one at its own cycle time (the age of its source's frame when "
                     "it went out)</p>"
                     + _table(["message", "sent", "from", "way", "frames", "p50 [µs]", "p99 [µs]",
                               "max [µs]"], rows, {4, 5, 6, 7}))
        rows = [[m, v["cycle_ms"], v["frames"], _ms(v["mean_ms"]), _ms(v["max_ms"]), v["missed"],
                 v["verdict"]] for m, v in bench["messages"].items()]
        parts.append(f"<p>the gateway's frames on the bench in {_e(name)}'s place, against the bench's DBC; "
                     f"E2E / SecOC reported by the bench's receivers: "
                     f"{_e(_counts(bench['protection'], 'nothing'))}</p>"
                     + _table([*period_columns, "timing"], rows, {1, 2, 3, 4, 5}))
        sub = d.get("substituted") or {}
        substituted = {k: v for way in ("to_device", "to_bench") for kind in ("stale", "unmapped")
                       for k, v in (sub.get(way) or {}).get(kind, {}).items()}
        parts.append("<p>substituted by the translation (a source stale or not yet received: the target's "
                     "default or last value; a source value outside its value-table mapping): "
                     f"{_e(_counts(substituted, 'nothing'))}</p>")
    return "".join(parts)


def _opcua_device(name: str, d: dict, period_columns: list[str]) -> str:
    """A device over OPC UA: the link, the PLC's writes (cycle, read age, round trip) against the bound, the
    bench's own calls, refusals, and the gateway's frames on the bench."""
    link, plc, bench = d["opcua"], d["plc"], d["bench"]
    mode = "its model (lockstep)" if d["mode"] == "model" else "the device (real time)"
    out = (f"<h3>{_e(name)}: {_e(d['node'])} over OPC UA, {_e(mode)} — {_e(d['verdict'])}</h3>"
           f"<p class=info>device file {_e(d['file'])}; the bench as {_e(link['role'])} at "
           f"{_e(link['endpoint'])}; security {_e(link['security'])}"
           f"{'; user ' + _e(link['user']) if link.get('user') else ''}; "
           f"{link['writes']} writes, {link['bench_writes']} updates by the bench</p>")
    rows = []
    for label, key, what in (("PLC cycle", "cycle", "time between its writes"),
                             ("read age", "read_age", "its write − the bench's update it echoed"),
                             ("round trip", "round_trip", "a bench update → the PLC's write reflecting it"),
                             ("the bench's OPC UA calls", "calls", "request → response (client role)")):
        f = link[key]
        rows.append([label, what, f["n"], _fmt(f["p50_ms"]), _fmt(f["p99_ms"]), _fmt(f["max_ms"])])
    echo = _e(link.get("echo") or "none")
    out += (f"<p>what the link measured (read age and round trip by the echo {echo})"
            f"; its writes' timing {_e(plc['timing'])}: {_e(plc['why'])}</p>"
            + _table(["", "what", "n", "p50 [ms]", "p99 [ms]", "max [ms]"], rows, {2, 3, 4, 5}))
    out += (f"<p>refused: {_e(_counts(link['refused'], 'none'))}; silences {link['silences']} (longest gap "
            f"{_e(_fmt(link['longest_gap_ms']))} ms); values not finite or not numbers: "
            f"{link['bad_values']}</p>")
    rows = [[m, v["cycle_ms"], v["frames"], _ms(v["mean_ms"]), _ms(v["max_ms"]), v["missed"],
             v["verdict"]] for m, v in bench["messages"].items()]
    out += (f"<p>the gateway's frames on the bench in {_e(name)}'s place, against the bench's DBC; E2E / "
            f"SecOC reported by the bench's receivers: {_e(_counts(bench['protection'], 'nothing'))}</p>"
            + _table([*period_columns, "timing"], rows, {1, 2, 3, 4, 5}))
    return out


def _faults_section(kpis: dict, meta: dict) -> str:
    rows = [["faults injected", kpis.get("faults_injected", "none")],
            ["E2E / SecOC reported by receivers", kpis.get("protection_events") or "nothing"],
            ["frames added (+) / removed (−) by faults", kpis.get("frames_faulted", 0)]]
    for flag, cars in sorted((kpis.get("plausibility_flags") or {}).items()):
        rows.append([f"first flagged: {flag} [s]", cars])
    out = _table(["", ""], rows)
    events = (meta.get("faults") or {}).get("events") or []
    if events:
        shown = events[:MAX_FAULT_EVENTS]
        more = (f" (first {MAX_FAULT_EVENTS} of {len(events)}; all in run.json)"
                if len(events) > len(shown) else "")
        out += (f"<details><summary>fault events{_e(more)}</summary><pre>"
                + _e("\n".join(json.dumps(e, default=str) for e in shown)) + "</pre></details>")
    return out


def _run_header(run_dir: Path) -> tuple[dict, dict, dict]:
    """(run.json, kpis.json, the resolved scenario) of a run folder; ReportError when it is none."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ReportError(f"{run_dir}: no such run folder")
    meta = _read_json(run_dir / "run.json", "the run's metadata")
    kpis = _read_json(run_dir / "kpis.json", "the run's KPIs")
    return meta, kpis, meta.get("scenario") or {}


def _versions_of(meta: dict) -> dict:
    return meta.get("versions") or {"python": meta.get("python"), "python-can": meta.get("python_can")}


def describe_scenario(scenario: dict) -> str:
    """What a run ran, in one line, from its resolved scenario (run.json): the train, its speed, what the desk
    did, the rail, the studies -- so a run with `--set train.initial_speed_kmh=120` reads 120 km/h where the
    scenario file's description still says 90."""
    train = scenario.get("train") or {}
    parts = []
    if train:
        speed = train.get("initial_speed_kmh")
        parts.append(f"{train.get('cars', '?')}-car train at {_fmt(speed)} km/h")
    for cmd in scenario.get("desk") or []:
        what = []
        if cmd.get("brake_step") is not None:
            what.append(f"brake step {cmd['brake_step']}")
        if cmd.get("emergency"):
            what.append("emergency brake")
        if cmd.get("target_stop_m") is not None:
            what.append(f"stop at {_fmt(cmd['target_stop_m'])} m")
        if what:
            parts.append(f"{' and '.join(what)} at {_fmt(cmd.get('at_s'))} s")
    rail = [r.get("condition") for r in (scenario.get("track") or {}).get("rail") or [] if r.get("condition")]
    if rail:
        parts.append("rail " + " → ".join(rail))
    studies = [st.name for st in registry.studies() if scenario.get(st.section) is not None]
    if studies:
        parts.append("studies: " + ", ".join(studies))
    if "seed" in scenario:
        parts.append(f"seed {scenario['seed']}")
    return "; ".join(parts)


def _key_figures(kpis: dict) -> str:
    """The run's figures a reader looks for first, on one strip: the train's, the frames, the bus, real
    time, each as the summary line gives it."""
    items = []

    def add(label: str, value: str) -> None:
        items.append(f"<span>{_e(label)} <b>{_e(value)}</b></span>")

    if "stopping_distance_m" in kpis:
        add("stopping distance", f"{kpis['stopping_distance_m']:.2f} m")
    if kpis.get("time_to_stop_s") is not None:
        add("time to stop", f"{kpis['time_to_stop_s']:.2f} s")
    if kpis.get("mean_abs_decel_error_mps2") is not None:
        add("mean |decel error|", f"{kpis['mean_abs_decel_error_mps2']:.3f} m/s²")
    if "max_slip_speed_mps" in kpis:
        add("max slip speed", f"{max(kpis['max_slip_speed_mps'], default=0):.3f} m/s")
    if "wsp_activations" in kpis:
        add("WSP activations", f"{sum(kpis['wsp_activations'])}")
    if "frames_lost" in kpis:
        add("frames lost", f"{kpis['frames_lost']} of {kpis.get('frames_sent')}")
    bus = kpis.get("bus") or {}
    if bus.get("load") is not None:
        add("bus load", f"{100 * bus['load']:.1f} %")
    rt = kpis.get("realtime") or {}
    if "held" in rt and "misses_bench" in rt:
        add("real time", f"{'held' if rt['held'] else 'NOT HELD'} ({rt['misses_bench']} bench misses)")
    if kpis.get("end_reason"):
        add("ended by", f"{kpis['end_reason']} at {_fmt(kpis.get('simulated_s'))} s")
    return f"<div class=figures>{''.join(items)}</div>" if items else ""


def render_run_report(run_dir: Path, interactive: bool = True) -> str:
    """The HTML page of a run folder (module docstring), from its run.json, kpis.json, truth.csv and PNG
    plots; `interactive=False` leaves the plotly figure (and the 4.8 MB of plotly.js) out — a campaign's
    points, of which there may be hundreds, keep the static figures and say how to get it.

    The page reads at a glance on a 1,280 px screen: the verdict, the key figures, the verdicts and the KPIs
    first, then the signals; a real-time run's nodes in one compact table; the details folded."""
    run_dir = Path(run_dir)
    meta, kpis, scenario = _run_header(run_dir)
    verdicts = run_verdicts(kpis, meta)
    failed = [v for v in verdicts if v.passed is False]
    name = scenario.get("name", run_dir.name)
    title = f"railhil run {name} ({meta.get('mode', '?')}, seed {scenario.get('seed')})"
    banner = ("<div class='banner fail'>FAIL: " + _e(", ".join(v.check for v in failed)) + "</div>"
              if failed else "<div class='banner pass'>PASS: every check holds</div>")
    vrows = "".join(f"<tr><td>{_e(v.check)}</td><td>{_e(v.value)}</td><td>{_e(v.criterion)}</td>"
                    f"{_verdict_cell(v.passed)}</tr>" for v in verdicts)
    repro = [["folder", str(run_dir.resolve())], ["seed", scenario.get("seed")], ["mode", meta.get("mode")],
             ["ended by", f"{kpis.get('end_reason')} after {_fmt(kpis.get('simulated_s'))} s simulated"],
             ["DBC", meta.get("dbc")],
             ["DBC SHA-256", meta.get("dbc_sha256")], ["git commit", meta.get("git_commit")],
             ["command", meta.get("command")], ["platform", meta.get("platform")],
             ["trace", meta.get("trace", "trace.blf")],
             ["wall time [s]", meta.get("wall_s")], ["simulated [s]", kpis.get("simulated_s")]]
    repro += [[f"version: {k}", v] for k, v in _versions_of(meta).items()]
    if interactive:
        cols, why = _read_truth(run_dir)
        signals, plotly = _signals_section([(name, cols, why)], title)
    else:
        signals, plotly = (f"<p class=info>no interactive figure in this page (a campaign point's page "
                           f"keeps the static figures below); <code>railhil report {_e(run_dir)}</code> "
                           f"writes it with the zoomable signals</p>"), False
    devices = _devices_section(kpis)
    realtime = _realtime_section(run_dir, meta, kpis)
    figures = [f for f in sorted(run_dir.glob("*.png")) if not (realtime and f.name == "lateness.png")]
    figures_html = (_images(figures) if not interactive else
                    f"<details><summary>{_e(', '.join(f.name for f in figures) or 'no plot')}: the static "
                    f"figures ({_e(PLOT_ROLE)})</summary>{_images(figures)}</details>")
    sections = [("verdicts", "Verdicts"), ("kpis", "KPIs"), *([("devices", "Devices")] if devices else []),
                ("signals", "Signals"), *([("realtime", "Real time")] if realtime else []),
                ("timing", "Timing"), ("faults", "Faults"), ("figures", "Static figures"),
                ("reproduce", "Reproduce"), ("scenario", "Scenario")]
    described = describe_scenario(scenario)
    file_says = (f" <span class=info>— the scenario file: {_e(scenario['description'])}</span>"
                 if scenario.get("description") else "")
    body = (f"<h1>{_e(title)}</h1>"
            + (f"<p class=describe>{_e(described)}{file_says}</p>" if described or file_says else "")
            + f"{banner}{_key_figures(kpis)}{_nav(sections)}"
            f"<h2 id=verdicts>Verdicts</h2><table><thead><tr><th>check</th><th>value</th><th>criterion</th>"
            f"<th>verdict</th></tr></thead><tbody>{vrows}</tbody></table>"
            f"<h2 id=kpis>KPIs</h2>{_kpi_section(kpis)}"
            + (f"<h2 id=devices>Devices</h2>{devices}" if devices else "")
            + f"<h2 id=signals>Signals</h2>{signals}"
            + (f"<h2 id=realtime>Real time</h2>{realtime}" if realtime else "")
            + f"<h2 id=timing>Timing</h2>{_timing_section(meta, kpis)}"
            f"<h2 id=faults>Faults</h2>{_faults_section(kpis, meta)}"
            f"<h2 id=figures>Static figures</h2>{figures_html}"
            f"<h2 id=reproduce>Reproduce</h2><details><summary>the folder, seed, DBC and its SHA-256, git "
            f"commit, command line, versions</summary>{_table(['', ''], repro)}</details>"
            f"<h2 id=scenario>Scenario</h2><details><summary>the resolved scenario (JSON)</summary><pre>"
            f"{_e(json.dumps(scenario, indent=2))}</pre></details>")
    return _page(title, body, plotly)


PLOT_ROLE = "plot.png is the Signals figure above as an image; a study adds its own"


def write_run_report(run_dir: Path, interactive: bool = True) -> Path:
    """Write <run_dir>/report.html (`interactive`: as render_run_report); returns its path."""
    page = render_run_report(run_dir, interactive)
    out = Path(run_dir) / REPORT_NAME
    out.write_text(page, encoding="utf-8")
    return out


# ------------------------------------------------------------------------------------- comparison page
COMPARE_PREFIX = "report-vs-"      # RUN/report-vs-<REF folder name>.html


def comparison_path(run_dir: Path, ref_dir: Path) -> Path:
    """Where `railhil report RUN --against REF` writes by default: RUN/report-vs-<REF's folder name>.html."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(ref_dir).resolve().name) or "run"
    return Path(run_dir) / f"{COMPARE_PREFIX}{name}.html"


def _is_num(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _signed(d: float) -> str:
    if d == 0:
        return "0"
    return f"{d:+d}" if isinstance(d, int) else f"{d:+.4g}"


def _delta(a: object, b: object, unit: str = "") -> tuple[str, str]:
    """(Δ = a − b, Δ relative to |b|) of two values of one KPI, as text; lists element by element; for an
    identifier or a text only whether they differ."""
    if unit in ("id", "text"):
        return ("" if a == b else "changed"), ""
    if _is_num(a) and _is_num(b):
        d = a - b
        return _signed(d), ("—" if b == 0 else "0 %" if d == 0 else f"{100 * d / abs(b):+.2f} %")
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b) and all(map(_is_num, a + b)):
        return ", ".join(_signed(x - y) for x, y in zip(a, b, strict=True)), ""
    return ("" if a == b else "changed"), ""


def _flat(v: object, prefix: str) -> dict[str, object]:
    """A mapping KPI (frames by node, flags by car) as one value per key: "frames_sent_by_node · BCU"."""
    if not isinstance(v, dict) or not v:
        return {prefix: v}
    out: dict[str, object] = {}
    for k, x in v.items():
        out.update(_flat(x, f"{prefix} · {k}"))
    return out


_NONE = object()                   # a KPI the run does not have


def _cell(v: object) -> str:
    return "<td class=info>(none)</td>" if v is _NONE else f"<td class=num>{_value_html(v)}</td>"


@dataclass
class GroupCompared:
    """How one group of KPIs compares between two runs: those both runs have, of them those that differ,
    and the dotted paths one run has only."""

    title: str
    compared: int = 0
    differ: int = 0
    only: list[str] = field(default_factory=list)
    max_rel: float = 0.0           # the largest |Δ| / |reference| of the numbers that differ (0: none)
    numbers_only: bool = True      # whether every KPI that differs is a number (max_rel says it all)

    def add(self, a: object, b: object) -> None:
        """Count one KPI both runs have (a list of one value per car, or one value)."""
        self.compared += 1
        if a == b:
            return
        self.differ += 1
        pairs = list(zip(a, b, strict=False)) if isinstance(a, list) and isinstance(b, list) else [(a, b)]
        for x, y in pairs:
            if _is_num(x) and _is_num(y) and y != 0:
                self.max_rel = max(self.max_rel, abs(x - y) / abs(y))
            elif x != y:
                self.numbers_only = False

    def text(self) -> str:
        if not self.compared:
            return f"{self.title}: none in both runs"
        if not self.differ:
            return f"{self.title}: the same ({self.compared} KPIs)"
        by = f", by at most {100 * self.max_rel:.2g} %" if self.numbers_only and self.max_rel else ""
        return f"{self.title}: {self.differ} of {self.compared} differ{by}"


def _compare_kpi_section(ka: dict, kb: dict) -> tuple[str, list[GroupCompared]]:
    """(HTML, each group compared) of the KPI tables of a comparison: per group, single values with both
    runs, Δ and Δ relative, and the per-car values (rows run / reference / Δ).  Like is compared with like:
    a KPI counts when both runs have it; those one run has only (a real-time run's per-node figures against
    a lockstep run) are listed apart, under their group."""
    order: list[str] = []
    titles: dict[str, str] = {}
    pairs: dict[str, dict[str, list]] = {}
    for side, kpis in ((0, ka), (1, kb)):
        for g in kpi_info.groups(kpis):
            if g.key not in pairs:
                order.append(g.key)
                titles[g.key], pairs[g.key] = g.title, {}
            for k in g.kpis:
                pairs[g.key].setdefault(k.path, [None, None])[side] = k
    parts, stats = [], []
    for key in order:
        group = GroupCompared(titles[key])
        single, per_car = [], []
        for a, b in pairs[key].values():
            k = a or b
            va, vb = (a.value if a else _NONE), (b.value if b else _NONE)
            unit, meaning = _unit_meaning(k)
            if va is _NONE or vb is _NONE:
                group.only.append(f"{k.path} ({'run' if vb is _NONE else 'reference'} only)")
                continue
            if (a and a.per_car) or (b and b.per_car):
                group.add(va, vb)
                per_car.append((k, va, vb, unit))
                continue
            fa, fb = _flat(va, k.path), _flat(vb, k.path)
            for path in dict.fromkeys([*fa, *fb]):
                x, y = fa.get(path, _NONE), fb.get(path, _NONE)
                if x is _NONE or y is _NONE:
                    group.only.append(f"{path} ({'run' if y is _NONE else 'reference'} only)")
                    continue
                group.add(x, y) if unit not in ("id", "text") else group.add(str(x), str(y))
                d, rel = _delta(x, y, unit)
                name = (k.info.name if k.info else k.key) + path[len(k.path):]
                cls = " class=changed" if x != y else (" class=undescribed" if k.info is None else "")
                single.append(f"<tr{cls}><td>{_e(name)} <code class=key>{_e(path)}</code></td>{_cell(x)}"
                              f"{_cell(y)}<td class='num delta'>{_e(d)}</td><td class='num delta'>{_e(rel)}"
                              f"</td><td>{_e(unit)}</td><td class=meaning>{_e(meaning)}</td></tr>")
        stats.append(group)
        parts.append(f"<h3>{_e(titles[key])}</h3><p class=info>{_e(group.text())}</p>")
        if single:
            parts.append("<table class=kpis><thead><tr><th>KPI</th><th>run</th><th>reference</th><th>Δ</th>"
                         "<th>Δ rel.</th><th>unit</th><th>meaning</th></tr></thead>"
                         f"<tbody>{''.join(single)}</tbody></table>")
        if per_car:
            n = max(len(v) for _, va, vb, _ in per_car for v in (va, vb) if isinstance(v, list))
            head = "".join(f"<th>car {i}</th>" for i in range(1, n + 1))
            rows = []
            for k, va, vb, unit in per_car:
                la = va if isinstance(va, list) else []
                lb = vb if isinstance(vb, list) else []
                cls = " class=changed" if va != vb else ""
                deltas = [_delta(x, y, unit)[0] for x, y in zip(la, lb, strict=False)]
                deltas += [""] * (n - len(deltas))
                rows.append(f"<tr{cls}><td rowspan=3>{_kpi_name(k)}</td><td>run</td>{_car_cells(la, n)}"
                            f"<td rowspan=3>{_e(unit)}</td></tr>"
                            f"<tr{cls}><td>reference</td>{_car_cells(lb, n)}</tr>"
                            f"<tr{cls}><td>Δ</td>"
                            + "".join(f"<td class='num delta'>{_e(d)}</td>" for d in deltas) + "</tr>")
            parts.append(f"<table><thead><tr><th>per car</th><th></th>{head}<th>unit</th></tr></thead>"
                         f"<tbody>{''.join(rows)}</tbody></table>")
        if group.only:
            parts.append(f"<details><summary>{len(group.only)} KPIs of one run only, not compared</summary>"
                         f"<p class=info>{_e(', '.join(group.only))}</p></details>")
    return "".join(parts), stats


def _flat_json(v: object, prefix: str = "") -> dict[str, object]:
    if isinstance(v, dict) and v:
        out: dict[str, object] = {}
        for k, x in v.items():
            out.update(_flat_json(x, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: v}


def _pair_rows(rows: list[tuple[str, object, object]], always: tuple[str, ...] = ()) -> str:
    """Rows label / run / reference, those that differ highlighted (but those in `always`: they differ
    between any two runs)."""
    return "".join(f"<tr{' class=changed' if a != b and label not in always else ''}><td>{_e(label)}</td>"
                   f"<td>{_e(_fmt(a))}</td><td>{_e(_fmt(b))}</td></tr>" for label, a, b in rows)


def render_comparison(run_dir: Path, ref_dir: Path) -> str:
    """The comparison page of two run folders (module docstring): Δ = RUN − REF."""
    run_dir, ref_dir = Path(run_dir), Path(ref_dir)
    meta_a, ka, sa = _run_header(run_dir)
    meta_b, kb, sb = _run_header(ref_dir)
    la, lb = run_dir.resolve().name, ref_dir.resolve().name
    if la == lb:
        la, lb = "run", "reference"
    va, vb = _versions_of(meta_a), _versions_of(meta_b)
    runs = [("folder", str(run_dir.resolve()), str(ref_dir.resolve())),
            ("scenario", sa.get("name"), sb.get("name")),
            ("what it ran", describe_scenario(sa), describe_scenario(sb)),
            ("description (the scenario file's)", sa.get("description"), sb.get("description")),
            ("seed", sa.get("seed"), sb.get("seed")), ("mode", meta_a.get("mode"), meta_b.get("mode")),
            ("ended by", ka.get("end_reason"), kb.get("end_reason")),
            ("simulated [s]", ka.get("simulated_s"), kb.get("simulated_s")),
            ("wall time [s]", meta_a.get("wall_s"), meta_b.get("wall_s")),
            ("git commit", meta_a.get("git_commit"), meta_b.get("git_commit")),
            ("DBC SHA-256", meta_a.get("dbc_sha256"), meta_b.get("dbc_sha256")),
            ("trace", meta_a.get("trace", "trace.blf"), meta_b.get("trace", "trace.blf"))]
    runs += [(f"version: {k}", va.get(k), vb.get(k)) for k in dict.fromkeys([*va, *vb])]
    fa, fb = _flat_json(sa), _flat_json(sb)
    diffs = [(k, fa.get(k), fb.get(k)) for k in dict.fromkeys([*fa, *fb]) if fa.get(k) != fb.get(k)]
    scen = (f"<table><thead><tr><th>key</th><th>run</th><th>reference</th></tr></thead><tbody>"
            f"{_pair_rows(diffs)}</tbody></table>" if diffs
            else "<p class=info>the two runs' resolved scenarios are the same</p>")
    verd_a = {v.check: v for v in run_verdicts(ka, meta_a)}
    verd_b = {v.check: v for v in run_verdicts(kb, meta_b)}
    regressions = [c for c in verd_a if verd_a[c].passed is False and c in verd_b and verd_b[c].passed]
    vrows = []
    for check in dict.fromkeys([*verd_a, *verd_b]):
        a, b = verd_a.get(check), verd_b.get(check)
        cells = "".join(f"<td>{_e(v.value)}</td>{_verdict_cell(v.passed)}" if v
                        else "<td class=info>—</td><td></td>" for v in (a, b))
        diff = (a.passed if a else None) != (b.passed if b else None) or (a and b and a.value != b.value)
        vrows.append(f"<tr{' class=changed' if diff else ''}><td>{_e(check)}</td>{cells}</tr>")
    kpi_html, groups = _compare_kpi_section(ka, kb)
    total, changed = sum(g.compared for g in groups), sum(g.differ for g in groups)
    only = sum(len(g.only) for g in groups)
    title = f"railhil comparison: {la} against {lb}"
    by_group = "; ".join(g.text() for g in groups if g.compared)
    apart = f"; {only} KPIs of one run only, listed apart" if only else ""
    if regressions:
        banner = ("<div class='banner fail'>REGRESSION: fails here, passes in the reference: "
                  f"{_e(', '.join(regressions))}</div>")
    elif changed:
        banner = (f"<div class='banner note'>{changed} of the {total} KPIs both runs have differ — "
                  f"{_e(by_group)}{_e(apart)}; no check that passes in the reference fails here</div>")
    else:
        banner = (f"<div class='banner pass'>the same: none of the {total} KPIs both runs have differs"
                  f"{_e(apart)}</div>")
    ca, why_a = _read_truth(run_dir)
    cb, why_b = _read_truth(ref_dir)
    signals, plotly = _signals_section([(la, ca, why_a), (lb, cb, why_b)],
                                       f"{la} (solid) against {lb} (dashed)")
    sections = [("runs", "Runs"), ("scenario", "Scenario differences"), ("verdicts", "Verdicts"),
                ("kpis", "KPIs"), ("signals", "Signals")]
    body = (f"<h1>{_e(title)}</h1>{banner}<p class=info>run: {_e(run_dir.resolve())}; reference: "
            f"{_e(ref_dir.resolve())}; Δ = run − reference, Δ rel. = Δ / |reference|; rows that differ are "
            f"highlighted</p>{_nav(sections)}"
            f"<h2 id=runs>Runs</h2><table class=runs><thead><tr><th></th><th>run: {_e(la)}</th>"
            f"<th>reference: {_e(lb)}</th></tr></thead><tbody>{_pair_rows(runs, ('folder', 'wall time [s]'))}"
            f"</tbody></table>"
            f"<h2 id=scenario>Scenario differences</h2>{scen}"
            f"<h2 id=verdicts>Verdicts</h2><table><thead><tr><th>check</th><th>run</th><th></th>"
            f"<th>reference</th><th></th></tr></thead><tbody>{''.join(vrows)}</tbody></table>"
            f"<h2 id=kpis>KPIs</h2>{kpi_html}"
            f"<h2 id=signals>Signals</h2>{signals}")
    return _page(title, body, plotly)


def comparison_summary(run_dir: Path, ref_dir: Path) -> str:
    """The comparison of two run folders in one line, as its page's banner: the regressions, else per group
    the KPIs both runs have and how many differ, and how many one run has only."""
    meta_a, ka, _ = _run_header(Path(run_dir))
    meta_b, kb, _ = _run_header(Path(ref_dir))
    verd_a = {v.check: v for v in run_verdicts(ka, meta_a)}
    verd_b = {v.check: v for v in run_verdicts(kb, meta_b)}
    regressions = [c for c in verd_a if verd_a[c].passed is False and c in verd_b and verd_b[c].passed]
    _, groups = _compare_kpi_section(ka, kb)
    only = sum(len(g.only) for g in groups)
    line = "; ".join(g.text() for g in groups if g.compared)
    line += f"; {only} KPIs of one run only, not compared" if only else ""
    return (f"REGRESSION: {', '.join(regressions)}; " if regressions else "") + line


def write_comparison(run_dir: Path, ref_dir: Path, out: Path | None = None) -> Path:
    """Write the comparison page of RUN against REF (`render_comparison`) to `out` (default
    `comparison_path`: RUN/report-vs-<REF's name>.html); returns its path."""
    out = Path(out) if out is not None else comparison_path(run_dir, ref_dir)
    if not out.parent.is_dir():
        raise ReportError(f"-o {out}: no such directory {out.parent}")
    out.write_text(render_comparison(run_dir, ref_dir), encoding="utf-8")
    return out


# ---------------------------------------------------------------------------------------- campaign page
def _read_results_csv(path: Path) -> tuple[list[str], list[dict]]:
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            return list(reader.fieldnames or []), list(reader)
    except FileNotFoundError:
        raise ReportError(f"{path.parent}: not a campaign folder: no results.csv") from None
    except (OSError, csv.Error, UnicodeDecodeError) as exc:
        raise ReportError(f"{path}: cannot read the campaign results: {exc}") from None


def render_campaign_report(out_dir: Path, table: tuple[list[str], list[dict]] | None = None,
                           name: str | None = None, description: str = "") -> str:
    """The HTML page of a campaign folder: counts, the results table (`table` = (columns, rows), else
    read from results.csv) with each point's status and a link to its run report (to its run folder
    when it has none: a point run without --plots), the summary plots."""
    out_dir = Path(out_dir)
    columns, rows = table if table is not None else _read_results_csv(out_dir / "results.csv")
    name = name or out_dir.name
    status = [str(r.get("status", "")) for r in rows]
    n_ok = status.count("ok")
    n_failed = len(rows) - n_ok
    cached = sum(str(r.get("cached")) in ("True", "true", "1") for r in rows)
    banner = (f"<div class='banner {'fail' if n_failed else 'pass'}'>{len(rows)} points: {n_ok} ok, "
              f"{n_failed} failed, {cached} from cache</div>")
    shown = rows[:MAX_TABLE_ROWS]
    head = "".join(f"<th>{_e(c)}</th>" for c in columns)
    body = []
    for r in shown:
        cells = []
        for c in columns:
            v = r.get(c, "")
            if c == "status":
                cells.append(_verdict_cell(None if v == "" else v == "ok").replace(">pass<", ">ok<")
                             .replace(">FAIL<", f">{_e(v)}<"))
            elif c == "run_dir" and v:        # a point run without --plots has no report: its folder
                link = f"{v}/{REPORT_NAME}" if (out_dir / v / REPORT_NAME).is_file() else f"{v}/"
                cells.append(f"<td><a href=\"{_e(link)}\">{_e(v)}</a></td>")
            else:
                cells.append(f"<td>{_e(_fmt(v))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    more = (f"<p class=info>first {MAX_TABLE_ROWS} of {len(rows)} rows; all in results.csv</p>"
            if len(rows) > len(shown) else "")
    title = f"railhil campaign {name}"
    page = (f"<h1>{_e(title)}</h1><p>{_e(description)}</p>{banner}"
            f"<p class=info>folder {_e(out_dir.resolve())}</p>"
            f"<h2>Plots</h2>{_images(sorted(out_dir.glob('plot_*.png')))}"
            f"<h2>Results</h2>{more}<div class=scroll><table><thead><tr>{head}</tr></thead><tbody>"
            f"{''.join(body)}</tbody></table></div>")
    return _page(title, page)


def write_campaign_report(out_dir: Path, table: tuple[list[str], list[dict]] | None = None,
                          name: str | None = None, description: str = "") -> Path:
    """Write <out_dir>/report.html (`render_campaign_report`); returns its path."""
    page = render_campaign_report(out_dir, table, name, description)
    out = Path(out_dir) / REPORT_NAME
    out.write_text(page, encoding="utf-8")
    return out


@dataclass(frozen=True)
class Section:
    """A section of a tables-and-figures page (render_sections_report)."""

    title: str
    text: str                              # a paragraph, plain text
    header: list[str]
    rows: list[list[object]]
    images: list[Path]


def render_sections_report(title: str, intro: str, sections: list[Section], banner: str = "",
                           failed: bool = False) -> str:
    """A page of sections, each a paragraph, a table and figures (inlined PNG): a test programme's report
    (hil.typetest).  `banner`: one line under the title, red when `failed`."""
    nav = _nav([(f"s{k}", s.title) for k, s in enumerate(sections)])
    head = f"<h1>{_e(title)}</h1><p>{_e(intro)}</p>"
    if banner:
        head += f"<div class='banner {'fail' if failed else 'pass'}'>{_e(banner)}</div>"
    body = [head, nav]
    for k, s in enumerate(sections):
        numeric = {i for i, _ in enumerate(s.header) if s.rows and all(
            isinstance(r[i], (int, float)) or r[i] is None for r in s.rows)}
        body.append(f"<h2 id=s{k}>{_e(s.title)}</h2><p>{_e(s.text)}</p>"
                    f"<div class=scroll>{_table(s.header, s.rows, numeric)}</div>{_images(s.images)}")
    return _page(title, "".join(body))


def write_report(folder: Path) -> Path:
    """report.html of a run folder (it has run.json) or a campaign folder (it has results.csv)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ReportError(f"{folder}: no such folder (expected a run folder or a campaign folder)")
    if (folder / "run.json").exists():
        return write_run_report(folder)
    if (folder / "results.csv").exists():
        return write_campaign_report(folder)
    raise ReportError(f"{folder}: neither a run folder (no run.json) nor a campaign folder (no results.csv)")
