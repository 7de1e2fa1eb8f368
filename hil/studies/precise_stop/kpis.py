"""The KPIs of precise stopping (seed 002 §VII) for a run, from the plant's truth: the stop error, the
fluctuations about the braking curve (the paper's S, V and a) and the jerk; kpis.json key "precise_stop"."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hil.report.kpis import RunView, per_car, rounded, train_decel
from hil.scenario.params import run_params

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

# Seed 002's published stop errors (§VII): the adaptive search without / with the differentiation unit
PAPER_STOP_ERROR_M = {"adaptive": "±25–45 m (Fig. 5)", "adaptive_diff": "±2–7 m (Fig. 6)"}
#: ... and the fluctuations about the curve it reports (§VII b): S [m], V [m/s], a [m/s²]
PAPER_FLUCTUATION = {"adaptive": (100.0, 3.0, 0.15), "adaptive_diff": (20.0, 1.0, 0.7)}
JERK_DT_S = 0.1         # jerk = difference of the train deceleration over 0.1 s (a ride-comfort sampling)
APPLY_LAG_S = 1.0       # the brake's lag after its first application ramp, for the a window (chosen)
CURVE_SIGNALS = {"ref": ("BCU_STOP", "RefSpeed"), "to_go": ("BCU_STOP", "DistanceToGo")}


def kpis(run: RunView) -> dict:
    i_stop = run.i_stop if run.stopped else None
    k = stop_kpis(run.scenario, run.cols, run.target, i_stop)
    sig = run.signals(CURVE_SIGNALS)
    k.update(curve_fluctuations(run.scenario, run.cols, sig["ref"], sig["to_go"], i_stop))
    return k


def curve_fluctuations(scenario: Scenario, cols: dict[str, np.ndarray], ref: tuple[np.ndarray, np.ndarray],
                       to_go: tuple[np.ndarray, np.ndarray], i_stop: int | None) -> dict:
    """Seed 002's fluctuations of S, V and a about the theoretical curve (§VII b), from the plant's truth
    against the curve the BCU follows, as BCU_STOP.RefSpeed (V_th, every 100 ms) carries it.

    The curve (firmware_py.stopping.Curve) ends at the target, so its distance to go is
    D_th = V_th²/(2 a_c) (plus v_0·(t_0 − t) before its start t_0, while it coasts) and S − S_th =
    D_th − (target − x), x = car 1's front (truth).  a_c and t_0: for the time curves of the adaptive
    methods from a least-squares line through V_th over time (the samples below the curve's initial speed
    v_0); for pi, whose curve is V_th(s) = √(2 a_c s) in the distance
    to go s the BCU believes, the median of V_th²/(2 s).  Window: from the first BCU_STOP with
    RefSpeed > 0 (the BCU follows the curve) to the standstill (the end of the run when the train did not
    stop); the curve stands at the target after its end.

    * `curve_s_dev_max_m`: max |S − S_th| [m] over the window (at the standstill it is the stop error);
    * `curve_v_dev_max_mps`: max |V − V_th| [m/s] over the window, V = car 1's speed;
    * `curve_a_dev_max_mps2`: max |a − a_th| [m/s²], a = the train's mass-weighted deceleration, a_th =
      a_c while the curve runs, from the brake's first application (the first time a reaches a_c, at the
      latest APPLY_LAG_S after the valve's application ramp, centred on t_0, has ended; the application
      itself is not a fluctuation) to the curve's end or the last sample before the standstill;
    * `curve_a_mps2`: a_c.  All None when the run has no curve (no trace, or the BCU never followed one).
    """
    none = {"curve_a_mps2": None, "curve_s_dev_max_m": None, "curve_v_dev_max_mps": None,
            "curve_a_dev_max_mps2": None}
    tr, vr = ref
    on = np.flatnonzero(vr > 0.0) if tr.size else np.zeros(0, dtype=int)
    if on.size < 3:
        return none
    t = cols["t_s"]
    t_on = float(tr[on[0]])
    v0 = float(vr[on[0]])
    if scenario.precise_stop.method == "pi":
        tg, dg = to_go
        sg = np.interp(tr[on], tg, dg) if tg.size else np.zeros(on.size)
        use = sg > 1.0
        if not use.any():
            return none
        a_c = float(np.median(vr[on][use] ** 2 / (2.0 * sg[use])))
    else:
        ramp = on[(vr[on] < v0 - 0.05) & (vr[on] > 0.05)]
        if ramp.size < 2:
            return none
        slope, icpt = np.polyfit(tr[ramp], vr[ramp], 1)
        a_c = float(-slope)
    if not a_c > 0.0:
        return none
    # the time curves start braking at t0, after the valve's lead: before it the curve coasts at v0
    t0 = (v0 - icpt) / slope if scenario.precise_stop.method != "pi" else t_on
    target_m = [e.target_stop_m for e in scenario.desk if e.target_stop_m is not None][-1]
    i_end = i_stop if i_stop is not None else len(t) - 1
    w = np.flatnonzero((t >= t_on) & (np.arange(len(t)) <= i_end))
    if w.size == 0:
        return none
    v_th = np.interp(t[w], tr, vr)
    if i_stop is not None:                 # after the curve's end and at the standstill: V_th = 0
        v_th = np.where(t[w] > float(tr[on[-1]]) + 0.1, 0.0, v_th)
    d_th = v_th ** 2 / (2.0 * a_c) + np.where(t[w] < t0, v0 * (t0 - t[w]), 0.0)   # the curve's to go
    s_dev = d_th - (target_m - cols["x_m_1"][w])
    v_dev = cols["v_mps_1"][w] - v_th
    a = train_decel(scenario, cols)[w]
    runs = (v_th > 0.0) & (v_th < v0 - 1e-9) if scenario.precise_stop.method != "pi" else v_th > 0.0
    runs &= w < i_end                      # not the standstill's own sample (the train stops in it)
    reached = np.flatnonzero(runs & (a >= a_c))
    t_applied = t0 + (t0 - t_on) + APPLY_LAG_S      # the valve's application ramp (centred on t0) and the lag
    if reached.size:
        t_applied = min(t_applied, float(t[w][reached[0]]))
    a_win = runs & (t[w] >= t_applied)
    return {"curve_a_mps2": rounded(a_c),
            "curve_s_dev_max_m": rounded(float(np.max(np.abs(s_dev))), 3),
            "curve_v_dev_max_mps": rounded(float(np.max(np.abs(v_dev))), 3),
            "curve_a_dev_max_mps2": (rounded(float(np.max(np.abs(a[a_win] - a_c))), 3) if a_win.any()
                                     else None)}


def stop_kpis(scenario: Scenario, cols: dict[str, np.ndarray], target: tuple[np.ndarray, np.ndarray],
                      i_stop: int | None) -> dict:
    """Seed 002's figures of merit, from the plant's truth.

    * `target_m`: the last target stop point the desk gave (track position of the leading car's front);
    * `stop_error_m`: car 1's front at the standstill (every car below the plant's standstill speed) minus
      the target [m]; + = overshoot; None when the train did not stop;
    * `jerk_p95_mps3`, `jerk_max_mps3`: |d/dt| of the train's mass-weighted deceleration, differenced over
      JERK_DT_S = 0.1 s, from the first non-zero target deceleration of the BCU to the standstill: the 95th
      percentile and the maximum [m/s³];
    * `braking_s`: that window's length [s]; `method`: the BCU's method ([precise_stop] method).
    """
    t = cols["t_s"]
    n = scenario.train.cars
    target_m = [e.target_stop_m for e in scenario.desk if e.target_stop_m is not None][-1]
    masses = np.asarray(run_params(scenario).plant.train.masses_kg)
    decel = -(per_car(cols, "a_mps2", n) @ masses) / masses.sum()
    tt, tv = target
    on = np.flatnonzero(tv > 0.0) if tt.size else np.zeros(0, dtype=int)
    t_on = float(tt[on[0]]) if on.size else float(t[0])
    t_end = float(t[i_stop]) if i_stop is not None else float(t[-1])
    grid = np.arange(t_on, t_end, JERK_DT_S)
    jerk = np.abs(np.diff(np.interp(grid, t, decel))) / JERK_DT_S if grid.size > 1 else np.zeros(1)
    return {
        "method": scenario.precise_stop.method,
        "target_m": target_m,
        "stop_error_m": rounded(float(cols["x_m_1"][i_stop]) - target_m, 3) if i_stop is not None else None,
        "stopped": i_stop is not None,
        "braking_s": rounded(t_end - t_on, 3),
        "jerk_p95_mps3": rounded(float(np.percentile(jerk, 95))),
        "jerk_max_mps3": rounded(float(jerk.max())),
    }


def summary_lines(k: dict) -> list[str]:
    """The precise-stop KPIs as summary lines, with seed 002's figure for the paper's methods."""
    paper = PAPER_STOP_ERROR_M.get(k["method"])
    err = k["stop_error_m"]
    return ["stop error              " + (f"{err:+.3f} m" if err is not None else "— (train did not stop)")
            + f" at target {k['target_m']:.2f} m, method {k['method']}"
            + (f"   (paper: {paper})" if paper else ""),
            f"jerk                    p95 {k['jerk_p95_mps3']:.3f} m/s³, max {k['jerk_max_mps3']:.3f} m/s³ "
            f"over {k['braking_s']:.1f} s of braking"] + fluctuation_lines(k)


def fluctuation_lines(k: dict) -> list[str]:
    """The fluctuations about the curve as one summary line, with seed 002's for the paper's methods."""
    if k.get("curve_s_dev_max_m") is None:
        return []
    a_dev = k["curve_a_dev_max_mps2"]
    paper = PAPER_FLUCTUATION.get(k["method"])
    a_txt = f"a ±{a_dev:.3f} m/s²" if a_dev is not None else "a —"
    return [f"curve fluctuation       S ±{k['curve_s_dev_max_m']:.2f} m, "
            f"V ±{k['curve_v_dev_max_mps']:.3f} m/s, {a_txt}"
            + (f"   (paper: S ±{paper[0]:g} m, V ±{paper[1]:g} m/s, a ±{paper[2]:g} m/s²)" if paper else "")]


# What each KPI above is, for report.html (hil.report.kpi_info): (display name, unit, meaning[, per car])
KPI_INFO = {
    "method": ("method", "text",
               "the BCU's stopping method: adaptive (Fig. 2), adaptive_diff (Fig. 3) or pi"),
    "target_m": ("target stop point", "m", "the desk's last target: track position of car 1's front"),
    "stop_error_m": ("stop error", "m", "car 1's front at the standstill − the target; + = overshoot; none "
                                        "when the train did not stop"),
    "stopped": ("stopped", "yes/no", "the train came to a standstill"),
    "braking_s": ("braking time", "s", "from the BCU's first non-zero target deceleration to the standstill"),
    "jerk_p95_mps3": ("jerk, 95th percentile", "m/s³",
                      "95th percentile of |d/dt| of the train deceleration (over 0.1 s) while braking"),
    "jerk_max_mps3": ("jerk, max", "m/s³", "largest |d/dt| of the train deceleration (over 0.1 s) while "
                                           "braking"),
    "curve_a_mps2": ("curve deceleration a_c", "m/s²",
                     "the deceleration of the braking curve the BCU follows (from BCU_STOP.RefSpeed)"),
    "curve_s_dev_max_m": ("path fluctuation max |S − S_th|", "m",
                          "largest distance of car 1's front from where the curve puts it, from the start of "
                          "the curve following to the standstill (seed 002 §VII: ±100 m / ±20 m)"),
    "curve_v_dev_max_mps": ("speed fluctuation max |V − V_th|", "m/s",
                            "largest difference of the train's speed from the curve's, same window "
                            "(seed 002 §VII: ±3 m/s / ±1 m/s)"),
    "curve_a_dev_max_mps2": ("deceleration fluctuation max |a − a_th|", "m/s²",
                             "largest difference of the train's deceleration from the curve's a_c, from the "
                             "brake's first application to the curve's end "
                             "(seed 002 §VII: ±0.15 / ±0.7 m/s²)"),
}
