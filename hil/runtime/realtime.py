"""Real-time runner: one OS process per node (PLANT, DESK, BCU, each BECU), or with [realtime] hosting
= "grouped" the plant in one and every other node in another (`_group_process`: one bus connection,
each frame received and decoded once), plus a recorder writing the trace, all on one python-can bus —
`udp_multicast` by default (no kernel module, no root), `socketcan` on vcan0 where the kernel has it,
or any python-can interface.

Bus configuration follows python-can's precedence: command-line flags, then python-can's own
configuration (CAN_* environment variables, ~/.canrc, /etc/can.conf), then the scenario's
[realtime] section.  A udp_multicast run without a named channel gets a multicast group and port of
its own, so parallel runs on one host do not hear each other.

Scheduling: every node process runs against absolute deadlines on CLOCK_MONOTONIC (openpilot's
Ratekeeper: next += period), all relative to one start instant t0 that the parent hands out once
every process has opened its bus.  Controllers get the scheduled time in integer microseconds, as in
lockstep.  A cycle that starts after its deadline is late and counted; a node up to CATCH_UP_CYCLES
periods behind runs its cycles back to back (so a short stall of the host does not change the mean
rate), one further behind skips to the next slot and counts the skipped cycles as missed.  The plant
never skips: physics time must not jump.  Every process asks the OS for a raised priority (nice
REALTIME_NICE) where it is allowed to.

Ctrl-C / SIGTERM: the parent sets the stop event; every node ends its loop, the plant hands back its
ground truth, the recorder closes the trace; the run folder is written as usual.  A node that dies
ends the run with a NodeDied error naming it.
"""

from __future__ import annotations

import gc
import multiprocessing as mp
import os
import queue
import random
import signal
import socket
import sys
import time
import traceback
from array import array
from collections.abc import Callable
from pathlib import Path

import can

from hil.can.codec import FrameError
from hil.errors import BusError, NodeDied, RailhilError
from hil.runtime.gctune import LOOP_THRESHOLDS
from hil.runtime.outcome import RunOutcome
from hil.runtime.plant_node import TruthLog
from hil.scenario import Scenario
from hil.trace.writers import open_writer

READY_TIMEOUT_S = 60.0         # processes importing numpy/cantools on a loaded 2-core machine
START_MARGIN_S = 0.3           # t0 lies this far after the last process reported ready
JOIN_TIMEOUT_S = 10.0
REALTIME_NICE = -10            # node processes ask for this priority where allowed (root, CAP_SYS_NICE)
CATCH_UP_CYCLES = 5            # a node at most this many periods late catches up instead of skipping
OBSERVE_AFTER_DEATH_S = 1.0    # after a node process dies, the others run on this long (its fail-safe),
                               # counted on the plant's clock so a plant lagging under load records it all
OBSERVE_GRACE_S = 30.0         # ... unless the plant does not get there within this much more wall time
END_NEVER_US = 2**62           # the plant's end-of-observation time while no node has died


def resolve_bus_config(cli: dict, scenario: Scenario) -> dict:
    cfg = dict(cli)
    if "interface" not in cfg:
        try:
            loaded = dict(can.util.load_config())
        except (can.CanError, ValueError):    # python-can has no configuration here: none given
            loaded = {}
        if loaded.get("interface"):
            cfg = {**loaded, **cfg}
        else:
            cfg["interface"] = scenario.realtime.interface
            if scenario.realtime.channel and "channel" not in cfg:
                cfg["channel"] = scenario.realtime.channel
    if cfg["interface"] == "udp_multicast" and not cfg.get("channel"):
        rnd = random.Random(os.getpid() ^ time.monotonic_ns())
        cfg["channel"] = f"239.255.{rnd.randrange(1, 255)}.{rnd.randrange(1, 255)}"
        cfg.setdefault("port", rnd.randrange(20000, 60000))
    if cfg["interface"] == "socketcan" and not cfg.get("channel"):
        cfg["channel"] = "vcan0"
    return cfg


