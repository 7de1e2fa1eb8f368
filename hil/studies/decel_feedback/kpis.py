"""The KPIs of the deceleration feedback (seed 004 §5.2, §6.4) for a run, from the plant's truth, and its
summary lines; kpis.json key "decel_feedback"."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hil.report.kpis import RunView, per_car, rounded
from hil.scenario.params import run_params
from plant_sim.params import PadParams

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

PAD_MU_NOMINAL = PadParams().mu_nominal   # μ_d0 of seed 004 eq. (32), the plant's pad model
# seed 004 §5.2: the band and the time outside it that engages the loop (firmware_py.decel_feedback)
BAND = (0.9, 1.1)

ENGAGE_AFTER_S = 0.5

MIN_SPEED_MPS = 1.0      # judged while the train is faster than this (the BCU's min_speed_mps)

MIN_TARGET_MPS2 = 0.2    # ... and the target above this (the BCU's min_target_mps2) ...

STEADY_TOL = 0.02        # ... and steady: the target through T_q within 2 % of it (steady_tol)

RATIO_TAU_S = 0.2        # the truth's deceleration is filtered like the BCU's ratio (τ, s)

FEEDBACK_SIGNALS = {"target": ("BCU_DEMAND", "TargetDecel"), "state": ("BCU_STATUS", "FbState"),
                    "phi": ("BCU_BRAKE_CORR", "FrictionPhi"), "slope": ("BCU_STATUS", "SlopeEst")}


def kpis(run: RunView) -> dict:
    """The figures of merit, judged from the BCU's own engagement where the trace shows it."""
    engaged = bcu_engagement_s(run.signals(FEEDBACK_SIGNALS))
    return feedback_kpis(run.scenario, run.cols, run.target, engaged_at_s=engaged)


