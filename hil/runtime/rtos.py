"""What the operating system gives a real-time process: scheduling class and priority, locked memory, CPU
affinity, timer slack; and how late this machine's sleeps return.

`make_realtime(priority, cpus)` asks for each where the OS permits it (root or CAP_SYS_NICE for
SCHED_FIFO, CAP_IPC_LOCK or a large enough RLIMIT_MEMLOCK for mlockall) and falls back step by step:
SCHED_FIFO → nice REALTIME_NICE → the normal priority. It never raises: the returned `RtSetup` says what
is in effect, and the runner prints that in one line, as openpilot's `config_realtime_process` asks for
a real-time priority and a core where it may (common/realtime.py).

`hold_cpu_latency(us)` asks the kernel to keep every CPU's idle-state exit latency within `us` for the
run (Linux PM QoS through /dev/cpu_dma_latency, as cyclictest and the other rt-tests do), where the OS
permits it: with 0, a CPU that waits for the next deadline polls instead of halting.

`sleep_lateness(seconds)` measures how late `time.sleep` to an absolute deadline returns on this machine
(CPython 3.11 sleeps with clock_nanosleep on CLOCK_MONOTONIC); the real-time hosts sleep until that
margin before a deadline and wait out the rest by polling (`hil.runtime.host`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import struct
import time
from array import array
from dataclasses import asdict, dataclass

NODE_PRIORITY = 50          # SCHED_FIFO priority of node and plant processes (1..99; openpilot uses 5x)
PROBE_PRIORITY = NODE_PRIORITY + 1   # the machine probe: one step above, so the bench's own CPU use is
#                                      never taken for the machine's (hil.runtime.probe)
RECORDER_PRIORITY = 40      # the recorder: below the nodes (its socket buffer absorbs a delay)
# a device's gateway (hil.runtime.gateway_host): just below the nodes, so that its wakes on every frame do
# not delay the bench's simulated nodes (their deadlines are the bench's verdict); above the recorders
GATEWAY_PRIORITY = NODE_PRIORITY - 1
REALTIME_NICE = -10         # the fallback where SCHED_FIFO is refused (needs CAP_SYS_NICE for < 0 too)
TIMER_SLACK_NS = 1          # PR_SET_TIMERSLACK: the kernel may delay a normal thread's timer by 50 µs
PR_SET_TIMERSLACK = 29      # <linux/prctl.h>
MCL_CURRENT, MCL_FUTURE, MCL_ONFAULT = 1, 2, 4    # <sys/mman.h>; ONFAULT: Linux ≥ 4.4
CPU_LATENCY_DEVICE = "/dev/cpu_dma_latency"  # Linux PM QoS: the largest idle-state exit latency any CPU
#                             may take while a process holds it open [µs, a native int32]
#                             (the kernel's Documentation/power/pm_qos_interface.rst)
MARGIN_MIN_NS = 50_000      # the precise wait's margin: at least this, ...
MARGIN_MAX_NS = 1_000_000   # ... at most this (a machine whose sleeps are later than that most of the
#                             time would spin for milliseconds a cycle; the margin is then capped)
MARGIN_QUANTILE = 75        # the margin covers this percentile of the calibration's sleep lateness (a higher
#                             one polls longer on every cycle: ~30 µs of CPU a wake for the last 15 %)

_libc = None


def _c() -> ctypes.CDLL | None:
    global _libc
    if _libc is None:
        name = ctypes.util.find_library("c")
        try:
            _libc = ctypes.CDLL(name, use_errno=True) if name else False
        except OSError:
            _libc = False
    return _libc or None


@dataclass(frozen=True)
class RtSetup:
    """What is in effect for one process."""

    policy: str                   # "SCHED_FIFO" | "nice" | "normal"
    priority: int                 # FIFO priority, or the nice value
    memory_locked: bool
    cpus: tuple[int, ...] | None  # the CPUs it may run on, None: not pinned
    timer_slack_ns: int | None    # None: unchanged (the kernel's 50 µs)
    refused: tuple[str, ...] = () # what the OS refused, and why ("SCHED_FIFO: Operation not permitted")

    def describe(self) -> str:
        sched = (f"SCHED_FIFO priority {self.priority}" if self.policy == "SCHED_FIFO"
                 else f"nice {self.priority}" if self.policy == "nice" else "normal priority")
        mem = "memory locked" if self.memory_locked else "memory not locked"
        cpus = f"on CPU {','.join(map(str, self.cpus))}" if self.cpus else "not pinned"
        return f"{sched}, {mem}, {cpus}"

    def as_dict(self) -> dict:
        return asdict(self)


def _why(exc: OSError) -> str:
    return exc.strerror or str(exc)


def make_realtime(priority: int = NODE_PRIORITY, cpus: tuple[int, ...] | None = None,
                  lock_memory: bool = True, fifo: bool = True) -> RtSetup:
    """Ask for SCHED_FIFO at `priority` (else nice REALTIME_NICE, else nothing), lock memory, pin to `cpus`
    and cut the timer slack, each where allowed; what is in effect."""
    refused: list[str] = []
    policy, prio = "normal", 0
    if fifo and hasattr(os, "sched_setscheduler"):
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            policy, prio = "SCHED_FIFO", priority
        except (OSError, ValueError) as exc:
            refused.append(f"SCHED_FIFO: {_why(exc) if isinstance(exc, OSError) else exc}")
    if policy == "normal":
        try:
            os.setpriority(os.PRIO_PROCESS, 0, REALTIME_NICE)
            policy, prio = "nice", REALTIME_NICE
        except (OSError, AttributeError) as exc:
            refused.append(f"nice {REALTIME_NICE}: {_why(exc) if isinstance(exc, OSError) else exc}")
    locked = False
    libc = _c()
    if lock_memory and libc is not None:
        # pages are locked as they are touched (MCL_ONFAULT), not all faulted in now: a process with numba's
        # compiler mapped would otherwise fault in hundreds of MB it never uses in the loop
        if libc.mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) == 0 or \
                libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
            locked = True
        else:
            refused.append(f"mlockall: {os.strerror(ctypes.get_errno())}")
    pinned = None
    if cpus and hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, set(cpus))
            pinned = tuple(sorted(cpus))
        except OSError as exc:
            refused.append(f"CPU affinity {sorted(cpus)}: {_why(exc)}")
    slack = None
    if libc is not None and policy != "SCHED_FIFO":   # real-time threads have no slack already
        if libc.prctl(PR_SET_TIMERSLACK, TIMER_SLACK_NS, 0, 0, 0) == 0:
            slack = TIMER_SLACK_NS
    return RtSetup(policy, prio, locked, pinned, slack, tuple(refused))


@dataclass
class CpuLatencyHold:
    """A request for the CPUs' idle-state exit latency, in effect while `fd` is open; what it got."""

    requested_us: int | None      # None: nothing asked ([realtime] cpu_latency_us "off", scheduling "normal")
    held: bool
    refused: str | None = None    # why it is not in effect ("CPU idle latency (/dev/cpu_dma_latency):
    #                               Permission denied")
    fd: int | None = None

    def describe(self) -> str:
        if self.requested_us is None:
            return "CPU idle states as the kernel chooses"
        if not self.held:
            return f"CPU idle states as the kernel chooses ({self.refused})"
        return (f"CPU idle exits held within {self.requested_us} us" +
                (" (idle CPUs poll, never halt)" if self.requested_us == 0 else ""))

    def as_dict(self) -> dict:
        return {"requested_us": self.requested_us, "held": self.held, "refused": self.refused}

    def release(self) -> None:
        """End the request (the kernel ends it too when the process exits)."""
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


