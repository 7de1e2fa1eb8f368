"""Reference governor (seed 001 eq. 9): time per evaluation of govern(), mean / p99 / max, in closed loop.

Each case runs the BECU's closed-loop model for its scenario -- the governor and the deceleration PI
(eq. 16) of scenarios/rg_*.toml as hil.runtime.assembly builds them, the cylinder lag (eq. 4), the hysteresis
(eq. 10a) and the friction lag whose rate switches at random inside the inclusion every cycle -- and
times every call of govern(), as the BECU makes it once per 10 ms cycle. There is no offline set
computation: the admissible set is evaluated online by prediction (firmware_py.governor's docstring).
Goal (issue #4): p99 ≤ 1 ms per evaluation.

    python bench/bench_governor.py
"""

from __future__ import annotations

import random
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from firmware_py.governor import GovernorState, govern, play  # noqa: E402
from firmware_py.pi import pi_step  # noqa: E402
from hil.scenario import load_scenario  # noqa: E402
from hil.scenario.params import run_params  # noqa: E402
from hil.studies.wheel_slip.scenario import reference_governor_params  # noqa: E402

CASES = (  # (label, scenario, simulated seconds)
    ("rg_low_adhesion, r0 = 0.25 g", "rg_low_adhesion.toml", 10.0),
    ("rg_aggressive, r0 = 0.178 g", "rg_aggressive.toml", 6.0),
)


def closed_loop_times(scenario: str, seconds: float, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(time per govern() call [s], predictions per call) over a closed-loop run of the BECU's model."""
    sc = load_scenario(ROOT / "scenarios" / scenario)
    gp = reference_governor_params(sc, 1, run_params(sc)).model
    r0 = sc.bcu.step_decel_mps2[7]
    rng = random.Random(seed)
    i = p = tau = f = 0.0
    r_prev = None
    times, evals = [], []
    for _ in range(round(seconds / gp.dt_s)):
        x = GovernorState(i, p, tau, f)
        t0 = time.perf_counter()
        d = govern(x, r0, gp, r_prev)
        times.append(time.perf_counter() - t0)
        evals.append(d.evaluations)
        r_prev = d.r_mps2
        u, i, _ = pi_step(gp.pi, i, d.r_mps2 - f / gp.mass_kg, gp.dt_s)      # eq. (16)
        p = u + (p - u) * gp.phi                                             # eq. (4)
        tau = play(tau, p, gp)                                               # eq. (10a)
        xi = rng.random()
        a = xi * gp.a_lo + (1.0 - xi) * gp.a_hi
        f = a * f + (1.0 - a) * gp.kappa * tau                               # slip inclusion, in F
    return np.array(times), np.array(evals)


def run() -> list[tuple[str, str]]:
    rows = []
    for label, scenario, seconds in CASES:
        t, n = closed_loop_times(scenario, seconds)
        us = t * 1e6
        rows.append((f"{label}: mean / p99 / max per evaluation",
                     f"{us.mean():.0f} / {np.percentile(us, 99):.0f} / {us.max():.0f} µs"))
        rows.append((f"{label}: predictions per evaluation, mean / max", f"{n.mean():.1f} / {n.max()}"))
        rows.append((f"{label}: evaluations over 1 ms", f"{np.mean(us > 1000.0) * 100:.1f} %"))
    rows.append(("offline set computation (time, size)", "none (online prediction)"))
    return rows


def main() -> None:
    rows = run()
    width = max(len(label) for label, _ in rows)
    print(f"reference governor, closed loop at 10 ms (Python {sys.version.split()[0]})")
    for label, figure in rows:
        print(f"  {label:<{width}}  {figure:>24}")


if __name__ == "__main__":
    main()
