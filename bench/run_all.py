"""`make bench`: every benchmark, in one process, printed as one table."""

from __future__ import annotations

import importlib
import os
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

BENCHES = ("bench_codec", "bench_lockstep", "bench_trace", "bench_governor", "bench_gps", "bench_campaign")


def main() -> int:
    print(f"railhil benchmarks — Python {platform.python_version()} on {platform.machine()}, "
          f"{os.cpu_count()} CPUs")
    for name in BENCHES:
        module = importlib.import_module(name)
        print(f"\n[{name}] {module.__doc__.strip().splitlines()[0]}")
        for label, figure in module.run():
            print(f"  {label:<62} {figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
