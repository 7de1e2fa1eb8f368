"""`railhil reproduce wheel-slip`: seed 001's Figs. 8 and 9, each with and without the reference governor,
in lockstep over CAN, our figures next to the paper's.

* Fig. 8 — scenarios/rg_low_adhesion.toml: r⁰ = 0.25 g on an adhesion peak of 0.2 g for 30 s.  Without
  the governor the WSP vents in a limit cycle (paper: mean tracking error 0.0718 g); with it the WSP never
  engages and the error settles at 0.0682 g (the least any reference gives without s > s̄); the governor
  shortens the manoeuvre's distance by 1.62 m.
* Fig. 9 — scenarios/rg_aggressive.toml: an aggressive PI; without the governor it overshoots into the
  WSP and cycles, with it there is no WSP and it settles faster (the paper gives no numbers).

Each run leaves its run folder under --out (trace, truth, kpis.json, wheel_slip.png, report.html); the
table prints at the end and results.json holds it.
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
from hil.studies.wheel_slip.kpis import (
    PAPER_FIG8_MEAN_ERROR_G,
    PAPER_FIG8_SS_ERROR_G,
    PAPER_FIG8_STOPPING_GAIN_M,
)

FIGURES = {"fig8": "rg_low_adhesion", "fig9": "rg_aggressive"}


class WheelSlipError(RailhilError):
    """A reproduction that cannot run as asked (bad option value)."""


def run_one(job: tuple[str, bool, str]) -> dict:
    """One lockstep run: figure, governor on/off, run folder -> its kpis.json entries."""

    figure, governor, out = job
    scenario = load_scenario(scenarios_dir() / f"{FIGURES[figure]}.toml",
                             sets=[f"wheel_slip.governor={'true' if governor else 'false'}"])
    report = run_scenario_lockstep(scenario, Path(out))
    return {"figure": figure, "governor": governor, "run_dir": out, "wheel_slip": report.kpis["wheel_slip"],
            "stopping_distance_m": report.kpis["stopping_distance_m"]}


def reproduce(out: Path, jobs: int, progress: bool = True) -> list[dict]:
    todo = [(fig, gov, str(out / f"{fig}-governor-{'on' if gov else 'off'}"))
            for fig in FIGURES for gov in (False, True)]
    return map_jobs(run_one, todo, jobs, "wheel-slip runs", progress)


def _g(x) -> str:
    return "—" if x is None else f"{x:.4f}"


def table(rows: list[dict]) -> list[str]:
    """Ours next to the paper's, per figure and governor setting."""
    k = {(r["figure"], r["governor"]): r["wheel_slip"] for r in rows}
    off8, on8, off9, on9 = k[("fig8", False)], k[("fig8", True)], k[("fig9", False)], k[("fig9", True)]
    gain = off8["distance_m"] - on8["distance_m"]
    lines = ["Fig. 8 (r0 = 0.25 g, adhesion peak 0.2 g, 30 s)   without governor      with governor",
             f"  mean tracking error [g]        ours {_g(off8['mean_error_g']):>8}  paper "
             f"{PAPER_FIG8_MEAN_ERROR_G}"
             f"    ours {_g(on8['mean_error_g'])}",
             f"  steady-state error [g]         ours {_g(off8['steady_state_error_g']):>8}"
             f"                  ours {_g(on8['steady_state_error_g'])}  paper {PAPER_FIG8_SS_ERROR_G}"
             f"  (bound {_g(on8.get('steady_state_bound_g'))})",
             f"  WSP activations                ours {off8['wsp_activations'][0]:>8}  paper: a limit cycle"
             f"   ours {on8['wsp_activations'][0]}  paper: never",
             f"  max slip, every 1 ms step      ours {off8['max_slip_every_step_mps'][0]:>8.4f}"
             f"                  ours {on8['max_slip_every_step_mps'][0]:.4f} m/s "
             f"(s̄ = {on8['slip_limit_mps']})",
             f"  distance over the manoeuvre    ours {off8['distance_m']:>8.2f}"
             f"                  ours {on8['distance_m']:.2f} m: the governor gains {gain:.2f} m"
             f" (paper {PAPER_FIG8_STOPPING_GAIN_M} m)",
             "Fig. 9 (aggressive PI; the paper publishes no numbers: without the governor it overshoots into "
             "WSP and cycles, with it no WSP and faster settling)",
             f"  WSP activations                ours {off9['wsp_activations'][0]:>8}"
             f"                  ours {on9['wsp_activations'][0]}",
             "  settling time (±2 %) [s]       ours "
             + (f"{off9['settling_time_s']:>8.2f}" if off9["settling_time_s"] is not None else "     not")
             + "                  ours "
             + (f"{on9['settling_time_s']:.2f}" if on9["settling_time_s"] is not None else "not settled")]
    return lines


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_run_options(p, "wheel-slip", "the four run folders and results.json")


def run(args: argparse.Namespace) -> int:
    out = checked_out(args, WheelSlipError)
    t0 = time.perf_counter()
    rows = reproduce(out, args.jobs, progress=not args.quiet)
    for line in table(rows):
        print(line)
    js = out / "results.json"
    js.write_text(json.dumps(rows, indent=1) + "\n")
    print(f"\n{len(rows)} lockstep runs over CAN in {time.perf_counter() - t0:.1f} s")
    print("files: " + ", ".join([js.as_posix()] + [r["run_dir"] for r in rows]))
    return 0
