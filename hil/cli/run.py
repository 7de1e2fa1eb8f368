"""`railhil run SCENARIO` — run a brake scenario in lockstep or as a real-time HIL; leave a run folder.

Exits 1 when a verdict that gates the exit code failed (hil.report.gate: real time held, each external
node PASS, each study's checks), after the summary and the run folder; `--exit-zero` exits 0 all the
same.  An interrupted run exits 130; errors exit with their RailhilError's code (hil.cli.main)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import can.cli

from hil.cli.bus_args import bus_config_from_args
from hil.devices.description import read_device_file
from hil.errors import BusError, DeviceError, ScenarioError
from hil.fmi.fmu import open_fmu, scenario_fmus
from hil.progress import progress_bar
from hil.report.gate import gates
from hil.report.run import run_scenario_lockstep, run_scenario_realtime
from hil.runtime.assembly import check_devices
from hil.scenario import load_scenario
from hil.scenario.model import DeviceRef
from hil.scenario.params import kmh


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="run a scenario and write its run folder",
        description="Run a brake scenario: lockstep (one process, simulated time, deterministic) or real "
                    "time (the nodes in OS processes on a python-can bus, udp_multicast by default; a node "
                    "may be external: a device under test on the bus). "
                    "Writes the trace (trace.blf; [trace] format: mf4, asc, log), truth.csv, kpis.json, "
                    "plot.png, run.json and report.html (the self-contained HTML report) to the run "
                    "folder and prints a summary.",
    )
    p.add_argument("scenario", type=Path,
                   help="scenario TOML file (e.g. scenarios/default.toml) or the name of a shipped scenario "
                        "(e.g. default; `railhil scenarios` lists them)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--lockstep", dest="mode", action="store_const", const="lockstep",
                      help="simulated time in one process (default)")
    mode.add_argument("--realtime", dest="mode", action="store_const", const="realtime",
                      help="the nodes in OS processes on a real python-can bus, wall-clock time")
    p.add_argument("--fallback-lockstep", action="store_true",
                   help="with --realtime: if the bus cannot be opened here, say so and run lockstep instead")
    p.add_argument("--hosting", choices=("grouped", "per-node"), default=None,
                   help="with --realtime: grouped = every simulated ECU in one process with one bus "
                        "connection, each frame received once, the plant in its own (the "
                        "default, [realtime] hosting; [realtime] plant_process = \"shared\" puts it there "
                        "too); per-node = one OS process per node (isolation tests, kill -9 of one ECU)")
    p.add_argument("--external", action="append", default=[], metavar="NODE",
                   help="with --realtime: NODE (e.g. BECU3) is not simulated; its frames must come from the "
                        "bus: a device under test, or `railhil node NODE SCENARIO` on this or another host, "
                        "started before the run (repeatable; also [nodes.NODE] external = true). The run "
                        "judges its frames like any node's")
    p.add_argument("--device", action="append", default=[], metavar="[NODE=]FILE",
                   help="a device on its own CAN matrix takes NODE's place (e.g. "
                        "BECU3=devices/acme_becu.toml; NODE defaults to the file's `replaces`): its device "
                        "file names its DBC, its bus and the map onto the bench (docs/devices.md). Lockstep "
                        "runs the device's model behind the gateway; --realtime bridges the bench's bus and "
                        "the device's. Repeatable; also [devices.NODE] file = ... in the scenario")
    p.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="override one scenario value (repeatable): a dotted key as in the TOML file and a "
                        "TOML value, e.g. --set wheel_slip.governor=false --set train.initial_speed_kmh=120; "
                        "text that is not TOML is taken as a string (--set becu.control=decel). "
                        "Checked like the file: an unknown key or bad value is an error")
    p.add_argument("--out", type=Path, default=None,
                   help="run folder (default runs/<scenario>-<mode>-<YYYYmmdd-HHMMSS>)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress line")
    p.add_argument("--exit-zero", action="store_true",
                   help="exploratory runs: exit 0 even when a verdict failed (the summary still says FAIL); "
                        "by default a failed verdict (real time not held, an external node not PASS, a "
                        "study's check) exits 1")
    can.cli.add_bus_arguments(p, group_title="bus arguments (real-time mode; python-can's flags)")
    p.set_defaults(func=run, mode="lockstep")


class Progress:
    """A progress bar over simulated seconds with the train's speed and position; silent when not a tty."""

    def __init__(self, enabled: bool, label: str, total_s: float) -> None:
        fmt = "{desc}: {n:.1f}/{total:.0f} s simulated |{bar}| {postfix} [{elapsed}]"
        self.bar = progress_bar(round(total_s, 1), enabled=enabled, desc=label, unit="s", leave=False,
                                bar_format=fmt)

    def __call__(self, now_us: int, truth: dict) -> None:
        if not self.bar.disable:
            self.bar.n = round(now_us / 1e6, 1)
            self.bar.set_postfix_str(f"v={kmh(float(truth['v_mps'].max())):.1f} km/h "
                                     f"x={float(truth['x_m'][0]):.1f} m")

    def close(self) -> None:
        self.bar.close()


