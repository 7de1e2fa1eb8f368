"""examples/plc_precise_stop: seed 002's stopping program on a PLC stand-in over OPC UA (asyncua on both
ends, SignAndEncrypt, a user and password), in the DESK's place: in lockstep it stops the train where
railhil's own search does; in real time, as the bench's client and as a server of its own, the train stops,
the PLC's cycle, read age and round trip are printed and real time holds."""

from __future__ import annotations

import json
import os
import select
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "plc_precise_stop"
PASSWORD = "brake-valve-4"
WAIT_S = 60.0
#: a shorter test than the paper's: 250 m ahead of a train at 50 km/h (its braking curve alone is 161 m)
SHORT = ("train.initial_speed_kmh=50", "desk.0.target_stop_m=250", "track.balises=[]", "max_duration_s=60")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def env(tmp_path: Path) -> dict:
    """The PLC's password, and the bench's own certificate kept in tmp_path (XDG_DATA_HOME)."""
    return {**os.environ, "RAILHIL_PLC_PASSWORD": PASSWORD, "XDG_DATA_HOME": str(tmp_path / "data")}


def run(args: list[str], tmp_path: Path, timeout: float = 400) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", "run", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout, env=env(tmp_path))


def stop_error(out: Path) -> float:
    return json.loads((out / "kpis.json").read_text())["precise_stop"]["stop_error_m"]


