"""`make soak`: consecutive real-time runs of the default scenario (SOAK_RUNS, default 10; each to its end,
about 30 s), each judged by its own verdict against the [realtime.deadline] budget (issue #17: 10 of 10
held).  Prints one line per run — held or not, the bench's and the machine's misses, the 10 ms nodes'
p99 lateness, the machine probe's p99 and its worst stall — then the count, with the load average.

    python bench/soak_realtime.py            # SOAK_RUNS=N for another count
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNS = int(os.environ.get("SOAK_RUNS", "10"))


def one_run(k: int) -> dict:
    with tempfile.TemporaryDirectory(prefix="railhil-soak-") as tmp:
        t = time.monotonic()
        done = subprocess.run([sys.executable, "-m", "hil", "run", "scenarios/default.toml", "--realtime",
                               "--out", tmp, "-q", "--exit-zero"],    # the verdict: read from kpis.json
                              cwd=ROOT, capture_output=True, text=True, timeout=600)
        if done.returncode != 0:
            return {"run": k, "error": (done.stderr.strip().splitlines() or ["?"])[-1]}
        kpis = json.loads((Path(tmp) / "kpis.json").read_text())
    rt = kpis["realtime"]
    worst = max(rt["nodes"], key=lambda n: rt["nodes"][n]["worst_bench_miss_us"])
    return {"run": k, "held": rt["held"], "bench": rt["misses_bench"], "machine": rt["misses_machine"],
            "behind": rt.get("misses_bench_behind", 0),
            "probes": rt.get("misses_machine_probes", rt["misses_machine"]),
            "p99": rt["p99_10ms_us"], "probe_p99": rt["machine"].get("p99_us"),
            "stall_ms": (rt["machine"].get("worst_stall_us") or 0) / 1e3, "worst": worst,
            "worst_miss_ms": rt["nodes"][worst]["worst_bench_miss_us"] / 1e3,
            "stop_m": kpis["stopping_distance_m"], "wall_s": time.monotonic() - t,
            "load": os.getloadavg()[0]}


def main() -> int:
    print(f"soak: {RUNS} real-time runs of scenarios/default.toml, one after the other; 1-min load average "
          f"{os.getloadavg()[0]:.1f}", flush=True)
    held = 0
    for k in range(1, RUNS + 1):
        r = one_run(k)
        if "error" in r:
            print(f"  run {k:2d}: FAILED: {r['error']}", flush=True)
            continue
        held += r["held"]
        verdict = "held    " if r["held"] else "NOT HELD"
        print(f"  run {k:2d}: {verdict} misses bench {r['bench']:3d} ({r['behind']} behind another cycle of "
              f"their host) / machine {r['machine']:3d} "
              f"({r['probes']} at the probes' stalls); 10 ms p99 {r['p99']} us; "
              f"probe p99 {r['probe_p99']} us, worst stall {r['stall_ms']:.1f} ms; worst "
              f"bench miss {r['worst_miss_ms']:.1f} ms ({r['worst']}); stop {r['stop_m']:.2f} m; load "
              f"{r['load']:.1f}", flush=True)
    print(f"soak: {held} of {RUNS} runs held real time (goal: {RUNS} of {RUNS}): "
          f"{'met' if held == RUNS else 'NOT met'}; 1-min load average {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
