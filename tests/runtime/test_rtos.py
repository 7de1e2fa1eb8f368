"""What the OS gives a real-time process (hil.runtime.rtos): SCHED_FIFO and locked memory where permitted,
the fallback where not, said in one line; the sleep calibration behind the hosts' precise wait."""

import json
import os
import shutil
import struct
import subprocess
import sys

import pytest
from conftest import ROOT

from hil.runtime.realtime import describe_setup
from hil.runtime.rtos import (
    CPU_LATENCY_DEVICE,
    MARGIN_MAX_NS,
    MARGIN_MIN_NS,
    CpuLatencyHold,
    RtSetup,
    hold_cpu_latency,
    sleep_lateness,
)

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


def _cpu_latency_now() -> int:
    with open(CPU_LATENCY_DEVICE, "rb") as f:            # reading gives the kernel's aggregate request
        return struct.unpack("=i", f.read(4))[0]


def test_a_cpu_latency_hold_is_the_kernels_while_it_is_open():
    """The run holds every CPU's idle exits within 0 µs (/dev/cpu_dma_latency) while the hold is open; the
    kernel's aggregate reads 0 then, and what it was after release."""
    if os.geteuid() != 0 or not os.path.exists(CPU_LATENCY_DEVICE):
        pytest.skip(f"needs root and {CPU_LATENCY_DEVICE} (the device is 0600 root; "
                    "the refusal is tested below)")
    before = _cpu_latency_now()
    hold = hold_cpu_latency(0)
    try:
        assert hold.held and hold.refused is None
        assert _cpu_latency_now() == 0
        assert hold.describe() == "CPU idle exits held within 0 us (idle CPUs poll, never halt)"
        assert hold.as_dict() == {"requested_us": 0, "held": True, "refused": None}
    finally:
        hold.release()
    hold.release()                                       # a second release is harmless
    assert _cpu_latency_now() == before


def test_a_cpu_latency_hold_that_is_refused_says_why_and_the_run_goes_on(tmp_path):
    missing = tmp_path / "no-such-device"
    hold = hold_cpu_latency(0, device=str(missing))
    assert not hold.held and hold.fd is None
    assert hold.refused == f"CPU idle latency ({missing}): No such file or directory"
    assert hold.describe() == f"CPU idle states as the kernel chooses (CPU idle latency ({missing}): " \
                              "No such file or directory)"
    hold.release()
    nothing = hold_cpu_latency(None)
    assert not nothing.held and nothing.refused is None
    assert nothing.describe() == "CPU idle states as the kernel chooses"


def test_the_set_up_line_names_the_idle_hold_and_its_refusal():
    fifo = RtSetup("SCHED_FIFO", 50, True, None, None).as_dict()
    held = CpuLatencyHold(0, True)
    line = describe_setup({"PLANT": fifo, "ECUS": fifo}, None, False, held)
    assert line == ("PLANT SCHED_FIFO priority 50, memory locked, not pinned; ECUS SCHED_FIFO priority "
                    "50, memory locked, not pinned; CPU idle exits held within 0 us (idle CPUs poll, never "
                    "halt); sleep to each deadline (no precise wait)")
    refused = CpuLatencyHold(0, False, "CPU idle latency (/dev/cpu_dma_latency): Permission denied")
    line = describe_setup({"ECUS": fifo}, None, False, refused)
    assert "refused: CPU idle latency (/dev/cpu_dma_latency): Permission denied;" in line
    assert "held within" not in line
