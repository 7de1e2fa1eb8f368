"""A real-time host: one or more nodes in one process on one python-can bus connection.

The runner (hil.runtime.realtime) starts one host per process: by default one for the plant and one for
every other simulated node ([realtime] hosting = "grouped"), or the plant in that same host
(plant_process = "shared"), or one host per node ("per-node"); `railhil node` runs a host alone. The
node code is the same in every hosting (hil.runtime.node.Node), as in lockstep.

Scheduling. Every node keeps its own absolute deadlines on CLOCK_MONOTONIC, relative to one start instant
t0 (openpilot's Ratekeeper: next += period); the earliest due runs next. The host sleeps until a margin
before the deadline (the margin from this machine's measured sleep lateness, hil.runtime.rtos), waits out
the rest of the margin by polling the clock, and releases the cycle: it takes the frames the bus has for
it, as an ECU's cycle task reads its receive mailboxes first, and runs the node: one sleep a wake (a
wake-up costs 40–60 µs of CPU here). Each cycle's release lateness (now − deadline) is recorded
(`CycleTiming`). A node more than CATCH_UP_CYCLES periods behind skips to its next slot and counts the
cycles skipped.

Receiving. A host does not wake for each frame: frames wait in the socket (its receive buffer enlarged)
until the host wakes for its next deadline, then they are taken (hil.can.frame_io: on udp_multicast
without a select or a can.Message per frame, python-can's wire format either way; frames are sent the
same way), and each is kept for the hosted nodes that receive it (`Delivery`; each node checks it and
decodes the signals it reads, as on the lockstep bus), stamped with its reception time — the kernel's
timestamp that python-can gives the message, where that is a plausible time of this run, else the time
it was taken from the socket.  A node
takes its frames at its own release, as an ECU's cycle task reads its mailboxes: each cycle checks
(SecOC, E2E) its own frames, not those of the nodes due after it.

Stalls.  Each host also watches for the machine keeping it from running (`StallWatch`): the probes see a
CPU every 10 ms, the host every instant of its own waits and cycles.

The plant. Its physics steps every 1 ms on a fixed clock, but only its frames are seen from outside:
with [realtime] plant_wake = "frames" (the default) the host wakes the plant when a frame of it is due
and computes the 1 ms steps since the last one, each with the commands whose reception time falls before
it (frames for the plant are kept with their times until then) — the same physics as a plant woken
every millisecond, ten times fewer wake-ups; "steps" wakes it every millisecond. The plant never skips a
step: physics time must not jump. More than PLANT_CATCH_UP_US behind, it computes the missed steps and
then rebases its schedule: its clock slips behind the bus's by the lag (`slip_us`), recorded in the truth
as rt_lag_s for every sample so that truth and trace times can be aligned.
"""

from __future__ import annotations

import gc
import heapq
import os
import resource
import time
from array import array
from collections.abc import Callable

import can
import numpy as np

from hil.can.frame_io import FrameIO
from hil.runtime.clock import RunClock

CATCH_UP_CYCLES = 5            # a node at most this many periods late catches up instead of skipping
PLANT_CATCH_UP_US = 50_000     # the plant further behind than this rebases its schedule (slips) [µs]
MAX_BATCH_US = 5_000           # a plant woken on its frames is woken at least this often [µs]: two
#                                smaller drains of its socket a 10 ms frame cycle, not one large one
TIMESTAMP_TRUST_US = 1_000_000  # a message timestamp further than this from now is not this run's [µs]
ECHO_DEPTH = 4                 # a host's last frames per id it sent, to know them when the bus echoes them
PARENT_CHECK_US = 500_000      # how often a host checks that its runner is alive [µs]
IDLE_GC_NS = 2_000_000         # the automatic collector is off in the loop: young objects are collected
IDLE_GC_OBJECTS = 5_000        # when at least this many were allocated and the next deadline is at least
IDLE_GC_OLDER = 10             # IDLE_GC_NS away (the middle generation every IDLE_GC_OLDER times); one
#                                collection of 50,000 young objects, at Python's own moment, took ~1 ms
EARLY_DRAIN_GAP_NS = 1_500_000     # a wait longer than this takes the frames waiting EARLY_DRAIN_LEAD_NS
EARLY_DRAIN_LEAD_NS = 700_000      # before its release [ns]: the cycle released then does not pay for them
HOST_STALL_NS = 500_000        # the machine kept the host from running longer than this: a stall it saw [ns]
#                                (as a probe's: hil.runtime.probe.PROBE_STALL_US)


