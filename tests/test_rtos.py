"""What the OS gives a real-time process (hil.runtime.rtos): SCHED_FIFO and locked memory where permitted,
the fallback where not, said in one line; the sleep calibration behind the hosts' precise wait."""

import json
import os
import shutil
import subprocess
import sys

import pytest
from conftest import ROOT

from hil.runtime.rtos import MARGIN_MAX_NS, MARGIN_MIN_NS, RtSetup, sleep_lateness

ASK = (f"import json, sys; sys.path.insert(0, {str(ROOT)!r}); from hil.runtime.rtos import make_realtime; "
       "print(json.dumps(make_realtime(50).as_dict()))")


def test_a_process_that_may_not_asks_and_says_what_is_in_effect():
    """As an unprivileged user (setpriv to nobody, no capabilities) SCHED_FIFO and mlockall are refused:
    the process runs on at the normal priority, and the set-up names what the OS refused and why."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv to start a process as an unprivileged user")
    done = subprocess.run(["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups",
                           "--inh-caps=-all", sys.executable, "-c", ASK], capture_output=True, text=True,
                          timeout=60)
    if done.returncode != 0 and "Permission denied" in done.stderr:
        pytest.skip(f"the user nobody cannot read this checkout: {done.stderr.strip().splitlines()[-1]}")
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout)
    rt = RtSetup(**{**got, "cpus": None, "refused": tuple(got["refused"])})
    assert rt.policy in ("nice", "normal") and not rt.memory_locked
    assert any(r.startswith("SCHED_FIFO: ") for r in rt.refused), rt.refused
    assert rt.describe().startswith(("nice ", "normal priority")) and "memory not locked" in rt.describe()


def test_root_gets_sched_fifo_and_locked_memory():
    if os.geteuid() != 0:
        pytest.skip("not root: SCHED_FIFO is refused here (the test above covers that case)")
    done = subprocess.run([sys.executable, "-c", ASK], capture_output=True, text=True, timeout=60)
    got = json.loads(done.stdout)
    assert got["policy"] == "SCHED_FIFO" and got["priority"] == 50 and got["memory_locked"], got


def test_the_calibration_measures_this_machines_sleep_lateness():
    cal = sleep_lateness(0.2)
    assert cal.samples == 200
    assert 0 <= cal.p50_us <= cal.p90_us <= cal.p99_us <= cal.max_us
    assert MARGIN_MIN_NS <= cal.margin_ns <= MARGIN_MAX_NS
