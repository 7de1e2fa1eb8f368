"""`railhil export-fmu plant|BECUn SCENARIO -o FILE.fmu` — railhil's plant or a BECU as an FMI 2.0
co-simulation FMU (hil.fmi.export), checked by FMPy's validation before it is reported written."""

from __future__ import annotations

import argparse
from pathlib import Path

from hil.errors import FmuError
from hil.fmi.fmu import open_fmu, validation_problems

HELP = "write railhil's plant or a BECU of a scenario as an FMI 2.0 co-simulation FMU"
DESCRIPTION = ("Write railhil's plant (WHAT = plant) or a BECU (WHAT = BECU3) of SCENARIO, with the "
               "scenario's parameters, as an FMI 2.0 co-simulation FMU built by PythonFMU, for Simulink, "
               "Dymola, OpenModelica, CANoe, SIL Kit or FMPy. Its variables carry the bench's port names "
               "(the DBC's MESSAGE.Signal, truth.COLUMN_k), so `--set plant.fmu=FILE` or `--set "
               "nodes.BECU3.fmu=FILE` imports it back without a map. It needs a Python with railhil "
               "installed at run time (docs/fmu.md).")


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export-fmu", help=HELP, description=DESCRIPTION)
    p.add_argument("what", metavar="WHAT", help="plant, or a BECU of the scenario (BECU1, BECU2, ...)")
    p.add_argument("scenario", metavar="SCENARIO", help="scenario file or shipped name (railhil scenarios)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FILE.fmu", help="the FMU to write")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="change a scenario key first, as `railhil run --set` (repeatable)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # lazy: keeps `railhil export-fmu --help` at 35 ms, not 430 ms (the FMU builder: -X importtime)
    from hil.fmi.export import export_node, export_plant
    from hil.scenario.load import load_scenario

    scenario = load_scenario(args.scenario, sets=args.sets)
    what = args.what
    if what.lower() == "plant":
        out = export_plant(scenario, args.output)
    elif what.upper().startswith("BECU"):
        out = export_node(scenario, what.upper(), args.output)
    else:
        raise FmuError(f"export-fmu: WHAT = {what!r}: expected plant or a BECU (BECU1 .. "
                       f"BECU{scenario.train.cars})")
    problems = validation_problems(out)
    if problems:
        raise FmuError(f"{out}: FMPy's validation found {len(problems)} problem(s), the first: {problems[0]}")
    info = open_fmu(out)
    kinds: dict[str, int] = {}
    for v in info.variables.values():
        kinds[v.causality] = kinds.get(v.causality, 0) + 1
    counts = ", ".join(f"{n} {c}s" for c, n in sorted(kinds.items()))
    step = f"{info.step_size_s * 1000:g} ms" if info.step_size_s else "any step"
    print(f"wrote {out}: {info.model_name}, FMI {info.fmi_version} co-simulation, {counts}; step {step}; "
          "FMPy validation passed")
    print(f"import it back: railhil run {args.scenario} --set "
          + ("plant.fmu=" if what.lower() == "plant" else f"nodes.{what.upper()}.fmu=") + f"{out}")
    return 0
