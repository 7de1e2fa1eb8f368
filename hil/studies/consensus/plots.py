"""The figures of consensus braking (seed 003): a run's consensus.png (speeds, couplers, tracking errors,
the observer: like Figs. 3-17) and the reproduction's cycle and latency sweeps."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hil.report.kpis import RunView
from hil.report.plots import pyplot
from hil.scenario.params import kmh
from hil.studies.consensus.kpis import v_star

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario


def case_series(sc: Scenario, cols: dict[str, np.ndarray], diag_t: np.ndarray, phi_hat2: np.ndarray) -> dict:
    """Decimated time series of a run for `plot_case`: every 10 ms, and the first 100 ms at full rate (the
    convergence of Fig. 3)."""
    n = sc.train.cars
    t = cols["t_s"]
    vs = v_star(sc, t)
    v = np.column_stack([cols[f"v_mps_{k}"] for k in range(1, n + 1)])
    dl = np.column_stack([cols[f"coupler_dl_m_{k}"] for k in range(1, n)]) if n > 1 else np.zeros((t.size, 0))
    k = max(1, round(0.01 / max(float(np.median(np.diff(t))), 1e-6)) if t.size > 1 else 1)
    idx = np.union1d(np.flatnonzero(t <= 0.1), np.arange(0, t.size, k))
    return {"t": t[idx], "v": v[idx], "v_star": vs[idx], "dl": dl[idx], "ve": (v - vs[:, None])[idx],
            "phi2": cols["phi_mps2_2"][idx] if "phi_mps2_2" in cols else np.zeros(idx.size),
            "diag_t": diag_t, "phi_hat2": phi_hat2}


def case_title(res: dict) -> str:
    return (f"seed 003 {res['label']}: cycle {res['cycle_ms']} ms, {res['bus']} bus, "
            f"max |Δl| {res['max_abs_dl_mm']} mm")


def run_plots(run: RunView) -> list[Path]:
    """consensus.png for a run."""
    if run.out_dir is None:
        return []
    sc = run.scenario
    diag = run.signals({"phi_hat": ("BECU2_CONS_DIAG", "PhiHat")})["phi_hat"]
    dl = max((float(np.max(np.abs(run.cols[f"coupler_dl_m_{k}"]))) for k in range(1, sc.train.cars)),
             default=0.0)
    title = (f"{sc.name} ({run.mode}, seed {sc.seed}): observer {'on' if sc.consensus.observer else 'off'}, "
             f"max |Δl| {1000 * dl:.2f} mm")
    return [plot_case(case_series(sc, run.cols, *diag), title, run.out_dir / "consensus.png")]


def plot_case(s: dict, title: str, path: Path) -> Path:
    """A run's speeds, couplers, tracking errors and car 2's observer (like Figs. 3-17 of seed 003) from
    its `case_series`."""
    plt = pyplot()
    fig, ax = plt.subplots(2, 2, figsize=(12, 8))
    t = s["t"]
    for k in range(s["v"].shape[1]):
        ax[0, 0].plot(t, kmh(s["v"][:, k]), lw=0.9, label=f"car {k + 1}")
        ax[1, 0].plot(t, kmh(s["ve"][:, k]), lw=0.9, label=f"car {k + 1}")
    ax[0, 0].plot(t, kmh(s["v_star"]), "k--", lw=0.9, label="v*(t)")
    for k in range(s["dl"].shape[1]):
        ax[0, 1].plot(t, s["dl"][:, k] * 100, lw=0.9, label=f"coupler {k + 1}-{k + 2}")
    for y in (-1, 1):
        ax[0, 1].axhline(y, color="r", ls=":", lw=0.8)
    ax[1, 1].plot(t, s["phi2"], lw=0.8, label="φ2/m2 (plant)")
    if len(s["diag_t"]):
        ax[1, 1].plot(s["diag_t"], s["phi_hat2"], lw=0.8, label="φ̂2 (BECU2 observer)")
    ax[1, 1].set_ylim(-3, 3)
    ax[0, 0].set(ylabel="speed [km/h]", title="speeds (Figs. 3, 7, 11, 14)")
    ax[0, 1].set(ylabel="relative displacement Δl [cm]", title="couplers (Figs. 4, 8, 13, 16)")
    ax[1, 0].set(ylabel="v − v* [km/h]", xlabel="t [s]", title="tracking error (Figs. 5, 9, 12, 15)")
    ax[1, 1].set(ylabel="[m/s²]", xlabel="t [s]", title="observer, car 2 (Figs. 6, 10, 17)")
    for a in ax.flat:
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_sweeps(cycle_rows: list[dict], lat_rows: list[dict], path: Path) -> Path:
    """max |Δl| over the consensus cycle (with the static bus load) and over the injected latency."""
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    for setting, case, mark in (("paper", 1, "o-"), ("can", 1, "s-"), ("can", 3, "s--"), ("can500", 1, "^-")):
        rows = [r for r in cycle_rows if r["setting"] == setting and r["case"] == case]
        a1.semilogy([r["cycle_ms"] for r in rows], [max(r["max_abs_dl_mm"], 1e-3) for r in rows], mark,
                    label=f"{setting} case {case}: max |Δl|")
    a1.axhline(10, color="r", ls=":", label="±1 cm")
    ax_load = a1.twinx()
    for setting, style in (("can", "k--"), ("can500", "k:")):
        rows = [r for r in cycle_rows if r["setting"] == setting and r["case"] == 1]
        ax_load.plot([r["cycle_ms"] for r in rows], [100 * r["bus_load_static"] for r in rows], style, lw=0.8,
                     label=f"static bus load ({setting})")
    ax_load.set_ylabel("bus load [%]")
    a1.set(xlabel="consensus cycle [ms]", ylabel="max |Δl| [mm]", title="cycle sweep")
    a1.legend(loc="upper left", fontsize=8)
    ax_load.legend(loc="lower right", fontsize=8)
    for setting, mark in (("paper", "o-"), ("can", "s-")):
        rows = sorted((r for r in lat_rows if r["setting"] == setting), key=lambda r: r["delay_ms"])
        a2.semilogy([r["delay_ms"] for r in rows], [max(r["max_abs_dl_mm"], 1e-3) for r in rows], mark,
                    label=setting)
    a2.axhline(10, color="r", ls=":")
    a2.legend(fontsize=8)
    a2.set(xlabel="injected latency on BECUn_CONS [ms]", ylabel="max |Δl| [mm]",
           title="latency sweep, case 1")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
