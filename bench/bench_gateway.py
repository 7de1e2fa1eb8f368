"""The gateway's latency per direction, a device on its own bus behind it, beside the machine's probe
(issue #42).

ACME's EBC-7 firmware (examples/acme_becu/ebc7.py, a plain python-can + cantools program) runs as an
external process on a udp_multicast group and port of the benchmark's own (TTL 0), and
`railhil run default --realtime` puts it in BECU3's place (examples/acme_becu/acme_becu.toml, its bus set
to that group), to the scenario's end (standstill, about 30 s) unless BENCH_RT_S cuts it, as a user runs it
(a subprocess, the bench's bus on a group of the run's own).  From its kpis.json:

- `devices.BECU3.latency`: for each routed frame, from the frame it was translated from on one bus's trace
  to it on the other's (the bench's trace.blf and the device's device-BECU3.blf, both stamped by the
  kernel at reception on this host), per direction: what a bus analyser with both buses in view measures;
- `devices.BECU3.processing`: what the gateway process measured itself, from the socket's reception
  timestamp of a frame to the return of the send of what it routed from it;
- `realtime.machine`: the machine probe of the same run (a bare loop per CPU sleeping to absolute 10 ms
  deadlines, one priority above the nodes), its p99 and worst stall: the floor the gateway's latency is
  read against;
- `realtime.held`, the device's verdict, the stopping distance.

The gateway drops what its buses held before the run's go (the firmware's frames while the run started);
the frames it routes between the go and t0 are in its own count but not the traces', whose figures start at
t0: its row says how many frames more it counts.

    python bench/bench_gateway.py
"""

from __future__ import annotations

import json
import os
import random
import selectors
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

ISSUE = "#42"                 # the issue that set the goals printed here (bench/run_all.py)
ROOT = Path(__file__).resolve().parents[1]
ACME = ROOT / "examples" / "acme_becu"
FIRMWARE = ACME / "ebc7.py"
DEVICE_FILE = ACME / "acme_becu.toml"
NODE = "BECU3"                # the node the device takes the place of (DEVICE_FILE's `replaces`)

RT_SECONDS = float(os.environ["BENCH_RT_S"]) if os.environ.get("BENCH_RT_S") else None   # None: to its end
GOAL_P99_US = 1_000           # gateway latency p99 ≤ 1 ms per direction on this machine (issue #42)
FIRMWARE_START_S = 30.0       # the firmware's first line ("EBC-7: on ...") within this
RUN_TIMEOUT_S = 600.0         # the whole `railhil run` command
WAYS = (("device_to_bench", "to_bench", "device → bench"), ("bench_to_device", "to_device", "bench → device"))


def own_group() -> dict:
    """A udp_multicast group and port of the benchmark's own, TTL 0 (the frames stay on this host)."""
    rnd = random.Random(os.getpid() ^ int.from_bytes(os.urandom(4), "little"))
    group = f"239.255.{rnd.randrange(1, 255)}.{rnd.randrange(1, 255)}"
    return {"interface": "udp_multicast", "channel": group, "port": rnd.randrange(20_000, 60_000),
            "hop_limit": 0}


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else "no output"


