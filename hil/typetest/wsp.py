"""Running a WSP test programme: every run in lockstep through the campaign executor (this process, local
worker processes or a Dask cluster), in two rounds: the dry references first (each strategy's demand at
each speed, hil.typetest.metrics.Demand), then every condition, whose metrics need that demand.

Each run keeps its folder (trace, truth.csv, kpis.json, run.json) under OUT/STRATEGY/CONDITION-SPEEDkmh;
its metrics are computed in the worker from the plant truth (hil.typetest.metrics) and come back small.
A run that succeeded leaves its result in its folder (wsp.json), keyed by its scenario, the DBC, the
railhil version, the metric thresholds and (a condition's run) its reference's demand: the same
programme into the same folder runs only what changed or failed (`resume`), as a campaign does.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hil.campaign.jobs import executor_map
from hil.campaign.sweep import point_key
from hil.report.run import run_scenario_lockstep
from hil.runtime.run import prepare_worker
from hil.scenario import Scenario
from hil.scenario.params import run_params
from hil.typetest.metrics import Demand, MetricParams, demand_from_dry, run_metrics, train_speed
from hil.typetest.programme import REFERENCE, Programme, RunSpec
from plant_sim.adhesion import mu_opt
from plant_sim.dynamics import car_constants, davis_resistance_scalar

PATH_STEP_S = 0.1          # the speed-over-distance path kept per run for the figures [s]
RESULT_FILE = "wsp.json"   # a run's result in its folder, for resuming


@dataclass
class RunResult:
    spec: RunSpec
    status: str                          # "ok" or "failed"
    error: str = ""
    metrics: dict = field(default_factory=dict)
    demand: Demand | None = None         # a reference run's: the demand of its strategy at its speed
    path: tuple[list[float], list[float]] = ((), ())   # (lead car position from the command [m], speed)
    wall_s: float = 0.0
    cached: bool = False                 # read from its folder's wsp.json, not run again


def available_for(scenario: Scenario) -> Callable[[float, float], float]:
    """available(x_lead, v) [m/s²]: the peak adhesion μ°(θ(x), v) × g under each car (the plant's rail and
    curve, seed 000 eq. (2)) averaged over the cars, plus the train's running resistance (Davis, eq. (4)
    seed 003) ÷ its mass; the cars at their rest pitch behind the leading one."""

    run = run_params(scenario)
    pp, track = run.plant, run.track
    cc = car_constants(pp.train)
    n = len(cc.mass_kg)
    offsets = np.arange(n) * cc.car_pitch_m
    total_mass = sum(cc.mass_kg)
    ap, g = pp.adhesion, pp.train.g_mps2
    c0, c1, c2 = n * cc.c0_N, n * cc.c1_Ns_per_m, sum(cc.c2_Ns2_per_m2)   # the train's Davis coefficients

    def available(x_lead_m: float, v_mps: float) -> float:
        v = max(v_mps, 0.0)
        mu = mu_opt(track.theta_at(x_lead_m - offsets), np.full(n, v), ap)
        return float(g * np.mean(mu) + davis_resistance_scalar(v, c0, c1, c2) / total_mass)

    return available


def run_job(spec: RunSpec, run_dir: str, params: MetricParams, demand: Demand | None) -> RunResult:
    """One run in lockstep into `run_dir` and its metrics (the worker's job; never raises).  A reference run
    without a demand derives its strategy's demand from itself."""

    prepare_worker(spec.scenario)
    t0 = time.perf_counter()
    try:
        report = run_scenario_lockstep(spec.scenario, Path(run_dir), interactive_report=False, plots=False)
        if report.outcome.reason == "interrupted":
            raise KeyboardInterrupt
        broken = {n: st for n, st in report.outcome.node_stats.items() if st.get("step_errors")}
        if broken:                       # a controller that raised sent safe values: no test result
            name, st = next(iter(broken.items()))
            raise RuntimeError(f"node {name}: {st['step_errors']} exceptions in its step() (last: "
                               f"{st.get('last_error', '?')}); the run is no test of its strategy")
        cols = report.outcome.truth.columns()
        t_cmd = report.kpis.get("brake_start_s")
        if t_cmd is None:
            raise ValueError("the run has no brake command (kpis.json brake_start_s)")
        own = demand_from_dry(cols, t_cmd) if spec.condition == REFERENCE and demand is None else None
        metrics = run_metrics(cols, t_cmd, params, own or demand, available_for(spec.scenario))
        t = cols["t_s"]
        i0 = int(np.searchsorted(t, t_cmd - 1e-9))
        step = max(1, round(PATH_STEP_S / float(np.median(np.diff(t)))))
        x = cols["x_m_1"][i0::step] - cols["x_m_1"][i0]
        v = train_speed(cols)[i0::step]
        return RunResult(spec, "ok", metrics=metrics, demand=own, path=(x.tolist(), v.tolist()),
                         wall_s=time.perf_counter() - t0)
    except Exception as exc:             # one failing run is recorded, the others go on
        return RunResult(spec, "failed", error=f"{type(exc).__name__}: {' '.join(str(exc).split())}",
                         wall_s=time.perf_counter() - t0)


def _failed(job: tuple, exc: BaseException) -> RunResult:
    return RunResult(job[0], "failed", error=f"{type(exc).__name__}: {' '.join(str(exc).split())}")


def _demand_json(d: Demand | None) -> dict | None:
    if d is None:
        return None
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in dataclasses.asdict(d).items()}