def orphaned() -> bool:
    """True when the runner process that started this one has died (e.g. kill -9): its children stop
    instead of running on with nobody to tell them to.  The parent's pid is compared too: multiprocessing's
    sentinel pipe of an early child stays open while a sibling forked after it lives."""
    import multiprocessing as mp
    import os

    parent = mp.parent_process()
    return parent is not None and (os.getppid() != parent.pid or not parent.is_alive())


class Delivery:
    """The frames a host receives, each taken from the bus once and handed to the hosted nodes that take it
    (Node.receive: each checks it and decodes the signals it reads).  Its own nodes' frames are handed over
    as they are sent (`sent`), since not every bus returns a socket's own frames (SocketCAN does not;
    udp_multicast on one host does, unless the host's FrameIO drops them); one that does comes back, is
    recognised among the last ECHO_DEPTH frames sent with its id, and is not delivered twice.  A node in
    `batched` gets its frames later, in time order: all of them at its release (`replay_all`), or up to a
    time (`replay`: the plant woken on its frames).  The nodes' counts are what one process per node would
    count: a frame the DBC does not define is unknown to every node, a malformed one bad for each node that
    takes its id (Node.receive counts it)."""

    def __init__(self, nodes: list, codec, batched: frozenset = frozenset(), echoes: bool = True) -> None:
        self.nodes = nodes
        self.echoes = echoes             # the bus returns this host's own frames (False: it drops them)
        self.codec = codec
        self.subscribers: dict[int, list] = {}
        for node in nodes:
            for fid in node.rx_ids:
                self.subscribers.setdefault(fid, []).append(node)
        self._echo: dict[int, list[bytes]] = {}      # id -> its last frames sent from here, oldest first
        self.batched = batched
        # a batched node's frames until it takes them: (reception time [µs], frame id, data)
        self.inbox: dict[object, list[tuple[int, int, bytes]]] = {node: [] for node in nodes
                                                                   if node.name in batched}
        self.received = 0                # frames from the bus that were not this host's own

    def sent(self, node, frame_id: int, data: bytes, t_us: int) -> None:
        """A hosted node sent this frame: the other hosted nodes get it now."""
        if self.echoes:
            recent = self._echo.setdefault(frame_id, [])
            recent.append(data)
            if len(recent) > ECHO_DEPTH:
                del recent[0]
        if frame_id in self.subscribers:
            self._deliver(frame_id, data, t_us, node)

    def receive(self, frame_id: int, data: bytes, t_us: int) -> None:
        """A frame from the bus."""
        recent = self._echo.get(frame_id) if self.echoes else None
        if recent and data in recent:                # the bus returned a frame sent from here
            recent.remove(data)
            return
        self.received += 1
        self._deliver(frame_id, data, t_us, None)

    def _deliver(self, frame_id: int, data: bytes, t_us: int, sender) -> None:
        subs = self.subscribers.get(frame_id)
        if subs is None:
            if sender is None and frame_id not in self.codec:
                for node in self.nodes:
                    node.stats.unknown_frames += 1
            return
        inbox = self.inbox
        for node in subs:
            if node is sender:
                continue
            if inbox and node in inbox:
                inbox[node].append((t_us, frame_id, data))
            else:
                node.receive(frame_id, data, t_us)

    def replay_all(self, node) -> None:
        """Hand a batched node every frame it has received, oldest first."""
        box = self.inbox[node]
        if box:
            for t_us, frame_id, data in box:
                node.receive(frame_id, data, t_us)
            box.clear()

    def replay(self, node, until_us: int, offset_us: int = 0) -> None:
        """Hand a batched node its frames received up to `until_us` on its own clock (host time −
        `offset_us`), oldest first."""
        box = self.inbox[node]
        if not box:
            return
        k = 0
        for t_us, frame_id, data in box:
            if t_us - offset_us > until_us:
                break
            node.receive(frame_id, data, t_us - offset_us)
            k += 1
        if k:
            del box[:k]


