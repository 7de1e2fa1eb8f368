"""A WSP test programme's results: results.json (every run, every metric), table.md and table.csv (one table
per condition, strategies side by side at each speed), one figure per condition (distance extension,
adhesion utilisation, air, slide; strategies as bars at each speed), a speed-over-distance figure per
condition, report.html; and the lines `railhil wsp-test` prints, each strategy against the first.
Definitions: hil.typetest.metrics (docs/wsp-test.md).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

from hil.report.html import Section, render_sections_report
from hil.scenario.params import kmh
from hil.typetest.programme import REFERENCE, Programme
from hil.typetest.wsp import RunResult

#: the table's metrics: (key, header, format)
COLUMNS = (
    ("stopping_distance_m", "stop [m]", "{:.1f}"),
    ("ideal_distance_m", "ideal [m]", "{:.1f}"),
    ("extension_pct", "extension [%]", "{:+.1f}"),
    ("utilisation", "utilisation", "{:.3f}"),
    ("air_free_l", "air [L]", "{:.0f}"),
    ("max_slip_speed_mps", "max slip [m/s]", "{:.2f}"),
    ("slide_integral_m", "slide [m]", "{:.2f}"),
    ("longest_not_rotating_s", "not rotating [s]", "{:.2f}"),
    ("wsp_activations", "WSP activations", "{:d}"),
)
#: the figure's panels: (key, y label)
PANELS = (("extension_pct", "stopping-distance extension [%]"), ("utilisation", "adhesion utilisation [-]"),
          ("air_free_l", "air vented [L free air]"), ("slide_integral_m", "slide above threshold [m]"))


def _shown(value, fmt: str) -> str:
    if value is None:
        return "—"
    try:
        return fmt.format(value)
    except (ValueError, TypeError):
        return str(value)


def record(r: RunResult) -> dict:
    return {"strategy": r.spec.strategy, "condition": r.spec.condition, "speed_kmh": r.spec.speed_kmh,
            "folder": r.spec.folder, "status": r.status, "error": r.error, "wall_s": round(r.wall_s, 2),
            **r.metrics}


def _by(results: list[RunResult]) -> dict[tuple[str, float, str], RunResult]:
    return {(r.spec.condition, r.spec.speed_kmh, r.spec.strategy): r for r in results}


def _order(results: list[RunResult]) -> tuple[list[str], list[float], list[str]]:
    conditions, speeds, strategies = [], [], []
    for r in results:
        s = r.spec
        for seq, v in ((conditions, s.condition), (speeds, s.speed_kmh), (strategies, s.strategy)):
            if v not in seq:
                seq.append(v)
    conditions.sort(key=lambda c: c != REFERENCE)            # the dry reference first
    return conditions, speeds, strategies


def condition_table(results: list[RunResult], condition: str) -> tuple[list[str], list[list[object]]]:
    """One condition: a row per speed and metric, a column per strategy."""
    _, speeds, strategies = _order(results)
    by = _by(results)
    header = ["speed [km/h]", "metric", *strategies]
    rows = []
    for speed in speeds:
        for key, name, fmt in COLUMNS:
            cells = []
            for s in strategies:
                r = by.get((condition, speed, s))
                if r is None:
                    cells.append("")
                elif r.status != "ok":
                    cells.append("failed")
                elif key == "stopping_distance_m" and not r.metrics.get("stopped"):
                    cells.append("no stop")
                else:
                    cells.append(_shown(r.metrics.get(key), fmt))
            rows.append([f"{speed:g}", name, *cells])
    return header, rows


def comparison_lines(results: list[RunResult]) -> list[str]:
    """Each strategy against the first, per condition: where it is better on distance extension and on air,
    and whether an axle stayed below the rotation threshold longer."""
    conditions, speeds, strategies = _order(results)
    if len(strategies) < 2:
        return []
    by = _by(results)
    first = strategies[0]
    lines = []
    for s in strategies[1:]:
        for c in conditions:
            if c == REFERENCE:
                continue
            ext = air = rot = 0
            n = 0
            for v in speeds:
                a, b = by.get((c, v, first)), by.get((c, v, s))
                if a is None or b is None or a.status != "ok" or b.status != "ok":
                    continue
                ma, mb = a.metrics, b.metrics
                if mb.get("extension_m") is None or ma.get("extension_m") is None:
                    continue
                n += 1
                ext += mb["extension_m"] < ma["extension_m"]
                air += mb["air_free_l"] < ma["air_free_l"]
                rot += mb["longest_not_rotating_s"] <= ma["longest_not_rotating_s"]
            if n:
                lines.append(f"{s} vs {first}, {c}: shorter extension at {ext} of {n} speeds, less air at "
                             f"{air} of {n}, no longer without rotation at {rot} of {n}")
    return lines


def _figure(results: list[RunResult], condition: str, path: Path, description: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, speeds, strategies = _order(results)
    by = _by(results)
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.5))
    width = 0.8 / max(len(strategies), 1)
    for ax, (key, label) in zip(axes.flat, PANELS, strict=True):
        for k, s in enumerate(strategies):
            vals = []
            for v in speeds:
                r = by.get((condition, v, s))
                val = r.metrics.get(key) if r is not None and r.status == "ok" else None
                vals.append(float("nan") if val is None else val)
            ax.bar([i + (k - (len(strategies) - 1) / 2) * width for i in range(len(speeds))], vals, width,
                   label=s)
        ax.set_xticks(range(len(speeds)), [f"{v:g} km/h" for v in speeds])
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    axes.flat[0].legend(fontsize=8)
    fig.suptitle(f"WSP test, {condition}: {description}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _paths_figure(results: list[RunResult], condition: str, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, speeds, strategies = _order(results)
    by = _by(results)
    fig, ax = plt.subplots(figsize=(10, 4))
    for k, s in enumerate(strategies):
        for j, v in enumerate(speeds):
            r = by.get((condition, v, s))
            if r is None or r.status != "ok" or not r.path[0]:
                continue
            ax.plot(r.path[0], [kmh(u) for u in r.path[1]], color=f"C{k}", lw=1,
                    ls=("-", "--", ":", "-.")[j % 4], label=f"{s} {v:g} km/h")
    ax.set_xlabel("distance from the brake command [m]")
    ax.set_ylabel("train speed [km/h]")
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, ncol=2)
    fig.suptitle(f"WSP test, {condition}: speed over distance", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def write(prog: Programme, results: list[RunResult], out_dir: Path, wall_s: float,
          plots: bool = True) -> list[Path]:
    """results.json, table.md, table.csv, the figures and report.html in `out_dir`."""

    out_dir.mkdir(parents=True, exist_ok=True)
    conditions, speeds, strategies = _order(results)
    spec = prog.spec
    failed = [r for r in results if r.status != "ok"]
    written = []
    doc = {"programme": str(prog.path), "name": spec.name, "description": spec.description,
           "metrics": spec.metrics.model_dump(), "wall_s": round(wall_s, 1),
           "strategies": {s: spec.strategies[s].description for s in strategies},
           "conditions": {c: (spec.reference if c == REFERENCE else spec.conditions[c]).description
                          for c in conditions},
           "comparison": comparison_lines(results), "runs": [record(r) for r in results]}
    (out_dir / "results.json").write_text(json.dumps(doc, indent=1, default=str) + "\n", encoding="utf-8")
    written.append(out_dir / "results.json")
    keys = ["strategy", "condition", "speed_kmh", "status", *[k for k, _, _ in COLUMNS], "stopped",
            "time_to_stop_s", "extension_m", "v0_mps", "folder", "error"]
    with open(out_dir / "table.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        for r in results:
            w.writerow(record(r))
    written.append(out_dir / "table.csv")
    md = [f"# WSP test {spec.name}", "", spec.description, "",
          f"Programme `{prog.path}`; {len(results)} runs, {len(failed)} failed, {wall_s:.0f} s wall.", ""]
    sections = []
    for c in conditions:
        cond = spec.reference if c == REFERENCE else spec.conditions[c]
        header, rows = condition_table(results, c)
        text = cond.description + (" — each strategy's own dry run: its ideal stop is itself (or, for a "
                                   "strategy with demand_from, the named strategy's dry run), so its "
                                   "extension is the definition's error" if c == REFERENCE else "")
        md += [f"## {c}", "", text, "", "| " + " | ".join(header) + " |",
               "|" + "|".join("---" for _ in header) + "|"]
        md += ["| " + " | ".join(str(x) for x in row) + " |" for row in rows]
        md.append("")
        images = []
        if plots:
            images = [_figure(results, c, out_dir / f"wsp_{c}.png", cond.description),
                      _paths_figure(results, c, out_dir / f"wsp_{c}_speed.png")]
            written += images
        sections.append(Section(c, text, header, rows, images))
    lines = comparison_lines(results)
    if lines:
        md += ["## Against the first strategy", "", *[f"- {line}" for line in lines], ""]
    if failed:
        md += ["## Failed runs", "", *[f"- {r.spec.folder}: {r.error}" for r in failed], ""]
    (out_dir / "table.md").write_text("\n".join(md), encoding="utf-8")
    written.append(out_dir / "table.md")
    banner = f"{len(results)} runs, {len(failed)} failed; " + "; ".join(lines)
    page = render_sections_report(f"railhil WSP test {spec.name}", spec.description, sections, banner,
                                  failed=bool(failed))
    (out_dir / "report.html").write_text(page, encoding="utf-8")
    written.append(out_dir / "report.html")
    return written

