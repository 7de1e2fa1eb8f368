"""The KPIs of the anti-collision device (seed 002) for a run, decided on plant truth: the minimum gap to
the leading train's last wagon, collision (gap ≤ 0), red-signal overruns (the front passes a signal
showing red), the ACD's brake applications and the unnecessary ones; kpis.json key "anticollision".

`run_judged` runs a scenario in lockstep without files and judges it (the campaign's job);
`judge_run_dir` judges a run folder of `railhil run`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np

from firmware_py.acd import Aspect, braking_distance_m
from hil.can.codec import Codec, loaded_dbc
from hil.can.dbc import load_dbc
from hil.report.kpis import RunView, read_signal, run_trace
from hil.runtime.lockstep import run_lockstep
from hil.runtime.run import TRACE_NAME, dbc_path_of
from hil.safety.injection import build_injector
from hil.scenario import Scenario
from hil.scenario.params import run_params
from hil.studies.anticollision.scenario import AcdStudyError, acd_params, aspect_at, leader_motion, spec_of


@dataclass
class Judgement:
    """A run judged on plant truth (module docstring).  Distances in m, times in s."""

    min_gap_m: float                 # smallest gap front → U1's last wagon (inf without U1)
    collision: bool                  # the gap reached 0
    overruns: int                    # signals passed while red
    min_signal_m: float              # smallest distance to a red signal ahead (inf: none)
    applications: int                # ACD brake applications (Request rising from NONE)
    unnecessary: int                 # of which unnecessary (obstacle farther than B + hysteresis)
    first_brake_s: float             # first ACD request [s] (nan: none)
    stop_gap_m: float                # gap at the end of the run
    ends: list = field(default_factory=list)

    def as_dict(self) -> dict:
        d = dict(vars(self))
        d.pop("ends")
        return d


def judge(scenario: Scenario, cols: Mapping[str, np.ndarray], req_t_s: np.ndarray,
          req: np.ndarray) -> Judgement:
    """Judge a run from its truth columns (t_s, x_m_1, v_mps_1) and the ACD's Request frames (times
    [s] and values), recomputing U1 and the signals from the scenario."""
    spec = spec_of(scenario)
    t = np.asarray(cols["t_s"])
    front = np.asarray(cols["x_m_1"]) + run_params(scenario).plant.train.car_pitch_m / 2.0
    v = np.asarray(cols["v_mps_1"])
    motion = leader_motion(spec)
    if motion is not None:
        gap = motion.rear_m(t) - front
        min_gap, stop_gap = float(gap.min()), float(gap[-1])
    else:
        gap = np.full_like(t, np.inf)
        min_gap = stop_gap = math.inf
    overruns, min_sig = 0, math.inf
    red_dist = np.full_like(t, np.inf)
    for sig in spec.signals:
        red = np.array([aspect_at(sig, ti) == Aspect.RED for ti in t])
        ahead = sig.position_m - front
        if red.any() and (ahead > 0).any():
            min_sig = min(min_sig, float(ahead[red & (ahead > -1.0)].min(initial=np.inf)))
        red_dist = np.where(red & (ahead > 0), np.minimum(red_dist, ahead), red_dist)
        crossed = np.flatnonzero((ahead[:-1] > 0) & (ahead[1:] <= 0))
        overruns += int(any(red[k + 1] for k in crossed))
    p = acd_params(spec)
    req = np.asarray(req)
    rises = np.flatnonzero((req[1:] > 0) & (req[:-1] == 0)) + 1
    if req.size and req[0] > 0:
        rises = np.concatenate([[0], rises])
    unnecessary = 0
    for k in rises:
        i = min(int(np.searchsorted(t, req_t_s[k])), len(t) - 1)
        b = braking_distance_m(float(v[i]), p.service_decel_mps2, p.reaction_s)
        if min(gap[i], red_dist[i]) > b + p.release_hysteresis_m:
            unnecessary += 1
    return Judgement(min_gap, min_gap <= 0.0, overruns, min_sig, int(rises.size), unnecessary,
                     float(req_t_s[rises[0]]) if rises.size else math.nan, stop_gap)


class RequestLog(can.Listener):
    """Keeps the ACD's ACD_BRAKE_REQ.Request of every frame on the bus (a python-can listener)."""

    def __init__(self, codec: Codec) -> None:
        self.fc = codec.by_name("ACD_BRAKE_REQ")
        self.t: list[float] = []
        self.req: list[int] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == self.fc.frame_id:
            self.t.append(msg.timestamp)
            self.req.append(int(self.fc.decode(bytes(msg.data))["Request"]))


