"""Real-time runner: the simulated nodes in as few processes as the machine needs, a recorder writing the
trace and a probe measuring the machine, all on one python-can bus — `udp_multicast` by default (no kernel
module, no root), `socketcan` on vcan0 where the kernel has it, or any python-can interface.

Hosting ([realtime] hosting, `--hosting`): "grouped" (the default) runs every simulated ECU in one
process with one bus connection (each frame received once, hil.runtime.host) and the plant in
its own (plant_process = "shared": in that one too); "per-node" runs one process per node (isolation
tests: kill -9 of one ECU; nodes spread over hosts). A node marked external ([nodes.NAME] external,
`--external NAME`) is not simulated: a device under test, another process or another host sends its
frames (`railhil node`), and the run judges them like any node's.

Bus configuration follows python-can's precedence: command-line flags, then python-can's own
configuration (CAN_* environment variables, ~/.canrc, /etc/can.conf), then the scenario's
[realtime] section.  A udp_multicast run without a named channel gets a multicast group and port of its
own, so parallel runs on one host do not hear each other, and a multicast TTL of 0, so that its frames stay
on this host — unless a node is external: the run then uses python-can's default group and port (and TTL
1: the LAN), as `railhil node` and any python-can program do by default.

Scheduling: every host runs its nodes against absolute deadlines on CLOCK_MONOTONIC, all relative to one
start instant t0 that the runner hands out once every process has opened its bus; controllers get the
scheduled time in integer microseconds, as in lockstep (hil.runtime.host).  Where the OS permits, the
hosts run SCHED_FIFO with memory locked, the plant and the ECUs on CPUs of their own (hil.runtime.rtos);
one line says what is in effect.  A probe process measures the machine's own timer lateness during the
run (hil.runtime.probe) and, before it, how late this machine's sleeps return: the margin of the hosts'
precise wait (run.json realtime.calibration).  Every cycle's lateness is judged afterwards
(hil.runtime.outcome.realtime_verdict).

Ctrl-C / SIGTERM: the runner sets the stop event; every host ends its loop, the plant hands back its
ground truth, the recorder closes the trace; the run folder is written as usual.  A host that dies ends
the run with a NodeDied error naming its nodes, after the others ran on for OBSERVE_AFTER_DEATH_S.
"""

from __future__ import annotations

import bisect
import functools
import gc
import logging
import math
import multiprocessing as mp
import os
import queue
import random
import signal
import socket
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

import can

from hil.can.codec import loaded_dbc
from hil.can.frame_io import FrameIO
from hil.devices.description import read_device_file
from hil.devices.device import TRUTH_FIELDS
from hil.devices.opcua import OpcUaLink
from hil.errors import BusError, DeviceError, NodeDied, RailhilError, ScenarioError
from hil.fmi.fmu import check_only
from hil.links.control_centre import make_keys
from hil.runtime.assembly import build_node, check_devices, for_realtime, node_names
from hil.runtime.clock import RunClock
from hil.runtime.gateway_host import GatewayHost, SharedTruth
from hil.runtime.gctune import LOOP_THRESHOLDS
from hil.runtime.host import Host, PlantEnd, orphaned
from hil.runtime.outcome import RunOutcome
from hil.runtime.plant_node import TruthLog
from hil.runtime.probe import HOST_SEEN, PROBE_PERIOD_US, probe_cpus, probe_process
from hil.runtime.release import node_release, node_releases
from hil.runtime.rtos import (
    GATEWAY_PRIORITY,
    NODE_PRIORITY,
    PROBE_PRIORITY,
    RECORDER_PRIORITY,
    CpuLatencyHold,
    RtSetup,
    hold_cpu_latency,
    make_realtime,
    pin_plan,
)
from hil.runtime.run import (
    RunRecord,
    check_out_dir,
    dbc_path_of,
    device_trace_name,
    messages_sent,
    trace_name,
    write_run_folder,
)
from hil.scenario import Scenario
from hil.scenario.model import NodeTiming
from hil.scenario.params import secoc_keys
from hil.trace.writers import open_writer

__all__ = ["describe_bus", "hosts", "open_bus", "resolve_bus_config", "run_realtime",
           "run_realtime_folder", "watch_command"]

READY_TIMEOUT_S = 60.0         # processes importing numpy/cantools on a loaded 2-core machine
START_MARGIN_S = 0.3           # t0 lies this far after the last process reported ready
JOIN_TIMEOUT_S = 10.0
OBSERVE_AFTER_DEATH_S = 1.0    # after a node process dies, the others run on this long (its fail-safe),
                               # counted on the plant's clock so a plant lagging under load records it all
OBSERVE_GRACE_S = 30.0         # ... unless the plant does not get there within this much more wall time
END_NEVER_US = 2**62           # the plant's end-of-observation time while no node has died
PARENT_CHECK_S = 0.5           # how often the recorder checks that its runner is alive [s]
RECORDER_BATCH_S = 0.02        # the recorder takes the frames from its socket this often [s]
GROUP_NAME = "ECUS"            # the process that hosts every simulated node but the plant (grouped)
SHARED_NAME = "NODES"          # ... and the plant too (plant_process = "shared")


def resolve_bus_config(cli: dict, scenario: Scenario, external: bool = False) -> dict:
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
        if external:                  # the bus a `railhil node` or a python-can program opens by default
            from can.interfaces.udp_multicast import UdpMulticastBus

            cfg["channel"] = UdpMulticastBus.DEFAULT_GROUP_IPv4
        else:
            rnd = random.Random(os.getpid() ^ time.monotonic_ns())
            cfg["channel"] = f"239.255.{rnd.randrange(1, 255)}.{rnd.randrange(1, 255)}"
            cfg.setdefault("port", rnd.randrange(20000, 60000))
            # nobody off this host knows the group: TTL 0 keeps the frames on it (the kernel loops them back
            # to every local socket and sends nothing out on the network interface: ~12 µs less a frame)
            cfg.setdefault("hop_limit", 0)
    if cfg["interface"] == "socketcan" and not cfg.get("channel"):
        cfg["channel"] = "vcan0"
    return cfg


OPCUA = "opcua"                 # a device's "bus" that is an OPC UA link (device_bus_config)


