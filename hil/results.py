"""What a run leaves: truth.csv, kpis.json, plot.png next to trace.blf, and the printed summary.

KPIs come from the plant's ground truth (not from what the controllers believe); the demand the
controllers were given is read back from the trace, decoded with the DBC.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable
from pathlib import Path

import can
import numpy as np
from cantools.database.can import Database

from hil.codec import Codec
from hil.errors import RailhilError
from hil.plant_node import STANDSTILL_MPS
from hil.scenario import Scenario

MOVING_MPS = 0.5        # a car below this speed is not judged for slip or deceleration tracking


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
        "mean_abs_decel_error_mps2": round(float(decel_err.mean()), 4) if decel_err.size else None,
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
    return kpis


def plot_run(scenario: Scenario, cols: dict[str, np.ndarray], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
        seen = ", ".join(f"{k} {v}" for k, v in kpis.get("protection_events", {}).items()) or "nothing"
        lines.append(f"faults injected         {injected}; receivers reported {seen}")
    bus = kpis.get("bus")
    if bus:
        lines.append(f"bus ({bus['bitrate_bps'] // 1000} kbit/s)       load {100 * bus['load']:.1f} %, "
                     f"worst response {bus['worst_response_us']:.0f} us ({bus['worst_response_message']}), "
                     f"{bus['deadline_misses']} deadline misses")
    lines.append("files: " + ", ".join(str(f) for f in files))
    return lines


def write_kpis(kpis: dict, path: Path) -> None:
    path.write_text(json.dumps(kpis, indent=2, sort_keys=True) + "\n")


def check_out_dir(out: Path) -> Path:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RailhilError(f"{out}: cannot create the run folder: {exc.strerror}") from None
    return out