def run_judged(scenario_json: str) -> dict:
    """One lockstep run in this process, no trace file, judged (a campaign worker's job)."""

    scenario = Scenario.model_validate_json(scenario_json)
    t0 = time.perf_counter()
    db, codec = loaded_dbc(dbc_path_of(scenario))     # once per worker process, not per run
    log = RequestLog(codec)
    outcome = run_lockstep(scenario, db, codec, log, injector=build_injector(scenario, db, codec))
    j = judge(scenario, outcome.truth.columns(), np.asarray(log.t), np.asarray(log.req))
    return {**j.as_dict(), "seed": scenario.seed, "prediction": spec_of(scenario).prediction,
            "simulated_s": outcome.end_us / 1e6, "end": outcome.reason, "wall_s": time.perf_counter() - t0}


def judge_run_dir(run_dir: Path) -> dict:
    """Judge a run folder of `railhil run` (lockstep or real time): its scenario (run.json), plant truth
    (truth.csv) and the ACD's requests in its trace."""
    import json


    run_dir = Path(run_dir)
    try:
        meta = json.loads((run_dir / "run.json").read_text())
        scenario = Scenario.model_validate(meta["scenario"])
        data = np.genfromtxt(run_dir / "truth.csv", delimiter=",", names=True)
    except (OSError, ValueError, KeyError) as exc:
        raise AcdStudyError(f"{run_dir}: not a readable run folder of `railhil run` "
                            f"(run.json, truth.csv, {TRACE_NAME}): {' '.join(str(exc).split())}") from None
    spec_of(scenario)
    db = load_dbc(dbc_path_of(scenario))
    trace, clock = run_trace(run_dir, meta)
    t, req, _ = read_signal(trace, db, Codec(db), "ACD_BRAKE_REQ", "Request", clock)
    cols = {name: np.asarray(data[name]) for name in data.dtype.names}
    j = judge(scenario, cols, np.asarray(t), np.asarray(req))
    return {**j.as_dict(), "seed": scenario.seed, "prediction": spec_of(scenario).prediction,
            "simulated_s": float(cols["t_s"][-1]), "mode": meta.get("mode")}


def kpis(run: RunView) -> dict:
    """The judgement of the run from its truth and the ACD's requests in its trace."""
    t, req = run.signals({"req": ("ACD_BRAKE_REQ", "Request")})["req"]
    j = judge(run.scenario, run.cols, t, req)
    out = j.as_dict()
    for key in ("min_gap_m", "min_signal_m", "stop_gap_m", "first_brake_s"):
        v = out[key]
        out[key] = None if not math.isfinite(v) else round(v, 3)    # JSON has no inf or NaN
    out["prediction"] = spec_of(run.scenario).prediction
    return out


def summary_lines(k: dict) -> list[str]:
    def m(x):
        return "—" if x is None else f"{x:.1f} m"

    return [f"anti-collision          min gap to the train ahead {m(k['min_gap_m'])}"
            + (" — COLLISION" if k["collision"] else "") + f", red-signal overruns {k['overruns']}, "
            f"closest to a red signal {m(k['min_signal_m'])}",
            f"  ... ACD (prediction {'on' if k['prediction'] else 'off'}) brake applications "
            f"{k['applications']} ({k['unnecessary']} unnecessary), first at "
            + ("—" if k["first_brake_s"] is None else f"{k['first_brake_s']:.2f} s")]


def verdicts(k: dict) -> list[tuple]:
    """The study's checks for report.html: (check, value, criterion, passed), on plant truth."""
    gap = "—" if k["min_gap_m"] is None else f"{k['min_gap_m']:.1f} m"
    return [("no collision with the train ahead", f"min gap {gap}", "gap > 0 all along", not k["collision"]),
            ("no red signal passed", str(k["overruns"]), "= 0", k["overruns"] == 0)]


# What each KPI above is, for report.html (hil.report.kpi_info): (display name, unit, meaning[, per car])
KPI_INFO = {
    "min_gap_m": ("min gap to the train ahead", "m",
                  "smallest distance from car 1's front to the leading train's last wagon (none: no "
                  "train ahead)"),
    "collision": ("collision", "yes/no", "that gap reached 0"),
    "overruns": ("red-signal overruns", "count", "signals the front passed while they showed red"),
    "min_signal_m": ("closest to a red signal", "m",
                     "smallest distance from the front to a signal ahead showing red (none: no red signal)"),
    "applications": ("ACD brake applications", "count", "ACD_BRAKE_REQ.Request rising from NONE"),
    "unnecessary": ("unnecessary applications", "count",
                    "applications while the obstacle was farther than braking distance + release hysteresis"),
    "first_brake_s": ("first ACD application", "s", "time of the ACD's first brake request (none: none)"),
    "stop_gap_m": ("gap at the end", "m", "gap to the train ahead when the run ended (none without one)"),
    "prediction": ("prediction", "yes/no",
                   "the ACD's dead reckoning with an uncertainty margin (seed 002 §X)"),
}