def describe_bus(cfg: dict) -> str:
    if cfg.get("interface") == OPCUA:
        return f"OPC UA {cfg['channel']} (the bench as {cfg['role']})"
    extra = f":{cfg['port']}" if "port" in cfg else ""
    return f"interface={cfg.get('interface')} channel={cfg.get('channel')}{extra}"


def bus_flags(cfg: dict) -> str:
    """python-can's command-line flags for this bus (cantools monitor, `railhil node`, can.viewer)."""
    flags = f"-i {cfg.get('interface')}"
    if cfg.get("channel") is not None:
        flags += f" -c {cfg['channel']}"
    if cfg.get("bitrate"):
        flags += f" -b {cfg['bitrate']}"
    extra = [f"{k}={v}" for k, v in cfg.items() if k not in ("interface", "channel", "bitrate")]
    if extra:
        flags += " --bus-kwargs " + " ".join(extra)
    return flags


def watch_command(cfg: dict, dbc_path: str) -> str:
    """The cantools monitor command line that shows this bus live (python-can's bus flags; the DBC
    comes first because --bus-kwargs takes every word after it)."""
    return f"cantools monitor {dbc_path} {bus_flags(cfg)}"


@contextmanager
def held_can_logs() -> Iterator[list[logging.LogRecord]]:
    """python-can's log records while a bus opens, held back: python-can's socketcan logs `Could not access
    SocketCAN device vcan9 ([Errno 19] No such device)` and then raises, which would add a loose line to the
    one-line error that says the same.  The caller passes them on once the bus is open (`pass_on`)."""
    held: list[logging.LogRecord] = []
    handler = logging.Handler()
    handler.emit = held.append
    logger = logging.getLogger("can")
    propagate, logger.propagate = logger.propagate, False
    logger.addHandler(handler)
    try:
        yield held
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate


def pass_on(held: list[logging.LogRecord]) -> None:
    for record in held:
        logging.getLogger(record.name).handle(record)


def open_bus(cfg: dict) -> can.BusABC:
    try:
        with held_can_logs() as held:
            bus = can.Bus(**cfg)
        pass_on(held)
        return bus
    except Exception as exc:
        hint = ""
        if cfg.get("interface") == "socketcan":
            hint = " (no SocketCAN here? `make vcan` sets up vcan0 where the kernel allows it)"
        raise BusError(f"cannot open the python-can bus {describe_bus(cfg)}: "
                       f"{' '.join(str(exc).split())}{hint}; use --lockstep to run without a bus") from None


RECORDER_RCVBUF_BYTES = 4 << 20    # a socket's receive buffer: ~30,000 frames of slack (chosen)


def enlarge_receive_buffer(bus: can.BusABC, nbytes: int = RECORDER_RCVBUF_BYTES) -> int | None:
    """Ask the kernel for a larger receive buffer on the bus's socket (udp_multicast, socketcan), so that a
    process that takes its frames in batches, or is descheduled for a while on a busy machine, does not
    drop frames; the size is capped by net.core.rmem_max (SO_RCVBUFFORCE goes past it where the process
    may).  Returns the buffer size the socket has now [bytes], None for a bus without a socket of its own
    (python-can keeps no public handle: the interfaces' private attributes are looked up)."""
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


def cpu_seconds() -> float:
    """CPU seconds (user + system) this process used so far."""
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return round(r.ru_utime + r.ru_stime, 3)


def hosts(scenario: Scenario, names: list[str]) -> dict[str, tuple[str, ...]]:
    """Process name -> the simulated nodes it runs ([realtime] hosting, plant_process)."""
    rt = scenario.realtime
    if rt.hosting == "per-node" or len(names) < 2:
        return {name: (name,) for name in names}
    ecus = tuple(n for n in names if n != "PLANT")
    if "PLANT" not in names:
        return {GROUP_NAME: ecus}
    if rt.plant_process == "shared":
        return {SHARED_NAME: tuple(names)}
    return {"PLANT": ("PLANT",), GROUP_NAME: ecus} if ecus else {"PLANT": ("PLANT",)}


def hosted_nodes(names, scenario: Scenario, dbc_path: str) -> tuple:
    """(codec, nodes, their releases) of the nodes a host runs, keyed for SecOC (a runner's host process,
    `railhil node`)."""

    db, codec = loaded_dbc(Path(dbc_path))
    codec.compile()                               # its frames' encode and decode: before the first cycle
    with for_realtime():                          # real devices where a node has them (the ACD's GPS pty)
        nodes = [build_node(name, scenario, db, codec, dbc_path) for name in names]
    releases = [node_release(scenario, db, node) for node in nodes]   # jitter, drift, start delay
    keys = secoc_keys(scenario)
    for node in nodes:
        node.use_keys(keys, scenario.secoc.window)
    return codec, nodes, releases


def idle_hold(scenario: Scenario) -> CpuLatencyHold:
    """The CPUs' idle-state exit latency asked for the run ([realtime] cpu_latency_us, with scheduling
    "auto"), held until its `release()`."""
    rt = scenario.realtime
    return hold_cpu_latency(rt.cpu_latency_us if rt.scheduling == "auto" and rt.cpu_latency_us != "off"
                            else None)


def os_setup(scenario: Scenario, priority: int, cpus: tuple[int, ...] | None = None) -> RtSetup:
    """What this process gets of the OS for real time ([realtime] scheduling)."""
    if scenario.realtime.scheduling == "normal":
        return RtSetup("normal", 0, False, None, None, ("[realtime] scheduling = \"normal\"",))
    return make_realtime(priority, cpus)


@dataclass
class Shared:
    """What the runner hands every process: the start event and instant, the stop event, the precise
    wait's margin and (for the plant's host) when a node's death has been observed long enough."""

    go: object
    stop: object
    t0_ns: object
    margin_ns: object
    end_at_us: object


def _ready_to_go(name: str, shared: Shared, results, rt: RtSetup) -> bool:
    """Report ready (with what the OS gave), then wait for the start; False: the runner died meanwhile."""
    gc.collect()                                     # before ready, not after go: nine processes
    gc.freeze()                                      # collecting at once made the first cycles up to
    gc.set_threshold(*LOOP_THRESHOLDS)               # 80 ms late; setup objects leave the scans
    results.put(("ready", name, rt.as_dict()))
    while not shared.go.wait(PARENT_CHECK_S):
        if orphaned():
            return False
    return True