def describe_bus(cfg: dict) -> str:
    extra = f":{cfg['port']}" if "port" in cfg else ""
    return f"interface={cfg.get('interface')} channel={cfg.get('channel')}{extra}"


def watch_command(cfg: dict, dbc_path: str) -> str:
    """The cantools monitor command line that shows this bus live (python-can's bus flags; the DBC
    comes first because --bus-kwargs takes every word after it)."""
    cmd = f"cantools monitor {dbc_path} -i {cfg.get('interface')}"
    if cfg.get("channel") is not None:
        cmd += f" -c {cfg['channel']}"
    extra = [f"{k}={v}" for k, v in cfg.items() if k not in ("interface", "channel", "bitrate")]
    if cfg.get("bitrate"):
        cmd += f" -b {cfg['bitrate']}"
    if extra:
        cmd += " --bus-kwargs " + " ".join(extra)
    return cmd


def open_bus(cfg: dict) -> can.BusABC:
    try:
        return can.Bus(**cfg)
    except Exception as exc:
        hint = ""
        if cfg.get("interface") == "socketcan":
            hint = " (no SocketCAN here? `make vcan` sets up vcan0 where the kernel allows it)"
        raise BusError(f"cannot open the python-can bus {describe_bus(cfg)}: "
                       f"{' '.join(str(exc).split())}{hint}; use --lockstep to run without a bus") from None


def _raise_priority(nice: int) -> bool:
    """Ask the OS for a higher scheduling priority (needs privileges; quietly kept as is otherwise)."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
        return True
    except (OSError, AttributeError):
        return False


def _monotonic_us(t0_ns: int, speed: float = 1.0) -> int:
    """Scheduled (simulated) microseconds since t0; wall time runs 1/speed times slower."""
    return int((time.monotonic_ns() - t0_ns) * speed) // 1000


def _wait_and_receive(bus: can.BusABC, node, deadline_ns: int, t0_ns: int, speed: float = 1.0) -> None:
    """Receive frames into the node until the deadline (the wait *is* the receive loop)."""
    while True:
        remaining = (deadline_ns - time.monotonic_ns()) / 1e9
        msg = bus.recv(timeout=remaining if remaining > 0 else 0.0)
        if msg is None:
            if remaining <= 0:
                return
            continue
        if node is not None and not msg.is_error_frame:
            node.receive(msg.arbitration_id, bytes(msg.data), _monotonic_us(t0_ns, speed))
        if remaining <= 0:
            continue          # drain what is already queued, then return on the next empty recv


PARENT_CHECK_S = 0.5     # how often a node or recorder process checks that its runner is alive [s]


def lateness_summary(lateness_us) -> dict:
    """p50 / p99 / max [µs] and the number of a node's cycle releases after their deadlines (the wait for
    the cycle returned this late; the cycle's frames follow right after)."""
    import numpy as np

    a = np.asarray(lateness_us, dtype=float)
    if not a.size:
        return {"p50": None, "p99": None, "max": None, "cycles": 0}
    p50, p99 = np.percentile(a, [50, 99])
    return {"p50": round(float(p50)), "p99": round(float(p99)), "max": int(a.max()), "cycles": int(a.size)}


def _orphaned() -> bool:
    """True when the runner process that started this one has died (e.g. kill -9): its children stop
    instead of running on with nobody to tell them to."""
    parent = mp.parent_process()
    return parent is not None and not parent.is_alive()


