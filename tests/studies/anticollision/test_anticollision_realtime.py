"""Seed 002's anti-collision device in a real-time run: one OS process per node on udp_multicast, the
ACD reading NMEA from a real pseudo-terminal through pyserial, the control centre as its own process
with its SQLite file — killed and restarted during the run without losing a report."""

from __future__ import annotations

import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from hil.links.control_centre import stored_reports
from hil.studies.anticollision.kpis import judge_run_dir

pytestmark = [pytest.mark.realtime, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[3]
WAIT_S = 120.0


def start_centre(db: Path, port: int) -> tuple[subprocess.Popen, int]:
    """The control centre as its own process; returns it and its port once it listens."""
    proc = subprocess.Popen([sys.executable, "-m", "hil.links.control_centre", "--db", str(db), "--port",
                             str(port)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()                     # blocks until it listens (or dies)
    m = re.match(r"listening on 127\.0\.0\.1:(\d+)", line)
    assert m, f"control centre did not start: {line!r}"
    return proc, int(m.group(1))


def rows_in(db: Path) -> int:
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as con:
            return con.execute("SELECT count(*) FROM reports").fetchone()[0]
    except sqlite3.OperationalError:
        return 0


def wait_until(predicate, timeout_s: float) -> None:
    """Wait (on an Event with a timeout, re-checking) until predicate() holds."""
    tick = threading.Event()
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        tick.wait(0.2)


def test_realtime_acd_over_a_pty_with_the_control_centre_restarted_mid_run(tmp_path):
    db = tmp_path / "cc.sqlite"
    centre, port = start_centre(db, 0)
    out = tmp_path / "run"
    run = subprocess.Popen(
        [sys.executable, "-m", "hil", "run", "scenarios/acd_anticollision.toml", "--realtime", "-q",
         "--out", str(out), "--set", "train.cars=1", "--set", "train.initial_speed_kmh=60",
         "--set", "acd.leader.rear_m=400", "--set", "acd.leader.profile.0.at_s=2",
         "--set", f"acd.control_centre=127.0.0.1:{port}"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        wait_until(lambda: rows_in(db) >= 10 or run.poll() is not None, WAIT_S)   # both trains report
        before = rows_in(db)
        assert run.poll() is None, "the run ended before the centre could be restarted"
        centre.send_signal(signal.SIGKILL)                # a crash of the centre mid-run
        centre.wait(timeout=30)
        centre, port2 = start_centre(db, port)            # back on the same port with the same file
        assert port2 == port
        stdout, stderr = run.communicate(timeout=WAIT_S)
        assert run.returncode in (0, 1), stderr      # 1: a verdict that failed (real time), not an error
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
            run.wait(timeout=30)
        centre.send_signal(signal.SIGTERM)
        centre.communicate(timeout=30)
    rows = stored_reports(db)
    assert len(rows) > before
    by_train: dict[str, list[int]] = {}
    for r in rows:
        by_train.setdefault(r["train"], []).append(r["seq"])
    assert set(by_train) == {"U1", "U2"}
    for train, seqs in by_train.items():                 # one session each, no report missing before the last
        assert sorted(seqs) == list(range(len(seqs))), train
    meta = json.loads((out / "run.json").read_text())
    line = meta["node_stats"]["ACD"]["gps_line"]
    assert line["serial"] == "pty" and line["port"].startswith("/dev/pts/")
    assert line["accepted"] > 10
    j = judge_run_dir(out)
    assert j["mode"] == "realtime" and not j["collision"] and j["applications"] >= 1 and j["min_gap_m"] > 0.0