def start_firmware(bus: dict, firmware: Path = FIRMWARE) -> subprocess.Popen:
    """The EBC-7's firmware on `bus`, once it printed which bus it is on; RuntimeError (one line) if it
    did not within FIRMWARE_START_S."""
    proc = subprocess.Popen([sys.executable, str(firmware), "-i", bus["interface"], "-c", bus["channel"],
                             "--bus-kwargs", f"port={bus['port']}", f"hop_limit={bus['hop_limit']}"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    seen = b""
    with selectors.DefaultSelector() as sel:       # on the pipe itself: no sleep, no buffered line unseen
        sel.register(proc.stdout.fileno(), selectors.EVENT_READ)
        while b"EBC-7: on" not in seen:
            ready = sel.select(timeout=FIRMWARE_START_S)
            chunk = os.read(proc.stdout.fileno(), 4096) if ready else b""
            if not chunk:
                exited = bool(ready) and _exits(proc)   # its output ended: exiting, maybe not reaped
                why = _last_line(_end(proc)[1]).removeprefix("error: ")
                where = firmware.relative_to(ROOT) if firmware.is_relative_to(ROOT) else firmware
                how = (f"exited (exit {proc.returncode})" if exited else "closed its output" if ready else
                       f"said nothing within {FIRMWARE_START_S:g} s")
                raise RuntimeError(f"the EBC-7 firmware ({where}) did not start: it {how}: {why}")
            seen += chunk
    return proc


def _exits(proc: subprocess.Popen, within_s: float = 10.0) -> bool:
    """True if `proc` (which closed its output) has exited within `within_s`."""
    try:
        proc.wait(timeout=within_s)
    except subprocess.TimeoutExpired:
        return False
    return True


def _end(proc: subprocess.Popen) -> tuple[str, str]:
    """SIGTERM (SIGKILL after 30 s), then what it printed: stdout, stderr."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
    return out.decode(errors="replace"), err.decode(errors="replace")


def stop_firmware(proc: subprocess.Popen) -> str:
    """SIGTERM, then its last line (its summary)."""
    return _last_line(_end(proc)[0])


def measure() -> tuple[dict, str]:
    """One real-time run of the default scenario with the EBC-7 behind the gateway: its kpis.json and the
    firmware's summary line."""
    bus = own_group()
    inline = ", ".join(f"{k} = {json.dumps(v)}" for k, v in bus.items())
    sets = [f'devices.{NODE}.file="{DEVICE_FILE}"', f"devices.{NODE}.bus={{{inline}}}"]
    if RT_SECONDS:
        sets.append(f"max_duration_s={RT_SECONDS}")
    firmware = start_firmware(bus)
    with tempfile.TemporaryDirectory(prefix="railhil-bench-gw-") as tmp:
        try:
            done = subprocess.run([sys.executable, "-m", "hil", "run", "default", "--realtime", "--exit-zero",
                                   *[a for s in sets for a in ("--set", s)], "--out", tmp, "-q"],
                                  cwd=ROOT, capture_output=True, text=True, timeout=RUN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"the real-time run did not end within {RUN_TIMEOUT_S:g} s") from None
        finally:
            summary = stop_firmware(firmware)
        if done.returncode != 0:
            why = _last_line(done.stderr).removeprefix("error: ")
            raise RuntimeError(f"the real-time run failed (exit {done.returncode}): {why}")
        kpis = json.loads((Path(tmp) / "kpis.json").read_text())
    return kpis, summary


def _figures(f: dict) -> str:
    if not f.get("frames"):
        return "no frames"
    return f"p50 {f['p50_us']:.0f} / p99 {f['p99_us']:.0f} / max {f['max_us']:.0f} us"


def rows(kpis: dict, firmware: str) -> list[tuple[str, str]]:
    """The printed rows of one run: latency, processing, the probe beside them, the goals, the verdicts."""
    d, rt = kpis["devices"][NODE], kpis["realtime"]
    machine = rt["machine"]
    if "error" in machine:
        probe = f"failed: {machine['error']}"
        beside = "machine probe failed"
    else:
        probe = (f"p50 {machine['p50_us']} / p99 {machine['p99_us']} us, worst stall "
                 f"{machine['worst_stall_us']} us, {machine['stalls']} stalls")
        beside = f"machine probe p99 {machine['p99_us']} us, worst stall {machine['worst_stall_us']} us"
    out = []
    for way, _, name in WAYS:
        f = d["latency"][way]
        out.append((f"gateway latency {name} (the two traces), {f['frames']} frames", _figures(f)))
    for way, side, name in WAYS:
        f = d["processing"][side]
        more = f["frames"] - d["latency"][way]["frames"]     # routed outside the run's window (its start)
        extra = f" ({more} frames more than the traces count in the run)" if more > 0 else ""
        out.append((f"  its own (reception to send), {name}, {f['frames']} frames", _figures(f) + extra))
    out.append((f"machine probe, same run (loop per CPU, 10 ms), {machine.get('cycles', 0)} cycles", probe))
    for way, _, name in WAYS:
        p99 = d["latency"][way]["p99_us"]
        label = f"gateway latency p99, {name} (goal ≤ {GOAL_P99_US / 1000:g} ms)"
        if p99 is None:
            out.append((label, f"no routed frames: NOT met ({beside})"))
        else:
            out.append((label, f"{p99:.0f} us: {'met' if p99 <= GOAL_P99_US else 'NOT met'} ({beside})"))
    out.append(("  real time: bench misses / machine misses (all nodes)",
                f"{'held' if rt['held'] else 'NOT HELD'}: {rt['misses_bench']} / {rt['misses_machine']}"
                + (f" (worst node: {rt['worst_node']})" if rt.get("worst_node") else "")))
    dev = d["device"]
    out.append((f"  device {NODE} ({d['node']}, {Path(d['dbc']).name}): verdict",
                f"{d['verdict']}: {dev['frames']} frames, timing {dev['timing']}, protection "
                f"{'clean' if dev['protection_clean'] else 'NOT clean'}; on the bench timing "
                f"{d['bench']['timing']}"))
    failing = [f"{where} {m}: {v['reason']}" for where, part in (("device", dev), ("bench", d["bench"]))
               for m, v in part.get("messages", {}).items() if v["verdict"] != "PASS"]
    if failing:
        more = f"; and {len(failing) - 2} more" if len(failing) > 2 else ""
        out.append(("  the device's or the gateway's frames that did not PASS",
                    "; ".join(failing[:2]) + more))
    stopped = "" if kpis.get("stopped") else " (train did not stop)"
    out.append((f"  stopping distance ({kpis['simulated_s']:.1f} s simulated, ended by {kpis['end_reason']})",
                f"{kpis['stopping_distance_m']:.2f} m{stopped}"))
    out.append(("  the EBC-7 firmware's own summary", firmware.removeprefix("EBC-7: ")))
    return out


def run() -> list[tuple[str, str]]:
    load_before = os.getloadavg()[0]
    kpis, firmware = measure()
    return [*rows(kpis, firmware), ("  machine: CPUs, 1-min load average before / after the run",
                                    f"{os.cpu_count()}, {load_before:.1f} / {os.getloadavg()[0]:.1f}")]


if __name__ == "__main__":
    try:
        for label, figure in run():
            print(f"  {label:<62} {figure}")
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(1) from None
