"""The figure of the wheel-slip governor (seed 001): wheel_slip.png, laid out like the paper's Figs. 8-9."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.report.kpis import RunView, per_car
from hil.report.plots import pyplot, wsp_intervals
from hil.scenario.params import run_params
from hil.studies.wheel_slip.kpis import scheduled_limit
from plant_sim.params import G_MPS2


def run_plots(run: RunView) -> list[Path]:
    """wheel_slip.png, seed 001's Figs. 8-9 for a run: deceleration v̇ with the requested r⁰ and the
    governed r (car 1's BECU1_DIAG.GovernedDecel, from the trace), true slip speed with s̄, cylinder
    pressure p with the set-point u, brake torque τ; WSP intervals (any car's WSP valve not FILL) shaded on
    every panel."""
    if run.out_dir is None:
        return []
    plt = pyplot()
    scenario, cols = run.scenario, run.cols
    ws = scenario.wheel_slip
    n = scenario.train.cars
    t = cols["t_s"]
    sig = run.signals({"r0": ("BCU_DEMAND", "TargetDecel"), "r": ("BECU1_DIAG", "GovernedDecel")})
    fig, axes = plt.subplots(4, 1, figsize=(10, 11), sharex=True)
    ax_d, ax_s, ax_p, ax_t = axes
    for i in range(1, n + 1):
        lbl = f" car {i}" if n > 1 else ""
        ax_d.plot(t, -cols[f"a_mps2_{i}"] / G_MPS2, lw=0.8, label="v̇ (plant)" + lbl)
        ax_s.plot(t, cols[f"slip_speed_mps_{i}"], lw=0.8, label="s = v − rω" + lbl)
        ax_p.plot(t, cols[f"p_Pa_{i}"] / 1e5, lw=0.8, label="p" + lbl)
        if f"p_set_Pa_{i}" in cols:
            ax_p.plot(t, cols[f"p_set_Pa_{i}"] / 1e5, lw=0.8, ls="--", label="u (set-point)" + lbl)
        ax_t.plot(t, cols[f"tau_Nm_{i}"] / 1e3, lw=0.8, label="τ" + lbl)
    if "r0" in sig and sig["r0"][0].size:
        ax_d.step(sig["r0"][0], sig["r0"][1] / G_MPS2, where="post", color="k", lw=1.0, label="r⁰ (demand)")
    if ws.governor and "r" in sig and sig["r"][0].size:
        ax_d.step(sig["r"][0], sig["r"][1] / G_MPS2, where="post", color="tab:red", lw=1.0,
                  label="r (governed, car 1)")
    if run_params(scenario).plant.adhesion.slip_speed_peak is None:   # s̄ moves with v on seed 000's rails
        ax_s.plot(t, scheduled_limit(scenario, cols["v_mps_1"]), color="tab:red", ls=":", lw=1.0,
                  label=f"s̄(v) ({ws.design_condition}, car 1's speed)")
    else:
        ax_s.axhline(ws.slip_max_mps, color="tab:red", ls=":", lw=1.0,
                     label=f"s̄ = {ws.slip_max_mps} m/s")
    wsp = per_car(cols, "wsp_valve", n) != 0
    for ax in axes:
        for a, b in wsp_intervals(t, np.any(wsp, axis=1)):
            ax.axvspan(a, b, color="tab:orange", alpha=0.25, lw=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    ax_d.set_ylabel("deceleration [g]")
    ax_s.set_ylabel("slip speed [m/s]")
    ax_p.set_ylabel("cylinder pressure [bar]")
    ax_t.set_ylabel("brake torque [kN m]")
    ax_t.set_xlabel("time [s]   (shaded: WSP engaged)")
    fig.suptitle(f"{scenario.name} ({run.mode}, seed {scenario.seed}), reference governor "
                 f"{'on' if ws.governor else 'off'}")
    fig.tight_layout()
    path = run.out_dir / "wheel_slip.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]
