"""Real-time cycle lateness of the default scenario against the machine's own floor and python-can's
send_periodic, and its CPU cost against a lockstep run of the same scenario (issue #17).

Each real-time run is `railhil run scenarios/default.toml --realtime` as a user runs it (a subprocess, its
own udp_multicast group), to its end (standstill, about 30 s) unless BENCH_RT_S cuts it: one with grouped
hosting (the default: every ECU in one process, the plant in its own), one with per-node hosting.  The
lateness of a cycle = CLOCK_MONOTONIC when the host releases it minus its absolute deadline, as the
runtime records every cycle; kpis.json `realtime` has the pooled p50/p99 of the 10 ms nodes (BCU,
BECU1-6), the plant's, the verdict against the budget and the machine probe's figures (a bare loop per
CPU sleeping to absolute 10 ms deadlines during the run, one priority above the nodes).

Beside each run, on the same bus, one more process with the nodes' real-time priority runs python-can's
`bus.send_periodic(msg, 0.010)` (its thread: absolute due times, `time.sleep` until due) while its main
thread receives the bus traffic, as a node does, from the run's first frame to its end; its lateness is
taken in python-can's `modifier_callback`, right before each send.  Where rt-tests is installed,
cyclictest (`-m -p 80 -i 10000 --laptop`, its histogram) runs beside the grouped run too.  `--laptop`:
by default cyclictest holds /dev/cpu_dma_latency at 0 while it runs, which puts every CPU's idle states,
and so the run beside it, in other conditions than the per-node run and a user's run ([realtime]
cpu_latency_us, "off" by default; docs/lockstep-and-realtime.md).  Without it, on 2026-12-04 at 18:03 the
grouped run's 10 ms p99 was 0 µs and the probe's 46 µs, against 70 and 118 µs at 17:15 with nothing
held.

CPU: the CPU seconds of the whole command (every process it starts, startup and the run folder included)
per simulated second, for the real-time runs and for `railhil run scenarios/default.toml --lockstep`,
measured in the same bench; their ratio against the goal (≤ 2×).  The lockstep command runs
LOCKSTEP_RUNS times (~10 s each) and its median is taken: one run's CPU moved by a fifth from run to run
here (8.7-11.1 s on 2026-12-03), which moved the ratio as much as anything the hosts did.

    python bench/bench_realtime.py
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import queue
import random
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ISSUE = "#17"                 # the issue that set the goals printed here (bench/run_all.py)
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

RT_SECONDS = float(os.environ["BENCH_RT_S"]) if os.environ.get("BENCH_RT_S") else None   # None: to its end
PERIOD_S = 0.010                                          # the cycle compared: 10 ms
PERIODIC_ID = 0x7F0                                       # the send_periodic frame (not in the DBC)
GOAL_PROBE_RATIO = 1.5        # 10 ms nodes' p99 ≤ 1.5 × the probe's p99, same run (issue #17)
GOAL_PERIODIC_RATIO = 2.0     # ... and ≥ 2 × better than python-can's send_periodic, same run
GOAL_CPU_RATIO = 2.0          # real-time CPU s per simulated s ≤ 2 × lockstep's
CYCLICTEST_ARGS = ("-m", "-p", "80", "-i", "10000", "--laptop")   # --laptop: the idle states left alone
LOCKSTEP_RUNS = 3             # the lockstep command's CPU: the median of this many runs


def _periodic_process(cfg: dict, stop, out) -> None:
    """python-can's send_periodic at 10 ms, from the run's first frame on the bus to `stop`; puts its
    lateness [ns] list."""
    import can

    from hil.runtime.rtos import NODE_PRIORITY, make_realtime

    bus = can.Bus(**cfg)
    make_realtime(NODE_PRIORITY)
    sent: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while bus.recv(timeout=0.5) is None and not stop.is_set() and time.monotonic() < deadline:
            pass                                # the run's nodes are not sending yet
        msg = can.Message(arbitration_id=PERIODIC_ID, data=bytes(8), is_extended_id=False)
        task = bus.send_periodic(msg, PERIOD_S,
                                 modifier_callback=lambda m: sent.append(time.perf_counter_ns()))
        while not stop.is_set():
            bus.recv(timeout=0.05)              # receive the bus traffic, as a node does
        task.stop()
    finally:
        bus.shutdown()
    t = np.asarray(sent, dtype=np.int64)
    due = t[0] + np.arange(t.size, dtype=np.int64) * round(PERIOD_S * 1e9) if t.size else t
    out.put((t - due).tolist())


def _stats_us(us) -> tuple[float, float, float, int]:
    a = np.asarray(us, dtype=float)
    if not a.size:
        return float("nan"), float("nan"), float("nan"), 0
    return float(np.percentile(a, 50)), float(np.percentile(a, 99)), float(a.max()), int(a.size)


def _cyclictest(seconds: float) -> subprocess.Popen | None:
    exe = shutil.which("cyclictest")
    if exe is None:
        return None
    return subprocess.Popen([exe, *CYCLICTEST_ARGS, "-q", "-D", f"{max(1, round(seconds))}s", "-h", "20000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def cyclictest_figures(text: str) -> tuple[float, float, float, int] | None:
    """p50 / p99 / max [µs] and samples from cyclictest's histogram output (-h)."""
    counts: dict[int, int] = {}
    for line in text.splitlines():
        m = re.match(r"^(\d{6})\s+(\d+)", line)
        if m:
            counts[int(m.group(1))] = counts.get(int(m.group(1)), 0) + int(m.group(2))
    mx = re.search(r"# Max Latencies:\s+(\d+)", text)
    total = sum(counts.values())
    if not total:
        return None
    us = np.repeat(np.array(sorted(counts)), [counts[k] for k in sorted(counts)])
    return float(np.percentile(us, 50)), float(np.percentile(us, 99)), float(mx.group(1)) if mx else \
        float(us.max()), total


