"""Shared fixtures: one lockstep run of the default scenario per test session (it is deterministic), and
one real-time run of it for the real-time tests; where the corpus of third-party files is (CORPUS); and the
helpers tests of several folders import (`from conftest import ...`: pytest puts this folder on sys.path)."""

from __future__ import annotations

import json
import os
import random
import selectors
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "scenarios" / "default.toml"


def _corpus() -> Path:
    """The corpus of DBC files and traces no one here wrote (python-can, cantools, opendbc, SavvyCAN): the
    folder RAILHIL_CORPUS names, else ../shared/corpus beside the repository, else the development
    machine's copy (a clean clone elsewhere, as CI's, still reads it); the tests that need it skip, saying
    so, where none exists."""
    named = os.environ.get("RAILHIL_CORPUS")
    if named:
        return Path(named)
    beside = ROOT.parent / "shared" / "corpus"
    for folder in (beside, Path("/work/shared/corpus")):
        if folder.is_dir():
            return folder
    return beside


CORPUS = _corpus()


@pytest.fixture(scope="session")
def default_lockstep(tmp_path_factory):
    """The default scenario run in lockstep with its own seed; returns the RunReport."""
    from hil.report.run import run_scenario_lockstep
    from hil.scenario import load_scenario

    out = tmp_path_factory.mktemp("default-lockstep")
    return run_scenario_lockstep(load_scenario(DEFAULT), out)


ATTEMPTS = 2      # a run that did not hold real time (a stall of the machine) is run once more
MACHINE_STALL_MAX_US = 20_000   # a closed-loop check stands on a run whose machine stalled less than this


def realtime_held(out) -> bool:
    """The run held real time (the bench's deadline misses within budget) and the machine did not stall
    long enough to change the closed loop (its worst probe stall below MACHINE_STALL_MAX_US)."""
    rt = json.loads((out / "kpis.json").read_text())["realtime"]
    return rt["held"] and (rt["machine"].get("worst_stall_us") or 0) < MACHINE_STALL_MAX_US


@pytest.fixture(scope="session")
def realtime_run(tmp_path_factory):
    """The default scenario in real time, every node simulated, hosted as configured by default (grouped):
    (out folder, stdout, stderr); run again (once) if it did not hold real time."""
    for _ in range(ATTEMPTS):
        out = tmp_path_factory.mktemp("default-realtime")
        proc = subprocess.run([sys.executable, "-m", "hil", "run", str(DEFAULT), "--realtime", "--out",
                               str(out), "-q"], cwd=ROOT, capture_output=True, text=True, timeout=400)
        assert proc.returncode in (0, 1), proc.stderr     # 1: real time not held (a verdict, judged here)
        if realtime_held(out):
            break
    return out, proc.stdout, proc.stderr


def railhil(capsys, *args) -> tuple[int, str, str]:
    """`railhil ARGS` run in-process through hil.cli.main: (exit code, stdout, stderr)."""
    from hil.cli.main import main

    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, err: str, *needles: str) -> None:
    """Bad input: exit 2 and one line `error: ...` naming each of `needles`, no traceback."""
    assert code == 2, (code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]


# --- processes and buses of the real-time tests (tests/runtime, tests/report, tests/devices) -------------

def kill_all(proc) -> None:
    """The runner and every node process it started (its own session): a failed test leaves none."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(timeout=30)


def own_bus() -> list[str]:
    """python-can flags of a udp_multicast bus of this test's own (parallel runs do not hear each other),
    TTL 0: both programs are on this host, and frames sent out on a VM's network interface can stall it."""
    rnd = random.Random(os.getpid() ^ time.monotonic_ns())
    return ["-i", "udp_multicast", "-c", f"239.255.{rnd.randrange(1, 255)}.{rnd.randrange(1, 255)}",
            "--bus-kwargs", f"port={rnd.randrange(20000, 60000)}", "hop_limit=0"]


def wait_for_output(proc, text: str, timeout_s: float = 60.0) -> str:
    """Block (on the pipe, at most `timeout_s` for each read) until `proc` printed `text` on stdout; what
    it printed so far.  Reads the pipe itself: a text file's readline would keep a second line buffered
    where select() cannot see it."""
    fd = proc.stdout.fileno()
    sel = selectors.DefaultSelector()
    sel.register(fd, selectors.EVENT_READ)
    seen = b""
    while text.encode() not in seen:
        chunk = os.read(fd, 4096) if sel.select(timeout=timeout_s) else b""
        if not chunk:
            raise AssertionError(f"no {text!r} within {timeout_s:g} s: {seen.decode()} (exit {proc.poll()})")
        seen += chunk
    return seen.decode()
