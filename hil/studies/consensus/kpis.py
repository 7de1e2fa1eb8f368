"""The KPIs of consensus braking (seed 003) for a run, from the plant's truth and BECU2's observer
frames; kpis.json key "consensus".  The reproduction (reproduce.py) reduces each of its runs the same way.

- max |Δl|: largest coupler deformation over every 1 ms plant step [mm]; holds: ≤ θ₂ = 10 mm.
- convergence time: from t0 (case 1) or from the end of skidding (case 2), the time after which every
  car's |v_i − v*| stays within a tolerance (TOLS_MPS: 1 km/h and 0.1 km/h) until the next event or
  the end [s].
- tracking RMS: RMS of v_i − v* over all cars from RMS_FROM (case 1: 1 s; case 2: recovery + 1 s; case
  3: the disturbance window from 6 s) [m/s].
- observer convergence: first time after t0 from which |φ̂₂ − φ₂/m₂| ≤ OBS_TOL for 100 ms (BECU2's DIAG
  frame against the plant's truth) [ms].
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hil.report.kpis import RunView
from hil.scenario.params import mps

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

TOLS_MPS = (mps(1.0), mps(0.1))   # convergence tolerances on |v_i − v*|: 1 km/h and 0.1 km/h (chosen)
OBS_TOL = 0.1                  # observer tolerance on |φ̂ − φ/m| [m/s²] (chosen)
THETA_M = 0.01                 # θ2 = −θ1 = 1 cm, Table 2


def settle_time(t: np.ndarray, ok: np.ndarray, start: float, end: float) -> float | None:
    """Time from `start` after which `ok` holds until `end` [s] (None: never)."""
    win = (t >= start) & (t < end)
    if not win.any():
        return None
    tw, okw = t[win], ok[win]
    if not okw[-1]:
        return None
    bad = np.flatnonzero(~okw)
    if bad.size == 0:
        return 0.0
    return float(tw[bad[-1] + 1] - start)          # okw[-1] holds, so bad[-1] + 1 is inside


def v_star(scenario: Scenario, t: np.ndarray) -> np.ndarray:
    """The virtual leader's speed v*(t) [m/s] (eq. (9) seed 003: constant deceleration a* from v*(t0))."""
    c = scenario.consensus
    return np.maximum(0.0, mps(c.v_ref_kmh) - mps(c.decel_kmh_s) * t)


def consensus_figures(sc: Scenario, cols: dict[str, np.ndarray], max_dl: float, diag_t: np.ndarray,
                      diag_phi_hat: np.ndarray) -> dict:
    """The figures of one run (module docstring): `max_dl` is the largest |Δl| over every plant step [m];
    `diag_t`, `diag_phi_hat` BECU2's observer estimates (BECU2_CONS_DIAG.PhiHat) and their times [s]."""
    c = sc.consensus
    n = sc.train.cars
    t = cols["t_s"]
    vs = v_star(sc, t)
    v = np.column_stack([cols[f"v_mps_{k}"] for k in range(1, n + 1)])
    ve = v - vs[:, None]
    end = float(t[-1]) + 1e-9
    events = [e for e in (c.rail_change_s, c.disturbance_start_s) if e is not None]
    first_event = min(events) if events else end
    recovery = None
    conv, conv_after = [], []
    for tol in TOLS_MPS:
        ok = np.all(np.abs(ve) <= tol, axis=1)
        conv.append(settle_time(t, ok, 0.0, first_event))
        if c.rail_change_s is not None:
            recovery = c.rail_change_s + c.skid_s
            nxt = c.disturbance_start_s if c.disturbance_start_s and c.disturbance_start_s > recovery else end
            conv_after.append(settle_time(t, ok, recovery, nxt))
        else:
            conv_after.append(None)
    rms_from = c.disturbance_start_s if c.disturbance_start_s is not None else (
        recovery + 1.0 if recovery is not None else 1.0)
    sel = t >= rms_from
    rms = float(np.sqrt(np.mean(ve[sel] ** 2))) if sel.any() else None
    obs_ms = None
    if diag_t.size:
        td = np.asarray(diag_t)
        phi_true = np.interp(td, t, cols["phi_mps2_2"])
        good = np.abs(np.asarray(diag_phi_hat) - phi_true) <= OBS_TOL
        win = max(1, round(0.1 / max(np.median(np.diff(td)), 1e-3))) if td.size > 1 else 1
        for k in range(len(good) - win):
            if good[k:k + win].all():
                obs_ms = round(float(td[k]) * 1000, 1)
                break
    return {
        "max_abs_dl_mm": round(max_dl * 1000, 3), "holds_1cm": bool(max_dl <= THETA_M),
        "converged_s": None if conv[0] is None else round(conv[0], 3),
        "converged_fine_s": None if conv[1] is None else round(conv[1], 3),
        "converged_after_recovery_s": None if conv_after[0] is None else round(conv_after[0], 3),
        "converged_after_recovery_fine_s": None if conv_after[1] is None else round(conv_after[1], 3),
        "tracking_rms_mps": None if rms is None else round(rms, 5), "rms_from_s": rms_from,
        "final_abs_ve_max_mps": round(float(np.max(np.abs(ve[-1]))), 4),
        "observer_converged_ms": obs_ms,
    }