def test_the_example_plc_stops_the_train_where_railhils_own_search_does(tmp_path):
    """Lockstep: the example's program as the device's model against the BCU's own adaptive_diff."""
    plc, own = tmp_path / "plc", tmp_path / "own"
    proc = run(["precise_stop", "--set", "precise_stop.method=plc", "--device",
                str(EXAMPLE / "plc_precise_stop.toml"), "--out", str(plc), "-q"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run(["precise_stop", "--set", "precise_stop.method=adaptive_diff", "--out", str(own), "-q"],
               tmp_path)
    assert proc.returncode == 0, proc.stderr
    e_plc, e_own = stop_error(plc), stop_error(own)
    assert abs(e_plc - e_own) <= 1.0, (e_plc, e_own)      # the same search, on the truth and on CAN
    assert abs(e_plc) <= 7.0 and abs(e_own) <= 7.0         # within the paper's ±2–7 m
    d = json.loads((plc / "kpis.json").read_text())["devices"]["DESK"]
    assert d["verdict"] == "PASS" and d["opcua"]["writes"] > 500


def test_method_plc_without_a_plc_is_one_line(tmp_path):
    proc = run(["precise_stop", "--set", "precise_stop.method=plc", "--out", str(tmp_path / "r")], tmp_path)
    assert proc.returncode == 2
    line = proc.stderr.strip().splitlines()[-1]
    assert "precise_stop.method = 'plc'" in line and "--device DESK=FILE" in line, line


def device_copy(tmp_path: Path, name: str, port: int) -> Path:
    """The example's device file beside its own pki/ in tmp_path, on a free port, for the short test."""
    text = (EXAMPLE / name).read_text()
    text = text.replace("48400/railhil", f"{port}/railhil").replace("48410/plc", f"{port}/plc")
    text = text.replace('Target = { value = "1500 m" }', 'Target = { value = "250 m" }')
    path = tmp_path / name
    path.write_text(text)
    return path


def start_plc(tmp_path: Path, port: int, *extra: str) -> subprocess.Popen:
    """plc.py, once it created its certificate (the device file trusts it) and said where it works."""
    path = "railhil" if "--serve" not in extra else "plc"
    proc = subprocess.Popen([sys.executable, str(EXAMPLE / "plc.py"), "--endpoint",
                             f"opc.tcp://127.0.0.1:{port}/{path}", "--pki", str(tmp_path / "pki"), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env(tmp_path))
    deadline = time.monotonic() + WAIT_S
    line = ""
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            break
        line = proc.stdout.readline()
        if line.startswith("PLC: certificate") or line.startswith("PLC: serving") or not line:
            break
    assert line.startswith("PLC:"), (line, proc.poll(), proc.stderr.read() if proc.poll() is not None else "")
    return proc


def stop(proc: subprocess.Popen) -> str:
    if proc.poll() is None:
        proc.terminate()
    out, _ = proc.communicate(timeout=30)
    return out


@pytest.mark.realtime
@pytest.mark.parametrize("name, role", [("plc_precise_stop.toml", "server"), ("plc_serves.toml", "client")])
def test_the_example_plc_over_opcua_stops_the_train_in_real_time(tmp_path, name, role):
    port = free_port()
    plc = start_plc(tmp_path, port, *(("--serve",) if role == "client" else ()))
    out = tmp_path / "run"
    try:
        sets = [a for s in SHORT for a in ("--set", s)]
        proc = run(["precise_stop", "--realtime", "--set", "precise_stop.method=plc", *sets, "--device",
                    str(device_copy(tmp_path, name, port)), "--out", str(out)], tmp_path)
    finally:
        said = stop(plc)
    # 1: real time not held on this shared machine (its stalls; the docs' runs show it held), judged below
    assert proc.returncode in (0, 1), proc.stdout[-2000:] + proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    device = next(line for line in lines if line.startswith("device DESK"))
    assert f"the bench as {role}" in device and "Basic256Sha256 SignAndEncrypt, user plc" in device, device
    assert any(line.strip().startswith("PLC cycle") for line in lines)
    assert any(line.strip().startswith("read age / round trip") and "by the echo Brake.Echo" in line
               for line in lines)
    if proc.returncode == 0:
        assert lines[-1].startswith("verdict: PASS (real time held, 1 device PASS)"), lines[-1]
    else:                                               # the only verdict that failed: the machine's
        assert lines[-1].startswith("verdict: FAIL — real time NOT HELD") and "device" not in lines[-1], \
            lines[-1]
    k = json.loads((out / "kpis.json").read_text())
    assert k["devices"]["DESK"]["verdict"] == "PASS", k["devices"]["DESK"]["plc"]
    assert k["precise_stop"]["stopped"] and abs(k["precise_stop"]["stop_error_m"]) <= 7.0, k["precise_stop"]
    link = k["devices"]["DESK"]["opcua"]
    assert link["cycle"]["p50_ms"] == pytest.approx(100.0, abs=10.0) and link["read_age"]["n"] > 50
    assert link["round_trip"]["p50_ms"] is not None and (role == "server" or link["calls"]["n"] > 50)
    assert "PLC: " in said and " scans," in said, said


@pytest.mark.realtime
def test_a_plc_that_falls_silent_fails_the_run_and_the_bcu_brakes(tmp_path):
    """The PLC stops writing 4 s into the run: the link reports the silence, the run fails (exit 1), the
    gateway sends no more DESK frames and the BCU takes the stale valve position as V: the train stops."""
    port = free_port()
    plc = start_plc(tmp_path, port, "--duration", "4")
    out = tmp_path / "run"
    try:
        sets = [a for s in SHORT for a in ("--set", s)]
        proc = run(["precise_stop", "--realtime", "--set", "precise_stop.method=plc", *sets, "--device",
                    str(device_copy(tmp_path, "plc_precise_stop.toml", port)), "--out", str(out)], tmp_path)
    finally:
        stop(plc)
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-2000:]
    last = proc.stdout.strip().splitlines()[-1]
    assert last.startswith("verdict: FAIL") and "device DESK" in last, last
    k = json.loads((out / "kpis.json").read_text())
    d = k["devices"]["DESK"]
    assert d["plc"]["timing"] == "FAIL" and d["opcua"]["silences"] >= 1, d["plc"]
    assert "silent" in d["plc"]["why"], d["plc"]
    assert d["bench"]["last_s"] < 8.0, d["bench"]               # no DESK frames once it is silent
    assert k["precise_stop"]["stopped"], k["precise_stop"]        # the BCU braked (V) and stopped it