def lag(t: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    """First-order lag of a sampled signal (exact for x held between samples)."""
    out = np.empty_like(x, dtype=float)
    acc = float(x[0]) if x.size else 0.0
    for k in range(x.size):
        if k:
            acc += (1.0 - np.exp(-(t[k] - t[k - 1]) / tau_s)) * (x[k] - acc)
        out[k] = acc
    return out


def feedback_ratio(scenario: Scenario, cols: dict[str, np.ndarray],
                  target: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times [s], actual/target deceleration, judged) from the plant's truth.

    actual: the mass-weighted train deceleration −v̇ through a first-order lag of RATIO_TAU_S
    (the car accelerations of one 1 ms step carry the couplers' oscillation); target: BCU_DEMAND.TargetDecel
    from the trace through the cylinder lag T_q (eq. (33), decel_feedback.tq_s) and the same filter.
    Judged, as the BCU judges: the demand is steady (the target through T_q within STEADY_TOL of
    the target) and above MIN_TARGET_MPS2, and the train is faster than MIN_SPEED_MPS."""
    n = scenario.train.cars
    t = cols["t_s"]
    masses = np.asarray(run_params(scenario).plant.train.masses_kg)
    decel = lag(t, -(per_car(cols, "a_mps2", n) @ masses) / masses.sum(), RATIO_TAU_S)
    tt, tv = target
    r0 = np.interp(t, tt, tv, left=0.0) if tt.size else np.zeros_like(t)
    expected = lag(t, lag(t, r0, scenario.decel_feedback.tq_s), RATIO_TAU_S)   # the same filter
    v = (per_car(cols, "v_mps", n) @ masses) / masses.sum()
    steady = np.abs(lag(t, r0, scenario.decel_feedback.tq_s) - r0) <= STEADY_TOL * r0
    judged = steady & (r0 >= MIN_TARGET_MPS2) & (v >= MIN_SPEED_MPS)
    ratio = np.where(judged, decel / np.maximum(expected, 1e-9), np.nan)
    return t, ratio, judged


def truth_engagement_s(t: np.ndarray, ratio: np.ndarray, judged: np.ndarray) -> float | None:
    """First time [s] at which the ratio has been outside BAND for more than
    ENGAGE_AFTER_S while judged (seed 004 §5.2's rule, on whatever ratio is given)."""
    lo, hi = BAND
    since = None
    for k in range(t.size):
        out = bool(judged[k]) and not (lo <= ratio[k] <= hi)
        if not out:
            since = None
        elif since is None:
            since = float(t[k])
        elif t[k] - since > ENGAGE_AFTER_S:
            return float(t[k])
    return None


def feedback_kpis(scenario: Scenario, cols: dict[str, np.ndarray], target: tuple[np.ndarray, np.ndarray],
                 engaged_at_s: float | None = None) -> dict:
    """Seed 004's figures of merit (§5.2, §6.4), from the plant's truth (`feedback_ratio` defines the ratio).

    * `engaged_at_s`: when the loop engaged: the BCU's own engagement (BCU_STATUS.FbState = ENGAGED in
      the trace) when given, else (`engage_source` "truth rule") the time at which §5.2's rule fires on the
      true ratio — the same instant for an open-loop run, which never engages;
    * `within_band_after_engagement`: the fraction of judged samples (10 ms) from then to the stop with the
      ratio within 90–110 %; `within_band_judged`: the same over every judged sample of the stop;
    * `ratio_min`, `ratio_max`, `ratio_rms_error`: over the judged samples after engagement;
    * `wsp_activations`: FILL→VENT transitions per car (seed 004: the loop must not cause WSP on dry rail);
    * `pad_mu_ratio_range`: the pad friction μ_d/μ_nominal of car 1 over the judged samples (eq. (25)).
    """
    t, ratio, judged = feedback_ratio(scenario, cols, target)
    source = "BCU"
    if engaged_at_s is None:
        engaged_at_s, source = truth_engagement_s(t, ratio, judged), "truth rule"
    lo, hi = BAND
    inside = judged & (ratio >= lo) & (ratio <= hi)
    out: dict = {"closed_loop": scenario.decel_feedback.closed_loop, "engaged_at_s": rounded(engaged_at_s, 3),
                 "engage_source": source, "band": list(BAND),
                 "within_band_judged": rounded(inside.sum() / max(int(judged.sum()), 1))}
    after = judged & (t >= engaged_at_s) if engaged_at_s is not None else np.zeros_like(judged)
    if after.any():
        r = ratio[after]
        out["within_band_after_engagement"] = rounded(inside[after].sum() / after.sum())
        out["window_s"] = [round(float(t[after][0]), 3), round(float(t[after][-1]), 3)]
        out["ratio_min"], out["ratio_max"] = rounded(float(r.min())), rounded(float(r.max()))
        out["ratio_rms_error"] = rounded(float(np.sqrt(np.mean((r - 1.0) ** 2))))
    else:
        out["within_band_after_engagement"] = None
    n = scenario.train.cars
    vent = per_car(cols, "wsp_valve", n) == 2
    out["wsp_activations"] = [int(k) for k in np.sum(vent[1:] & ~vent[:-1], axis=0) + vent[0]]
    if "mu_pad_1" in cols and judged.any():
        mu = cols["mu_pad_1"][judged] / PAD_MU_NOMINAL
        out["pad_mu_ratio_range"] = [rounded(float(mu.min())), rounded(float(mu.max()))]
    return out


def bcu_engagement_s(sig: dict[str, tuple[np.ndarray, np.ndarray]]) -> float | None:
    """First time [s] the trace's BCU_STATUS.FbState says ENGAGED (2), or None."""
    ts, vs = sig.get("state", (np.array([]), np.array([])))
    hit = np.flatnonzero(vs == 2)
    return float(ts[hit[0]]) if hit.size else None


def summary_lines(k: dict) -> list[str]:
    """The KPIs as summary lines."""
    loop = "closed loop" if k["closed_loop"] else "open loop (monitor only)"
    eng = k["engaged_at_s"]
    lines = [f"decel feedback          {loop}; engagement "
             + (f"at {eng:.2f} s ({k['engage_source']})" if eng is not None else "condition never met")]
    if k.get("within_band_after_engagement") is not None:
        lines.append(f"actual/target in 90-110% {100 * k['within_band_after_engagement']:.1f} % of the time "
                     f"after engagement ({k['window_s'][0]:.1f}-{k['window_s'][1]:.1f} s; ratio "
                     f"{k['ratio_min']:.3f}-{k['ratio_max']:.3f}, rms error {k['ratio_rms_error']:.3f})")
    lines.append(f"  ... over the whole stop {100 * k['within_band_judged']:.1f} %"
                 + ("; pad friction μ_d/μ_d0 {:.3f}-{:.3f}".format(*k["pad_mu_ratio_range"])
                    if k.get("pad_mu_ratio_range") else "")
                 + "   (paper, Figs. 19-20: closed loop smoother and closer to 1.32 m/s², no figure given)")
    return lines


# What each KPI above is, for report.html (hil.report.kpi_info): (display name, unit, meaning[, per car])
KPI_INFO = {
    "closed_loop": ("closed loop", "yes/no",
                    "the BCU corrects the pressure (φ, eq. 34); no: it monitors only"),
    "engaged_at_s": ("engaged at", "s",
                     "when the loop engaged (BCU_STATUS.FbState = ENGAGED, else §5.2's rule on the true "
                     "ratio); none: never"),
    "engage_source": ("engagement from", "text", "BCU (the trace) or truth rule"),
    "band": ("band", "1", "[low, high] of actual/target deceleration the loop keeps to (§5.2)"),
    "within_band_judged": ("within band, whole stop", "1",
                           "fraction of judged samples with the ratio in the band (judged: steady target "
                           "> 0.2 m/s², train > 1 m/s)"),
    "within_band_after_engagement": ("within band after engagement", "1",
                                     "the same from the engagement to the stop; none: not engaged"),
    "window_s": ("judged window", "s", "[start, end] of the judged samples after engagement"),
    "ratio_min": ("min ratio", "1", "smallest actual/target deceleration after engagement"),
    "ratio_max": ("max ratio", "1", "largest actual/target deceleration after engagement"),
    "ratio_rms_error": ("ratio RMS error", "1", "RMS of ratio − 1 after engagement"),
    "wsp_activations": ("WSP activations", "count", "times the car's applied WSP valve went to VENT", True),
    "pad_mu_ratio_range": ("pad friction μ_d/μ_d0", "1", "[min, max] of car 1's pad friction over nominal "
                                                         "(eq. 25), judged samples"),
}
