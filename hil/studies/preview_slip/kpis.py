"""The KPIs of slip control with preview (seed 000) for a run: the tracking-error norm n_e of §3.2 and
the α each car's slip loop achieves, from the plant's truth and the BECUs' SlipRef frames; kpis.json
key "preview_slip"."""

from __future__ import annotations

import math

import numpy as np

from hil.report.kpis import RunView, rounded


def tracking_norm(cols: dict, n: int) -> float:
    """n_e = (1/S) √(∫_0^S ‖e(ξ)‖² dξ) of seed 000 §3.2, e_i = σ°(x_i, v) − σ_i, over x_1 (trapezoid)."""
    x = cols["x_m_1"]
    e2 = sum((cols[f"sigma_opt_{k}"] - cols[f"slip_ratio_{k}"]) ** 2 for k in range(1, n + 1))
    s = float(x[-1] - x[0])
    if s <= 0:
        return float("nan")
    return math.sqrt(float(np.trapezoid(e2, x))) / s


def achieved_alpha(cols: dict, k: int, ref: np.ndarray) -> float:
    """α [1/s] of eq. (4) that car k's slip loop achieves, from its first application: 1/t63, t63 the time
    σ_k takes from the start of braking to reach 1 − 1/e of the reference Σ_k° (from its SlipRef frames,
    held) — the time constant of a first-order loop.  NaN if it never gets there."""
    t, sig = cols["t_s"], cols[f"slip_ratio_{k}"]
    if ref.size == 0 or t.size < 3:
        return float("nan")
    idx = np.searchsorted(ref[:, 0], t, side="right") - 1
    r = np.where(idx >= 0, ref[np.maximum(idx, 0), 1], np.nan)
    reached = np.flatnonzero(np.isfinite(r) & (sig >= (1.0 - math.exp(-1.0)) * r))
    if reached.size == 0:
        return float("nan")
    t63 = float(t[reached[0]] - ref[0, 0])
    return 1.0 / t63 if t63 > 0 else float("nan")


def kpis(run: RunView) -> dict:
    """* `tracking_norm`: n_e of §3.2 over the run (`tracking_norm`);
    * `mean_abs_slip_error`: per car, mean |σ°(x_i, v) − σ_i| over the samples where the car moves;
    * `achieved_alpha_per_s`: per car, 1/t63 of its first application (`achieved_alpha`; None: never
      reached), next to the design α of eq. (4) `alpha_design_per_s`."""
    pv = run.scenario.preview
    n = run.scenario.train.cars
    cols = run.cols
    refs = run.signals({f"ref{k}": (f"BECU{k}_SLIP_REF", "SlipRef") for k in range(1, n + 1)})
    alphas = []
    for k in range(1, n + 1):
        t_ref, v_ref = refs[f"ref{k}"]
        a = achieved_alpha(cols, k, np.column_stack([t_ref, v_ref]) if t_ref.size else np.zeros((0, 2)))
        alphas.append(rounded(a, 3) if math.isfinite(a) else None)
    errors = []
    for k in range(1, n + 1):
        moving = cols[f"v_mps_{k}"] > 0.5
        e = np.abs(cols[f"sigma_opt_{k}"] - cols[f"slip_ratio_{k}"])[moving]
        errors.append(rounded(float(e.mean()), 5) if e.size else None)
    ne = tracking_norm(cols, n)
    return {"mode": pv.mode, "method": pv.method, "sigma_source": pv.sigma_source,
            "tracking_norm": rounded(ne, 6) if math.isfinite(ne) else None, "mean_abs_slip_error": errors,
            "achieved_alpha_per_s": alphas, "alpha_design_per_s": pv.alpha_per_s}


def summary_lines(k: dict) -> list[str]:
    alphas = " ".join("—" if a is None else f"{a:.2f}" for a in k["achieved_alpha_per_s"])
    errors = " ".join("—" if e is None else f"{e:.4f}" for e in k["mean_abs_slip_error"])
    ne = "—" if k["tracking_norm"] is None else f"{k['tracking_norm']:.5f}"
    return [f"slip reference          {k['method']} ({k['mode']} mode, {k['sigma_source']} σ°): tracking "
            f"norm n_e {ne}",
            f"  ... per car           mean |σ° − σ| {errors}; achieved α {alphas} 1/s (design "
            f"{k['alpha_design_per_s']:g})"]


# What each KPI above is, for report.html (hil.report.kpi_info): (display name, unit, meaning[, per car])
KPI_INFO = {
    "mode": ("mode", "text",
             "paper: the reduced slip model of eq. (4) in the plant; full: the wheelset plant, each BECU's "
             "slip loop tracking the reference"),
    "method": ("slip reference", "text", "Lf (car 1's σ°), Bd (own σ°), Dp (preview, eqs. 9–11) or ideal "
                                         "(the limit S°)"),
    "sigma_source": ("σ° source", "text", "oracle (the plant's true σ°) or estimate (each BECU's estimator)"),
    "tracking_norm": ("tracking norm n_e", "1/√m",
                      "(1/S)·√(∫‖σ° − σ‖² dx) over car 1's travel S (§3.2); smaller: closer to the "
                      "optimum"),
    "mean_abs_slip_error": ("mean |σ° − σ|", "1",
                            "mean distance of the car's slip ratio from the optimal one while it moves "
                            "(> 0.5 m/s)", True),
    "achieved_alpha_per_s": ("achieved α", "1/s",
                             "1/t63 of the car's first application: σ reaching 1 − 1/e of its SlipRef; none "
                             "if never", True),
    "alpha_design_per_s": ("design α", "1/s", "α of eq. (4) the scenario asks of the slip loop"),
}
