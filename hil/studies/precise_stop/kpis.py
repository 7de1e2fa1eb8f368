"""The KPIs of precise stopping (seed 002 §VII) for a run, from the plant's truth: the stop error and the
jerk; kpis.json key "precise_stop"."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hil.report.kpis import RunView, per_car, rounded

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

# Seed 002's published stop errors (§VII): the adaptive search without / with the differentiation unit
PAPER_STOP_ERROR_M = {"adaptive": "±25–45 m (Fig. 5)", "adaptive_diff": "±2–7 m (Fig. 6)"}
JERK_DT_S = 0.1         # jerk = difference of the train deceleration over 0.1 s (a ride-comfort sampling)


def kpis(run: RunView) -> dict:
    return stop_kpis(run.scenario, run.cols, run.target, run.i_stop if run.stopped else None)


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
    masses = np.asarray(scenario.train.masses())
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
            f"over {k['braking_s']:.1f} s of braking"]


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
}