def hold_cpu_latency(us: int | None, device: str = CPU_LATENCY_DEVICE) -> CpuLatencyHold:
    """Ask that no CPU take an idle state whose exit is slower than `us` while the returned hold is open.

    A timer that fires on a halted CPU waits for it to wake; in a VM a halted vCPU is handed back to the
    host, which may run another guest on that core until the interrupt comes.  With 0 an idle CPU polls
    (Linux's poll idle state; the haltpoll governor of KVM guests does the same), as cyclictest asks by
    default.  Writing needs root (the device is 0600); elsewhere the hold says what refused it and the run
    goes on.  The request is the process's open file: it ends at `release()` or when the process dies."""
    if us is None:
        return CpuLatencyHold(None, False)
    try:
        fd = os.open(device, os.O_WRONLY | os.O_CLOEXEC)
    except OSError as exc:
        return CpuLatencyHold(us, False, f"CPU idle latency ({device}): {_why(exc)}")
    try:
        os.write(fd, struct.pack("=i", us))
    except OSError as exc:
        os.close(fd)
        return CpuLatencyHold(us, False, f"CPU idle latency ({device}): {_why(exc)}")
    return CpuLatencyHold(us, True, None, fd)


def pin_plan(hosts: list[str], n_cpus: int | None = None) -> dict[str, tuple[int, ...] | None]:
    """CPUs for the hosts of a grouped run: with two CPUs or more, the plant (1 ms) gets the last one and
    a host of the ECUs the one before, so that a plant step and an ECU cycle never wait for each other;
    everything else (recorder, probe, per-node hosting) is left to the scheduler."""
    n = n_cpus if n_cpus is not None else len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") \
        else (os.cpu_count() or 1)
    plan: dict[str, tuple[int, ...] | None] = {h: None for h in hosts}
    if n < 2 or len(hosts) != 2:
        return plan
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else list(range(n))
    for host in hosts:
        plan[host] = (allowed[-1],) if host == "PLANT" else (allowed[-2],)
    return plan


@dataclass(frozen=True)
class SleepCalibration:
    """How late `time.sleep` to an absolute deadline returned during the calibration [µs], and the margin
    the hosts stop sleeping at before each deadline [ns]."""

    seconds: float
    samples: int
    p50_us: float
    p90_us: float
    p99_us: float
    max_us: float
    margin_ns: int                # MARGIN_QUANTILE of the lateness, within [MARGIN_MIN_NS, MARGIN_MAX_NS]
    capped: bool                  # the machine's sleeps were later than MARGIN_MAX_NS at MARGIN_QUANTILE

    def as_dict(self) -> dict:
        return asdict(self)


def sleep_lateness(seconds: float = 1.0, period_ns: int = 1_000_000) -> SleepCalibration:
    """Sleep to absolute deadlines `period_ns` apart for `seconds` and measure how late each sleep
    returned; the margin is the MARGIN_QUANTILE of it, within [MARGIN_MIN_NS, MARGIN_MAX_NS]."""
    import numpy as np

    late = array("q")
    now = time.monotonic_ns
    deadline = now() + period_ns
    end = deadline + round(seconds * 1e9)
    while deadline < end:
        remaining = deadline - now()
        if remaining > 0:
            time.sleep(remaining / 1e9)
        late.append(now() - deadline)
        deadline += period_ns
    a = np.asarray(late, dtype=float) / 1e3
    p50, p90, p99, at = np.percentile(a, [50, 90, 99, MARGIN_QUANTILE])
    want = round(float(at) * 1e3)
    margin = min(max(want, MARGIN_MIN_NS), MARGIN_MAX_NS)
    return SleepCalibration(seconds, int(a.size), round(float(p50), 1), round(float(p90), 1),
                            round(float(p99), 1), round(float(a.max()), 1), margin, want > MARGIN_MAX_NS)
