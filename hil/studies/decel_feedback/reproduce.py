"""`railhil reproduce decel-feedback`: seed 004's line test (§6.4, Figs. 19-20), the BCU with deceleration
feedback against the open-loop BCU, in lockstep over CAN.

scenarios/decel_feedback.toml: a 6-car train brakes from 60 km/h at the full service step (target
1.32 m/s², the paper's line test) on dry rail with a 5 ‰ ramp while the pad friction drifts with speed and
disc temperature (eqs. (24)-(25)).  Two runs: as given (closed loop) and with
`decel_feedback.closed_loop = false` (the function monitors only).  The paper shows the two as Figs. 19-20
(cylinder pressure and deceleration before/after) and states that the closed loop is smoother and closer
to the target, without figures; ours are the share of time the actual/target deceleration stays within
the 90-110 % band of §5.2, and the pressure and deceleration side by side (fig19_20.png).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from hil.campaign.jobs import add_run_options, checked_out, map_jobs
from hil.errors import RailhilError
from hil.report.run import run_scenario_lockstep
from hil.resources import scenarios_dir
from hil.scenario import load_scenario
from hil.studies.decel_feedback.plots import compare_runs

SCENARIO = "decel_feedback"
PAPER_TARGET_MPS2 = 1.32     # seed 004 §6.4: the line test's target deceleration at 60 km/h


class DecelFeedbackError(RailhilError):
    """A reproduction that cannot run as asked (bad option value)."""


def run_one(job: tuple[bool, str]) -> dict:
    closed, out = job
    scenario = load_scenario(scenarios_dir() / f"{SCENARIO}.toml",
                             sets=[f"decel_feedback.closed_loop={'true' if closed else 'false'}"])
    report = run_scenario_lockstep(scenario, Path(out))
    return {"closed_loop": closed, "run_dir": out, "decel_feedback": report.kpis["decel_feedback"],
            "stopping_distance_m": report.kpis["stopping_distance_m"],
            "wsp_activations": report.kpis["wsp_activations"]}


def table(rows: list[dict]) -> list[str]:
    by = {r["closed_loop"]: r for r in rows}
    lines = [f"Seed 004 line test (60 km/h, target {PAPER_TARGET_MPS2} m/s²)     open loop    closed loop"
             f"   paper"]

    def pct(x):
        return "—" if x is None else f"{100 * x:.1f} %"

    ko, kc = by[False]["decel_feedback"], by[True]["decel_feedback"]
    lines.append(f"  actual/target in 90-110 % after engagement {pct(ko['within_band_after_engagement']):>10}"
                 f"   {pct(kc['within_band_after_engagement']):>10}   closed loop 'closer to the target'")
    lines.append(f"  ... over the whole stop                    {pct(ko['within_band_judged']):>10}"
                 f"   {pct(kc['within_band_judged']):>10}")
    for key, label in (("ratio_min", "ratio min"), ("ratio_max", "ratio max"),
                       ("ratio_rms_error", "rms error")):
        lines.append(f"  {label:<43}{ko.get(key, float('nan')):>10.3f}   {kc.get(key, float('nan')):>10.3f}")
    lines.append(f"  WSP activations (dry rail: none expected)  {sum(by[False]['wsp_activations']):>10}"
                 f"   {sum(by[True]['wsp_activations']):>10}   none")
    lines.append(f"  stopping distance [m]                      {by[False]['stopping_distance_m']:>10.2f}"
                 f"   {by[True]['stopping_distance_m']:>10.2f}")
    eng = kc["engaged_at_s"]
    lines.append("  closed loop engaged at " + (f"{eng:.2f} s ({kc['engage_source']})" if eng is not None
                                                else "— (the condition was never met)"))
    return lines


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_run_options(p, "decel-feedback", "the two run folders, fig19_20.png and results.json")


def run(args: argparse.Namespace) -> int:
    out = checked_out(args, DecelFeedbackError)
    t0 = time.perf_counter()
    todo = [(False, str(out / "open-loop")), (True, str(out / "closed-loop"))]
    rows = map_jobs(run_one, todo, min(args.jobs, 2), "decel-feedback runs", not args.quiet)
    for line in table(rows):
        print(line)
    fig = compare_runs(Path(todo[0][1]), Path(todo[1][1]), out / "fig19_20.png")
    js = out / "results.json"
    js.write_text(json.dumps(rows, indent=1) + "\n")
    print(f"\n2 lockstep runs over CAN in {time.perf_counter() - t0:.1f} s")
    print("files: " + ", ".join([fig.as_posix(), js.as_posix()] + [r["run_dir"] for r in rows]))
    return 0
