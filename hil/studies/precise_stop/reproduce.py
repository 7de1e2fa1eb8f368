"""`railhil reproduce precise-stop`: seed 002 §VII, stopping at a target point, as a seeded randomized
campaign of lockstep runs of scenarios/precise_stop.toml per method, judged on the plant's truth.

The paper's test (§VII): the train departs 1500 m before the stop point (`--distance`, default 1500 m),
coasting at 90 km/h; the platform's balises lie 200 m and 25 m before the point.  Each run varies what the
BCU does not know: train mass ±15 % (the BECUs' inverse brake model assumes the nominal 40 t), gradient
±5 ‰ and pad friction ±15 % (as the brake torque gain, which scales with μ_pad; the BECUs assume the
nominal gain).  Methods: the paper's adaptive search without ("adaptive", Fig. 2; paper ±25-45 m) and with
the differentiation unit ("adaptive_diff", Fig. 3; paper ±2-7 m), the PI baseline, and the PI without
balises (the odometer alone).  The first table gives per method the mean, p95 and max |stop error|, the
mean signed error and the p95 of each run's jerk p95; the second the fluctuations about the curve (kpis.py
`curve_fluctuations`) next to the paper's.  The verdicts: the differentiation unit at least
`GOAL_DIFF_FACTOR` times more precise than the plain search (p95), and the best method's p95 within
`GOAL_P95_M`; a verdict that fails makes the command exit 1 (`--exit-zero` for exploratory runs).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from hil.campaign.jobs import add_run_options, checked_out, map_jobs
from hil.errors import RailhilError
from hil.report.run import run_scenario_lockstep
from hil.resources import scenarios_dir
from hil.scenario import load_scenario
from hil.studies.precise_stop.kpis import PAPER_FLUCTUATION, PAPER_STOP_ERROR_M
from plant_sim.params import BrakeParams

SCENARIO = "precise_stop"
METHODS = ("adaptive", "adaptive_diff", "pi")
NO_BALISES = "pi, no balises"      # the PI baseline on the odometer alone (the foundation's reference point)
#: the platform's balises, metres before the stop point (a pre-announcing one and one just before the
#: stop, as precision-stopping balise groups are laid; chosen)
BALISES_BEFORE_M = (200.0, 25.0)
PAPER_DISTANCE_M = 1500.0          # §VII: "a train departs from the coordinates x = 1500 m"
GOAL_P95_M = 0.3                   # platform-door accuracy for the best method (issue #5)
GOAL_DIFF_FACTOR = 5.0             # §VII: ±25-45 m without the unit, ±2-7 m with it: 5-10 times (issue 43)
#: the paper's bands of |stop error| [m] (§VII a)
PAPER_BAND_M = {"adaptive": (25.0, 45.0), "adaptive_diff": (2.0, 7.0)}
FLUCTUATIONS = (("curve_s_dev_max_m", "S", "m", 2), ("curve_v_dev_max_mps", "V", "m/s", 2),
                ("curve_a_dev_max_mps2", "a", "m/s²", 3))


class PreciseStopError(RailhilError):
    """A reproduction that cannot run as asked (bad option value)."""


def randomized_sets(method: str, k: int, distance_m: float | None, balises: bool = True) -> list[str]:
    """`--set` overrides of run k (seeded): mass ±15 %, gradient ±5 ‰, pad friction ±15 % (brake gain),
    the stop point `distance_m` ahead (None: uniform in 400–1500 m), balises BALISES_BEFORE_M before it."""
    rng = np.random.default_rng([2, k])               # seed 002, run k: the same for every method
    mass = 40_000.0 * rng.uniform(0.85, 1.15)
    permille = rng.uniform(-5.0, 5.0)
    gain = BrakeParams().alpha_squeeze_Nm_per_Pa * rng.uniform(0.85, 1.15)
    spread = rng.uniform(400.0, 1500.0)               # drawn always, so that the plant does not depend on it
    dist = spread if distance_m is None else distance_m
    laid = [round(dist - b, 2) for b in BALISES_BEFORE_M] if balises else []
    return [f"precise_stop.method={method}", f"seed={k}", f"train.mass_kg={mass:.1f}",
            f"track.gradient=[{{from_m = -500.0, permille = {permille:.3f}}}]",
            f"plant.brake_gain_Nm_per_Pa={gain:.6f}", f"desk.0.target_stop_m={dist:.2f}",
            f"track.balises={laid}"]


def run_one(args: tuple[str, int, float | None, str]) -> dict:
    """One lockstep run (in a worker process): its precise-stop KPIs, labelled with the method."""

    label, k, distance_m, out = args
    method, balises = ("pi", False) if label == NO_BALISES else (label, True)
    scenario = load_scenario(scenarios_dir() / f"{SCENARIO}.toml",
                             sets=randomized_sets(method, k, distance_m, balises))
    report = run_scenario_lockstep(scenario, Path(out) / f"{label.replace(', ', '_').replace(' ', '_')}_{k}")
    return {**report.kpis["precise_stop"], "method": label, "k": k}


def run_campaign(out: Path, methods, runs: int, distance_m: float | None = PAPER_DISTANCE_M, jobs: int = 2,
                 progress: bool = False) -> list[dict]:
    todo = [(m, k, distance_m, str(out)) for m in methods for k in range(runs)]
    return map_jobs(run_one, todo, jobs, "precise-stop runs", progress)


def table(results: list[dict]) -> dict[str, dict[str, float]]:
    """Per method: mean, p95 and max |stop error| [m], mean signed error [m], p95 of the jerk p95, and for
    each fluctuation (S, V, a) the mean and the max over the runs of each run's max |·| (None when no run
    has it)."""
    out = {}
    for m in dict.fromkeys(r["method"] for r in results):
        rs = [r for r in results if r["method"] == m]
        err = np.array([r["stop_error_m"] if r["stop_error_m"] is not None else math.inf for r in rs])
        jerk = np.array([r["jerk_p95_mps3"] for r in rs])
        ae = np.abs(err)
        out[m] = {"runs": len(rs), "mean": float(np.mean(ae)), "p95": float(np.percentile(ae, 95)),
                  "max": float(np.max(ae)), "bias": float(np.mean(err)),
                  "jerk_p95": float(np.percentile(jerk, 95))}
        for key, *_ in FLUCTUATIONS:
            vals = [r[key] for r in rs if r.get(key) is not None]
            out[m][key] = (float(np.mean(vals)), float(np.max(vals))) if vals else None
    return out


def verdicts(t: dict) -> list[tuple[str, bool | None]]:
    """The gating verdicts as (line, passed); passed None: not judged (a method it needs did not run)."""
    out: list[tuple[str, bool | None]] = []
    if "adaptive" in t and "adaptive_diff" in t:
        plain, diff = t["adaptive"]["p95"], t["adaptive_diff"]["p95"]
        factor = plain / diff if diff > 0.0 else math.inf
        ok = factor >= GOAL_DIFF_FACTOR
        out.append((f"differentiation unit: p95 |stop error| {plain:.2f} m without, {diff:.2f} m with it: "
                    f"{factor:.1f}x more precise, goal >= {GOAL_DIFF_FACTOR:g}x (paper 5-10x) "
                    + ("met" if ok else "NOT met"), ok))
    else:
        out.append(("differentiation unit: not judged (needs both adaptive and adaptive_diff)", None))
    best = min(t, key=lambda m: t[m]["p95"])
    if any(m.startswith("pi") for m in t):
        ok = t[best]["p95"] <= GOAL_P95_M
        out.append((f"best method {best}: p95 |stop error| {t[best]['p95']:.2f} m, goal <= {GOAL_P95_M} m "
                    + ("met" if ok else "NOT met"), ok))
    else:
        out.append((f"best method {best}: p95 |stop error| {t[best]['p95']:.2f} m, goal <= {GOAL_P95_M} m "
                    f"not judged (the goal is the baseline's: pi did not run)", None))
    return out


def band_line(m: str, r: dict) -> str:
    """Where the method's typical (mean) and p95 |stop error| lie against the paper's band (informative)."""
    lo, hi = PAPER_BAND_M[m]

    def where(x: float) -> str:
        return "below" if x < lo else "in" if x <= hi else "ABOVE"
    return (f"paper band {m}: ±{lo:g}-{hi:g} m; mean |e| {r['mean']:.2f} m {where(r['mean'])}, "
            f"p95 {r['p95']:.2f} m {where(r['p95'])} the band")


def table_lines(t: dict) -> list[str]:
    lines = [f"{'method':14s} {'runs':>4s} {'mean|e|':>8s} {'p95|e|':>8s} {'max|e|':>8s} {'mean e':>8s} "
             f"{'jerk p95':>9s}  paper"]
    for m, r in t.items():
        lines.append(f"{m:14s} {r['runs']:4d} {r['mean']:8.2f} {r['p95']:8.2f} {r['max']:8.2f} "
                     f"{r['bias']:+8.2f} {r['jerk_p95']:9.3f}  "
                     f"{PAPER_STOP_ERROR_M.get(m, '— (not in the paper)')}")
    lines += ["", "fluctuation about the curve: max |S - S_th| [m], |V - V_th| [m/s], |a - a_th| [m/s²] "
              "per run, mean over the runs (worst run)"]
    lines.append(f"{'method':14s} {'S':>16s} {'V':>14s} {'a':>16s}   paper (§VII)")
    for m, r in t.items():
        cells = []
        for (key, _, _, nd), width in zip(FLUCTUATIONS, (16, 14, 16), strict=True):
            cell = f"{r[key][0]:.{nd}f} ({r[key][1]:.{nd}f})" if r[key] else "—"
            cells.append(cell.rjust(width))
        paper = PAPER_FLUCTUATION.get(m)
        lines.append(f"{m:14s} {' '.join(cells)}   "
                     + (f"±{paper[0]:g} m, ±{paper[1]:g} m/s, ±{paper[2]:g} m/s²" if paper else "—"))
    lines.append("")
    lines += [band_line(m, t[m]) for m in PAPER_BAND_M if m in t]
    lines += [line for line, _ in verdicts(t)]
    return lines


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, default=20,
                   help="seeded randomized runs per method (default 20; about 5 s of wall time per run on "
                        "one core, so the default takes about 4 min on 2 cores)")
    p.add_argument("--distance", type=float, default=PAPER_DISTANCE_M, metavar="M",
                   help="the stop point this far ahead of the train's start [m] (default "
                        f"{PAPER_DISTANCE_M:g}, the paper's test)")
    p.add_argument("--method", dest="methods", action="append", choices=METHODS + (NO_BALISES,),
                   help="a method to run (repeatable; default: all four)")
    p.add_argument("--exit-zero", action="store_true",
                   help="exploratory runs: exit 0 even when a verdict failed (the table still says NOT met); "
                        "by default a failed verdict exits 1")
    add_run_options(p, "precise-stop", "the run folders and results.json")


def run(args: argparse.Namespace) -> int:
    if args.runs < 1:
        raise PreciseStopError(f"--runs {args.runs}: expected at least 1 run per method")
    if not 50.0 <= args.distance <= 20_000.0:
        raise PreciseStopError(f"--distance {args.distance}: expected a stop point 50-20000 m ahead")
    out = checked_out(args, PreciseStopError)
    t0 = time.perf_counter()
    methods = tuple(args.methods or METHODS + (NO_BALISES,))
    results = run_campaign(out, methods, args.runs, args.distance, args.jobs, progress=not args.quiet)
    t = table(results)
    for line in table_lines(t):
        print(line)
    js = out / "results.json"
    js.write_text(json.dumps(results, indent=1) + "\n")
    print(f"\n{len(results)} lockstep runs over CAN in {time.perf_counter() - t0:.1f} s")
    print(f"files: {js}, run folders in {out}")
    failed = [line for line, ok in verdicts(t) if ok is False]
    return 1 if failed and not args.exit_zero else 0
