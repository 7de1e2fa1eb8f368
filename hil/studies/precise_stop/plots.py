"""The figure of precise stopping (seed 002): precise_stop.png, the approach to the target point."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.report.kpis import RunView
from hil.report.plots import pyplot
from hil.scenario.params import kmh, run_params

STOP_SIGNALS = {"to_go": ("BCU_STOP", "DistanceToGo"), "ref": ("BCU_STOP", "RefSpeed"),
                "cmd": ("BCU_STOP", "StopCommand"), "target": ("BCU_DEMAND", "TargetDecel")}


def run_plots(run: RunView) -> list[Path]:
    """precise_stop.png: above, speed over the distance to the target point — the train's (plant truth,
    car 1's front) and the braking curve the BCU follows (BCU_STOP.RefSpeed over its DistanceToGo, where it
    believes the train is); below, over time, the stopping controller's command and the BCU's target
    deceleration, with the true distance to go on a second axis."""
    if run.out_dir is None:
        return []
    plt = pyplot()
    sc = run.scenario
    target_m = [e.target_stop_m for e in sc.desk if e.target_stop_m is not None][-1]
    cols, t = run.cols, run.t
    to_go = target_m - cols["x_m_1"]
    sig = run.signals(STOP_SIGNALS)
    fig, (ax_v, ax_a) = plt.subplots(2, 1, figsize=(10, 8))
    ax_v.plot(to_go, kmh(cols["v_mps_1"]), lw=1.0, label="train (plant truth)")
    if sig["ref"][0].size:                   # RefSpeed is 0 while the BCU is not following the curve
        following = sig["ref"][1] > 0
        ax_v.plot(sig["to_go"][1], np.where(following, kmh(sig["ref"][1]), np.nan), lw=0.8, ls="--",
                  color="k", label="braking curve (BCU_STOP, at the BCU's odometer)")
    for b in run_params(sc).balises:
        ax_v.axvline(target_m - b, color="tab:green", lw=0.6, ls=":")
    ax_v.set_xlim(max(float(np.max(to_go)), 1.0), min(float(np.min(to_go)), 0.0) - 1.0)
    ax_v.set_xlabel("distance to the target point [m]   (dotted: balises)")
    ax_v.set_ylabel("speed [km/h]")
    if sig["cmd"][0].size:
        ax_a.step(sig["cmd"][0], sig["cmd"][1], where="post", lw=0.8, label="stopping command (BCU_STOP)")
    if sig["target"][0].size:
        ax_a.step(sig["target"][0], sig["target"][1], where="post", lw=1.0, color="k",
                  label="target deceleration (BCU_DEMAND)")
    ax_a.set_xlabel("time [s]")
    ax_a.set_ylabel("deceleration [m/s²]")
    ax_d = ax_a.twinx()
    ax_d.plot(t, to_go, color="tab:gray", lw=0.8, label="distance to go (truth)")
    ax_d.set_ylabel("distance to go [m]")
    ax_d.legend(fontsize=8, loc="lower left")
    for ax in (ax_v, ax_a):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    k = run.stopped and float(to_go[run.i_stop])
    err = f", stop error {-k:+.3f} m" if run.stopped else ", did not stop"
    fig.suptitle(f"{sc.name} ({run.mode}, seed {sc.seed}): precise stopping, method {sc.precise_stop.method}"
                 + err)
    fig.tight_layout()
    path = run.out_dir / "precise_stop.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]