def lateness_summary(lateness_us) -> dict:
    """p50 / p99 / max [µs] and the number of a node's cycle releases (the wait for the cycle returned
    this late after its deadline; the cycle's frames follow right after)."""
    a = np.asarray(lateness_us, dtype=float)
    if not a.size:
        return {"p50": None, "p99": None, "max": None, "cycles": 0}
    p50, p99 = np.percentile(a, [50, 99])
    return {"p50": round(float(p50)), "p99": round(float(p99)), "max": int(a.max()), "cycles": int(a.size)}



class CycleTiming:
    """One node's real-time record: each cycle's deadline [µs since t0, on the bus's clock] and release
    lateness [µs]; in the wait before it and in the cycle, the time the machine took from its host, the
    host's CPU time and its time waiting for a CPU (`StallWatch`) [µs]; the cycles released late, the
    cycles skipped, the largest lag (and when) and, for the plant, how far its clock slipped behind the
    bus's."""

    def __init__(self, period_us: int, may_skip: bool = True, judged_in: str = "cycles") -> None:
        self.period_us, self.may_skip = period_us, may_skip   # the plant never skips: physics time
        self.judged_in = judged_in     # "wakes": the plant woken on its frames (wakes ≤ period_us apart)
        self.deadline_us = array("q")
        self.lateness = array("q")
        self.ended_us = array("q")     # when each cycle's frames were out [µs since t0]: it blocked the next
        self.wait_lost_us = array("q")   # the time the machine took from the host in the wait before it
        self.cycle_lost_us = array("q")  # ... and in the cycle
        self.wait_cpu_us, self.cycle_cpu_us = array("q"), array("q")        # the host's CPU time in each
        self.wait_delay_us, self.cycle_delay_us = array("q"), array("q")    # its time waiting for a CPU
        self.late = self.missed = self.max_lag = self.max_lag_at = 0
        self.slip_us = 0

    def released(self, deadline_ns: int, t0_ns: int, now_ns: int, lost_ns: int = 0, cpu_ns: int = 0,
                 delay_ns: int = 0) -> int:
        """The wait for a cycle returned at `now_ns`, its deadline was `deadline_ns`; in the wait the machine
        took `lost_ns`, the host ran `cpu_ns` and waited `delay_ns` for a CPU: its lateness [µs]."""
        late = (now_ns - deadline_ns) // 1000
        self.deadline_us.append((deadline_ns - t0_ns) // 1000)
        self.lateness.append(late)
        self.wait_lost_us.append(lost_ns // 1000)
        self.wait_cpu_us.append(cpu_ns // 1000)
        self.wait_delay_us.append(delay_ns // 1000)
        return late

    def ended(self, t0_ns: int, lost_ns: int = 0, cpu_ns: int = 0, delay_ns: int = 0) -> None:
        """The cycle released last has sent its frames now; in it the machine took `lost_ns`, the host ran
        `cpu_ns` and waited `delay_ns` for a CPU."""
        self.ended_us.append((time.monotonic_ns() - t0_ns) // 1000)
        self.cycle_lost_us.append(lost_ns // 1000)
        self.cycle_cpu_us.append(cpu_ns // 1000)
        self.cycle_delay_us.append(delay_ns // 1000)

    def cycles_to_skip(self, lag_us: int, due_us: int) -> int:
        """The next cycle, due at `due_us`, is `lag_us` late when the one before ended: count it, and
        the cycles to skip when it is more than CATCH_UP_CYCLES periods behind."""
        if lag_us <= 0:
            return 0
        self.late += 1
        if lag_us > self.max_lag:
            self.max_lag, self.max_lag_at = lag_us, due_us
        if lag_us > CATCH_UP_CYCLES * self.period_us and self.may_skip:
            skipped = lag_us // self.period_us
            self.missed += skipped
            return skipped
        return 0

    def stats(self, node) -> dict:
        """The node's stats with its real-time figures."""
        stats = node.stats.as_dict()
        stats["late_cycles"] = self.late          # started after their deadline
        stats["missed_cycles"] = self.missed      # skipped after falling more than CATCH_UP_CYCLES behind
        stats["max_lag_us"] = self.max_lag        # the latest a cycle was due when the one before ended
        stats["max_lag_at_us"] = self.max_lag_at  # ... and that cycle's time in the run
        stats["lateness_us"] = lateness_summary(self.lateness)
        if not self.may_skip:
            stats["slip_us"] = self.slip_us       # the plant's clock behind the bus's at the end
        return stats

    def payload(self, node) -> dict:
        return {"stats": self.stats(node), "lateness_us": self.lateness, "deadline_us": self.deadline_us,
                "period_us": self.period_us, "ended_us": self.ended_us, "judged_in": self.judged_in,
                "wait_lost_us": self.wait_lost_us, "cycle_lost_us": self.cycle_lost_us,
                "wait_cpu_us": self.wait_cpu_us, "cycle_cpu_us": self.cycle_cpu_us,
                "wait_delay_us": self.wait_delay_us, "cycle_delay_us": self.cycle_delay_us}


class PlantEnd:
    """When a host with the plant ends the run: standstill for `linger_us`, `max_us` simulated, or the
    runner's `end_at_us` (a node died: its aftermath recorded); `progress` gets the plant's glance every
    250 ms of simulated time."""

    def __init__(self, linger_us: int, max_us: int, end_at_us=None, progress=None) -> None:
        self.linger_us, self.max_us, self.end_at_us, self.progress = linger_us, max_us, end_at_us, progress
        self.stopped_since: int | None = None
        self.next_progress = 0
        self.reason: str | None = None

    def after(self, plant, now_us: int) -> bool:
        """The plant computed its step at `now_us`: True when the run ends (reason in `reason`)."""
        if plant.standstill:
            if self.stopped_since is None:
                self.stopped_since = now_us
            elif now_us - self.stopped_since >= self.linger_us:
                self.reason = "standstill"
                return True
        else:
            self.stopped_since = None
        if now_us >= self.max_us:
            self.reason = "max_duration"
            return True
        if self.end_at_us is not None and now_us >= self.end_at_us.value:
            self.reason = "observed"
            return True
        if self.progress is not None and now_us >= self.next_progress:
            self.progress.put((now_us, plant.glance()))
            self.next_progress += 250_000
        return False


class StallWatch:
    """What a host sees of the machine itself.  Its time is split into windows: a wait (from a cycle's end
    to the next release) and a cycle (release to its frames out); of each it keeps its CPU time
    (`cpu_ns`), its time runnable waiting for a CPU (`delay_ns`) and the time lost.  The time lost is the
    wall time minus the CPU time, minus the wait for a CPU (the kernel's run_delay,
    /proc/thread-self/schedstat), minus the sleep it asked for and the lateness the precise wait allows each
    sleep (its margin: a sleep's usual lateness, as calibrated).  What is left the kernel did not give to
    any process of this machine's: the hypervisor took the virtual CPU, or the timer fired late — the
    machine's doing, as a probe's stall is.  A cycle in which the thread blocked of its own accord (a
    voluntary context switch) counts nothing.  More than HOST_STALL_NS lost in one window is a stall
    (`rows`: placed at the end of its window, where within it is not known; µs since t0).

    The probes sample each CPU every 10 ms and miss what falls between; the host sees every instant of its
    own waits and cycles.  Where schedstat cannot be read, nothing is counted (`why_not`)."""

    def __init__(self, t0_ns: int, threshold_ns: int = HOST_STALL_NS, allowance_ns: int = 0) -> None:
        self.t0_ns, self.threshold_ns = t0_ns, threshold_ns
        self.allowance_ns = allowance_ns   # of each sleep's lateness, not counted: what the wait allows for
        self.intervals = array("q")      # start, end, start, end, ... [µs since t0]
        self.why_not: str | None = "not watched"
        self._fd: int | None = None
        self._wall = self._cpu = self._delay = self._asleep = self._voluntary = 0
        self.cpu_ns = self.delay_ns = 0  # the last window's CPU time and time waiting for a CPU [ns]

    def _lost(self, now_ns: int) -> int:
        """The time lost since the window began [ns]; a new window begins at `now_ns`."""
        cpu, delay = time.thread_time_ns(), int(os.pread(self._fd, 64, 0).split()[1])
        self.cpu_ns, self.delay_ns = cpu - self._cpu, delay - self._delay
        lost = (now_ns - self._wall) - self.cpu_ns - self.delay_ns - self._asleep
        self._wall, self._cpu, self._delay, self._asleep = now_ns, cpu, delay, 0
        return lost

    def _saw(self, lost_ns: int, end_ns: int) -> None:
        self.intervals.extend(((end_ns - lost_ns - self.t0_ns) // 1000, (end_ns - self.t0_ns) // 1000))

    def start(self) -> None:
        """Begin watching, in the thread that runs the loop."""
        try:
            self._fd = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
            int(os.pread(self._fd, 64, 0).split()[1])
        except (OSError, IndexError, ValueError) as exc:
            self.close()
            self.why_not = f"/proc/thread-self/schedstat unreadable ({exc})"
            return
        self.why_not = None
        self._lost(time.monotonic_ns())

    def asleep(self, ns: float) -> None:
        """The host asked to sleep this long in the window (and allows it to return `allowance_ns` late)."""
        self._asleep += int(ns) + self.allowance_ns

    def released(self, now_ns: int) -> int:
        """A wait ended at `now_ns` (a cycle's release); the cycle's window begins.  The time the wait lost
        [ns]."""
        if self._fd is None:
            return 0
        lost = self._lost(now_ns)
        if lost > self.threshold_ns:
            self._saw(lost, now_ns)
        self._voluntary = resource.getrusage(resource.RUSAGE_THREAD).ru_nvcsw
        return max(lost, 0)

    def cycle_ended(self) -> int:
        """The cycle released last has sent its frames; the wait's window begins.  The time the cycle lost
        [ns] (0 when it blocked of its own accord)."""
        if self._fd is None:
            return 0
        now = time.monotonic_ns()
        lost = self._lost(now)
        if resource.getrusage(resource.RUSAGE_THREAD).ru_nvcsw != self._voluntary:
            self.delay_ns = 0            # it blocked: none of its time is counted the machine's
            return 0
        if lost <= 0:
            return 0
        if lost > self.threshold_ns:
            self._saw(lost, now)
        return lost

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def rows(self) -> list[list[int]]:
        """The stalls as [start, end] rows [µs since t0]."""
        a = self.intervals
        return [[a[k], a[k + 1]] for k in range(0, len(a), 2)]


class Host:
    """Nodes hosted in this process, their releases and the bus: `run()` until `stop` is set, the plant
    ends the run, or `orphaned()` says the runner died."""

    def __init__(self, nodes: list, releases: list, codec, bus: can.BusABC, clock: RunClock, *,
                 margin_ns: int = 0, plant_wake: str = "frames", end: PlantEnd | None = None,
                 orphaned: Callable[[], bool] | None = None,
                 publish: Callable[[object], None] | None = None) -> None:
        """`clock`: the run's (hil.runtime.clock.RunClock.starting: its t0 and speed); `publish(plant
        controller)`: called after each wake's plant steps (a device's truth quantities,
        hil.runtime.gateway_host.SharedTruth)."""
        self.nodes, self.releases, self.bus = nodes, releases, bus
        self.publish = publish
        self.clock, self.margin_ns = clock, margin_ns
        self._now_us: int | None = None            # now, once per drain
        self.plant = next((k for k, n in enumerate(nodes) if n.name == "PLANT"), None)
        self.batched = self.plant is not None and plant_wake == "frames"
        # every node takes its frames at its own release (an ECU reads its mailboxes at its cycle's start):
        # a cycle then checks (SecOC, E2E) only its own frames, not those of the nodes due after it
        self.delivery = Delivery(nodes, codec, frozenset(n.name for k, n in enumerate(nodes)
                                                         if k != self.plant or self.batched))
        # udp_multicast on Linux: its own frames do not come back, nor the DBC's frames no hosted node takes
        # (a frame the DBC does not define still comes: every node counts it)
        unwanted = [fc.frame_id for fc in codec if fc.frame_id not in self.delivery.subscribers]
        self.io = FrameIO(bus, drop_own=True, drop_ids=unwanted)
        self.delivery.echoes = not self.io.own_dropped
        # a node is judged in its cycles; the plant woken on its frames in its wakes (MAX_BATCH_US apart:
        # its 1 ms steps are computed at each, on time by construction, and its frames leave at them)
        self.timings = [CycleTiming(MAX_BATCH_US, may_skip=False, judged_in="wakes")
                        if k == self.plant and self.batched
                        else CycleTiming(n.period_us, may_skip=k != self.plant) for k, n in enumerate(nodes)]
        self.end = end
        self.orphaned = orphaned
        self.reason: str | None = None
        self.end_us = 0
        if self.plant is not None:            # the plant's lag behind the bus at each truth sample
            truth = nodes[self.plant].controller.truth
            if hasattr(truth, "t_us"):          # the foundation's TruthLog (a study's may have no µs)
                truth.rt_lag_us = []
        self.frames_received = 0
        self.timestamps_untrusted = 0    # frames stamped on reception, their own timestamp implausible
        self.stalls = StallWatch(clock.t0_ns, allowance_ns=margin_ns)

    # -- time --------------------------------------------------------------------------------------
    def now_us(self) -> int:
        """Bus time [µs since t0, simulated: × speed]."""
        return self.clock.now_us()

    def _drain(self) -> None:
        """Every frame the socket holds, delivered with its reception time."""
        self._now_us = None
        self.io.take(self._on_frame)

    def _on_frame(self, timestamp: float, frame_id: int, _extended: bool, data: bytes, msg) -> None:
        if msg is not None and (msg.is_error_frame or msg.is_remote_frame):
            return
        now_us = self._now_us
        if now_us is None:
            now_us = self._now_us = self.now_us()
        t_us = self.clock.simulated_us(timestamp)
        if not (now_us - TIMESTAMP_TRUST_US < t_us <= now_us + 1000):   # not this run's clock
            t_us = now_us
            self.timestamps_untrusted += 1
        self.frames_received += 1
        self.delivery.receive(frame_id, data, t_us)

    def _wait(self, deadline_ns: int) -> int:
        """Collect garbage if there is time, sleep until the precise wait's margin before the deadline, poll
        out the rest; now [ns] (the cycle's release).  The frames are taken after it (`_drain`).  Taking them
        before it too, at every wake, cost a second sleep a wake (taking them ends at an instant no estimate
        knows): 0.85 of ECUS's 6.3 and 0.6 of PLANT's 4.9 sampled CPU s (py-spy on the hosts of a run).  Only
        a wait longer than EARLY_DRAIN_GAP_NS takes them early, EARLY_DRAIN_LEAD_NS before the release: the
        BCU's, after the plant's frames of the period came in: its window's parts, p50 each (taking frames,
        its cycle, its sends), 236 + 259 + 92 → 15 + 227 + 88 µs, at no CPU measurable in this VM's noise."""
        now = time.monotonic_ns
        remaining = deadline_ns - now()
        if remaining > IDLE_GC_NS and gc.get_count()[0] > IDLE_GC_OBJECTS:
            gc.collect(1 if gc.get_count()[1] >= IDLE_GC_OLDER else 0)
            remaining = deadline_ns - now()
        if remaining > EARLY_DRAIN_GAP_NS:   # a long wait: the frames waiting are taken before the release
            self.stalls.asleep(remaining - EARLY_DRAIN_LEAD_NS)
            time.sleep((remaining - EARLY_DRAIN_LEAD_NS) / 1e9)
            self._drain()
            remaining = deadline_ns - now()
        if remaining > self.margin_ns:
            self.stalls.asleep(remaining - self.margin_ns)
            time.sleep((remaining - self.margin_ns) / 1e9)
        t = now()
        while t < deadline_ns:
            t = now()
        return t

    def _send(self, node, frames) -> None:
        send, sent = self.io.send, self.delivery.sent
        for fc, data in frames:
            send(fc.frame_id, fc.is_extended_id, data)
            sent(node, fc.frame_id, data, self.now_us())

    # -- the loop ----------------------------------------------------------------------------------
    def run(self, stop) -> None:
        gc.disable()                         # collected at idle moments instead (_wait)
        self.stalls.start()
        try:
            self._loop(stop)
        finally:
            gc.enable()
            self.io.close()
            self.stalls.close()

    def _plant_wake_ns(self, node, slot_ns: int) -> int:
        """When to wake the plant whose next step is `slot_ns` [ns, its own clock]: at that step, or, woken
        on its frames, at the step its next frame is due (at most MAX_BATCH_US on)."""
        if not self.batched:
            return slot_ns
        slot_us = slot_ns // 1000
        return max(slot_us, min(node.next_frame_due_us, slot_us + MAX_BATCH_US)) * 1000

    def _loop(self, stop) -> None:
        nodes, releases, timings = self.nodes, self.releases, self.timings
        deadline_of, t0 = self.clock.deadline_ns, self.clock.t0_ns
        plant = self.plant
        nominal = [0] * len(nodes)
        slot = [0] * len(nodes)              # each node's next release on its own clock [ns]
        schedule = []                        # (wake on the bus's clock [ns], node index)
        for i, release in enumerate(releases):
            slot[i], nominal[i], _ = release.next()
            schedule.append((self._plant_wake_ns(nodes[i], slot[i]) if i == plant else slot[i], i))
        heapq.heapify(schedule)
        slip_ns = 0                          # the plant's clock behind the bus's [ns of bus time]
        next_check_us = 0
        while not stop.is_set():
            wake_ns, i = schedule[0]
            node = nodes[i]
            if wake_ns // 1000 >= next_check_us:
                next_check_us = wake_ns // 1000 + PARENT_CHECK_US
                if self.orphaned is not None and self.orphaned():
                    self.reason = "orphaned"
                    return
            deadline_ns = deadline_of(wake_ns)
            now_ns = self._wait(deadline_ns)
            watch = self.stalls
            lost_ns = watch.released(now_ns)
            timing = timings[i]
            late_us = timing.released(deadline_ns, t0, now_ns, lost_ns, watch.cpu_ns, watch.delay_ns)
            self._drain()
            if i != plant:
                self.delivery.replay_all(node)
                self.end_us = slot[i] // 1000
                self._send(node, node.cycle(slot[i] // 1000, nominal[i]))
                timing.ended(t0, watch.cycle_ended(), watch.cpu_ns, watch.delay_ns)
                release_ns, nominal[i], _ = releases[i].next()
                due_us = release_ns // 1000
                for _ in range(timing.cycles_to_skip(self.now_us() - due_us, due_us)):
                    release_ns, nominal[i], _ = releases[i].next()
                slot[i] = release_ns
                heapq.heapreplace(schedule, (release_ns, i))
                continue
            # the plant: every 1 ms step up to the wake, each with the commands received before it
            wake_own_us = (wake_ns - slip_ns) // 1000
            lag_us = late_us + slip_ns // 1000
            truth = node.controller.truth
            lags = getattr(truth, "rt_lag_us", None)
            while slot[i] // 1000 <= wake_own_us:
                step_us = slot[i] // 1000
                if self.batched:
                    self.delivery.replay(node, step_us, slip_ns // 1000)
                n_truth = len(truth.t_us) if lags is not None else 0
                frames = node.cycle(step_us, nominal[i])
                if lags is not None and len(truth.t_us) != n_truth:
                    lags.append(lag_us)
                if frames:
                    self._send(node, frames)
                self.end_us = step_us
                slot[i], nominal[i], _ = releases[i].next()
                if self.end is not None and self.end.after(node.controller, step_us):
                    self.reason = self.end.reason
                    timing.ended(t0, watch.cycle_ended(), watch.cpu_ns, watch.delay_ns)
                    return
            if self.publish is not None:
                self.publish(node.controller)
            timing.ended(t0, watch.cycle_ended(), watch.cpu_ns, watch.delay_ns)
            behind_us = self.now_us() - (slot[i] + slip_ns) // 1000
            timing.cycles_to_skip(behind_us, slot[i] // 1000)
            if behind_us > PLANT_CATCH_UP_US:          # rebase: the plant's clock slips behind the bus's
                slip_ns += behind_us * 1000
                timing.slip_us = slip_ns // 1000
            heapq.heapreplace(schedule, (self._plant_wake_ns(node, slot[i]) + slip_ns, i))

    def payloads(self) -> dict[str, dict]:
        """Each hosted node's result: its stats and timing (and the plant's truth)."""
        out = {}
        for node, timing in zip(self.nodes, self.timings, strict=True):
            payload = timing.payload(node)
            payload["end_us"] = self.end_us
            if node.name == "PLANT":
                payload["truth"] = node.controller.truth
            out[node.name] = payload
        return out
