"""The figure of the anti-collision device (seed 002): anticollision.png, the approach to the obstacle."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from firmware_py.acd import Aspect
from hil.report.kpis import RunView
from hil.report.plots import pyplot
from hil.scenario.params import kmh, run_params
from hil.studies.anticollision.scenario import aspect_at, leader_motion, spec_of

REQUESTS = {0: "none", 1: "service", 2: "emergency"}


def run_plots(run: RunView) -> list[Path]:
    """anticollision.png: above, the gap from the own train's front to the leading train's last wagon and
    the distance to the next red signal (plant truth), with the ACD's requests shaded; below, the own
    train's speed and the ACD's requested deceleration (ACD_BRAKE_REQ)."""
    if run.out_dir is None:
        return []
    plt = pyplot()
    sc, cols, t = run.scenario, run.cols, run.t
    spec = spec_of(sc)
    front = cols["x_m_1"] + run_params(sc).plant.train.car_pitch_m / 2.0
    motion = leader_motion(spec)
    sig = run.signals({"req": ("ACD_BRAKE_REQ", "Request"), "decel": ("ACD_BRAKE_REQ", "RequestedDecel")})
    fig, (ax_g, ax_v) = plt.subplots(2, 1, figsize=(10, 8), sharex=True)
    if motion is not None:
        ax_g.plot(t, motion.rear_m(t) - front, lw=1.0, label="gap to the train ahead (truth)")
    for s in spec.signals:
        red = np.array([aspect_at(s, ti) == Aspect.RED for ti in t])
        ahead = np.where(red & (s.position_m - front > 0), s.position_m - front, np.nan)
        if np.isfinite(ahead).any():
            ax_g.plot(t, ahead, lw=1.0, ls="--", label=f"red signal {s.id} ahead (truth)")
    rt, rv = sig["req"]
    for k in range(rt.size):
        if rv[k] > 0:
            end = rt[k + 1] if k + 1 < rt.size else float(t[-1])
            ax_g.axvspan(rt[k], end, color="tab:red" if rv[k] >= 2 else "tab:orange", alpha=0.15, lw=0)
    ax_g.axhline(0.0, color="k", lw=0.6)
    ax_g.set_ylabel("distance [m]   (shaded: ACD request)")
    ax_v.plot(t, kmh(cols["v_mps_1"]), lw=1.0, label="own train speed (truth)")
    ax_r = ax_v.twinx()
    dt, dv = sig["decel"]
    if dt.size:
        ax_r.step(dt, dv, where="post", color="tab:red", lw=0.8, label="requested deceleration (ACD)")
    ax_r.set_ylabel("requested deceleration [m/s²]")
    ax_r.legend(fontsize=8, loc="lower left")
    ax_v.set_ylabel("speed [km/h]")
    ax_v.set_xlabel("time [s]")
    for ax in (ax_g, ax_v):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    gap = (motion.rear_m(t) - front).min() if motion is not None else math.inf
    fig.suptitle(f"{sc.name} ({run.mode}, seed {sc.seed}): ACD prediction "
                 f"{'on' if spec.prediction else 'off'}"
                 + (f", min gap {gap:.1f} m" if math.isfinite(gap) else ""))
    fig.tight_layout()
    path = run.out_dir / "anticollision.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]
