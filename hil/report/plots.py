"""The run's figures: plot.png (speed, cylinder pressure and slip per car) from the plant's truth, and
each study's own figure (hil/studies/<name>/plots.py `run_plots(run) -> list[Path]`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hil.scenario import registry

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
        axes[0].plot(t, cols[f"v_mps_{i}"] * 3.6, label=f"car {i}", lw=1)
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
    fig.tight_layout()
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