def _exit_text(code: int) -> str:
    """A process's exit code in words: "exit 1", "killed by SIGSEGV"."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit {code}"


def _report_failure(results, name: str, exc: BaseException) -> None:
    """Tell the runner why this process ends (it names the node or host), then exit non-zero."""
    detail = "".join(traceback.format_exception_only(type(exc), exc)).strip()
    if not isinstance(exc, RailhilError):
        detail += " | " + traceback.format_exc().strip().splitlines()[-3].strip()
    results.put(("error", name, detail))
    raise SystemExit(1) from None


def _host_process(host: str, names: tuple[str, ...], scenario_json: str, dbc_path: str, cfg: dict,
                  shared: Shared, results, progress, cpus, truth=None) -> None:
    """One host: the nodes `names` on one bus connection (hil.runtime.host.Host)."""

    signal.signal(signal.SIGINT, signal.SIG_IGN)         # the parent coordinates shutdown
    bus = None
    try:
        scenario = Scenario.model_validate_json(scenario_json)
        codec, nodes, releases = hosted_nodes(names, scenario, dbc_path)
        bus = open_bus(cfg)
        enlarge_receive_buffer(bus)                       # frames wait there until the next deadline
        rt = os_setup(scenario, NODE_PRIORITY, cpus)
        for node in nodes:                                # what a device needs to know first (a GPS pty)
            for line in getattr(node.controller, "announce", lambda: [])():
                results.put(("info", host, line))
        if not _ready_to_go(host, shared, results, rt):
            return
        end = None
        if "PLANT" in names:
            end = PlantEnd(round(scenario.end_after_standstill_s * 1e6), round(scenario.max_duration_s * 1e6),
                           shared.end_at_us, progress)
        publish = None
        if truth is not None and "PLANT" in names:         # a device's map reads the plant's truth

            publish = SharedTruth(truth, scenario.train.cars).write
        clock = RunClock.starting(shared.t0_ns.value, scenario.realtime.speed)
        runner = Host(nodes, releases, codec, bus, clock, margin_ns=shared.margin_ns.value,
                      plant_wake=scenario.realtime.plant_wake, end=end, orphaned=orphaned, publish=publish)
        runner.run(shared.stop)
        if runner.reason == "orphaned":          # nobody reads the results: a large put would block the exit
            return
        if runner.reason in ("standstill", "max_duration", "observed"):
            results.put(("done", host, runner.reason))
        for name, payload in runner.payloads().items():
            payload["stats"]["host"] = host
            results.put(("result", name, payload))
        results.put(("host", host, {"frames_received": runner.frames_received,
                                    "timestamps_untrusted": runner.timestamps_untrusted,
                                    "cpu_s": cpu_seconds(), "stalls_us": runner.stalls.rows(),
                                    "stalls_not_counted": runner.stalls.why_not}))
    except BaseException as exc:  # report, then exit non-zero: the parent names the host
        _report_failure(results, host, exc)
    finally:
        if bus is not None:
            bus.shutdown()


def device_bus_config(scenario: Scenario, node: str, bench_cfg: dict) -> dict | None:
    """The python-can bus of the device in `node`'s place: the scenario's [devices.NODE] bus, else its device
    file's [bus]; None: the bench's own (bus = "bench"); a DeviceError naming both when neither gives one."""

    ref = scenario.devices[node]
    spec = read_device_file(ref.file)
    if spec.transport == "opcua":               # no bus: an OPC UA link (hil.devices.opcua)
        return {"interface": OPCUA, "channel": spec.opcua.endpoint, "role": spec.opcua.role}
    if not ref.bus and spec.bus == "bench":
        return None
    cfg = dict(ref.bus) if ref.bus else dict(spec.bus)
    if not cfg or "interface" not in cfg:
        raise DeviceError(f"{ref.file}: no [bus] interface for the device's own bus (or [devices.{node}] bus "
                          "in the scenario): a real-time run needs it, e.g. interface = \"udp_multicast\", "
                          "channel = \"239.74.163.7\"")
    if all(cfg.get(k) == bench_cfg.get(k) for k in ("interface", "channel", "port")):
        raise DeviceError(f"{ref.file}: the device's bus {describe_bus(cfg)} is the bench's; give it a bus "
                          "of its own")
    return cfg


def _check_link(device) -> None:
    """An OPC UA device's link opened once and closed, in the parent: an endpoint that cannot be reached
    or served, a refused login, a variable the PLC's server does not have or of another type, a certificate
    that is not one — each one line (DeviceError, BusError) before any process starts."""

    link = OpcUaLink(device)
    link.start()
    link.close()


def _gateway_process(name: str, scenario_json: str, dbc_path: str, cfg: dict, device_cfg: dict,
                     shared: Shared, results, cpus, truth=None) -> None:
    """The gateway of the device in node `name`'s place, between the bench's bus and the device's
    (hil.runtime.gateway_host)."""

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    buses = []
    try:
        scenario = Scenario.model_validate_json(scenario_json)
        _, (node,), _ = hosted_nodes((name,), scenario, dbc_path)
        if truth is not None:                    # the plant's truth, as its host writes it
            node.gateway.to_device.truth = SharedTruth(truth, scenario.train.cars).read
        link = None
        if device_cfg is not None and device_cfg.get("interface") == OPCUA:
            link = OpcUaLink(node.gateway.device)
            link.start()                          # the server up, or the PLC's server connected
            buses = [open_bus(cfg)]
        else:
            buses = [open_bus(cfg)] + ([] if device_cfg is None else [open_bus(device_cfg)])   # None: one bus
        for bus in buses:
            enlarge_receive_buffer(bus)
        rt = os_setup(scenario, GATEWAY_PRIORITY, cpus)
        if not _ready_to_go(name, shared, results, rt):
            return
        device_port = link if link is not None else buses[1] if len(buses) > 1 else None
        clock = RunClock.starting(shared.t0_ns.value, scenario.realtime.speed)
        host = GatewayHost(node.gateway, buses[0], device_port, clock, orphaned=orphaned,
                           first_device_frame=lambda t: results.put(("seen", name, t)))
        host.run(shared.stop)
        if host.reason == "orphaned":
            return
        payload = host.payload()
        if link is not None:                      # the PLC's cycle, read age, round trip: its own terms
            payload["device"]["opcua"] = link.payload(host.clock.t0_s, host.stopped_epoch)
            payload["device"]["bus_mode"] = OPCUA
        payload["stats"]["host"] = name
        results.put(("result", name, payload))
        results.put(("host", name, {"frames_received": sum(host.frames_received.values()),
                                    "timestamps_untrusted": host.timestamps_untrusted,
                                    "cpu_s": cpu_seconds()}))
    except BaseException as exc:  # report, then exit non-zero: the parent names the gateway
        _report_failure(results, name, exc)
    finally:
        for bus in buses:
            bus.shutdown()


def _recorder_process(trace_path: str, cfg: dict, go, stop, results, name: str = "RECORDER") -> None:
    """Every frame of the bus into the trace (python-can's writer for the suffix), taken from the socket
    every RECORDER_BATCH_S (its receive buffer enlarged), so that the recorder does not wake for each;
    plain data frames taken without a can.Message (hil.can.frame_io) go to the BLF writer's write_frame,
    which writes the bytes python-can's writer would."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    bus = None
    try:
        bus = open_bus(cfg)
        enlarge_receive_buffer(bus)
        rt = make_realtime(RECORDER_PRIORITY)
        writer = open_writer(trace_path)          # wall-clock timestamps: the writer's own epoch
        results.put(("ready", name, rt.as_dict()))
        frames = 0
        lost_runner = False
        next_check = time.monotonic() + PARENT_CHECK_S
        io = FrameIO(bus)
        write_frame = getattr(writer, "write_frame", None)     # the BLF writer's, without a Message

        def record(timestamp: float, frame_id: int, extended: bool, data: bytes, msg) -> None:
            if msg is None and write_frame is not None:
                write_frame(timestamp, frame_id, extended, data)
            else:
                writer.on_message_received(msg if msg is not None else can.Message(
                    timestamp=timestamp, arbitration_id=frame_id, is_extended_id=extended, data=data,
                    check=False))

        try:
            while True:
                stopping = stop.wait(RECORDER_BATCH_S)
                if stopping:
                    time.sleep(0.2)              # let in-flight frames of the last cycle arrive
                try:
                    frames += io.take(record)
                except can.CanOperationError:
                    # a SocketCAN device set down reports ENETDOWN first, then the frames still in the
                    # socket: they go into the trace too, then the error ends the recorder
                    with suppress(can.CanOperationError):
                        io.take(record)
                    raise
                if stopping:
                    break
                if time.monotonic() > next_check:
                    next_check = time.monotonic() + PARENT_CHECK_S
                    if orphaned():              # runner gone: close the trace, keep what it has
                        lost_runner = True
                        break
        finally:
            writer.stop()                         # flushed and closed
        if not lost_runner:
            results.put(("result", name, {"stats": {"frames_recorded": frames}}))
            results.put(("host", name, {"cpu_s": cpu_seconds()}))
    except BaseException as exc:
        results.put(("error", name, " ".join(str(exc).split())))
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


def check_node_names(scenario: Scenario, names, what: str) -> list[str]:
    """`names` as given (`what`: how the user named them, "--external", "node"), checked: each a node of the
    scenario, none twice; a ScenarioError naming the first that is not."""

    every = node_names(scenario)
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise ScenarioError(f"{what} {name}: given twice")
        seen.add(name)
        if name not in every:
            raise ScenarioError(f"{what} {name}: scenario {scenario.name!r} has no node {name!r}; its nodes "
                                f"are {', '.join(every)}")
    return list(names)


def external_nodes(scenario: Scenario, cli: list[str] | tuple[str, ...] = ()) -> list[str]:
    """The nodes that are not simulated ([nodes.NAME] external = true and `--external NAME`), checked: each
    a node of the scenario, none given twice on the command line, not every node."""

    names = node_names(scenario)
    seen = set(check_node_names(scenario, cli, "--external"))
    in_file = sorted(n for n, spec in scenario.nodes.items() if spec.external and n not in seen)
    check_node_names(scenario, in_file, "[nodes.NAME] external: node")
    external = [n for n in names if n in seen or (n in scenario.nodes and scenario.nodes[n].external)]
    if len(external) == len(names):
        raise ScenarioError(f"every node of scenario {scenario.name!r} is external: nothing to simulate")
    return external


@functools.cache
def _device_cached(path: str, mtime_ns: int, dbc_path: str, scenario_json: str, node: str):
    scenario = Scenario.model_validate_json(scenario_json)
    db, codec = loaded_dbc(Path(dbc_path))
    return build_node(node, scenario, db, codec, dbc_path).gateway.device


def _device_of(scenario: Scenario, node: str):
    """The device in `node`'s place (hil.devices.device.Device), loaded once."""
    file = scenario.devices[node].file
    return _device_cached(file, Path(file).stat().st_mtime_ns, str(dbc_path_of(scenario)),
                          scenario.model_dump_json(), node)


def marked_external(scenario: Scenario, external) -> Scenario:
    """The scenario as the run's processes get it: each external node marked `[nodes.NAME] external`, so
    that a node built there knows which device is outside (the plant serves an external ACD's GPS line)."""

    if not external:
        return scenario
    nodes = dict(scenario.nodes)
    for name in external:
        nodes[name] = nodes.get(name, NodeTiming()).model_copy(update={"external": True})
    return scenario.model_copy(update={"nodes": nodes})


class ServedCentre:
    """The control centre a run serves an external ACD (hil.links.control_centre, its own process): on a
    port of this host, its database and the trains' keys (fresh, mode 0600) in the run folder; the run's
    scenario names it ([acd] control_centre, control_centre_keys), so that the plant reports the leader to
    it, and the device, with its train's key, reports itself and hears the leader."""

    START_TIMEOUT_S = 30.0

    def __init__(self, folder: Path, scenario: Scenario) -> None:
        import subprocess


        spec = scenario.acd
        trains = [f"U{spec.train_id}"] + ([] if spec.leader is None else [f"U{spec.leader.train_id}"])
        self.summary = ""
        self.keys = folder / "centre-keys.toml"
        self.db = folder / "centre.sqlite"
        make_keys(self.keys, trains)
        self.proc = subprocess.Popen([sys.executable, "-m", "hil.links.control_centre", "--db", str(self.db),
                                      "--port", "0", "--keys", str(self.keys)],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = _first_line(self.proc, self.START_TIMEOUT_S)
        if not line.startswith("listening on "):
            self.stop()
            raise NodeDied(f"the control centre for the external ACD did not start: {line or self.summary}")
        self.address = line.split()[2]
        print(f"realtime: control centre on {self.address} (database {self.db.name}; each train's key in "
              f"{self.keys}: the external ACD, train {trains[0]}, signs with its own)", file=sys.stderr,
              flush=True)
        acd = spec.model_copy(update={"control_centre": self.address, "control_centre_keys": str(self.keys)})
        self.scenario = scenario.model_copy(update={"acd": acd})

    def stop(self) -> None:
        """SIGINT, then its summary line (reports, refusals)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            out, err = self.proc.communicate(timeout=JOIN_TIMEOUT_S)
        except Exception:
            self.proc.kill()
            out, err = self.proc.communicate()
        lines = [ln for ln in (out + err).splitlines() if ln.strip()]
        self.summary = lines[-1] if lines else ""

    def record(self) -> dict:
        return {"address": getattr(self, "address", None), "database": str(self.db), "keys": str(self.keys),
                "summary": self.summary}


def _first_line(proc, timeout_s: float) -> str:
    """The first line `proc` prints on stdout, waiting at most `timeout_s` ('' if none came)."""
    import selectors

    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    return proc.stdout.readline().strip() if sel.select(timeout_s) else ""


def _external_ids(db, external: list[str]) -> dict[str, set[int]]:
    """The frame ids each external node sends (the DBC's senders)."""
    return {name: {m.frame_id for m in db.messages if name in m.senders} for name in external}


def run_realtime(scenario: Scenario, dbc_path: str, trace_path: Path, cfg: dict,
                 progress: Callable[[int, dict], None] | None = None,
                 external: list[str] | tuple[str, ...] = (),
                 device_traces: dict[str, Path] | None = None) -> tuple[RunOutcome, RunClock, str | None]:
    """Run the simulated nodes in their hosts, the recorder and the probe, and for each device in a node's
    place ([devices.NODE]) its gateway and a recorder of its own bus (into `device_traces[NODE]`); returns
    the outcome, the run's clock (its t0 on the trace's clock: 0 when it never started) and the failure
    (None: none)."""

    watch = open_bus(cfg)                       # fail early, in the parent, with one clear line
    names = node_names(scenario)
    devices = [n for n in names if n in scenario.devices]
    simulated = [n for n in names if n not in external and n not in devices]
    external_ids = _external_ids(loaded_dbc(Path(dbc_path))[0], list(external))
    device_cfgs = {n: device_bus_config(scenario, n, cfg) for n in devices}   # None: on the bench's bus
    linked = [n for n, c in device_cfgs.items() if c is not None and c["interface"] == OPCUA]   # OPC UA
    device_watch = {}                           # each device's bus, until its first frame came
    try:
        for n in linked:                        # its endpoint, security and variables checked first
            _check_link(_device_of(scenario, n))
        for n, dcfg in device_cfgs.items():
            if n not in linked:
                device_watch[n] = open_bus(dcfg if dcfg is not None else cfg)
    except BaseException:
        for bus in (watch, *device_watch.values()):
            if bus is not None:
                bus.shutdown()
        raise
    device_ids = {n: {m.frame_id for m in _device_of(scenario, n).db.messages
                      if _device_of(scenario, n).node in m.senders} for n in devices if n not in linked}
    if not external:
        watch.shutdown()
        watch = None
    check_out_dir(trace_path.parent)            # only now: a bus that does not open leaves no folder
    outside = [*external, *devices]             # what the bench serves a real device: the ACD's GPS and radio
    scenario = marked_external(scenario, outside)
    centre = None
    if "ACD" in outside and scenario.acd is not None and scenario.acd.control_centre is None:
        centre = ServedCentre(trace_path.parent, scenario)   # the external ACD's radio: the bench serves it
        scenario = centre.scenario
    ctx = mp.get_context("fork" if sys.platform.startswith("linux") else "spawn")
    shared = Shared(ctx.Event(), ctx.Event(), ctx.Value("q", 0), ctx.Value("q", 0),
                    ctx.Value("q", END_NEVER_US, lock=False))    # set by this process only: no lock needed
    results = ctx.Queue()
    progress_q = ctx.Queue() if progress is not None else None
    scenario_json = scenario.model_dump_json()
    rt = scenario.realtime
    plan = hosts(scenario, simulated)
    cpus = pin_plan(list(plan)) if rt.pin_cpus and rt.scheduling == "auto" and rt.hosting == "grouped" else {}
    procs = {}
    cpus_probed = probe_cpus()
    for k, cpu in enumerate(cpus_probed):       # one probe per CPU, staggered; the first calibrates
        name = "PROBE" if cpu is None else f"PROBE{cpu}"
        procs[name] = ctx.Process(target=probe_process, name=f"railhil-{name}", daemon=True,
                                  args=(name, cpu, k * PROBE_PERIOD_US // len(cpus_probed), shared.t0_ns,
                                        shared.go, shared.stop, results,
                                        {"priority": PROBE_PRIORITY, "fifo": rt.scheduling == "auto",
                                         "lock_memory": rt.scheduling == "auto"},
                                        rt.calibration_s if k == 0 else 0.0))
    procs["RECORDER"] = ctx.Process(target=_recorder_process, name="railhil-RECORDER",
                                    args=(str(trace_path), cfg, shared.go, shared.stop, results), daemon=True)
    truth = None                                # the plant's truth, where a device's map reads it
    if any(_device_of(scenario, n).uses_truth for n in devices):
        truth = ctx.Array("d", [math.nan] * (len(TRUTH_FIELDS) * scenario.train.cars), lock=False)
    for name in devices:                        # each device: its gateway, and a recorder of its own bus
        if device_cfgs[name] is not None and name not in linked:   # (on the bench's bus: the run's
            #                                                         recorder has its frames; OPC UA: none)
            procs[f"RECORDER-{name}"] = ctx.Process(
                target=_recorder_process, name=f"railhil-RECORDER-{name}", daemon=True,
                args=(str(device_traces[name]), device_cfgs[name], shared.go, shared.stop, results,
                      f"RECORDER-{name}"))
        procs[name] = ctx.Process(target=_gateway_process, name=f"railhil-GATEWAY-{name}", daemon=True,
                                  args=(name, scenario_json, dbc_path, cfg, device_cfgs[name], shared,
                                        results, None, truth))
    hosted = {name: (name,) for name in procs}
    for host, members in plan.items():
        hosted[host] = members
        procs[host] = ctx.Process(target=_host_process, name=f"railhil-{host}", daemon=True,
                                  args=(host, members, scenario_json, dbc_path, cfg, shared, results,
                                        progress_q if "PLANT" in members else None, cpus.get(host), truth))

    old_term = signal.getsignal(signal.SIGTERM)

    def on_term(signum, frame):
        raise _Terminate()

    signal.signal(signal.SIGTERM, on_term)
    # Ctrl-C / kill -INT ends the run cleanly even where the shell started us with SIGINT ignored (`cmd &`
    # in a script, some CI runners): Python keeps an inherited SIG_IGN instead of raising KeyboardInterrupt
    old_int = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    payloads: dict[str, dict] = {}
    setups: dict[str, dict] = {}
    probe_errors: dict[str, str] = {}
    calibration: dict | None = None
    host_info: dict[str, dict] = {}
    reason = "interrupted"
    wall0 = time.perf_counter()
    clock = RunClock(speed=rt.speed)    # until t0 is handed out
    failure: str | None = None
    external_seen: dict[str, float] = {}
    device_seen: dict[str, float] = {}
    infos: list[str] = []
    idle = idle_hold(scenario)          # for the whole run, before the probe calibrates the sleeps under it
    try:
        for p in procs.values():
            p.start()
        ready: set[str] = set()
        deadline = time.monotonic() + READY_TIMEOUT_S
        while len(ready) < len(procs):
            try:
                kind, name, detail = results.get(timeout=min(0.5, max(0.1, deadline - time.monotonic())))
            except queue.Empty:
                died = [f"{n} ({_exit_text(p.exitcode)})" for n, p in procs.items()
                        if n not in ready and p.exitcode is not None]
                if died:                           # a crash says nothing on the queue: its exit code does
                    raise NodeDied(f"node process {', '.join(died)} ended at start without a word") from None
                if time.monotonic() < deadline:
                    continue
                missing = sorted(set(procs) - ready)
                raise NodeDied(f"nodes {', '.join(missing)} did not start "
                               f"within {READY_TIMEOUT_S:.0f} s") from None
            if kind == "error":
                raise NodeDied(f"node {name} failed at start: {detail}")
            if kind == "info":                     # a host says what a device needs: print it now
                print(f"realtime: {detail}", file=sys.stderr, flush=True)
                infos.append(detail)
            elif kind == "probe_error":            # the run goes on without that probe, and says so
                probe_errors[name] = detail
                ready.add(name)
            elif kind == "calibrated":
                calibration = detail["calibration"]
                setups[name] = detail["rt"]
                ready.add(name)
            else:
                setups[name] = detail
                ready.add(name)
        shared.margin_ns.value = calibration["margin_ns"] if calibration and rt.precise_wait else 0
        t0 = time.monotonic_ns() + int(START_MARGIN_S * 1e9)
        clock = RunClock.starting(t0, rt.speed)
        shared.t0_ns.value = t0
        wall0 = time.perf_counter() + START_MARGIN_S
        shared.go.set()
        print(f"realtime: {len(procs)} processes on {describe_bus(cfg)}; pids "
              + " ".join(f"{n}={p.pid}" for n, p in procs.items()), file=sys.stderr, flush=True)
        print(f"realtime: watch it live with: {watch_command(cfg, dbc_path)}", file=sys.stderr, flush=True)
        print(f"realtime: {describe_setup(setups, calibration, rt.precise_wait, idle)}", file=sys.stderr,
              flush=True)
        if external:
            one = len(external) == 1
            its, it = ("its", "it") if one else ("their", "each")
            print(f"realtime: external {', '.join(external)}: not simulated, {its} frames must come from the "
                  f"bus (start {it} before the run, e.g. railhil node {','.join(external)} SCENARIO "
                  f"{bus_flags(cfg)}); waiting up to {rt.external_wait_s:g} s for "
                  f"{'its first frame' if one else 'their first frames'}", file=sys.stderr, flush=True)
        for name in devices:
            device = _device_of(scenario, name)
            where = "the bench's bus" if device_cfgs[name] is None else describe_bus(device_cfgs[name])
            first = "write" if name in linked else "frame"
            print(f"realtime: device {device.node} ({device.dbc_path.name}) in {name}'s place, on {where} "
                  f"behind the gateway; waiting up to {rt.external_wait_s:g} s for its first {first}",
                  file=sys.stderr, flush=True)
        limit = time.monotonic() + START_MARGIN_S + clock.wall_s(scenario.max_duration_s) + 30.0
        wait_external_until = time.monotonic() + START_MARGIN_S + rt.external_wait_s
        death: str | None = None          # a node died: the others run on for OBSERVE_AFTER_DEATH_S
        observe_until = 0.0
        while True:
            if progress_q is not None:
                _show_progress(progress_q, progress)
            if watch is not None:
                _watch_external(watch, external_ids, external_seen, clock.t0_s)
                if len(external_seen) == len(external_ids):
                    watch.shutdown()
                    watch = None
                elif time.monotonic() > wait_external_until:
                    silent = [n for n in external_ids if n not in external_seen]
                    many = len(silent) > 1
                    raise NodeDied(f"external node{'s' if many else ''} {', '.join(silent)} sent no frame "
                                   f"within {rt.external_wait_s:g} s on {describe_bus(cfg)}: start "
                                   f"{'them' if many else 'it'} before the run (railhil node "
                                   f"{','.join(silent)} SCENARIO {bus_flags(cfg)}, or the device on that "
                                   "bus)")
            for name in list(device_watch):
                _watch_external(device_watch[name], {name: device_ids[name]}, device_seen, clock.t0_s)
                if name in device_seen:
                    device_watch.pop(name).shutdown()
                elif time.monotonic() > wait_external_until:
                    raise NodeDied(f"device {name} ({_device_of(scenario, name).node} of "
                                   f"{Path(scenario.devices[name].file).name}) sent no frame within "
                                   f"{rt.external_wait_s:g} s on {describe_bus(device_cfgs[name] or cfg)}: "
                                   "start it before the run, on that bus")
            for name in linked:
                if name not in device_seen and time.monotonic() > wait_external_until:
                    device = _device_of(scenario, name)
                    raise NodeDied(f"device {name} ({device.node} of {device.path.name}) wrote nothing "
                                   f"within {rt.external_wait_s:g} s over {describe_bus(device_cfgs[name])}: "
                                   "start it before the run" + (" (it connects to the bench's server)"
                                                          if device_cfgs[name]["role"] == "server" else ""))
            if death is not None and time.monotonic() >= observe_until:
                raise NodeDied(death)
            try:
                kind, name, detail = results.get(timeout=0.05 if (death or watch or device_watch
                                                                  or len(device_seen) < len(linked)) else 0.2)
            except queue.Empty:
                dead = [n for n, p in procs.items() if p.exitcode is not None and not n.startswith("PROBE")
                        and not all(m in payloads for m in hosted[n])]
                if dead and death is None:
                    code = procs[dead[0]].exitcode
                    what = (f"node {dead[0]}" if len(hosted[dead[0]]) == 1 else
                            f"host {dead[0]} (nodes {', '.join(hosted[dead[0]])})")
                    death = f"{what} died (exit code {code}); run ended"
                    if "PLANT" in hosted[dead[0]] or dead[0] == "RECORDER":     # nothing left to observe
                        raise NodeDied(death) from None
                    print(f"realtime: {what} died; the others run on for "
                          f"{OBSERVE_AFTER_DEATH_S:g} s so their reaction is recorded", file=sys.stderr)
                    shared.end_at_us.value = clock.now_us() + round(OBSERVE_AFTER_DEATH_S * 1e6)
                    observe_until = time.monotonic() + clock.wall_s(OBSERVE_AFTER_DEATH_S) + OBSERVE_GRACE_S
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
            elif kind == "host":
                host_info[name] = detail
            elif kind == "seen":                   # an OPC UA device's first write (its gateway saw it)
                device_seen.setdefault(name, round(detail - clock.t0_s, 4))
    except (KeyboardInterrupt, _Terminate):
        reason = "interrupted"
        print("\nstopping: interrupt received, closing the trace", file=sys.stderr)
    except RailhilError as exc:
        failure = str(exc)
    finally:
        shared.stop.set()
        shared.go.set()
        if watch is not None:
            watch.shutdown()
        for bus in device_watch.values():
            bus.shutdown()
        end = time.monotonic() + JOIN_TIMEOUT_S
        want = len(procs) - len(plan) + len(simulated) - len(probe_errors)    # nodes, recorder, probes
        hosts_cpu = set(plan) | {"RECORDER"}        # each reports its CPU seconds after its results
        while (len(payloads) < want or not hosts_cpu <= set(host_info)) and time.monotonic() < end:
            try:
                kind, name, detail = results.get(timeout=0.2)
            except queue.Empty:
                if all(p.exitcode is not None for p in procs.values()):
                    break
                continue
            if kind == "result":
                payloads[name] = detail
            elif kind == "host":
                host_info[name] = detail
            elif kind == "probe_error":
                probe_errors[name] = detail
            elif kind == "error" and failure is None:
                failure = f"node {name} died: {detail}"
        for p in procs.values():
            p.join(timeout=max(0.1, end - time.monotonic()))
            if p.is_alive():
                p.terminate()
                p.join(1.0)
        signal.signal(signal.SIGTERM, old_term)
        signal.signal(signal.SIGINT, old_int)
        idle.release()
        if centre is not None:
            centre.stop()
    wall = time.perf_counter() - wall0
    if "PLANT" in external:
        raise NodeDied("the PLANT is external: its ground truth is on another host; run the plant here")
    if "PLANT" not in payloads:
        raise NodeDied((failure or "the PLANT process ended without handing back its ground truth")
                       + (f"; the trace so far is in {trace_path}" if trace_path.exists() else ""))
    if failure is not None:
        reason = "failed"
    truth: TruthLog = payloads["PLANT"]["truth"]
    nodes = [n for n in names if (n in simulated or n in devices) and n in payloads]
    probes = {n: payloads[n] for n in procs if n.startswith("PROBE") and n in payloads}
    for name, probe in probes.items():          # each process's CPU seconds side by side in run.json
        if "cpu_s" in probe:
            host_info.setdefault(name, {"cpu_s": probe["cpu_s"]})
    host_stalls = {h: {"stalls_us": info.pop("stalls_us"), "not_counted": info.pop("stalls_not_counted")}
                   for h, info in host_info.items() if "stalls_us" in info}
    judged_until_the_end(payloads)
    realtime = {
        "host_stalls": host_stalls,
        "hosting": rt.hosting, "plant_process": rt.plant_process, "plant_wake": rt.plant_wake,
        "hosts": {h: list(m) for h, m in plan.items()},
        "os": setups, "cpu_latency": idle.as_dict(), "calibration": calibration,
        "precise_wait": rt.precise_wait,
        "margin_ns": shared.margin_ns.value, "probes": probes, "probe_errors": probe_errors,
        "external": list(external),
        "external_first_frame_s": external_seen, "device_first_frame_s": device_seen,
        "announced": infos, **({"control_centre": centre.record()} if centre is not None else {}),
        "devices": {n: describe_bus(c or cfg) for n, c in device_cfgs.items()},
        "deadline": rt.deadline.model_dump(),
        "cycles": {n: cycle_record(payloads[n], setups) for n in nodes},
        "host_frames": host_info,
    }
    outcome = RunOutcome(
        mode="realtime", end_us=truth_end_us(truth), reason=reason, truth=truth,
        frames_by_node={n: payloads[n]["stats"]["frames_sent"] for n in nodes},
        node_stats={n: payloads[n]["stats"] for n in nodes}, wall_s=wall,
        lateness_us={n: payloads[n]["lateness_us"] for n in nodes}, realtime=realtime,
        devices={n: payloads[n].pop("device") for n in devices if n in payloads})
    return outcome, clock, failure


PER_CYCLE = ("deadline_us", "lateness_us", "ended_us", *HOST_SEEN)     # a node's records, one per cycle
CPU_WAITS = ("wait_delay_us", "cycle_delay_us")


def cycle_record(payload: dict, setups: dict[str, dict]) -> dict:
    """A node's cycles as the verdict reads them (hil.runtime.probe.machine_cycles), its host, and the
    number of CPUs the host was pinned to (absent: not pinned, every CPU).  Its waits for a CPU only from a
    host at SCHED_FIFO: below it, the bench's own recorder and runner may have held the CPU."""
    host = payload["stats"].get("host")
    setup = setups.get(host) or {}
    fifo = setup.get("policy") == "SCHED_FIFO"
    return {**{k: payload[k] for k in ("period_us", "judged_in", *PER_CYCLE) if fifo or k not in CPU_WAITS},
            "host": host, **({"cpus": len(setup["cpus"])} if setup.get("cpus") else {})}


def judged_until_the_end(payloads: dict[str, dict]) -> None:
    """Keep of each node's (and probe's) per-cycle records only the cycles due by the plant's last wake: the
    run ended there (standstill, the duration, a death observed); the cycles a host released after it,
    before it heard the run was over, are not the run's (the plant then hands its results over, at the nodes'
    priority: one such BCU cycle waited 10 ms for a CPU)."""
    plant = payloads.get("PLANT")
    if plant is None or not len(plant["deadline_us"]):
        return
    end_us = plant["deadline_us"][-1]
    for name, payload in payloads.items():
        if name == "PLANT" or "deadline_us" not in payload:
            continue
        k = bisect.bisect_right(payload["deadline_us"], end_us)
        for key in PER_CYCLE:
            if key in payload:
                del payload[key][k:]


def _watch_external(bus: can.BusABC, ids: dict[str, set[int]], seen: dict[str, float],
                    epoch_t0: float) -> None:
    """Note when each external node's first frame went by [s after t0]."""
    while (msg := bus.recv(0.0)) is not None:
        for name, own in ids.items():
            if name not in seen and msg.arbitration_id in own:
                seen[name] = round(msg.timestamp - epoch_t0, 4)


def describe_setup(setups: dict[str, dict], calibration: dict | None, precise: bool,
                   idle: CpuLatencyHold | None = None) -> str:
    """One line: what the OS granted the hosts (the first host's, and where others differ), the CPUs' idle
    states and the wait."""
    parts = []
    for name, d in setups.items():
        if name == "RECORDER" or name.startswith("PROBE"):
            continue
        rt = RtSetup(**{**d, "cpus": tuple(d["cpus"]) if d.get("cpus") else None,
                        "refused": tuple(d.get("refused") or ())})
        parts.append(f"{name} {rt.describe()}")
    refused = sorted({r for d in setups.values() for r in d.get("refused") or ()})
    wait = ("precise wait: sleep to "
            f"{calibration['margin_ns'] / 1e3:.0f} us before each deadline, then poll (this machine's sleeps "
            f"returned p50 {calibration['p50_us']:.0f} / p90 {calibration['p90_us']:.0f} / max "
            f"{calibration['max_us']:.0f} us late in {calibration['seconds']:g} s)" if precise and calibration
            else "sleep to each deadline (no precise wait)")
    if idle is not None and idle.refused:
        refused.append(idle.refused)
    held = f"; {idle.describe()}" if idle is not None and idle.held else ""
    return "; ".join(parts) + held + (f"; refused: {', '.join(refused)}" if refused else "") + f"; {wait}"


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


def run_realtime_folder(scenario: Scenario, out_dir: Path, cli_bus_config: dict,
                        progress: Callable[[int, dict], None] | None = None,
                        external: tuple[str, ...] = ()) -> RunRecord:
    """Run `scenario` in real time into the run folder `out_dir`: its trace (and each device's own bus's),
    truth.csv and run.json with the bus and the failure (`RunRecord.failure`: why the run ended early, a
    node died; None: it did not).  The bus: `cli_bus_config`, then python-can's configuration, then the
    scenario's [realtime] (resolve_bus_config); `external`: nodes another process or host runs.  Bad input
    is one line before any process starts, and leaves no folder."""

    if scenario.faults:                           # not silently dropped: say where they work
        kinds = ", ".join(sorted({f.kind for f in scenario.faults}))
        raise ScenarioError(f"scenario {scenario.name!r}: [[faults]] ({kinds}) are injected by the lockstep "
                            "run; run it with --lockstep (in real time, kill a node process instead)")
    dbc_path = dbc_path_of(scenario)
    db, codec = loaded_dbc(dbc_path)              # bad DBC: one line, before any process starts
    codec.compile()                               # once, inherited by the processes it forks
    external = external_nodes(scenario, external)
    if "PLANT" in external:
        raise ScenarioError("the PLANT cannot be external in `railhil run`: the run's KPIs come from its "
                            "ground truth; run the ECUs elsewhere instead (--external BCU ... here, railhil "
                            "node there)")

    check_devices(scenario)
    # a program joins the bench's bus at python-can's default group: a node run elsewhere, or a device on it
    on_bench = [n for n in scenario.devices if device_bus_config(scenario, n, {}) is None]
    cfg = resolve_bus_config(cli_bus_config, scenario, external=bool(external) or bool(on_bench))
    clash = sorted(set(external) & set(scenario.devices))
    if clash:
        raise ScenarioError(f"--external {clash[0]}: a device already takes its place "
                            f"([devices.{clash[0]}]); a node is either external or a device's")
    with check_only():                            # FMUs checked here, instantiated in their processes
        nodes = [build_node(name, scenario, db, codec, str(dbc_path)) for name in node_names(scenario)]
    node_releases(scenario, db, nodes)            # bad bindings or [nodes.*]: one line, before any process
    if scenario.messages:
        print("notice: [messages.*] extra delays apply to lockstep runs only; the real-time bus has its own",
              file=sys.stderr)
    trace = out_dir / trace_name(scenario)        # its folder is made once the bus opened
    device_traces = {n: out_dir / device_trace_name(scenario, n) for n in scenario.devices}   # own buses
    outcome, clock, failure = run_realtime(scenario, str(dbc_path), trace, cfg, progress=progress,
                                           external=external, device_traces=device_traces)
    run = RunRecord(scenario, outcome, out_dir, db, codec, outcome.truth.columns(), clock,
                    messages_sent(nodes), failure)
    return write_run_folder(run, extra={"bus": {k: str(v) for k, v in cfg.items()}, "failure": failure})
