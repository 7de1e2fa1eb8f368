"""`railhil node NAME SCENARIO` — run one node (or several, NAME,NAME) alone on a python-can bus.

The node is the one `railhil run` would simulate, with the same code (hil.runtime.host.Host): a second
process, a second host or a board on a CAN adapter can so take a node's place in a run started with
`railhil run SCENARIO --realtime --external NAME`.  By default it starts with the bus: its clock, E2E
counters and SecOC freshness begin at the first frame it hears from another node (the wire contract of
docs/external-ecu.md), so start it before the run.  It ends on Ctrl-C or SIGTERM, after --duration, or
when the bus has been silent for --until-idle seconds, and prints what it did.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path

import can.cli

from hil.cli.bus_args import bus_config_from_args
from hil.errors import RailhilError
from hil.runtime.clock import RunClock
from hil.runtime.host import Host, PlantEnd
from hil.runtime.probe import late_threshold_us
from hil.runtime.realtime import (
    bus_flags,
    check_node_names,
    describe_bus,
    enlarge_receive_buffer,
    held_can_logs,
    hosted_nodes,
    idle_hold,
    os_setup,
    pass_on,
    resolve_bus_config,
)
from hil.runtime.rtos import NODE_PRIORITY, sleep_lateness
from hil.runtime.run import dbc_path_of
from hil.scenario import load_scenario

WAIT_REPORT_S = 10.0          # while waiting for the bus, say so this often [s]


class NodeArgError(RailhilError, ValueError):
    """`railhil node` given names or options that cannot work."""


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "node",
        help="run one node (or several) of a scenario alone on a python-can bus: the stand-in for a device, "
             "or the ECUs on another host",
        description="Run one node of a scenario alone on a python-can bus (udp_multicast by default: "
                    "python-can's default group and port unless you name a channel), as railhil run would "
                    "simulate it: so that a second process, a second host or a board on a CAN adapter takes "
                    "its place in `railhil run SCENARIO --realtime --external NAME`. Several names "
                    "(BCU,BECU1,...) run in one process with one bus connection. Start it before the run: it "
                    "begins with the first frame it hears from another node (--start now: at once).",
    )
    p.add_argument("names", metavar="NAME",
                   help="the node (e.g. BECU3), or several separated by commas (e.g. DESK,BCU,BECU1,BECU2)")
    p.add_argument("scenario", type=Path, help="scenario TOML file or the name of a shipped scenario")
    p.add_argument("--start", choices=("bus", "now"), default="bus",
                   help="bus: at the first frame of another node (the default; its counters and freshness "
                        "then match a run's); now: at once")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C / SIGTERM)")
    p.add_argument("--until-idle", type=float, default=None, metavar="S",
                   help="stop once no frame of another node was heard for S seconds (the run ended)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="override one scenario value, as for railhil run")
    p.add_argument("--stats", type=Path, default=None, metavar="FILE",
                   help="write what each node did (cycles, lateness, frames, E2E / SecOC) as JSON")
    can.cli.add_bus_arguments(p, group_title="bus arguments (python-can's flags)")
    p.set_defaults(func=run)


def _names(text: str, scenario) -> list[str]:
    names = check_node_names(scenario, [n.strip() for n in text.split(",") if n.strip()], "node")
    if not names:
        raise NodeArgError("no node named: give NAME, e.g. BECU3 or BCU,BECU1")
    return names


def _wait_for_bus(bus, own_ids: set[int], stop: threading.Event) -> can.Message | None:
    """Block until a frame of another node (an id the hosted nodes do not send) comes by; None: stopped."""
    next_report = time.monotonic() + WAIT_REPORT_S
    while not stop.is_set():
        msg = bus.recv(0.2)
        if msg is not None and not msg.is_error_frame and msg.arbitration_id not in own_ids:
            return msg
        if time.monotonic() > next_report:
            print("node: still waiting for the bus (no frame of another node yet)", file=sys.stderr,
                  flush=True)
            next_report += WAIT_REPORT_S
    return None


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario, None, args.sets)
    names = _names(args.names, scenario)
    for value, flag in ((args.duration, "--duration"), (args.until_idle, "--until-idle")):
        if value is not None and not value > 0:
            raise NodeArgError(f"{flag} {value:g}: expected a number of seconds > 0")
    codec, nodes, releases = hosted_nodes(names, scenario, str(dbc_path_of(scenario)))
    cfg = resolve_bus_config(bus_config_from_args(args), scenario, external=True)
    try:
        with held_can_logs() as held:         # python-can's own line about it: not beside the error
            bus = can.Bus(**cfg)
        pass_on(held)
    except Exception as exc:      # bad input on this command line: exit 2, one line
        why = " ".join(str(exc).split())
        raise NodeArgError(f"cannot open the python-can bus {describe_bus(cfg)}: {why}") from None
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    idle = idle_hold(scenario)
    try:
        enlarge_receive_buffer(bus)
        rt = os_setup(scenario, NODE_PRIORITY)
        margin = sleep_lateness(scenario.realtime.calibration_s) if scenario.realtime.precise_wait else None
        own_ids = {fc.codec.frame_id for node in nodes for fc in node.tx}
        print(f"node {','.join(names)}: on {describe_bus(cfg)} ({bus_flags(cfg)}); {rt.describe()}"
              + (f"; {idle.describe()}" if idle.requested_us is not None else "")
              + (f"; precise wait margin {margin.margin_ns / 1e3:.0f} us" if margin else ""), flush=True)
        if args.start == "bus":
            print(f"node {','.join(names)}: waiting for the first frame of another node", flush=True)
            first = _wait_for_bus(bus, own_ids, stop)
            if first is None:
                return 0
        t0 = time.monotonic_ns()
        print(f"node {','.join(names)}: started", flush=True)
        end = None
        if "PLANT" in names:
            end = PlantEnd(round(scenario.end_after_standstill_s * 1e6), round(scenario.max_duration_s * 1e6))
        host = Host(nodes, releases, codec, bus, RunClock.starting(t0, scenario.realtime.speed),
                    margin_ns=margin.margin_ns if margin else 0, plant_wake=scenario.realtime.plant_wake,
                    end=end)
        if args.start == "bus":
            host.delivery.receive(first.arbitration_id, bytes(first.data), 0)
        watchdog = threading.Thread(target=_watch, args=(host, stop, args.duration, args.until_idle),
                                    daemon=True)
        watchdog.start()
        host.run(stop)
        stop.set()
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
        idle.release()
        bus.shutdown()
    report = {}
    for name, payload in host.payloads().items():
        stats = payload["stats"]
        threshold = late_threshold_us(payload["period_us"], scenario.realtime.deadline.miss_min_us,
                                      scenario.realtime.deadline.miss_period_pct / 100)
        misses = sum(1 for v in payload["lateness_us"] if v > threshold)
        events: dict[str, int] = {}
        for _, _, status in stats.get("e2e_events") or ():
            events[status] = events.get(status, 0) + 1
        report[name] = {k: stats.get(k) for k in ("cycles", "frames_sent", "frames_received", "bad_frames",
                                                  "step_errors", "e2e_discarded", "lateness_us")}
        report[name].update({"misses": misses, "miss_threshold_us": threshold, "reported": events})
        lat = stats["lateness_us"]
        print(f"node {name}: {stats['cycles']} cycles, lateness p50 {lat['p50']} / p99 {lat['p99']} / max "
              f"{lat['max']} us, {misses} late by more than {threshold} us; frames sent "
              f"{stats['frames_sent']}, received {stats['frames_received']}; receivers' checks: "
              + (", ".join(f"{k} {v}" for k, v in sorted(events.items())) or "nothing reported"))
    if args.stats is not None:
        args.stats.write_text(json.dumps(report, indent=2, default=str) + "\n")
        print(f"files: {args.stats}")
    if "PLANT" in names:
        print("note: railhil node keeps no ground truth of the plant; run the plant with railhil run for "
              "KPIs", file=sys.stderr)
    return 0


def _watch(host, stop: threading.Event, duration: float | None, idle: float | None) -> None:
    """Set `stop` after `duration` s, or once the host heard no frame for `idle` s."""
    start = time.monotonic()
    last_count, last_change = -1, start
    while not stop.wait(0.25):
        now = time.monotonic()
        if duration is not None and now - start >= duration:
            stop.set()
        if idle is not None:
            if host.delivery.received != last_count:
                last_count, last_change = host.delivery.received, now
            elif now - last_change >= idle:
                print(f"node: no frame for {idle:g} s: the bus is idle, stopping", file=sys.stderr,
                      flush=True)
                stop.set()