def with_devices(scenario, given: list[str]):
    """The scenario with the devices of `--device [NODE=]FILE` in their nodes' places (a path from the
    current directory; NODE: the file's `replaces`); a DeviceError naming the option for a file that
    does not read, names another node, or a node given a device twice."""

    devices = dict(scenario.devices)
    from_cli: set[str] = set()
    for item in given:
        node, sep, file = item.rpartition("=")
        path = Path(file).resolve()
        spec = read_device_file(path)
        node = node.strip() if sep else spec.replaces
        if spec.replaces != node:
            raise DeviceError(f"--device {item}: the device file replaces {spec.replaces}, not {node} (its "
                              "key 'replaces')")
        if node in devices:
            where = ("--device gives it twice" if node in from_cli else
                     f"the scenario's [devices.{node}] already puts {devices[node].file} there")
            raise DeviceError(f"--device {item}: two devices for node {node}: {where}; one device per node")
        devices[node] = DeviceRef(file=str(path))
        from_cli.add(node)
    scenario = scenario.model_copy(update={"devices": devices})
    check_devices(scenario)
    return scenario


def fmu_lines(scenario) -> list[str]:
    """The summary's line per FMU the run stepped in a node's place (run.json `fmus` has its SHA-256)."""

    lines = []
    for node, path in scenario_fmus(scenario).items():
        info = open_fmu(path)
        tool = f", by {info.generation_tool}" if info.generation_tool else ""
        lines.append(f"{'FMU ' + node:<23} {info.model_name} ({Path(path).name}, FMI {info.fmi_version} "
                     f"co-simulation{tool})")
    return lines


def run(args: argparse.Namespace) -> int:
    overrides = {"seed": args.seed} if args.seed is not None else None
    sets = list(args.sets) + ([f"realtime.hosting={args.hosting}"] if args.hosting else [])
    scenario = with_devices(load_scenario(args.scenario, overrides, sets), args.device)
    mode = args.mode
    if args.external and mode != "realtime":
        raise ScenarioError(f"--external {args.external[0]}: an external node takes part in a real-time run "
                            "only; add --realtime")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out = args.out or Path("runs") / f"{scenario.name}-{mode}-{stamp}"
    if mode == "realtime":
        try:
            progress = Progress(not args.quiet, "realtime", scenario.max_duration_s)
            try:
                report = run_scenario_realtime(scenario, out, bus_config_from_args(args), progress=progress,
                                               external=tuple(args.external))
            finally:
                progress.close()
        except BusError as exc:
            if not args.fallback_lockstep:
                raise
            print(f"notice: {exc}", file=sys.stderr)
            print("notice: falling back to lockstep (simulated time, one process)", file=sys.stderr)
            mode = "lockstep"
            out = args.out or Path("runs") / f"{scenario.name}-{mode}-{stamp}"
    if mode == "lockstep":
        marked = sorted(n for n, spec in scenario.nodes.items() if spec.external)
        if marked:                               # not silently dropped: say where it applies
            print(f"notice: [nodes.{marked[0]}] external applies to real-time runs only; in lockstep "
                  f"{', '.join(marked)} {'is' if len(marked) == 1 else 'are'} simulated", file=sys.stderr)

        progress = Progress(not args.quiet, "lockstep", scenario.max_duration_s)
        try:
            report = run_scenario_lockstep(scenario, out, progress=progress)
        finally:
            progress.close()
    summary = report.summary()                   # its last line: the verdict (hil.report.gate)
    for line in summary[:1] + fmu_lines(scenario) + summary[1:]:
        print(line)
    if report.outcome.reason == "interrupted":
        return 130
    failed = [g for g in gates(report.kpis) if not g.passed]
    return 1 if failed and not args.exit_zero else 0
