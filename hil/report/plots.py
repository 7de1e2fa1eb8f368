"""The run's figures: plot.png (speed, cylinder pressure and slip per car) from the plant's truth, and
each study's own figure (hil/studies/<name>/plots.py `run_plots(run) -> list[Path]`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hil.scenario import registry
from hil.scenario.params import kmh

if TYPE_CHECKING:
    from hil.report.kpis import RunView
    from hil.scenario.model import ScenarioBase as Scenario


def pyplot():
    """matplotlib's pyplot, on the Agg backend (no display needed) unless a program has chosen its own
    already (a notebook's inline backend stays: a run started from a notebook must not switch it)."""
    import sys

    import matplotlib

    if "matplotlib.pyplot" not in sys.modules:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_run(scenario: Scenario, cols: dict[str, np.ndarray], path: Path, title: str) -> Path:
    """plot.png: speed, cylinder pressure and slip speed per car over time."""
    plt = pyplot()
    n = scenario.train.cars
    t = cols["t_s"]
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    for i in range(1, n + 1):
        axes[0].plot(t, kmh(cols[f"v_mps_{i}"]), label=f"car {i}", lw=1)
        axes[1].plot(t, cols[f"p_Pa_{i}"] / 1e3, lw=1)
        axes[2].plot(t, cols[f"slip_speed_mps_{i}"], lw=1)
    axes[0].set_ylabel("speed [km/h]")
    axes[1].set_ylabel("cylinder pressure [kPa]")
    axes[2].set_ylabel("slip speed v − rω [m/s]")
    axes[2].set_xlabel("time [s]")
    axes[0].legend(ncol=min(n, 4), fontsize=8)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    fig.suptitle(title)
    # fixed margins, as tight_layout would set them for this figure: it draws the figure once more to
    # measure them (55 of the plot's 210 ms, every railhil run)
    fig.subplots_adjust(left=0.08, right=0.98, top=0.95, bottom=0.06, hspace=0.08)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def wsp_intervals(t: np.ndarray, active: np.ndarray) -> list[tuple[float, float]]:
    """[start, end) times [s] of the runs of True in `active` (sampled at t): shaded spans in a figure."""
    edges = np.diff(np.concatenate([[0], active.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return [(float(t[a]), float(t[b - 1]) + step) for a, b in zip(starts, ends, strict=True)]


def study_plots(run: RunView) -> list[Path]:
    """Every active study's run figures, written into the run folder; the files written."""
    files: list[Path] = []
    for study in registry.active(run.scenario):
        files += study.part("plots").run_plots(run)
    return files


LATENESS_NAME = "lateness.png"     # a real-time run's lateness histogram (plot_lateness)


def lateness_text(us: int | None) -> str:
    """A lateness measured in whole µs: 0 is "< 1 µs" (on time to the µs, the precise wait's doing), not
    a broken 0."""
    return "—" if us is None else "< 1 µs" if us == 0 else f"{us} µs"


def plot_lateness(rt: dict, path: Path) -> Path:
    """lateness.png of a real-time run (kpis.json `realtime`, hil.runtime.outcome.realtime_verdict): the
    histogram of each simulated node's cycle release lateness and of the machine probe's, on the same
    bins, with the deadline-miss threshold of a 10 ms cycle."""
    plt = pyplot()
    edges = list(rt["histogram_edges_us"])
    labels = [f"{e / 1e3:g} ms" if e >= 1000 else f"{e} µs" for e in edges]
    labels = [f"≥{lo}" if k == len(edges) - 1 else f"{lo}–{labels[k + 1]}"
              for k, lo in enumerate(labels)]
    series = [(name, v["histogram"]) for name, v in rt["nodes"].items()]
    machine = rt.get("machine") or {}
    if "histogram" in machine:
        series.append(("machine probe", machine["histogram"]))
    fig, ax = plt.subplots(figsize=(10, 3.8))
    x = np.arange(len(edges))
    width = 0.85 / max(len(series), 1)
    for k, (name, counts) in enumerate(series):
        total = max(sum(counts), 1)
        ax.bar(x + (k - (len(series) - 1) / 2) * width, np.asarray(counts) / total, width,
               label=name, hatch="//" if name == "machine probe" else None)
    ax.set_yscale("log")
    ax.set_ylim(bottom=1e-5)
    ax.set_xticks(x, labels, rotation=30, fontsize=8)
    ax.set_xlabel("release lateness (the cycle's wait returned this late after its absolute deadline)")
    ax.set_ylabel("fraction of cycles")
    threshold = edges.index(500) if 500 in edges else None
    if threshold is not None:
        ax.axvline(threshold - 0.5, color="red", lw=1, ls="--", label="miss threshold (10 ms cycle)")
    verdict = "held" if rt["held"] else "NOT HELD"
    ax.set_title(f"release lateness per node, real time {verdict}: 10 ms nodes p50 "
                 f"{lateness_text(rt.get('p50_10ms_us'))}, p99 {lateness_text(rt.get('p99_10ms_us'))} "
                 f"(measured in whole µs)", fontsize=10)
    ax.legend(fontsize=7, ncol=3)
    ax.grid(True, axis="y", alpha=0.3)
    # fixed margins for the rotated bin labels: tight_layout draws the figure once more to measure them
    # (about a fifth of this plot's CPU time in a real-time run's report)
    fig.subplots_adjust(left=0.07, right=0.99, top=0.92, bottom=0.25)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
