"""The KPIs of the wheel-slip governor (seed 001) for a run, from the plant's truth (decelerations in g,
g = 9.81 m/s²), and its summary lines; kpis.json key "wheel_slip"."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hil.report.kpis import MOVING_MPS, RunView, per_car, rounded
from hil.scenario.params import run_params
from hil.studies.wheel_slip.scenario import design_slip_mps
from plant_sim.adhesion import mu_slip_speed_scalar
from plant_sim.params import G_MPS2

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

SETTLE_BAND = 0.02      # settled: within ±2 % of the steady-state deceleration from then on (chosen)

# Seed 001's published figures (Danielson & Di Cairano, ACC 2020, §IV-A), printed next to ours
PAPER_FIG8_MEAN_ERROR_G = 0.0718      # Fig. 8a, no governor: lim 1/T ∫ r⁰ − v̇ dt (WSP limit cycle)
PAPER_FIG8_SS_ERROR_G = 0.0682        # Fig. 8b, governor: lim r⁰ − v̇, reference cut to r ≈ 0.2 g
PAPER_FIG8_STOPPING_GAIN_M = 1.62     # §IV-A: the governor improves stopping accuracy over 30 s by this


def kpis(run: RunView) -> dict:
    return governor_kpis(run.scenario, run.cols, run.target, run.t_brake, run.i_stop)


def governor_kpis(scenario: Scenario, cols: dict[str, np.ndarray], target: tuple[np.ndarray, np.ndarray],
                 t_brake: float, i_stop: int) -> dict:
    """Seed 001's figures of merit of a run, from the plant's truth (decelerations in g, g = 9.81 m/s²).

    * braking window: from the first brake command to the stop or the end of the run, samples (10 ms)
      where the train moves (faster than MOVING_MPS); r⁰ is BCU_DEMAND.TargetDecel from the trace, v̇ the
      mass-weighted train deceleration of the truth.
    * `max_slip_every_step_mps`: per car, the largest true slip speed v − rω over EVERY 1 ms plant step
      up to the window's last sample (plant truth column slip_speed_max_mps, not the 10 ms samples);
      `slip_within_limit`: whether that is ≤ s̄ = `slip_limit_mps` (wheel_slip.slip_max_mps, eq. (8)).
      On seed 000's rail curves (plant.adhesion = "track") s̄(v) moves with the speed
      (hil.studies.wheel_slip.scenario.design_slip_mps): `slip_limit_mps` is None, `slip_limit_share_max`
      is per car the largest s / s̄(v) over the window's 10 ms truth samples, and `slip_within_limit`
      whether that is ≤ 1.
    * `wsp_activations`, `wsp_time_s`: per car, FILL→VENT transitions of the applied WSP valve and the
      time it was not FILL [s].
    * `mean_error_g`: mean of r⁰ − v̇ over the window (the paper's lim 1/T ∫ r⁰ − v̇ dt, Fig. 8a).
    * steady state: the last `wheel_slip.steady_state_window_s` of the window, at most its second half;
      `steady_state_error_g` is mean r⁰ − v̇ there, `steady_state_bound_g` = r⁰ − μ(s̄)·g with μ the
      scenario's adhesion curve (plant.adhesion = "slip_speed"; else None): the smallest steady error
      any reference can give without s > s̄, and `steady_state_excess_g` = error − bound.
    * `settling_time_s`: from the brake command to the first sample after which v̇ stays within
      ±SETTLE_BAND of its steady-state mean until the window ends; None (not settled) when v̇ leaves
      that band inside the steady-state window itself (a limit cycle);
      `overshoot_g`: largest v̇ in the window less that mean.
    * `distance_m`: distance travelled over the window; `beyond_ideal_m`: how much farther than ideal
      braking at exactly r⁰(t) from the same start, = ∬ (r⁰ − v̇) dt². The paper's stopping-accuracy
      effect (1.62 m) is the difference of `distance_m` between the runs without and with governor.
    """
    n = scenario.train.cars
    t = cols["t_s"]
    v = per_car(cols, "v_mps", n)
    a = per_car(cols, "a_mps2", n)
    masses = np.asarray(run_params(scenario).plant.train.masses_kg)
    decel = -(a @ masses) / masses.sum()
    tt, tv = target
    r0 = np.interp(t, tt, tv, left=0.0) if tt.size else np.zeros_like(t)
    window = (t >= t_brake) & (np.arange(len(t)) <= i_stop) & np.any(v > MOVING_MPS, axis=1)
    idx = np.flatnonzero(window)
    ws = scenario.wheel_slip
    scheduled = run_params(scenario).plant.adhesion.slip_speed_peak is None   # seed 000's rail curves
    s_bar = None if scheduled else ws.slip_max_mps
    out: dict = {"governor": ws.governor, "slip_limit_mps": s_bar, "paper_figure": ws.paper_figure}
    wsp = per_car(cols, "wsp_valve", n)
    vent = wsp == 2
    out["wsp_activations"] = [int(k) for k in np.sum(vent[1:] & ~vent[:-1], axis=0) + vent[0]]
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    out["wsp_time_s"] = [round(float(k) * dt, 3) for k in np.sum(wsp != 0, axis=0)]
    if idx.size < 2:
        out["window_s"] = None
        return out
    i1 = int(idx[-1])
    tw, dw, rw = t[idx], decel[idx], r0[idx]
    s_max = per_car(cols, "slip_speed_max_mps", n)[i1]
    out["max_slip_every_step_mps"] = [round(float(s), 5) for s in s_max]
    if scheduled:
        share = np.max(per_car(cols, "slip_speed_mps", n)[idx] / scheduled_limit(scenario, v[idx]), axis=0)
        out["slip_limit_share_max"] = [round(float(s), 4) for s in share]
        out["slip_within_limit"] = [bool(s <= 1.0) for s in share]
    else:
        out["slip_within_limit"] = [bool(s <= s_bar) for s in s_max]
    out["window_s"] = [round(float(tw[0]), 3), round(float(tw[-1]), 3)]
    err = rw - dw
    out["mean_error_g"] = rounded(float(np.mean(err)) / G_MPS2)
    span = tw[-1] - tw[0]
    ss = tw >= tw[-1] - min(ws.steady_state_window_s, span / 2.0)
    out["steady_state_window_s"] = [round(float(tw[ss][0]), 3), round(float(tw[-1]), 3)]
    d_ss = float(np.mean(dw[ss]))
    r0_ss = float(np.mean(rw[ss]))
    out["steady_state_decel_g"] = rounded(d_ss / G_MPS2)
    out["steady_state_error_g"] = rounded((r0_ss - d_ss) / G_MPS2)
    bound = None
    peak = run_params(scenario).plant.adhesion.slip_speed_peak
    if peak is not None:                                   # seed 001's slip-speed curve
        mu_bar = mu_slip_speed_scalar(s_bar, *peak)
        bound = max(r0_ss / G_MPS2 - mu_bar, 0.0)
        out["mu_at_slip_limit"] = rounded(mu_bar, 5)
    out["steady_state_bound_g"] = rounded(bound)
    out["steady_state_excess_g"] = rounded(None if bound is None else (r0_ss - d_ss) / G_MPS2 - bound)
    outside = np.flatnonzero(np.abs(dw - d_ss) > SETTLE_BAND * abs(d_ss))
    if outside.size == 0:
        settle = 0.0
    elif outside[-1] + 1 < len(tw) and not ss[outside[-1]]:
        settle = float(tw[outside[-1] + 1]) - t_brake
    else:
        settle = None          # still outside the band in the steady-state window: not settled
    out["settling_time_s"] = rounded(settle, 3)
    out["overshoot_g"] = rounded((float(np.max(dw)) - d_ss) / G_MPS2)
    x = cols["x_m_1"]
    x_b = float(np.interp(t_brake, t, x))
    v_b = float(np.interp(t_brake, t, cols["v_mps_1"]))
    dist = float(x[i1]) - x_b
    # x_ideal(T) = x_b + v_b (T − t_b) − ∫ (T − t) r⁰(t) dt over [t_b, T]
    seg = (t >= t_brake) & (np.arange(len(t)) <= i1)
    ideal = v_b * (t[i1] - t_brake) - float(np.trapezoid((t[i1] - t[seg]) * r0[seg], t[seg]))
    out["distance_m"] = round(dist, 3)
    out["beyond_ideal_m"] = round(dist - ideal, 3)
    return out


def scheduled_limit(scenario: Scenario, v: np.ndarray) -> np.ndarray:
    """s̄(v) [m/s] of the governor on seed 000's rail curves, per sample and car."""

    ws, ap = scenario.wheel_slip, run_params(scenario).plant.adhesion
    return design_slip_mps(ws.design_condition, ws.slip_fraction, np.asarray(v, dtype=float), ap)


def summary_lines(k: dict) -> list[str]:
    """The KPIs as summary lines, with the paper's figure next to ours where the scenario redoes one of its
    figures ([wheel_slip] paper_figure)."""
    if not k or k.get("window_s") is None:
        return []
    fig8 = k.get("paper_figure") == "fig8"

    def paper(text: str) -> str:
        return f"   (paper: {text})" if fig8 else ""

    held = all(k["slip_within_limit"])
    if k.get("slip_limit_mps") is None:
        limit = ("max slip ÷ s̄(v)         " + " ".join(f"{s:.3f}" for s in k["slip_limit_share_max"])
                 + f" (10 ms samples): s {'≤' if held else '>'} s̄(v) " + ("held" if held else "NOT held"))
    else:
        limit = ("max slip, every step    " + " ".join(f"{s:.4f}" for s in k["max_slip_every_step_mps"])
                 + f" m/s: s {'≤' if held else '>'} s̄ = {k['slip_limit_mps']} m/s "
                 + ("at every plant step" if held else "NOT held"))
    lines = [
        f"reference governor      {'on' if k.get('governor') else 'off'}",
        limit,
        "WSP per car             " + ", ".join(f"{a} activations / {w:.2f} s"
                                               for a, w in zip(k["wsp_activations"], k["wsp_time_s"],
                                                               strict=True)),
        f"mean decel error        {k['mean_error_g']:.4f} g over "
        f"{k['window_s'][0]:.1f}-{k['window_s'][1]:.1f} s"
        + paper(f"{PAPER_FIG8_MEAN_ERROR_G} g without governor, Fig. 8a"),
        f"steady-state error      {k['steady_state_error_g']:.4f} g over {k['steady_state_window_s'][0]:.1f}-"
        f"{k['steady_state_window_s'][1]:.1f} s"
        + (f", bound r⁰ − μ(s̄)g {k['steady_state_bound_g']:.4f} g ({k['steady_state_excess_g']:+.4f} g)"
           if k.get("steady_state_bound_g") is not None else "")
        + paper(f"{PAPER_FIG8_SS_ERROR_G} g with governor, Fig. 8b"),
        "decel settling (±2 %)   " + (f"{k['settling_time_s']:.2f} s" if k["settling_time_s"] is not None
                                      else "not settled") + f", overshoot {k['overshoot_g']:.4f} g",
        f"distance over manoeuvre {k['distance_m']:.2f} m, "
        f"{k['beyond_ideal_m']:.2f} m beyond ideal r⁰ braking"
        + paper(f"governor gains {PAPER_FIG8_STOPPING_GAIN_M} m: compare runs with wheel_slip.governor "
                f"on/off"),
    ]
    if k.get("paper_figure") == "fig9":
        lines.append("paper, Fig. 9 (no figures published): without governor overshoot into WSP and cycling; "
                     "with it no WSP and faster settling")
    return lines


def verdicts(k: dict) -> list[tuple]:
    """The study's checks for report.html: (check, value, criterion, passed)."""
    if k.get("slip_within_limit") is None:
        return []
    if k.get("slip_limit_mps") is None:
        shares = " ".join(f"{s:.3f}" for s in k["slip_limit_share_max"])
        return [("slip ≤ s̄(v) at every 10 ms sample", shares, "largest s ÷ s̄(v) ≤ 1",
                 all(k["slip_within_limit"]))]
    slips = " ".join(f"{s:.4f}" for s in k["max_slip_every_step_mps"])
    return [("slip ≤ s̄ at every plant step", f"{slips} m/s", f"≤ {k['slip_limit_mps']} m/s",
             all(k["slip_within_limit"]))]


# What each KPI above is, for report.html (hil.report.kpi_info): (display name, unit, meaning[, per car])
KPI_INFO = {
    "governor": ("reference governor", "yes/no", "each BECU's reference governor (eq. 9) limits its "
                                                 "deceleration reference"),
    "slip_limit_mps": ("slip limit s̄", "m/s", "the slip speed the governor keeps below (eq. 8); none on "
                                              "seed 000's rail curves, where s̄(v) moves with the speed"),
    "slip_limit_share_max": ("max slip ÷ s̄(v)", "-", "largest slip speed as a share of the speed-scheduled "
                                                     "limit s̄(v) over the 10 ms samples (rail curves)", True),
    "paper_figure": ("paper figure", "text", "the seed 001 figure the scenario redoes (fig8, fig9), or none"),
    "window_s": ("braking window", "s", "[start, end]: from the brake command to the stop, while the train "
                                        "moves (> 0.5 m/s); none when it never moved"),
    "max_slip_every_step_mps": ("max slip, every plant step", "m/s",
                                "largest true slip speed v − rω of the car over every 1 ms plant step of the "
                                "window", True),
    "slip_within_limit": ("slip within s̄", "yes/no", "the car's slip stayed ≤ s̄ at every plant step", True),
    "wsp_activations": ("WSP activations", "count", "times the car's applied WSP valve went to VENT", True),
    "wsp_time_s": ("WSP time", "s", "time the car's applied WSP valve was not FILL", True),
    "mean_error_g": ("mean deceleration error", "g",
                     "mean r⁰ − v̇ over the window (the paper's lim 1/T ∫ r⁰ − v̇ dt, Fig. 8a)"),
    "steady_state_window_s": ("steady-state window", "s",
                              "[start, end]: the last steady_state_window_s of the window, at most its half"),
    "steady_state_decel_g": ("steady-state deceleration", "g", "mean train deceleration in the steady state"),
    "steady_state_error_g": ("steady-state error", "g", "mean r⁰ − v̇ in the steady state (Fig. 8b)"),
    "mu_at_slip_limit": ("μ(s̄)", "1", "adhesion at the slip limit on the scenario's slip-speed curve"),
    "steady_state_bound_g": ("steady-state error bound", "g",
                             "r⁰ − μ(s̄)·g: the least steady error any reference gives without s > s̄ (none "
                             "without the slip-speed adhesion curve)"),
    "steady_state_excess_g": ("error above the bound", "g", "steady-state error − bound"),
    "settling_time_s": ("settling time", "s",
                        "brake command to v̇ staying within ±2 % of its steady value; none: not settled"),
    "overshoot_g": ("overshoot", "g", "largest v̇ in the window above its steady value"),
    "distance_m": ("distance over the window", "m", "car 1's travel over the braking window"),
    "beyond_ideal_m": ("beyond ideal braking", "m",
                       "distance − that of braking at exactly r⁰(t) from the same start (∬ r⁰ − v̇ dt²)"),
}
