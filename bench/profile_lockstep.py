"""Where the default lockstep run's wall goes, per component: py-spy samples `bench_lockstep`'s traced run.

py-spy (a sampling profiler: it reads the process from outside, so the run is not slowed per call as
under cProfile or line_profiler) records RUNS traced runs of scenarios/default.toml, after one run not
counted (compiled code loaded, caches warm).  Each sample is counted for the innermost component on its
stack (the controllers, node dispatch, the event loop, the bit-timed bus, ...), a sample inside
`prepare_lockstep` for the set-up; the table gives each component's share of the samples in the runs.
docs/performance.md ("Profiling") shows its table.

On the compiled build (`railhil --version`), a compiled module has no Python frames: py-spy samples the
native stacks too (`--native`), and a frame of mypyc's C function for a module (`CPyDef_becu___Becu___step`:
mypyc's prefix of the module, then the function) counts for that module's component.  `RAILHIL_PURE=1`
profiles the pure build.

    make profile                                    # installs py-spy (the `profile` extra), then runs this
    python bench/profile_lockstep.py [--runs 8] [--rate HZ] [--raw FILE]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ENTRY = "_profiled_runs"       # the child's function whose samples are counted (the warm-up run is not)

# (component, what names it in a stack frame: a path or a generated code's file name); the innermost
# frame that matches one decides, so a callee's own component wins over its caller's; in a frame, the first
# component that names it
COMPONENTS = (
    ("node dispatch (`hil/runtime/node.py`: cycle, output checks, receive, RxTable)",
     ("hil/runtime/node.py", "firmware_py/rx.py")),       # before the controllers: the table is the node's
    ("controllers (firmware_py: BECU, BCU)", ("firmware_py/",)),
    ("event loop (`hil/runtime/lockstep.py`, `release.py`)", ("hil/runtime/lockstep.py",
                                                              "hil/runtime/release.py")),
    ("codec encode/decode (generated code)", ("railhil codec", "hil/can/codec.py")),
    ("SecOC (`hil/can/secoc.py` + `cryptography` CMAC)", ("hil/can/secoc.py", "cryptography")),
    ("plant physics + sensors (plant_sim, compiled)", ("plant_sim/",)),
    ("E2E (`hil/can/e2e.py` + fastcrc)", ("hil/can/e2e.py", "fastcrc")),
    ("bit-timed bus (`hil/can/bustiming.py`: arbitration, queues, stuffing)", ("hil/can/bustiming.py",)),
    ("plant node glue + truth log (`hil/runtime/plant_node.py`)", ("hil/runtime/plant_node.py",)),
    ("trace writer (`hil/trace/writers.py`)", ("hil/trace/writers.py",)),
)
SETUP = "set-up (`prepare_lockstep`)"


def native_keys(compiled: tuple[str, ...]) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """COMPONENTS with the names of the compiled modules' C functions added to each component's keys:
    mypyc names a module's functions `CPyDef_<prefix>...` (and their Python wrappers `CPyPy_<prefix>...`),
    the prefix the shortest suffix of the module's name that tells it from the others compiled with it
    (mypyc.namegen, whose map this uses): `becu___` for firmware_py.becu."""
    from mypyc.namegen import make_module_translation_map

    modules = {path: path.removesuffix(".py").replace("/", ".") for path in compiled}
    prefix = make_module_translation_map(list(modules.values()))
    keyed = []
    for name, keys in COMPONENTS:
        c_names = tuple(f"{kind}_{prefix[module].replace('.', '___')}" for path, module in modules.items()
                        for kind in ("CPyDef", "CPyPy") if any(path.startswith(k) for k in keys))
        keyed.append((name, keys + c_names))
    return tuple(keyed)


def shares(raw_lines: list[str], components: tuple[tuple[str, tuple[str, ...]], ...] = COMPONENTS
           ) -> tuple[Counter, int]:
    """(samples per component, samples in the counted runs) from py-spy's raw output ("f1;f2;... n")."""
    counts: Counter = Counter()
    total = 0
    for line in raw_lines:
        stack, _, n = line.rstrip().rpartition(" ")
        if not stack or not n.isdigit():
            continue
        frames = stack.split(";")
        if not any(ENTRY in f for f in frames) or not any("run_lockstep" in f for f in frames):
            continue
        total += int(n)
        if any("prepare_lockstep" in f for f in frames):
            counts[SETUP] += int(n)
            continue
        for frame in reversed(frames):     # run_lockstep's own frame, the event loop, at the latest
            hit = next((name for name, keys in components if any(k in frame for k in keys)), None)
            if hit is not None:
                counts[hit] += int(n)
                break
    return counts, total


def _profiled_runs(runs: int) -> None:
    from bench_lockstep import _once

    for _ in range(runs):
        _once(True)


def child(runs: int) -> None:
    """The profiled process: one run not counted, then `runs` runs inside ENTRY."""
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_lockstep import _once

    _once(True)
    _profiled_runs(runs)


def py_spy() -> str | None:
    here = Path(sys.executable).parent / "py-spy"
    return str(here) if here.exists() else shutil.which("py-spy")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=8, help="traced runs counted (default 8)")
    parser.add_argument("--rate", type=int, help="samples per second (default 400; 100 on the compiled "
                        "build, whose native stacks py-spy takes milliseconds to unwind: at 400 Hz the run "
                        "stalls)")
    parser.add_argument("--raw", type=Path, help="also keep py-spy's raw samples in FILE")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args.runs)
        return 0
    if args.runs < 1 or (args.rate is not None and args.rate < 1):
        print("profile_lockstep: --runs and --rate must be at least 1", file=sys.stderr)
        return 2
    spy = py_spy()
    if spy is None:
        print("profile_lockstep: py-spy not found; install it with `make profile` or "
              "`.venv/bin/pip install 'railhil[profile]'`", file=sys.stderr)
        return 2
    from hil.build import COMPILED, state

    build = state()
    native = build.mode == "compiled"          # mypyc's C functions have no Python frames: py-spy --native
    components = native_keys(COMPILED) if native else COMPONENTS
    if args.rate is None:
        args.rate = 100 if native else 400
    with tempfile.TemporaryDirectory(prefix="railhil-profile-") as tmp:
        raw = args.raw or Path(tmp) / "samples.txt"
        cmd = [spy, "record", "--rate", str(args.rate), "--format", "raw", "--output", str(raw),
               *(["--native"] if native else []), "--",
               sys.executable, str(Path(__file__).resolve()), "--child", "--runs", str(args.runs)]
        print(f"sampling {args.runs} traced runs of scenarios/default.toml at {args.rate} Hz (py-spy"
              f"{', native stacks' if native else ''}); build: {build.line()} ...", file=sys.stderr)
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0 or not raw.exists():
            tail = " ".join((proc.stderr or proc.stdout).split())[-300:]
            print(f"profile_lockstep: py-spy failed (exit {proc.returncode}): {tail}", file=sys.stderr)
            return 1
        counts, total = shares(raw.read_text().splitlines(), components)
    if total == 0:
        print("profile_lockstep: no samples inside the runs (py-spy saw no run_lockstep)", file=sys.stderr)
        return 1
    print(f"build: {build.line()}")
    print(f"| component ({total} samples in {args.runs} runs, {args.rate} Hz) | share |")
    print("|---|---:|")
    for name, n in counts.most_common():
        print(f"| {name} | {100 * n / total:.0f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