def _hosted_nodes(names, scenario_json: str, dbc_path: str) -> tuple:
    """(scenario, codec, nodes, their releases) of the nodes a process hosts, keyed for SecOC."""
    from hil.can.codec import Codec
    from hil.can.dbc import load_dbc
    from hil.runtime.assembly import build_node
    from hil.runtime.release import node_release
    from hil.scenario import Scenario as _Scenario
    from hil.scenario.params import secoc_keys

    scenario = _Scenario.model_validate_json(scenario_json)
    db = load_dbc(dbc_path)
    codec = Codec(db)
    nodes = [build_node(name, scenario, db, codec, dbc_path) for name in names]
    releases = [node_release(scenario, db, node) for node in nodes]   # jitter, drift, start delay
    keys = secoc_keys(scenario)
    for node in nodes:
        node.use_keys(keys, scenario.secoc.window)
    return scenario, codec, nodes, releases


def _ready_to_go(name: str, go, results) -> bool:
    """Report ready, then wait for the start; False: the runner died meanwhile."""
    _raise_priority(REALTIME_NICE)
    gc.collect()                                     # before ready, not after go: nine processes
    gc.freeze()                                      # collecting at once made the first cycles up to
    gc.set_threshold(*LOOP_THRESHOLDS)               # 80 ms late; setup objects leave the scans
    results.put(("ready", name, None))
    while not go.wait(PARENT_CHECK_S):
        if _orphaned():
            return False
    return True


