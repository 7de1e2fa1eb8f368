"""What a run leaves: truth.csv, kpis.json, plot.png next to trace.blf, and the printed summary.

KPIs come from the plant's ground truth (not from what the controllers believe); the demand the
controllers were given is read back from the trace, decoded with the DBC.

Runs whose BECUs use seed 001's deceleration PI (`[becu] control = "decel"`) also get the seed-001 KPIs
under kpis.json's key "seed001" (`seed001_kpis`, definitions there) and, as plot.png, a figure laid out
like the paper's Figs. 8-9 (`plot_seed001`).

Runs whose BCU has seed 004's deceleration feedback (`[bcu] decel_feedback = true` or `false`, the
open-loop comparison) get the seed-004 KPIs under "seed004" (`seed004_kpis`) and a plot laid out like
the paper's Figs. 19-20 (`plot_seed004`); `compare_seed004` draws an open-loop and a closed-loop run
side by side.

Runs with a target stop point (a `[[desk]]` event with `target_stop_m`, seed 002) get the precise-stop KPIs
under "precise_stop" (`precise_stop_kpis`: stop error and jerk), printed in the summary.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable
from pathlib import Path

import can
import numpy as np
from cantools.database.can import Database

from hil.can.codec import Codec
from hil.errors import RailhilError
from hil.runtime.plant_node import STANDSTILL_MPS
from hil.scenario import Scenario
from plant_sim.adhesion import mu_slip_speed_scalar
from plant_sim.params import PadParams

MOVING_MPS = 0.5        # a car below this speed is not judged for slip or deceleration tracking
G_MPS2 = 9.81           # g, the unit of seed 001's decelerations (plant_sim.params.TrainParams.g_mps2)
SETTLE_BAND = 0.02      # settled: within ±2 % of the steady-state deceleration from then on (chosen)

# Seed 001's published figures (Danielson & Di Cairano, ACC 2020, §IV-A), printed next to ours
PAPER_FIG8_MEAN_ERROR_G = 0.0718      # Fig. 8a, no governor: lim 1/T ∫ r⁰ − v̇ dt (WSP limit cycle)
PAPER_FIG8_SS_ERROR_G = 0.0682        # Fig. 8b, governor: lim r⁰ − v̇, reference cut to r ≈ 0.2 g
PAPER_FIG8_STOPPING_GAIN_M = 1.62     # §IV-A: the governor improves stopping accuracy over 30 s by this
PAD_MU_NOMINAL = PadParams().mu_nominal   # μ_d0 of seed 004 eq. (32), the plant's pad model
# Seed 002's published stop errors (§VII): the adaptive search without / with the differentiation unit
PAPER_SEED002_STOP_ERROR_M = {"adaptive": "±25–45 m (Fig. 5)", "adaptive_diff": "±2–7 m (Fig. 6)"}
JERK_DT_S = 0.1         # jerk = difference of the train deceleration over 0.1 s (a ride-comfort sampling)


def write_truth_csv(columns: dict[str, np.ndarray], path: Path) -> None:
    names = list(columns)
    rows = np.column_stack([columns[n] for n in names])
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(names)
        for row in rows:
            w.writerow([f"{x:.6g}" for x in row])


def read_signal(trace: Path, db: Database, codec: Codec, message: str, signal: str,
                t0_s: float = 0.0, speed: float = 1.0) -> tuple[np.ndarray, np.ndarray, int]:
    """Simulated times [s] ((timestamp - t0) * speed) and values of one signal in a trace, and the
    number of frames in the whole trace (one pass over the file)."""
    fid = db.get_message_by_name(message).frame_id
    fc = codec[fid]
    ts, vs = [], []
    total = 0
    with can.LogReader(str(trace)) as reader:
        for msg in reader:
            total += 1
            if msg.arbitration_id == fid and not msg.is_error_frame and not msg.is_remote_frame:
                ts.append((msg.timestamp - t0_s) * speed)
                vs.append(fc.decode(bytes(msg.data))[signal])
    return np.asarray(ts), np.asarray(vs), total


def _per_car(cols: dict[str, np.ndarray], key: str, n: int) -> np.ndarray:
    return np.column_stack([cols[f"{key}_{i}"] for i in range(1, n + 1)])


def compute_kpis(scenario: Scenario, cols: dict[str, np.ndarray], target: tuple[np.ndarray, np.ndarray],
                 brake_start_s: float | None, frames_sent: dict[str, int], frames_recorded: int,
                 in_flight: int = 0, overwritten: int = 0, faulted: int = 0) -> dict:
    n = scenario.train.cars
    t = cols["t_s"]
    x = _per_car(cols, "x_m", n)
    v = _per_car(cols, "v_mps", n)
    a = _per_car(cols, "a_mps2", n)
    slip = _per_car(cols, "slip_speed_mps", n)
    ratio = _per_car(cols, "slip_ratio", n)
    wsp = _per_car(cols, "wsp_valve", n)
    masses = np.asarray(scenario.train.masses())
    t_brake = brake_start_s if brake_start_s is not None else float(t[0])
    moving = v > MOVING_MPS

    stop_idx = np.flatnonzero(np.all(v < STANDSTILL_MPS, axis=1) & (t >= t_brake))
    stopped = stop_idx.size > 0
    i_stop = int(stop_idx[0]) if stopped else len(t) - 1
    x_brake = float(np.interp(t_brake, t, x[:, 0]))
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0

    # train deceleration (mass-weighted) against the BCU's target, while the train moves after braking
    train_decel = -(a @ masses) / masses.sum()
    tt, tv = target
    target_at = np.interp(t, tt, tv, left=0.0) if tt.size else np.zeros_like(t)
    judged = (t >= t_brake) & np.any(moving, axis=1)
    decel_err = np.abs(target_at - train_decel)[judged]

    vent = wsp == 2
    activations = np.sum(vent[1:] & ~vent[:-1], axis=0) + vent[0]
    kpis = {
        "stopped": bool(stopped),
        "brake_start_s": round(t_brake, 6),
        "stopping_distance_m": round(float(x[i_stop, 0]) - x_brake, 3),
        "time_to_stop_s": round(float(t[i_stop]) - t_brake, 3) if stopped else None,
        "max_slip_speed_mps": [round(float(s), 4) for s in np.max(np.where(moving, slip, 0.0), axis=0)],
        "max_slip_ratio": [round(float(s), 4) for s in np.max(np.where(moving, ratio, 0.0), axis=0)],
        "wsp_activations": [int(k) for k in activations],
        "wsp_time_s": [round(float(k) * dt, 3) for k in np.sum(vent | (wsp == 1), axis=0)],
        # no BCU_DEMAND in the trace (seed 000's paper mode has no BCU): no target to judge against
        "mean_abs_decel_error_mps2": (round(float(decel_err.mean()), 4) if decel_err.size and tt.size
                                      else None),
        "frames_sent": int(sum(frames_sent.values())),
        "frames_recorded": int(frames_recorded),          # in the trace
        "frames_in_flight": int(in_flight),               # queued or on the wire at the end
        "frames_overwritten": int(overwritten),           # replaced in a full transmit queue
        "frames_faulted": int(faulted),                   # added (+) / removed (-) by injected faults
        "frames_lost": int(sum(frames_sent.values())) + faulted - int(frames_recorded) - in_flight
        - overwritten,
        "frames_sent_by_node": dict(frames_sent),
    }
    if n > 1:
        dl = np.column_stack([cols[f"coupler_dl_m_{i}"] for i in range(1, n)])
        kpis["max_abs_coupler_dl_m"] = round(float(np.max(np.abs(dl))), 4)
    if scenario.becu.control == "decel":
        kpis["seed001"] = seed001_kpis(scenario, cols, target, t_brake, i_stop)
    if scenario.bcu.decel_feedback is not None:
        kpis["seed004"] = seed004_kpis(scenario, cols, target)
    if any(e.target_stop_m is not None for e in scenario.desk):
        kpis["precise_stop"] = precise_stop_kpis(scenario, cols, target, i_stop if stopped else None)
    return kpis


def _r(x: float | None, nd: int = 4) -> float | None:
    return None if x is None else round(float(x), nd) + 0.0      # + 0.0: no "-0.0"


def seed001_kpis(scenario: Scenario, cols: dict[str, np.ndarray], target: tuple[np.ndarray, np.ndarray],
                 t_brake: float, i_stop: int) -> dict:
    """Seed 001's figures of merit, from the plant's truth (decelerations in g, g = 9.81 m/s²).

    * braking window: from the first brake command to the stop or the end of the run, samples (10 ms)
      where the train moves (faster than MOVING_MPS); r⁰ is BCU_DEMAND.TargetDecel from the trace, v̇ the
      mass-weighted train deceleration of the truth.
    * `max_slip_every_step_mps`: per car, the largest true slip speed v − rω over EVERY 1 ms plant step
      up to the window's last sample (plant truth column slip_speed_max_mps, not the 10 ms samples);
      `slip_within_limit`: whether that is ≤ s̄ = `slip_limit_mps` (becu.slip_max_mps, eq. (8)).
    * `wsp_activations`, `wsp_time_s`: per car, FILL→VENT transitions of the applied WSP valve and the
      time it was not FILL [s].
    * `mean_error_g`: mean of r⁰ − v̇ over the window (the paper's lim 1/T ∫ r⁰ − v̇ dt, Fig. 8a).
    * steady state: the last `report.steady_state_window_s` of the window, at most its second half;
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
    v = _per_car(cols, "v_mps", n)
    a = _per_car(cols, "a_mps2", n)
    masses = np.asarray(scenario.train.masses())
    decel = -(a @ masses) / masses.sum()
    tt, tv = target
    r0 = np.interp(t, tt, tv, left=0.0) if tt.size else np.zeros_like(t)
    window = (t >= t_brake) & (np.arange(len(t)) <= i_stop) & np.any(v > MOVING_MPS, axis=1)
    idx = np.flatnonzero(window)
    s_bar = scenario.becu.slip_max_mps
    out: dict = {"slip_limit_mps": s_bar, "paper_figure": scenario.report.paper_figure}
    wsp = _per_car(cols, "wsp_valve", n)
    vent = wsp == 2
    out["wsp_activations"] = [int(k) for k in np.sum(vent[1:] & ~vent[:-1], axis=0) + vent[0]]
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    out["wsp_time_s"] = [round(float(k) * dt, 3) for k in np.sum(wsp != 0, axis=0)]
    if idx.size < 2:
        out["window_s"] = None
        return out
    i1 = int(idx[-1])
    tw, dw, rw = t[idx], decel[idx], r0[idx]
    s_max = _per_car(cols, "slip_speed_max_mps", n)[i1]
    out["max_slip_every_step_mps"] = [round(float(s), 5) for s in s_max]
    out["slip_within_limit"] = [bool(s <= s_bar) for s in s_max]
    out["window_s"] = [round(float(tw[0]), 3), round(float(tw[-1]), 3)]
    err = rw - dw
    out["mean_error_g"] = _r(float(np.mean(err)) / G_MPS2)
    span = tw[-1] - tw[0]
    ss = tw >= tw[-1] - min(scenario.report.steady_state_window_s, span / 2.0)
    out["steady_state_window_s"] = [round(float(tw[ss][0]), 3), round(float(tw[-1]), 3)]
    d_ss = float(np.mean(dw[ss]))
    r0_ss = float(np.mean(rw[ss]))
    out["steady_state_decel_g"] = _r(d_ss / G_MPS2)
    out["steady_state_error_g"] = _r((r0_ss - d_ss) / G_MPS2)
    bound = None
    if scenario.plant.adhesion == "slip_speed":
        mu_bar = mu_slip_speed_scalar(s_bar, scenario.plant.mu_peak, scenario.plant.slip_peak_mps)
        bound = max(r0_ss / G_MPS2 - mu_bar, 0.0)
        out["mu_at_slip_limit"] = _r(mu_bar, 5)
    out["steady_state_bound_g"] = _r(bound)
    out["steady_state_excess_g"] = _r(None if bound is None else (r0_ss - d_ss) / G_MPS2 - bound)
    outside = np.flatnonzero(np.abs(dw - d_ss) > SETTLE_BAND * abs(d_ss))
    if outside.size == 0:
        settle = 0.0
    elif outside[-1] + 1 < len(tw) and not ss[outside[-1]]:
        settle = float(tw[outside[-1] + 1]) - t_brake
    else:
        settle = None          # still outside the band in the steady-state window: not settled
    out["settling_time_s"] = _r(settle, 3)
    out["overshoot_g"] = _r((float(np.max(dw)) - d_ss) / G_MPS2)
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


# seed 004 §5.2: the band and the time outside it that engages the loop (firmware_py.decel_feedback)
SEED004_BAND = (0.9, 1.1)
SEED004_ENGAGE_AFTER_S = 0.5
SEED004_MIN_SPEED_MPS = 1.0      # judged while the train is faster than this (the BCU's min_speed_mps)
SEED004_MIN_TARGET_MPS2 = 0.2    # ... and the target above this (the BCU's min_target_mps2) ...
SEED004_STEADY_TOL = 0.02        # ... and steady: the target through T_q within 2 % of it (steady_tol)
SEED004_RATIO_TAU_S = 0.2        # the truth's deceleration is filtered like the BCU's ratio (τ, s)


def _lag(t: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    """First-order lag of a sampled signal (exact for x held between samples)."""
    out = np.empty_like(x, dtype=float)
    acc = float(x[0]) if x.size else 0.0
    for k in range(x.size):
        if k:
            acc += (1.0 - np.exp(-(t[k] - t[k - 1]) / tau_s)) * (x[k] - acc)
        out[k] = acc
    return out


def seed004_ratio(scenario: Scenario, cols: dict[str, np.ndarray],
                  target: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times [s], actual/target deceleration, judged) from the plant's truth.

    actual: the mass-weighted train deceleration −v̇ through a first-order lag of SEED004_RATIO_TAU_S
    (the car accelerations of one 1 ms step carry the couplers' oscillation); target: BCU_DEMAND.TargetDecel
    from the trace through the cylinder lag T_q (eq. (33), bcu.feedback_tq_s) and the same filter.
    Judged, as the BCU judges: the demand is steady (the target through T_q within SEED004_STEADY_TOL of
    the target) and above SEED004_MIN_TARGET_MPS2, and the train is faster than SEED004_MIN_SPEED_MPS."""
    n = scenario.train.cars
    t = cols["t_s"]
    masses = np.asarray(scenario.train.masses())
    decel = _lag(t, -(_per_car(cols, "a_mps2", n) @ masses) / masses.sum(), SEED004_RATIO_TAU_S)
    tt, tv = target
    r0 = np.interp(t, tt, tv, left=0.0) if tt.size else np.zeros_like(t)
    expected = _lag(t, _lag(t, r0, scenario.bcu.feedback_tq_s), SEED004_RATIO_TAU_S)   # the same filter
    v = (_per_car(cols, "v_mps", n) @ masses) / masses.sum()
    steady = np.abs(_lag(t, r0, scenario.bcu.feedback_tq_s) - r0) <= SEED004_STEADY_TOL * r0
    judged = steady & (r0 >= SEED004_MIN_TARGET_MPS2) & (v >= SEED004_MIN_SPEED_MPS)
    ratio = np.where(judged, decel / np.maximum(expected, 1e-9), np.nan)
    return t, ratio, judged


def seed004_engagement_s(t: np.ndarray, ratio: np.ndarray, judged: np.ndarray) -> float | None:
    """First time [s] at which the ratio has been outside SEED004_BAND for more than
    SEED004_ENGAGE_AFTER_S while judged (seed 004 §5.2's rule, on whatever ratio is given)."""
    lo, hi = SEED004_BAND
    since = None
    for k in range(t.size):
        out = bool(judged[k]) and not (lo <= ratio[k] <= hi)
        if not out:
            since = None
        elif since is None:
            since = float(t[k])
        elif t[k] - since > SEED004_ENGAGE_AFTER_S:
            return float(t[k])
    return None


def seed004_kpis(scenario: Scenario, cols: dict[str, np.ndarray], target: tuple[np.ndarray, np.ndarray],
                 engaged_at_s: float | None = None) -> dict:
    """Seed 004's figures of merit (§5.2, §6.4), from the plant's truth (`seed004_ratio` defines the ratio).

    * `engaged_at_s`: when the loop engaged: the BCU's own engagement (BCU_STATUS.FbState = ENGAGED in
      the trace) when given, else (`engage_source` "truth rule") the time at which §5.2's rule fires on the
      true ratio — the same instant for an open-loop run, which never engages;
    * `within_band_after_engagement`: the fraction of judged samples (10 ms) from then to the stop with the
      ratio within 90–110 %; `within_band_judged`: the same over every judged sample of the stop;
    * `ratio_min`, `ratio_max`, `ratio_rms_error`: over the judged samples after engagement;
    * `wsp_activations`: FILL→VENT transitions per car (seed 004: the loop must not cause WSP on dry rail);
    * `pad_mu_ratio_range`: the pad friction μ_d/μ_nominal of car 1 over the judged samples (eq. (25)).
    """
    t, ratio, judged = seed004_ratio(scenario, cols, target)
    source = "BCU"
    if engaged_at_s is None:
        engaged_at_s, source = seed004_engagement_s(t, ratio, judged), "truth rule"
    lo, hi = SEED004_BAND
    inside = judged & (ratio >= lo) & (ratio <= hi)
    out: dict = {"closed_loop": bool(scenario.bcu.decel_feedback), "engaged_at_s": _r(engaged_at_s, 3),
                 "engage_source": source, "band": list(SEED004_BAND),
                 "within_band_judged": _r(inside.sum() / max(int(judged.sum()), 1))}
    after = judged & (t >= engaged_at_s) if engaged_at_s is not None else np.zeros_like(judged)
    if after.any():
        r = ratio[after]
        out["within_band_after_engagement"] = _r(inside[after].sum() / after.sum())
        out["window_s"] = [round(float(t[after][0]), 3), round(float(t[after][-1]), 3)]
        out["ratio_min"], out["ratio_max"] = _r(float(r.min())), _r(float(r.max()))
        out["ratio_rms_error"] = _r(float(np.sqrt(np.mean((r - 1.0) ** 2))))
    else:
        out["within_band_after_engagement"] = None
    n = scenario.train.cars
    vent = _per_car(cols, "wsp_valve", n) == 2
    out["wsp_activations"] = [int(k) for k in np.sum(vent[1:] & ~vent[:-1], axis=0) + vent[0]]
    if "mu_pad_1" in cols and judged.any():
        mu = cols["mu_pad_1"][judged] / PAD_MU_NOMINAL
        out["pad_mu_ratio_range"] = [_r(float(mu.min())), _r(float(mu.max()))]
    return out


def seed004_summary_lines(k: dict | None) -> list[str]:
    """The seed-004 KPIs as summary lines."""
    if not k:
        return []
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


def precise_stop_kpis(scenario: Scenario, cols: dict[str, np.ndarray], target: tuple[np.ndarray, np.ndarray],
                      i_stop: int | None) -> dict:
    """Seed 002's figures of merit, from the plant's truth.

    * `target_m`: the last target stop point the desk gave (track position of the leading car's front);
    * `stop_error_m`: car 1's front at the standstill (every car below the plant's standstill speed) minus
      the target [m]; + = overshoot; None when the train did not stop;
    * `jerk_p95_mps3`, `jerk_max_mps3`: |d/dt| of the train's mass-weighted deceleration, differenced over
      JERK_DT_S = 0.1 s, from the first non-zero target deceleration of the BCU to the standstill: the 95th
      percentile and the maximum [m/s³];
    * `braking_s`: that window's length [s]; `stopping`: the BCU's method ([bcu] stopping).
    """
    t = cols["t_s"]
    n = scenario.train.cars
    target_m = [e.target_stop_m for e in scenario.desk if e.target_stop_m is not None][-1]
    masses = np.asarray(scenario.train.masses())
    decel = -(_per_car(cols, "a_mps2", n) @ masses) / masses.sum()
    tt, tv = target
    on = np.flatnonzero(tv > 0.0) if tt.size else np.zeros(0, dtype=int)
    t_on = float(tt[on[0]]) if on.size else float(t[0])
    t_end = float(t[i_stop]) if i_stop is not None else float(t[-1])
    grid = np.arange(t_on, t_end, JERK_DT_S)
    jerk = np.abs(np.diff(np.interp(grid, t, decel))) / JERK_DT_S if grid.size > 1 else np.zeros(1)
    return {
        "stopping": scenario.bcu.stopping,
        "target_m": target_m,
        "stop_error_m": _r(float(cols["x_m_1"][i_stop]) - target_m, 3) if i_stop is not None else None,
        "stopped": i_stop is not None,
        "braking_s": _r(t_end - t_on, 3),
        "jerk_p95_mps3": _r(float(np.percentile(jerk, 95))),
        "jerk_max_mps3": _r(float(jerk.max())),
    }


def precise_stop_summary_lines(k: dict | None) -> list[str]:
    """The precise-stop KPIs as summary lines, with seed 002's figure for the paper's methods."""
    if not k:
        return []
    paper = PAPER_SEED002_STOP_ERROR_M.get(k["stopping"])
    err = k["stop_error_m"]
    return ["stop error              " + (f"{err:+.3f} m" if err is not None else "— (train did not stop)")
            + f" at target {k['target_m']:.2f} m, method {k['stopping']}"
            + (f"   (paper: {paper})" if paper else ""),
            f"jerk                    p95 {k['jerk_p95_mps3']:.3f} m/s³, max {k['jerk_max_mps3']:.3f} m/s³ "
            f"over {k['braking_s']:.1f} s of braking"]


def read_signals(trace: Path, db: Database, codec: Codec, wanted: dict[str, tuple[str, str]],
                 t0_s: float = 0.0, speed: float = 1.0) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Several signals of a trace in one pass: name -> (message, signal) in, name -> (simulated times
    [s], values) out (a message the DBC lacks gives empty arrays)."""
    by_id: dict[int, list[tuple[str, str]]] = {}
    for name, (message, signal) in wanted.items():
        try:
            fid = db.get_message_by_name(message).frame_id
        except KeyError:
            continue
        by_id.setdefault(fid, []).append((name, signal))
    series: dict[str, tuple[list, list]] = {name: ([], []) for name in wanted}
    with can.LogReader(str(trace)) as reader:
        for msg in reader:
            entries = by_id.get(msg.arbitration_id)
            if entries is None or msg.is_error_frame or msg.is_remote_frame:
                continue
            decoded = codec[msg.arbitration_id].decode(bytes(msg.data))
            for name, signal in entries:
                series[name][0].append((msg.timestamp - t0_s) * speed)
                series[name][1].append(decoded[signal])
    return {name: (np.asarray(ts), np.asarray(vs)) for name, (ts, vs) in series.items()}


def plot_run(scenario: Scenario, cols: dict[str, np.ndarray], path: Path, title: str,
             trace_t0_s: float | None = None, trace_speed: float = 1.0) -> None:
    """plot.png: speed, cylinder pressure and slip per car; for seed-001 runs (control = "decel") the
    layout of the paper's Figs. 8-9 instead (`plot_seed001`), which also reads the trace next to it
    (trace_t0_s: the trace's timestamp at simulated time 0; None = lockstep, whose trace starts at 0)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if scenario.becu.control == "decel":
        plot_seed001(scenario, cols, path, title, trace_t0_s, trace_speed)
        return
    if scenario.bcu.decel_feedback is not None:
        plot_seed004(scenario, cols, path, title, trace_t0_s, trace_speed)
        return
    n = scenario.train.cars
    t = cols["t_s"]
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    for i in range(1, n + 1):
        axes[0].plot(t, cols[f"v_mps_{i}"] * 3.6, label=f"car {i}", lw=1)
        axes[1].plot(t, cols[f"p_Pa_{i}"] / 1e3, lw=1)
        axes[2].plot(t, cols[f"slip_speed_mps_{i}"], lw=1)
    axes[0].set_ylabel("speed [km/h]")
    axes[1].set_ylabel("cylinder pressure [kPa]")
    axes[2].set_ylabel("slip speed v − rω [m/s]")
    axes[2].set_xlabel("time [s]")
    axes[0].legend(ncol=min(n, 4), fontsize=8)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _wsp_intervals(t: np.ndarray, active: np.ndarray) -> list[tuple[float, float]]:
    """[start, end) times [s] of the runs of True in `active` (sampled at t)."""
    edges = np.diff(np.concatenate([[0], active.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return [(float(t[a]), float(t[b - 1]) + step) for a, b in zip(starts, ends, strict=True)]


def plot_seed001(scenario: Scenario, cols: dict[str, np.ndarray], path: Path, title: str,
                 trace_t0_s: float | None = None, trace_speed: float = 1.0) -> None:
    """Seed 001's Figs. 8-9 for a run: deceleration v̇ with the requested r⁰ and the governed r (car 1's
    BECU1_DIAG.GovernedDecel, from the trace), true slip speed with s̄, cylinder pressure p with the
    set-point u, brake torque τ; WSP intervals (any car's WSP valve not FILL) shaded on every panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hil.can.dbc import DEFAULT_DBC, load_dbc

    n = scenario.train.cars
    t = cols["t_s"]
    trace = path.parent / "trace.blf"
    sig: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    if trace.exists():
        db = load_dbc(Path(scenario.dbc) if scenario.dbc else DEFAULT_DBC)
        sig = read_signals(trace, db, Codec(db), {"r0": ("BCU_DEMAND", "TargetDecel"),
                                                  "r": ("BECU1_DIAG", "GovernedDecel")},
                           0.0 if trace_t0_s is None else trace_t0_s, trace_speed)
        end = float(t[-1]) + 1.0 if len(t) else 0.0
        if trace_t0_s is None and any(ts.size and ts[0] > end for ts, _ in sig.values()):
            sig = {}                 # a real-time trace (wall-clock timestamps) without its t0: not aligned
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
    if scenario.becu.governor and "r" in sig and sig["r"][0].size:
        ax_d.step(sig["r"][0], sig["r"][1] / G_MPS2, where="post", color="tab:red", lw=1.0,
                  label="r (governed, car 1)")
    ax_s.axhline(scenario.becu.slip_max_mps, color="tab:red", ls=":", lw=1.0,
                 label=f"s̄ = {scenario.becu.slip_max_mps} m/s")
    wsp = _per_car(cols, "wsp_valve", n) != 0
    for ax in axes:
        for a, b in _wsp_intervals(t, np.any(wsp, axis=1)):
            ax.axvspan(a, b, color="tab:orange", alpha=0.25, lw=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    ax_d.set_ylabel("deceleration [g]")
    ax_s.set_ylabel("slip speed [m/s]")
    ax_p.set_ylabel("cylinder pressure [bar]")
    ax_t.set_ylabel("brake torque [kN m]")
    ax_t.set_xlabel("time [s]   (shaded: WSP engaged)")
    fig.suptitle(f"{title}, reference governor {'on' if scenario.becu.governor else 'off'}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _feedback_signals(scenario: Scenario, trace: Path, t_end: float, trace_t0_s: float | None,
                      trace_speed: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """TargetDecel and BCU_STATUS's FbState, FrictionPhi, SlopeEst from a run's trace ({} when there is
    none, or it is a real-time trace given without its t0)."""
    from hil.can.dbc import DEFAULT_DBC, load_dbc

    if not trace.exists():
        return {}
    db = load_dbc(Path(scenario.dbc) if scenario.dbc else DEFAULT_DBC)
    sig = read_signals(trace, db, Codec(db), {"target": ("BCU_DEMAND", "TargetDecel"),
                                              "state": ("BCU_STATUS", "FbState"),
                                              "phi": ("BCU_STATUS", "FrictionPhi"),
                                              "slope": ("BCU_STATUS", "SlopeEst")},
                       0.0 if trace_t0_s is None else trace_t0_s, trace_speed)
    if trace_t0_s is None and any(ts.size and ts[0] > t_end + 1.0 for ts, _ in sig.values()):
        return {}
    return sig


def bcu_engagement_s(sig: dict[str, tuple[np.ndarray, np.ndarray]]) -> float | None:
    """First time [s] the trace's BCU_STATUS.FbState says ENGAGED (2), or None."""
    ts, vs = sig.get("state", (np.array([]), np.array([])))
    hit = np.flatnonzero(vs == 2)
    return float(ts[hit[0]]) if hit.size else None


def plot_seed004(scenario: Scenario, cols: dict[str, np.ndarray], path: Path, title: str,
                 trace_t0_s: float | None = None, trace_speed: float = 1.0) -> None:
    """Seed 004's Figs. 19-20 for one run: deceleration (truth, filtered as in `seed004_ratio`) with the
    target and the 90-110 % band; cylinder pressure per car; the BCU's φ and the pad friction μ_d/μ_d0;
    the BCU's slope estimate.  The BCU's engagement (trace) is a vertical line on every panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = scenario.train.cars
    t = cols["t_s"]
    sig = _feedback_signals(scenario, path.parent / "trace.blf", float(t[-1]) if len(t) else 0.0,
                            trace_t0_s, trace_speed)
    target = sig.get("target", (np.array([]), np.array([])))
    masses = np.asarray(scenario.train.masses())
    decel = _lag(t, -(_per_car(cols, "a_mps2", n) @ masses) / masses.sum(), SEED004_RATIO_TAU_S)
    fig, axes = plt.subplots(3, 1, figsize=(10, 10), sharex=True)
    ax_d, ax_p, ax_f = axes
    ax_d.plot(t, decel, lw=1.0, label="train deceleration (plant, mass-weighted)")
    if target[0].size:
        ax_d.step(target[0], target[1], where="post", color="k", lw=1.0, label="target (BCU_DEMAND)")
        for f in SEED004_BAND:
            ax_d.step(target[0], f * target[1], where="post", color="k", lw=0.6, ls=":")
    for i in range(1, n + 1):
        ax_p.plot(t, cols[f"p_Pa_{i}"] / 1e3, lw=0.8, label=f"car {i}")
    if "phi" in sig and sig["phi"][0].size:
        ax_f.step(sig["phi"][0], sig["phi"][1], where="post", color="tab:red", lw=1.0, label="φ (BCU_STATUS)")
    if "mu_pad_1" in cols:
        ax_f.plot(t, cols["mu_pad_1"] / PAD_MU_NOMINAL, lw=0.8, color="tab:green",
                  label="μ_d/μ_d0 car 1 (plant)")
    if "slope" in sig and sig["slope"][0].size:
        ax_s = ax_f.twinx()
        ax_s.step(sig["slope"][0], sig["slope"][1] * 1e3, where="post", color="tab:gray", lw=0.8,
                  label="slope estimate [‰]")
        ax_s.set_ylabel("slope estimate [‰]")
        ax_s.legend(fontsize=8, loc="lower right")
    eng = bcu_engagement_s(sig)
    for ax in axes:
        if eng is not None:
            ax.axvline(eng, color="tab:purple", lw=1.0, ls="--")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    ax_d.set_ylabel("deceleration [m/s²]")
    ax_p.set_ylabel("cylinder pressure [kPa]")
    ax_f.set_ylabel("φ, μ_d/μ_d0 [-]")
    ax_f.set_xlabel("time [s]" + ("   (dashed: the BCU's feedback engaged)" if eng is not None else ""))
    loop = "closed loop" if scenario.bcu.decel_feedback else "open loop"
    fig.suptitle(f"{title}, deceleration feedback: {loop}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def compare_seed004(open_dir: Path, closed_dir: Path, out: Path) -> Path:
    """Seed 004's Figs. 19-20 as the paper shows them: cylinder pressure (car 1) and train deceleration of
    an open-loop and a closed-loop run of the same scenario, side by side in one figure, from the two run
    folders (truth.csv, run.json, trace.blf).  Returns `out`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_p, ax_d) = plt.subplots(2, 1, figsize=(10, 8), sharex=True)
    for label, folder, color in (("before (open loop)", Path(open_dir), "tab:blue"),
                                 ("after (closed loop)", Path(closed_dir), "tab:red")):
        meta = json.loads((folder / "run.json").read_text())
        scenario = Scenario.model_validate(meta["scenario"])
        cols = read_truth_csv(folder / "truth.csv")
        t = cols["t_s"]
        n = scenario.train.cars
        masses = np.asarray(scenario.train.masses())
        decel = _lag(t, -(_per_car(cols, "a_mps2", n) @ masses) / masses.sum(), SEED004_RATIO_TAU_S)
        sig = _feedback_signals(scenario, folder / "trace.blf", float(t[-1]), meta.get("trace_t0_s"), 1.0)
        ax_p.plot(t, cols["p_Pa_1"] / 1e3, color=color, lw=1.0, label=f"{label}, car 1")
        ax_d.plot(t, decel, color=color, lw=1.0, label=label)
        target = sig.get("target")
        if target is not None and target[0].size and "closed" in label:
            ax_d.step(target[0], target[1], where="post", color="k", lw=1.0, label="target")
            for f in SEED004_BAND:
                ax_d.step(target[0], f * target[1], where="post", color="k", lw=0.6, ls=":")
    ax_p.set_ylabel("cylinder pressure [kPa]   (Fig. 19)")
    ax_d.set_ylabel("deceleration [m/s²]   (Fig. 20)")
    ax_d.set_xlabel("time [s]")
    for ax in (ax_p, ax_d):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("seed 004 line test: before / after the deceleration feedback")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def read_truth_csv(path: Path) -> dict[str, np.ndarray]:
    """truth.csv (written by `write_truth_csv`) back as columns."""
    try:
        data = np.genfromtxt(path, delimiter=",", names=True)
    except OSError as exc:
        raise RailhilError(f"{path}: cannot read the truth of a run: {exc}") from None
    return {name: np.asarray(data[name], dtype=float) for name in data.dtype.names}


def summary_lines(kpis: dict, files: Iterable[Path]) -> list[str]:
    def per_car(values, fmt):
        return " ".join(fmt.format(v) for v in values)

    lines = [
        f"stopping distance       {kpis['stopping_distance_m']:.2f} m"
        + ("" if kpis["stopped"] else "  (train did not stop)"),
        f"time to stop            {kpis['time_to_stop_s']:.2f} s" if kpis["time_to_stop_s"] is not None
        else "time to stop            —",
        f"max slip speed per car  {per_car(kpis['max_slip_speed_mps'], '{:.3f}')} m/s",
        f"max slip ratio per car  {per_car(kpis['max_slip_ratio'], '{:.3f}')}",
        f"WSP activations per car {per_car(kpis['wsp_activations'], '{:d}')}",
        "mean |decel error|      " + (f"{kpis['mean_abs_decel_error_mps2']:.3f} m/s²"
                                      if kpis["mean_abs_decel_error_mps2"] is not None else "—"),
        f"frames sent             {kpis['frames_sent']} ({kpis['frames_lost']} not in the trace"
        + (f", {kpis['frames_in_flight']} still queued at the end" if kpis.get("frames_in_flight") else "")
        + (f", {kpis['frames_overwritten']} overwritten in a transmit queue"
           if kpis.get("frames_overwritten") else "") + ")",
    ]
    if kpis.get("faults_injected") is not None or kpis.get("protection_events"):
        injected = ", ".join(f"{k} {v}" for k, v in (kpis.get("faults_injected") or {}).items()) or "none"
        seen = ", ".join(f"{k} {v}" + (" (frames 1.5 cycles late)" if k == "NONEWDATA" else "")
                         for k, v in kpis.get("protection_events", {}).items()) or "nothing"
        lines.append(f"faults injected         {injected}; receivers reported {seen}")
    flags = kpis.get("plausibility_flags")
    if flags:                         # first time [s] each sensor fault / implausible car was flagged
        shown = "; ".join(f"{flag} " + ", ".join(f"{car} {t:.2f} s" for car, t in cars.items())
                          for flag, cars in sorted(flags.items()))
        lines.append(f"sensor flags            {shown}")
    lines += seed001_summary_lines(kpis.get("seed001"))
    lines += seed004_summary_lines(kpis.get("seed004"))
    lines += precise_stop_summary_lines(kpis.get("precise_stop"))
    bus = kpis.get("bus")
    if bus:
        lines.append(f"bus ({bus['bitrate_bps'] // 1000} kbit/s)       load {100 * bus['load']:.1f} %, "
                     f"worst response {bus['worst_response_us']:.0f} us ({bus['worst_response_message']}), "
                     f"{bus['deadline_misses']} deadline misses")
    rt = kpis.get("realtime")
    if rt:
        worst = rt["worst_node"]
        skipped = ", ".join(f"{n} {k}" for n, k in rt["missed_cycles"].items() if k)
        lines.append(f"real time               held: no cycle more than {rt['limit_ms']:g} ms late (worst "
                     f"{worst} {rt['max_lag_ms'][worst]:g} ms)" if rt["held"] else
                     f"real time               NOT HELD: {worst} up to {rt['max_lag_ms'][worst]:g} ms late"
                     + (f", cycles skipped: {skipped}" if skipped else "")
                     + " - the machine was short of CPU; this run's figures are not the controllers' at "
                       "their cycle times")
    lines.append("files: " + ", ".join(str(f) for f in files))
    return lines


def seed001_summary_lines(k: dict | None) -> list[str]:
    """The seed-001 KPIs as summary lines, with the paper's figure next to ours where the scenario redoes
    one of its figures ([report] paper_figure)."""
    if not k or k.get("window_s") is None:
        return []
    fig8 = k.get("paper_figure") == "seed001_fig8"

    def paper(text: str) -> str:
        return f"   (paper: {text})" if fig8 else ""

    held = all(k["slip_within_limit"])
    lines = [
        "max slip, every step    " + " ".join(f"{s:.4f}" for s in k["max_slip_every_step_mps"])
        + f" m/s: s {'≤' if held else '>'} s̄ = {k['slip_limit_mps']} m/s "
        + ("at every plant step" if held else "NOT held"),
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
        + paper(f"governor gains {PAPER_FIG8_STOPPING_GAIN_M} m: compare runs with becu.governor on/off"),
    ]
    if k.get("paper_figure") == "seed001_fig9":
        lines.append("paper, Fig. 9 (no figures published): without governor overshoot into WSP and cycling; "
                     "with it no WSP and faster settling")
    return lines


def write_kpis(kpis: dict, path: Path) -> None:
    path.write_text(json.dumps(kpis, indent=2, sort_keys=True) + "\n")


def check_out_dir(out: Path) -> Path:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RailhilError(f"{out}: cannot create the run folder: {exc.strerror}") from None
    return out
