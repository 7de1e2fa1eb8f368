"""`make bench`: every benchmark, in one process, printed as one table, then the figures that have a goal
gathered at the end, each next to its goal and the issue that set it (each benchmark's ISSUE).

BENCH_FRAMES=N shortens the multi-process bus benchmark (default 10⁶ frames, a few minutes);
BENCH_RT_S=S the real-time runs (the lateness runs and the gateway's; default: to the scenario's end);
BENCH_ONLY=name,name runs only those.
"""

from __future__ import annotations

import importlib
import os
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

BENCHES = ("bench_codec", "bench_lockstep", "bench_plain", "bench_trace", "bench_mf4", "bench_governor",
           "bench_fmu", "bench_gps", "bench_campaign", "bench_frame_io", "bench_realtime", "bench_gateway",
           "bench_bus")


def main() -> int:
    print(f"railhil benchmarks — Python {platform.python_version()} on {platform.machine()}, "
          f"{os.cpu_count()} CPUs, 1-min load average {os.getloadavg()[0]:.1f}")
    only = [b for b in os.environ.get("BENCH_ONLY", "").split(",") if b]
    goals: list[tuple[str, str, str, str]] = []
    for name in BENCHES:
        if only and name not in only:
            continue
        module = importlib.import_module(name)
        print(f"\n[{name}] {module.__doc__.strip().splitlines()[0]}", flush=True)
        try:
            rows = module.run()
        except Exception as exc:          # one broken benchmark does not hide the others' figures
            rows = [("FAILED", f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}")]
        for label, figure in rows:
            print(f"  {label:<62} {figure}", flush=True)
            if "goal" in label:
                goals.append((name, getattr(module, "ISSUE", "?"), label, figure))
    if goals:
        print("\n[goals] each figure next to its goal and the issue that set it, measured above in this run")
        for name, issue, label, figure in goals:
            print(f"  {name:<16} {issue:<9} {label:<62} {figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