class CycleTiming:
    """One node's real-time record: each cycle's release lateness [µs], the cycles released late, the
    cycles skipped and the largest lag (and when), kept the same way in a node process and a group."""

    def __init__(self, period_us: int, may_skip: bool = True) -> None:
        self.period_us, self.may_skip = period_us, may_skip   # the plant never skips: physics time
        self.lateness = array("q")
        self.late = self.missed = self.max_lag = self.max_lag_at = 0

    def released(self, deadline_ns: int) -> None:
        """The wait for a cycle returned now, its deadline was `deadline_ns`."""
        self.lateness.append((time.monotonic_ns() - deadline_ns) // 1000)

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
        stats = vars(node.stats).copy()
        stats["late_cycles"] = self.late          # started after their deadline
        stats["missed_cycles"] = self.missed      # skipped after falling more than CATCH_UP_CYCLES behind
        stats["max_lag_us"] = self.max_lag        # the latest a cycle was due when the one before ended
        stats["max_lag_at_us"] = self.max_lag_at  # ... and that cycle's time in the run
        stats["lateness_us"] = lateness_summary(self.lateness)
        return stats


def _report_failure(results, name: str, exc: BaseException) -> None:
    """Tell the runner why this process ends (it names the node or host), then exit non-zero."""
    detail = "".join(traceback.format_exception_only(type(exc), exc)).strip()
    if not isinstance(exc, RailhilError):
        detail += " | " + traceback.format_exc().strip().splitlines()[-3].strip()
    results.put(("error", name, detail))
    raise SystemExit(1) from None


def _node_process(name: str, scenario_json: str, dbc_path: str, cfg: dict, t0_ns, end_at_us, go, stop,
                  results, progress) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)         # the parent coordinates shutdown
    bus = None
    try:
        scenario, _, (node,), (release,) = _hosted_nodes((name,), scenario_json, dbc_path)
        bus = open_bus(cfg)
        if not _ready_to_go(name, go, results):
            return
        t0 = t0_ns.value
        is_plant = name == "PLANT"
        plant = node.controller if is_plant else None
        linger_us = round(scenario.end_after_standstill_s * 1e6)
        max_us = round(scenario.max_duration_s * 1e6)
        stopped_since = None
        speed = scenario.realtime.speed
        release_ns, nominal_us, _ = release.next()
        next_us = release_ns // 1000
        next_progress = 0
        next_parent_check_us = 0
        timing = CycleTiming(node.period_us, may_skip=not is_plant)
        while not stop.is_set():
            if next_us >= next_parent_check_us:          # a runner killed (-9) must not leave us running
                next_parent_check_us = next_us + round(PARENT_CHECK_S * 1e6)
                if _orphaned():
                    return
            deadline_ns = t0 + round(release_ns / speed)
            _wait_and_receive(bus, node, deadline_ns, t0, speed)
            timing.released(deadline_ns)
            frames = node.cycle(release_ns // 1000, nominal_us)
            for fc, data in frames:
                bus.send(can.Message(arbitration_id=fc.frame_id, is_extended_id=fc.is_extended_id,
                                     data=data, check=False))
            release_ns, nominal_us, _ = release.next()
            next_us = release_ns // 1000
            skipped = timing.cycles_to_skip(_monotonic_us(t0, speed) - next_us, next_us)
            if skipped:
                for _ in range(skipped):
                    release_ns, nominal_us, _ = release.next()
                next_us = release_ns // 1000
            if is_plant:
                now = next_us - node.period_us
                if plant.standstill:
                    stopped_since = now if stopped_since is None else stopped_since
                    if now - stopped_since >= linger_us:
                        results.put(("done", name, "standstill"))
                        break
                else:
                    stopped_since = None
                if now >= max_us:
                    results.put(("done", name, "max_duration"))
                    break
                if now >= end_at_us.value:               # a node died: its aftermath is recorded
                    results.put(("done", name, "observed"))
                    break
                if progress is not None and now >= next_progress:
                    progress.put((now, plant.glance()))
                    next_progress += 250_000
        payload = {"stats": timing.stats(node), "end_us": next_us, "lateness_us": timing.lateness}
        if is_plant:
            payload["truth"] = node.controller.truth
        results.put(("result", name, payload))
    except BaseException as exc:  # report, then exit non-zero: the parent names the node
        _report_failure(results, name, exc)
    finally:
        if bus is not None:
            bus.shutdown()


ECHO_DEPTH = 4     # a grouped host's last frames per id it sent, to know them when the bus echoes them


class GroupDelivery:
    """The frames a grouped host receives, each decoded once and handed to the hosted nodes that take
    it (as the lockstep bus does).  Its own nodes' frames are handed over as they are sent (`sent`),
    since not every bus returns a socket's own frames (SocketCAN does not, udp_multicast on one host
    does); one that does comes back, is recognised among the last ECHO_DEPTH frames sent with its id,
    and is not delivered twice.  The nodes' counts are what one process per node would count: a frame
    the DBC does not define is unknown to every node, a malformed one bad for each node that takes its
    id."""

    def __init__(self, nodes: list, codec) -> None:
        self.nodes = nodes
        self.codec = codec
        self.subscribers: dict[int, list] = {}
        for node in nodes:
            for fid in node.rx_ids:
                self.subscribers.setdefault(fid, []).append(node)
        self._echo: dict[int, list[bytes]] = {}      # id -> its last frames sent from here, oldest first

    def sent(self, node, frame_id: int, data: bytes, t_us: int) -> None:
        """A hosted node sent this frame: the other hosted nodes get it now."""
        recent = self._echo.setdefault(frame_id, [])
        recent.append(data)
        if len(recent) > ECHO_DEPTH:
            del recent[0]
        self._deliver(frame_id, data, t_us, node)

    def receive(self, frame_id: int, data: bytes, t_us: int) -> None:
        """A frame from the bus."""
        recent = self._echo.get(frame_id)
        if recent and data in recent:                # the bus returned a frame sent from here
            recent.remove(data)
            return
        self._deliver(frame_id, data, t_us, None)

    def _deliver(self, frame_id: int, data: bytes, t_us: int, sender) -> None:
        subs = self.subscribers.get(frame_id)
        if subs is None:
            if sender is None and frame_id not in self.codec:
                for node in self.nodes:
                    node.stats.unknown_frames += 1
            return
        try:
            values = self.codec[frame_id].decode(data)
        except FrameError:           # short or malformed frame on a real bus: counted, not raised
            for node in subs:
                if node is not sender:
                    node.stats.bad_frames += 1
            return
        for node in subs:
            if node is not sender:
                node.receive_values(frame_id, values, t_us, data)


def _group_process(group: str, names: tuple[str, ...], scenario_json: str, dbc_path: str, cfg: dict,
                   t0_ns, go, stop, results) -> None:
    """Several nodes (not the plant) in one process on one bus connection: each node's cycles keep their
    own absolute deadlines (the earliest due runs next; lateness, catch-up and skipping per node as in
    `_node_process`), the frames between them are received once (`GroupDelivery`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)         # the parent coordinates shutdown
    bus = None
    try:
        import heapq

        scenario, codec, nodes, releases = _hosted_nodes(names, scenario_json, dbc_path)
        delivery = GroupDelivery(nodes, codec)
        bus = open_bus(cfg)
        if not _ready_to_go(group, go, results):
            return
        t0 = t0_ns.value
        speed = scenario.realtime.speed
        n = len(nodes)
        nominal = [0] * n
        schedule = []                                     # (release ns, node index): the next cycle of each
        for i, release in enumerate(releases):
            release_ns, nominal[i], _ = release.next()
            schedule.append((release_ns, i))
        heapq.heapify(schedule)
        timings = [CycleTiming(node.period_us) for node in nodes]
        next_parent_check_us = 0
        next_us = 0
        while not stop.is_set():
            release_ns, i = schedule[0]
            next_us = release_ns // 1000
            if next_us >= next_parent_check_us:          # a runner killed (-9) must not leave us running
                next_parent_check_us = next_us + round(PARENT_CHECK_S * 1e6)
                if _orphaned():
                    return
            deadline_ns = t0 + round(release_ns / speed)
            _wait_and_receive(bus, delivery, deadline_ns, t0, speed)
            timings[i].released(deadline_ns)
            node = nodes[i]
            frames = node.cycle(next_us, nominal[i])
            for fc, data in frames:
                bus.send(can.Message(arbitration_id=fc.frame_id, is_extended_id=fc.is_extended_id,
                                     data=data, check=False))
                delivery.sent(node, fc.frame_id, data, _monotonic_us(t0, speed))
            release = releases[i]
            release_ns, nominal[i], _ = release.next()
            due_us = release_ns // 1000
            for _ in range(timings[i].cycles_to_skip(_monotonic_us(t0, speed) - due_us, due_us)):
                release_ns, nominal[i], _ = release.next()
            heapq.heapreplace(schedule, (release_ns, i))
        for node, timing in zip(nodes, timings, strict=True):
            stats = timing.stats(node)
            stats["host"] = group
            results.put(("result", node.name, {"stats": stats, "end_us": next_us,
                                               "lateness_us": timing.lateness}))
    except BaseException as exc:  # report, then exit non-zero: the parent names the host
        _report_failure(results, group, exc)
    finally:
        if bus is not None:
            bus.shutdown()


GROUP_NAME = "ECUS"                # the process that hosts every node but the plant ([realtime] hosting)


def hosts(scenario: Scenario, names: list[str]) -> dict[str, tuple[str, ...]]:
    """Process name -> the nodes it runs: one process per node, or (hosting "grouped") the plant alone
    and GROUP_NAME with every other node."""
    if scenario.realtime.hosting == "grouped" and len(names) > 2:
        return {"PLANT": ("PLANT",), GROUP_NAME: tuple(n for n in names if n != "PLANT")}
    return {name: (name,) for name in names}


RECORDER_RCVBUF_BYTES = 4 << 20    # the recorder's socket receive buffer: ~30,000 frames of slack (chosen)


def enlarge_receive_buffer(bus: can.BusABC, nbytes: int = RECORDER_RCVBUF_BYTES) -> int | None:
    """Ask the kernel for a larger receive buffer on the bus's socket (udp_multicast, socketcan), so that a
    recorder descheduled for a while on a busy machine does not drop frames; the size is capped by
    net.core.rmem_max (SO_RCVBUFFORCE goes past it where the process may).  Returns the buffer size the
    socket has now [bytes], None for a bus without a socket of its own (python-can keeps no public
    handle: the interfaces' private attributes are looked up)."""
    sock = getattr(getattr(bus, "_multicast", None), "_socket", None) or getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        return None
    for option in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
        if option is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, option, nbytes)
            break
        except OSError:                       # SO_RCVBUFFORCE needs CAP_NET_ADMIN: fall back
            continue
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def _recorder_process(trace_path: str, cfg: dict, go, stop, results) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    bus = None
    try:
        bus = open_bus(cfg)
        enlarge_receive_buffer(bus)
        _raise_priority(REALTIME_NICE)
        writer = open_writer(trace_path)          # wall-clock timestamps: the writer's own epoch
        results.put(("ready", "RECORDER", None))
        notifier = can.Notifier(bus, [writer], timeout=0.05)
        while not stop.wait(PARENT_CHECK_S):
            if _orphaned():                              # runner gone: close the trace, keep what it has
                break
        time.sleep(0.2)             # let in-flight frames of the last cycle arrive before closing
        notifier.stop()             # stops its listeners too: the trace is flushed and closed
        results.put(("result", "RECORDER", {"stats": {}}))
    except BaseException as exc:
        results.put(("error", "RECORDER", " ".join(str(exc).split())))
        raise SystemExit(1) from None
    finally:
        if bus is not None:
            bus.shutdown()


class _Terminate(Exception):
    pass


def truth_end_us(truth) -> int:
    """The time of the last ground-truth sample [µs]: the foundation's TruthLog keeps `t_us`; a study's
    truth (seed 000's reduced model, ...) gives only its columns, whose `t_s` is in seconds."""
    t_us = getattr(truth, "t_us", None)
    if t_us is not None:
        return int(t_us[-1]) if len(t_us) else 0
    t_s = truth.columns().get("t_s")
    return round(float(t_s[-1]) * 1e6) if t_s is not None and len(t_s) else 0


def run_realtime(scenario: Scenario, dbc_path: str, trace_path: Path, cfg: dict,
                 progress: Callable[[int, dict], None] | None = None) -> tuple[RunOutcome, float]:
    """Run the nodes in their processes ([realtime] hosting: one per node, or grouped); returns the
    outcome and the trace's epoch at t0."""
    from hil.report.kpis import check_out_dir
    from hil.runtime.assembly import node_names

    probe = open_bus(cfg)                       # fail early, in the parent, with one clear line
    probe.shutdown()
    check_out_dir(trace_path.parent)            # only now: a bus that does not open leaves no folder
    ctx = mp.get_context("fork" if sys.platform.startswith("linux") else "spawn")
    go, stop = ctx.Event(), ctx.Event()
    t0_ns = ctx.Value("q", 0)
    end_at_us = ctx.Value("q", END_NEVER_US, lock=False)  # set by this process only: no lock needed
    results = ctx.Queue()
    progress_q = ctx.Queue() if progress is not None else None
    scenario_json = scenario.model_dump_json()
    names = node_names(scenario)
    procs = {"RECORDER": ctx.Process(target=_recorder_process, name="railhil-RECORDER",
                                     args=(str(trace_path), cfg, go, stop, results), daemon=True)}
    hosted = {"RECORDER": ("RECORDER",)}
    for host, members in hosts(scenario, names).items():
        hosted[host] = members
        if len(members) > 1:
            procs[host] = ctx.Process(target=_group_process, name=f"railhil-{host}", daemon=True,
                                      args=(host, members, scenario_json, dbc_path, cfg, t0_ns, go, stop,
                                            results))
            continue
        procs[host] = ctx.Process(target=_node_process, name=f"railhil-{host}", daemon=True,
                                  args=(host, scenario_json, dbc_path, cfg, t0_ns, end_at_us, go, stop,
                                        results, progress_q if host == "PLANT" else None))

    old_term = signal.getsignal(signal.SIGTERM)

    def on_term(signum, frame):
        raise _Terminate()

    signal.signal(signal.SIGTERM, on_term)
    # Ctrl-C / kill -INT ends the run cleanly even where the shell started us with SIGINT ignored (`cmd &`
    # in a script, some CI runners): Python keeps an inherited SIG_IGN instead of raising KeyboardInterrupt
    old_int = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    payloads: dict[str, dict] = {}
    reason = "interrupted"
    wall0 = time.perf_counter()
    epoch_t0 = 0.0
    failure: str | None = None
    try:
        for p in procs.values():
            p.start()
        ready: set[str] = set()
        deadline = time.monotonic() + READY_TIMEOUT_S
        while len(ready) < len(procs):
            try:
                kind, name, detail = results.get(timeout=max(0.1, deadline - time.monotonic()))
            except queue.Empty:
                missing = sorted(set(procs) - ready)
                raise NodeDied(f"nodes {', '.join(missing)} did not start "
                               f"within {READY_TIMEOUT_S:.0f} s") from None
            if kind == "error":
                raise NodeDied(f"node {name} failed at start: {detail}")
            ready.add(name)
        t0 = time.monotonic_ns() + int(START_MARGIN_S * 1e9)
        epoch_t0 = time.time() + (t0 - time.monotonic_ns()) / 1e9
        t0_ns.value = t0
        wall0 = time.perf_counter() + START_MARGIN_S
        go.set()
        print(f"realtime: {len(procs)} processes on {describe_bus(cfg)}; pids "
              + " ".join(f"{n}={p.pid}" for n, p in procs.items()), file=sys.stderr, flush=True)
        print(f"realtime: watch it live with: {watch_command(cfg, dbc_path)}", file=sys.stderr, flush=True)
        limit = time.monotonic() + START_MARGIN_S + scenario.max_duration_s / scenario.realtime.speed + 30.0
        death: str | None = None          # a node died: the others run on for OBSERVE_AFTER_DEATH_S
        observe_until = 0.0
        while True:
            if progress_q is not None:
                _show_progress(progress_q, progress)
            if death is not None and time.monotonic() >= observe_until:
                raise NodeDied(death)
            try:
                kind, name, detail = results.get(timeout=0.05 if death else 0.2)
            except queue.Empty:
                dead = [n for n, p in procs.items()
                        if p.exitcode is not None and not all(m in payloads for m in hosted[n])]
                if dead and death is None:
                    code = procs[dead[0]].exitcode
                    what = (f"node {dead[0]}" if len(hosted[dead[0]]) == 1 else
                            f"host {dead[0]} (nodes {', '.join(hosted[dead[0]])})")
                    death = f"{what} died (exit code {code}); run ended"
                    if dead[0] == "PLANT":                # nothing left to observe
                        raise NodeDied(death) from None
                    print(f"realtime: {what} died; the others run on for "
                          f"{OBSERVE_AFTER_DEATH_S:g} s so their reaction is recorded", file=sys.stderr)
                    speed = scenario.realtime.speed
                    end_at_us.value = _monotonic_us(t0, speed) + round(OBSERVE_AFTER_DEATH_S * 1e6)
                    observe_until = time.monotonic() + OBSERVE_AFTER_DEATH_S / speed + OBSERVE_GRACE_S
                if time.monotonic() > limit:
                    raise NodeDied("the plant did not finish within the scenario's max_duration_s") from None
                continue
            if kind == "error":
                raise NodeDied(f"node {name} died: {detail}")
            if kind == "done":
                reason = detail
                if death is not None:
                    raise NodeDied(death)
                break
            if kind == "result":
                payloads[name] = detail
    except (KeyboardInterrupt, _Terminate):
        reason = "interrupted"
        print("\nstopping: interrupt received, closing the trace", file=sys.stderr)
    except RailhilError as exc:
        failure = str(exc)
    finally:
        stop.set()
        go.set()
        end = time.monotonic() + JOIN_TIMEOUT_S
        while len(payloads) < len(names) + 1 and time.monotonic() < end:     # every node and the recorder
            try:
                kind, name, detail = results.get(timeout=0.2)
            except queue.Empty:
                if all(p.exitcode is not None for p in procs.values()):
                    break
                continue
            if kind == "result":
                payloads[name] = detail
            elif kind == "error" and failure is None:
                failure = f"node {name} died: {detail}"
        for p in procs.values():
            p.join(timeout=max(0.1, end - time.monotonic()))
            if p.is_alive():
                p.terminate()
                p.join(1.0)
        signal.signal(signal.SIGTERM, old_term)
        signal.signal(signal.SIGINT, old_int)
    wall = time.perf_counter() - wall0
    if "PLANT" not in payloads:
        raise NodeDied((failure or "the PLANT process ended without handing back its ground truth")
                       + (f"; the trace so far is in {trace_path}" if trace_path.exists() else ""))
    if failure is not None:
        reason = "failed"
    plant = payloads["PLANT"]
    truth: TruthLog = plant["truth"]
    end_us = truth_end_us(truth)
    outcome = RunOutcome(
        mode="realtime", end_us=end_us, reason=reason, truth=truth,
        frames_by_node={n: payloads[n]["stats"]["frames_sent"] for n in names if n in payloads},
        node_stats={n: payloads[n]["stats"] for n in names if n in payloads}, wall_s=wall,
        lateness_us={n: payloads[n]["lateness_us"] for n in names if n in payloads})
    return outcome, epoch_t0, failure


def _show_progress(q, progress: Callable[[int, dict], None]) -> None:
    item = None
    while True:
        try:
            item = q.get_nowait()
        except queue.Empty:
            break
    if item is not None:
        now_us, truth = item
        progress(now_us, truth)


def run_scenario_realtime(scenario: Scenario, out_dir: Path, cli_bus_config: dict,
                          progress: Callable[[int, dict], None] | None = None):
    from hil.can.codec import Codec
    from hil.can.dbc import load_dbc
    from hil.runtime.run import dbc_path_of, finish_run, trace_name

    if scenario.faults:                           # not silently dropped: say where they work
        from hil.errors import ScenarioError
        kinds = ", ".join(sorted({f.kind for f in scenario.faults}))
        raise ScenarioError(f"scenario {scenario.name!r}: [[faults]] ({kinds}) are injected by the lockstep "
                            "run; run it with --lockstep (in real time, kill a node process instead)")
    cfg = resolve_bus_config(cli_bus_config, scenario)
    dbc_path = dbc_path_of(scenario)
    db = load_dbc(dbc_path)                       # bad DBC: one line, before any process starts
    codec = Codec(db)
    from hil.runtime.assembly import build_node, node_names
    from hil.runtime.release import node_releases

    nodes = [build_node(name, scenario, db, codec, str(dbc_path)) for name in node_names(scenario)]
    node_releases(scenario, db, nodes)            # bad bindings or [nodes.*]: one line, before any process
    if scenario.messages:
        print("notice: [messages.*] extra delays apply to lockstep runs only; the real-time bus has its own",
              file=sys.stderr)
    trace = out_dir / trace_name(scenario)        # its folder is made once the bus opened
    outcome, epoch_t0, failure = run_realtime(scenario, str(dbc_path), trace, cfg, progress=progress)
    report = finish_run(scenario, outcome, out_dir, db, codec, trace_t0_s=epoch_t0,
                        trace_speed=scenario.realtime.speed,
                        extra={"bus": {k: str(v) for k, v in cfg.items()}, "failure": failure})
    if failure is not None:                      # nothing recorded is lost: the folder is written first
        raise NodeDied(f"{failure}; what was recorded is in {out_dir}")
    return report