def kpis(run: RunView) -> dict:
    cols = run.cols
    n = run.scenario.train.cars
    dl = [np.max(np.abs(cols[f"coupler_dl_m_{k}"])) for k in range(1, n) if cols[f"coupler_dl_m_{k}"].size]
    diag = run.signals({"phi_hat": ("BECU2_CONS_DIAG", "PhiHat")})["phi_hat"] if n > 1 else (np.zeros(0),) * 2
    return {"observer": run.scenario.consensus.observer,
            **consensus_figures(run.scenario, cols, float(max(dl, default=0.0)), *diag)}


def summary_lines(k: dict) -> list[str]:
    def s(x, unit=" s"):
        return "—" if x is None else f"{x:g}{unit}"

    return [f"consensus braking       max |Δl| {k['max_abs_dl_mm']:.2f} mm "
            f"({'within' if k['holds_1cm'] else 'OUTSIDE'} ±1 cm); converged to 1 / 0.1 km/h in "
            f"{s(k['converged_s'])} / {s(k['converged_fine_s'])}"
            + (f", after the recovery {s(k['converged_after_recovery_s'])} / "
               f"{s(k['converged_after_recovery_fine_s'])}" if k["converged_after_recovery_s"] is not None
               else ""),
            f"  ... observer {'on' if k['observer'] else 'off'}: converged at "
            f"{s(k['observer_converged_ms'], ' ms')}; tracking rms {s(k['tracking_rms_mps'], ' m/s')} from "
            f"{k['rms_from_s']:g} s   (paper: ±1 cm, "
            f"convergence < 0.04 s)"]


def verdicts(k: dict) -> list[tuple]:
    """The study's checks for report.html: (check, value, criterion, passed), on plant truth."""
    return [("couplers within ±1 cm", f"max |Δl| {k['max_abs_dl_mm']:.2f} mm", "≤ 10 mm (θ2, Table 2)",
             k["holds_1cm"])]


# What each KPI above is, for report.html (hil.report.kpi_info): (display name, unit, meaning[, per car])
KPI_INFO = {
    "observer": ("observer", "yes/no", "u_i3 compensates the observer's estimate (eq. 29)"),
    "max_abs_dl_mm": ("max |Δl|", "mm", "largest coupler deformation over every 1 ms plant step"),
    "holds_1cm": ("within ±1 cm", "yes/no", "max |Δl| ≤ θ2 = 10 mm (Table 2)"),
    "converged_s": ("converged to 1 km/h", "s",
                    "from t0, the time after which every |v_i − v*| stays within 1 km/h until the first "
                    "event; none: never"),
    "converged_fine_s": ("converged to 0.1 km/h", "s", "the same within 0.1 km/h"),
    "converged_after_recovery_s": ("converged after recovery, 1 km/h", "s",
                                   "the same from the end of skidding (case 2); none without a rail change"),
    "converged_after_recovery_fine_s": ("converged after recovery, 0.1 km/h", "s",
                                        "the same within 0.1 km/h"),
    "tracking_rms_mps": ("tracking RMS", "m/s", "RMS of v_i − v* over all cars from rms_from_s"),
    "rms_from_s": ("RMS from", "s", "start of the tracking RMS (1 s, recovery + 1 s, or the disturbance)"),
    "final_abs_ve_max_mps": ("final max |v_i − v*|", "m/s",
                             "largest speed error of any car at the last sample"),
    "observer_converged_ms": ("observer converged", "ms",
                              "first time from which |φ̂₂ − φ₂/m₂| ≤ 0.1 m/s² for 100 ms (BECU2's DIAG); "
                              "none: never"),
}
