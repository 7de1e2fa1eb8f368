"""The figures of slip control with preview (seed 000): a run's slip against its references
(preview_slip.png) and the reproduction's Figs. 5-7."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.report.kpis import RunView
from hil.report.plots import pyplot


def run_plots(run: RunView) -> list[Path]:
    """preview_slip.png: per car, the slip ratio σ_i (plant), its reference Σ_i° (BECUi_SLIP_REF) and the
    optimum σ°(x_i, v) (plant truth) over the position of car 1."""
    if run.out_dir is None:
        return []
    plt = pyplot()
    n = run.scenario.train.cars
    cols = run.cols
    refs = run.signals({f"ref{k}": (f"BECU{k}_SLIP_REF", "SlipRef") for k in range(1, n + 1)})
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n + 1), sharex=True, squeeze=False)
    x1 = cols["x_m_1"]
    for k in range(1, n + 1):
        ax = axes[k - 1, 0]
        ax.plot(x1, cols[f"sigma_opt_{k}"], color="tab:red", lw=0.8, ls=":", label="σ° (plant)")
        ax.plot(x1, cols[f"slip_ratio_{k}"], color="tab:blue", lw=1.0, label="σ (plant)")
        t_ref, v_ref = refs[f"ref{k}"]
        if t_ref.size:
            ax.step(np.interp(t_ref, cols["t_s"], x1), v_ref, where="post", color="k", lw=0.8,
                    label="Σ° (BECU reference)")
        ax.set_ylabel(f"car {k} slip [-]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("position of car 1 [m]")
    pv = run.scenario.preview
    fig.suptitle(f"{run.scenario.name}: slip reference {pv.method}, {pv.mode} mode")
    fig.tight_layout()
    path = run.out_dir / "preview_slip.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]


def plot_figures(s: dict, table1: dict[tuple[str, float], dict], out: Path) -> list[Path]:
    """Figs. 5-7 of seed 000 from the reproduction's summary `s` and the Table 1 runs with their truth,
    `table1[(method, Delta2)]`; the PNG files written into `out`."""
    plt = pyplot()
    files = []
    styles = {"ideal": ("r", ":"), "Lf": ("k", "-."), "Bd": ("g", "--"), "Dp": ("b", "-")}
    fig, axes = plt.subplots(1, 3, figsize=(15, 4), sharey=True)
    for ax, d, tag in zip(axes, sorted({d for _, d in table1}), "abc", strict=False):
        for m, (col, ls) in styles.items():
            r = table1[(m, d)]
            ax.plot(r["t_s"], r["v_mps"], color=col, linestyle=ls, label=f"{m} (S = {r['S_m']:.1f} m)")
        ax.set_title(f"({tag}) Delta2 = {d:.0f} m")
        ax.set_xlabel("t [s]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("v [m/s]")
    fig.suptitle("Fig. 5: speed, campaign 1 (alpha = 1.5, v(0) = 30 m/s), paper mode over CAN")
    files.append(out / "fig5.png")
    fig.savefig(files[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)

    c2 = s["c2"]
    a = [r["alpha"] for r in c2]
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    axes[0, 0].plot(a, [r["ideal"] for r in c2], "r:", a, [r["Bd"] for r in c2], "g--", a,
                    [r["Dp"] for r in c2], "b-")
    axes[0, 0].legend(["S°", "S^Bd", "S^Dp"])
    axes[0, 0].set_title("(a) stopping distance [m]")
    axes[0, 1].plot(a, [r["A_m"] for r in c2], "k-", label="A [m]")
    axes[0, 1].plot(a, [r["A_pct"] for r in c2], "b--", label="A%")
    axes[0, 1].legend()
    axes[0, 1].set_title("(b) A [m] and A%")
    axes[1, 0].plot(a, [r["A_pct_ideal"] for r in c2], "b-")
    axes[1, 0].set_title("(c) A%° [%]")
    axes[1, 1].plot(a, [r["N_pct"] for r in c2], "b-")
    axes[1, 1].set_title("(d) N% [%]")
    for ax in axes.flat:
        ax.set_xlabel("alpha [1/s]")
        ax.grid(True, alpha=0.3)
    fig.suptitle("Fig. 6: campaign 2 (v(0) = 50 m/s, Delta2 = 50 m)")
    fig.tight_layout()
    files.append(out / "fig6.png")
    fig.savefig(files[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    c3 = [r for r in s["c3"] if r["v0"] == 40.0]
    b = [r["beta"] for r in c3]
    axes[0].plot(b, [r["ideal"] for r in c3], "r:", b, [r["Bd"] for r in c3], "g--", b,
                 [r["Dp"] for r in c3], "b-")
    axes[0].legend(["S°", "S^Bd", "S^Dp"])
    axes[0].set_title("(a) stopping distance [m], v(0) = 40 m/s")
    for v0, ls in ((20.0, "-."), (30.0, "--"), (40.0, "-")):
        rows = [r for r in s["c3"] if r["v0"] == v0]
        axes[1].plot([r["beta"] for r in rows], [r["A_pct"] for r in rows], "b" + ls,
                     label=f"v(0) = {v0:.0f}")
    axes[1].legend()
    axes[1].set_title("(b) A% [%]")
    for ax in axes:
        ax.set_xlabel("beta")
        ax.grid(True, alpha=0.3)
    fig.suptitle("Fig. 7: campaign 3 (alpha = 1.5, Delta2 = 50 m)")
    files.append(out / "fig7.png")
    fig.savefig(files[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)
    return files