def _demand_of(data: dict | None) -> Demand | None:
    if data is None:
        return None
    return Demand(**{k: (np.asarray(v, dtype=float) if isinstance(v, list) else v) for k, v in data.items()})


def run_key(spec: RunSpec, params: MetricParams, demand: Demand | None) -> str:
    """What a run's result depends on: its scenario with the DBC and railhil's version (the campaign's
    point key), the metric thresholds and the demand it is judged against."""

    extra = json.dumps({"metrics": dataclasses.asdict(params), "demand": _demand_json(demand)},
                       sort_keys=True)
    return hashlib.sha256((point_key(spec.scenario) + extra).encode()).hexdigest()


def _cached(spec: RunSpec, run_dir: Path, key: str) -> RunResult | None:
    try:
        data = json.loads((run_dir / RESULT_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if data.get("key") != key or data.get("status") != "ok":
        return None
    return RunResult(spec, "ok", metrics=data["metrics"], demand=_demand_of(data.get("demand")),
                     path=tuple(data.get("path", ((), ()))), wall_s=data.get("wall_s", 0.0), cached=True)


def _store(r: RunResult, run_dir: Path, key: str) -> None:
    if r.status != "ok" or not run_dir.is_dir():
        return
    tmp = run_dir / f".{RESULT_FILE}.tmp"
    tmp.write_text(json.dumps({"key": key, "status": r.status, "metrics": r.metrics,
                               "demand": _demand_json(r.demand), "path": list(r.path), "wall_s": r.wall_s},
                              default=str) + "\n", encoding="utf-8")
    os.replace(tmp, run_dir / RESULT_FILE)


def _run_all(specs: list[RunSpec], demands: list[Demand | None], out_dir: Path, params: MetricParams,
             executor: Executor | None, progress, resume: bool) -> list[RunResult]:
    """`specs` with their demands: the cached ones read, the others run (and stored), in order."""

    keys = [run_key(s, params, d) for s, d in zip(specs, demands, strict=True)]
    results: list[RunResult | None] = [None] * len(specs)
    todo = []
    for i, (s, key) in enumerate(zip(specs, keys, strict=True)):
        hit = _cached(s, out_dir / s.folder, key) if resume else None
        if hit is not None:
            results[i] = hit
            if progress is not None:
                progress(hit)
        else:
            todo.append(i)
    jobs = [(specs[i], str(out_dir / specs[i].folder), params, demands[i]) for i in todo]
    ran = executor_map(run_job, jobs, executor, progress, _failed)
    for i, r in zip(todo, ran, strict=True):
        _store(r, out_dir / specs[i].folder, keys[i])
        results[i] = r
    return results


def run_programme(prog: Programme, specs: list[RunSpec], out_dir: Path, executor: Executor | None = None,
                  progress: Callable[[RunResult], None] | None = None,
                  resume: bool = True) -> list[RunResult]:
    """Every run of `specs` (the references that give a demand first), results in the order of `specs`; with
    `resume`, a run whose folder holds its result for the same key (`run_key`) is read, not run."""
    params = prog.metric_params
    refs = [s for s in specs if s.condition == REFERENCE and prog.demand_source(s.strategy) == s.strategy]
    done: dict[int, RunResult] = {}
    demands = {}
    for s, r in zip(refs, _run_all(refs, [None] * len(refs), out_dir, params, executor, progress, resume),
                    strict=True):
        done[id(s)] = r
        demands[(s.strategy, s.speed_kmh)] = r.demand
    rest = [s for s in specs if id(s) not in done]
    wanted = [demands.get((prog.demand_source(s.strategy), s.speed_kmh)) for s in rest]
    for s, d, r in zip(rest, wanted, _run_all(rest, wanted, out_dir, params, executor, progress, resume),
                       strict=True):
        if r.status == "ok" and d is None:
            r.metrics = {**r.metrics, "note": (
                f"the dry reference of {prog.demand_source(s.strategy)} failed: judged against its own"
                if s.condition == REFERENCE else "its dry reference failed: no ideal stop")}
        done[id(s)] = r
    return [done[id(s)] for s in specs]
