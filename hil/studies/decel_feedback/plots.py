"""The figures of the deceleration feedback (seed 004): a run's decel_feedback.png (Figs. 19-20 for one
run) and `compare_runs`, an open-loop and a closed-loop run side by side as the paper shows them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.report.kpis import RunView, per_car
from hil.report.plots import pyplot
from hil.scenario.params import run_params
from hil.studies.decel_feedback.kpis import (
    BAND,
    FEEDBACK_SIGNALS,
    PAD_MU_NOMINAL,
    RATIO_TAU_S,
    bcu_engagement_s,
    lag,
)


def run_plots(run: RunView) -> list[Path]:
    """decel_feedback.png, seed 004's Figs. 19-20 for one run: deceleration (truth, filtered as in
    `feedback_ratio`) with the
    target and the 90-110 % band; cylinder pressure per car; the BCU's φ and the pad friction μ_d/μ_d0;
    the BCU's slope estimate.  The BCU's engagement (trace) is a vertical line on every panel."""
    if run.out_dir is None:
        return []
    plt = pyplot()
    scenario, cols = run.scenario, run.cols
    n = scenario.train.cars
    t = cols["t_s"]
    sig = run.signals(FEEDBACK_SIGNALS)
    target = sig["target"]
    masses = np.asarray(run_params(scenario).plant.train.masses_kg)
    decel = lag(t, -(per_car(cols, "a_mps2", n) @ masses) / masses.sum(), RATIO_TAU_S)
    fig, axes = plt.subplots(3, 1, figsize=(10, 10), sharex=True)
    ax_d, ax_p, ax_f = axes
    ax_d.plot(t, decel, lw=1.0, label="train deceleration (plant, mass-weighted)")
    if target[0].size:
        ax_d.step(target[0], target[1], where="post", color="k", lw=1.0, label="target (BCU_DEMAND)")
        for f in BAND:
            ax_d.step(target[0], f * target[1], where="post", color="k", lw=0.6, ls=":")
    for i in range(1, n + 1):
        ax_p.plot(t, cols[f"p_Pa_{i}"] / 1e3, lw=0.8, label=f"car {i}")
    if sig["phi"][0].size:
        ax_f.step(sig["phi"][0], sig["phi"][1], where="post", color="tab:red", lw=1.0,
                  label="φ (BCU_BRAKE_CORR)")
    if "mu_pad_1" in cols:
        ax_f.plot(t, cols["mu_pad_1"] / PAD_MU_NOMINAL, lw=0.8, color="tab:green",
                  label="μ_d/μ_d0 car 1 (plant)")
    if sig["slope"][0].size:
        ax_s = ax_f.twinx()
        ax_s.step(sig["slope"][0], sig["slope"][1] * 1e3, where="post", color="tab:gray", lw=0.8,
                  label="slope estimate [‰]")
        ax_s.set_ylabel("slope estimate [‰]")
        ax_s.legend(fontsize=8, loc="lower right")
    eng = bcu_engagement_s(sig)
    for ax in axes:
        if eng is not None:
            ax.axvline(eng, color="tab:purple", lw=1.0, ls="--")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    ax_d.set_ylabel("deceleration [m/s²]")
    ax_p.set_ylabel("cylinder pressure [kPa]")
    ax_f.set_ylabel("φ, μ_d/μ_d0 [-]")
    ax_f.set_xlabel("time [s]" + ("   (dashed: the BCU's feedback engaged)" if eng is not None else ""))
    loop = "closed loop" if scenario.decel_feedback.closed_loop else "open loop"
    fig.suptitle(f"{scenario.name} ({run.mode}, seed {scenario.seed}), deceleration feedback: {loop}")
    fig.tight_layout()
    path = run.out_dir / "decel_feedback.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]


def compare_runs(open_dir: Path, closed_dir: Path, out: Path) -> Path:
    """Seed 004's Figs. 19-20 as the paper shows them: cylinder pressure (car 1) and train deceleration of
    an open-loop and a closed-loop run of the same scenario, side by side in one figure, from the two run
    folders (truth.csv, run.json, the trace).  Returns `out`."""
    plt = pyplot()
    fig, (ax_p, ax_d) = plt.subplots(2, 1, figsize=(10, 8), sharex=True)
    for label, folder, color in (("before (open loop)", Path(open_dir), "tab:blue"),
                                 ("after (closed loop)", Path(closed_dir), "tab:red")):
        view = RunView.from_folder(folder)
        scenario, cols = view.scenario, view.cols
        t = cols["t_s"]
        n = scenario.train.cars
        masses = np.asarray(run_params(scenario).plant.train.masses_kg)
        decel = lag(t, -(per_car(cols, "a_mps2", n) @ masses) / masses.sum(), RATIO_TAU_S)
        sig = view.signals(FEEDBACK_SIGNALS)
        ax_p.plot(t, cols["p_Pa_1"] / 1e3, color=color, lw=1.0, label=f"{label}, car 1")
        ax_d.plot(t, decel, color=color, lw=1.0, label=label)
        target = sig["target"]
        if target[0].size and "closed" in label:
            ax_d.step(target[0], target[1], where="post", color="k", lw=1.0, label="target")
            for f in BAND:
                ax_d.step(target[0], f * target[1], where="post", color="k", lw=0.6, ls=":")
    ax_p.set_ylabel("cylinder pressure [kPa]   (Fig. 19)")
    ax_d.set_ylabel("deceleration [m/s²]   (Fig. 20)")
    ax_d.set_xlabel("time [s]")
    for ax in (ax_p, ax_d):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("seed 004 line test: before / after the deceleration feedback")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