def _command_cpu(args: list[str]) -> tuple[float, subprocess.CompletedProcess]:
    """CPU seconds (user + system) of a command and every process it started, and its result."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=900)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime), done


def measure(hosting: str, with_cyclictest: bool = False) -> dict:
    """One real-time run of the default scenario with `hosting`, send_periodic (and cyclictest) beside it:
    its kpis.json `realtime`, send_periodic's lateness [µs], cyclictest's figures, the command's CPU s."""
    rnd = random.Random(os.getpid() ^ time.monotonic_ns())
    group, port = f"239.255.{rnd.randrange(1, 255)}.{rnd.randrange(1, 255)}", rnd.randrange(20000, 60000)
    # TTL 0, as a run on its own group has: the frames stay on this host (sent out on this VM's network
    # interface, they stalled every CPU for milliseconds: cyclictest p99 4.6-6.5 ms against 31-42 us)
    cfg = {"interface": "udp_multicast", "channel": group, "port": port, "hop_limit": 0}
    ctx = mp.get_context("fork")
    stop, out = ctx.Event(), ctx.Queue()
    periodic = ctx.Process(target=_periodic_process, args=(cfg, stop, out), daemon=True)
    periodic.start()
    sets = ["--set", f"max_duration_s={RT_SECONDS}"] if RT_SECONDS else []
    with tempfile.TemporaryDirectory(prefix="railhil-bench-rt-") as tmp:
        cyc = _cyclictest(RT_SECONDS or 32.0) if with_cyclictest else None
        try:
            cpu, done = _command_cpu([sys.executable, "-m", "hil", "run", "scenarios/default.toml",
                                      "--realtime", "--hosting", hosting, "-i", "udp_multicast", "-c", group,
                                      "--bus-kwargs", f"port={port}", "hop_limit=0", "--out", tmp, "-q",
                                      "--exit-zero", *sets])
        finally:
            stop.set()
        cyc_text = cyc.communicate(timeout=60)[0] if cyc is not None else ""
        if done.returncode != 0:
            raise RuntimeError(f"the real-time run failed: {done.stderr.strip().splitlines()[-1:]}")
        kpis = json.loads((Path(tmp) / "kpis.json").read_text())
        hosts = json.loads((Path(tmp) / "run.json").read_text()).get("realtime", {}).get("host_frames", {})
    try:
        periodic_ns = out.get(timeout=30)
    except queue.Empty:
        periodic_ns = []
    periodic.join(5)
    return {"rt": kpis["realtime"], "simulated_s": kpis["simulated_s"], "cpu_s": cpu,
            "host_cpu_s": {h: v["cpu_s"] for h, v in hosts.items() if "cpu_s" in v},
            "send_periodic": [ns / 1e3 for ns in periodic_ns],
            "cyclictest": cyclictest_figures(cyc_text) if cyc_text else None}


def lockstep_cpu(runs: int = LOCKSTEP_RUNS) -> tuple[list[float], float]:
    """CPU seconds of each of `runs` runs of `railhil run scenarios/default.toml --lockstep` (the whole
    command) and its simulated seconds (the same every run: lockstep is deterministic)."""
    cpus = []
    for _ in range(runs):
        with tempfile.TemporaryDirectory(prefix="railhil-bench-ls-") as tmp:
            cpu, done = _command_cpu([sys.executable, "-m", "hil", "run", "scenarios/default.toml",
                                      "--lockstep", "--out", tmp, "-q"])
            if done.returncode != 0:
                raise RuntimeError(f"the lockstep run failed: {done.stderr.strip()}")
            cpus.append(cpu)
            simulated = json.loads((Path(tmp) / "kpis.json").read_text())["simulated_s"]
    return cpus, simulated


def _rows(m: dict, hosting: str) -> list[tuple[str, str]]:
    rt = m["rt"]
    ten = [v for n, v in rt["nodes"].items() if v["period_us"] == 10_000]
    cycles = sum(v["cycles"] for v in ten)
    p50, p99 = rt["p50_10ms_us"], rt["p99_10ms_us"]
    mx = max(v["max_us"] for v in ten)
    machine = rt["machine"]
    rows = [(f"{hosting}: railhil nodes at 10 ms ({len(ten)}), {m['simulated_s']:.0f} s, {cycles} cycles",
             f"p50 {p50} / p99 {p99} / max {mx} us")]
    if "error" in machine:
        rows.append((f"{hosting}: machine probe", f"failed: {machine['error']}"))
    else:
        rows.append((f"{hosting}: machine probe (bare loop per CPU, 10 ms), same run, {machine['cycles']} "
                     "cycles", f"p50 {machine['p50_us']} / p99 {machine['p99_us']} / max "
                     f"{machine['max_us']} us, {machine['stalls']} stalls"))
        ratio = p99 / max(machine["p99_us"], 1)
        rows.append((f"{hosting}: p99 railhil / p99 probe (goal ≤ {GOAL_PROBE_RATIO:g}x)",
                     f"{ratio:.2f}x: {'met' if ratio <= GOAL_PROBE_RATIO else 'NOT met'}"))
    if m["send_periodic"]:
        q50, q99, qmx, qn = _stats_us(m["send_periodic"])
        rows.append((f"{hosting}: python-can send_periodic at 10 ms, same run, {qn} cycles",
                     f"p50 {q50:.0f} / p99 {q99:.0f} / max {qmx:.0f} us"))
        ratio = q99 / max(p99, 1)
        rows.append((f"{hosting}: p99 send_periodic / p99 railhil (goal ≥ {GOAL_PERIODIC_RATIO:g}x)",
                     f"{ratio:.2f}x: {'met' if ratio >= GOAL_PERIODIC_RATIO else 'NOT met'}"))
    else:
        rows.append((f"{hosting}: python-can send_periodic", "no data (its process did not report)"))
    if m.get("cyclictest"):
        c50, c99, cmx, cn = m["cyclictest"]
        rows.append((f"{hosting}: cyclictest {' '.join(CYCLICTEST_ARGS)}, same run, {cn} samples",
                     f"p50 {c50:.0f} / p99 {c99:.0f} / max {cmx:.0f} us"))
    plant = rt["nodes"].get("PLANT")
    if plant:
        rows.append(("  PLANT (its 1 ms steps computed at wakes, judged in its wakes)",
                     f"{plant['cycles']} wakes, p50 {plant['p50_us']} / p99 {plant['p99_us']} / max "
                     f"{plant['max_us']} us"))
    rows.append(("  verdict: bench misses / machine misses (all nodes)",
                 f"{'held' if rt['held'] else 'NOT HELD'}: {rt['misses_bench']} / {rt['misses_machine']} "
                 f"({rt.get('misses_machine_probes', rt['misses_machine'])} at the probes' stalls)"))
    rows.append(("  CPU s per simulated s (the whole command)",
                 f"{m['cpu_s'] / m['simulated_s']:.3f} ({m['cpu_s']:.1f} s for {m['simulated_s']:.1f} s)"))
    if m.get("host_cpu_s"):
        by = m["host_cpu_s"]
        hosts = ", ".join(f"{h} {c:.1f}" for h, c in sorted(by.items(), key=lambda kv: -kv[1]))
        rows.append(("  CPU s by process (the rest: the runner's start-up, waits and report)",
                     f"{hosts}; rest {m['cpu_s'] - sum(by.values()):.1f}"))
    return rows


def run() -> list[tuple[str, str]]:
    load_before = os.getloadavg()[0]
    rows = []
    cpus_ls, sim_ls = lockstep_cpu()
    cpu_ls = float(np.median(cpus_ls))
    grouped = measure("grouped", with_cyclictest=True)
    rows += _rows(grouped, "grouped")
    rows += _rows(measure("per-node"), "per-node")
    per_ls = cpu_ls / sim_ls
    per_rt = grouped["cpu_s"] / grouped["simulated_s"]
    rows.append((f"lockstep: CPU s per simulated s (the whole command, median of {len(cpus_ls)})",
                 f"{per_ls:.3f} ({cpu_ls:.1f} s for {sim_ls:.1f} s; runs: "
                 f"{', '.join(f'{c:.1f}' for c in cpus_ls)} s)"))
    rows.append((f"grouped real time / lockstep, CPU per simulated s (goal ≤ {GOAL_CPU_RATIO:g}x)",
                 f"{per_rt / per_ls:.2f}x: {'met' if per_rt / per_ls <= GOAL_CPU_RATIO else 'NOT met'}"))
    if shutil.which("cyclictest") is None:
        rows.append(("cyclictest", "not installed (Debian: apt-get install rt-tests)"))
    rows.append(("  machine: CPUs, 1-min load average before / after the runs",
                 f"{os.cpu_count()}, {load_before:.1f} / {os.getloadavg()[0]:.1f}"))
    return rows


if __name__ == "__main__":
    for label, figure in run():
        print(f"  {label:<62} {figure}")
