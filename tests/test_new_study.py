"""A new study by the shape alone: docs/architecture.md's checklist "Adding a study", followed step by step.

The test copies railhil's source into a temporary folder, writes a minimal study there — a reference stage
in every BECU that clamps the deceleration demand — with one file per step of the checklist, adds the one
registry line, and runs it in lockstep as a user would (`python -m hil run ... --lockstep`).  Nothing else
of the copy changes: no core module, no other study.  The clamp must hold on the bus (every BECU's
cylinder set-point at most the pressure of the clamped demand), its KPIs and summary line must appear,
and `railhil reproduce demand-clamp` must exist.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from firmware_py.becu import BecuParams

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("firmware_py", "plant_sim", "hil", "dbc", "scenarios")
CLAMP_MPS2 = 0.3

# ---- the checklist's files, as a newcomer writes them --------------------------------------------------
STUDY_FILES = {
    # step 2: the controller lives in firmware_py/, a stage with its parameters, inputs and outputs
    "firmware_py/demand_clamp.py": '''
        """A BECU reference stage that clamps the deceleration demand (firmware_py.becu.ReferenceStage)."""

        from dataclasses import dataclass


        @dataclass(frozen=True)
        class ClampParams:
            max_decel_mps2: float = 1.0          # the largest deceleration reference the loop tracks [m/s²]


        class DemandClamp:
            INPUTS: tuple[str, ...] = ()
            OUTPUTS: tuple[str, ...] = ()

            def __init__(self, params: ClampParams) -> None:
                self.p = params

            def reference(self, now_us, rx, r_mps2, loop, out):
                return min(r_mps2, self.p.max_decel_mps2)
    ''',
    # step 3: the scenario section and the stage's parameters built from it
    "hil/studies/demand_clamp/scenario.py": '''
        """The scenario section [demand_clamp]: the largest deceleration each BECU tracks."""

        from typing import Annotated

        from pydantic import Field

        from firmware_py.demand_clamp import ClampParams
        from hil.scenario.base import Strict


        class DemandClampSpec(Strict):
            max_decel_mps2: Annotated[float, Field(gt=0, le=2, description="clamp [m/s²]")] = 1.0


        def clamp_params(scenario) -> ClampParams:
            return ClampParams(scenario.demand_clamp.max_decel_mps2)
    ''',
    # step 4: the bindings: no node of its own, a stage in each foundation BECU
    "hil/studies/demand_clamp/nodes.py": '''
        """The clamp as a reference stage of each foundation BECU."""

        from firmware_py.demand_clamp import DemandClamp
        from hil.studies.demand_clamp.scenario import clamp_params


        def node_names(scenario, names):
            return names


        def build_node(name, scenario, db, codec, dbc_name="DBC"):
            return None


        def becu_stages(scenario, car, run, reference, setpoint):
            if scenario.demand_clamp is not None:
                reference.append(DemandClamp(clamp_params(scenario)))
    ''',
    # step 5: its DBC part: no frame, no signal
    "hil/studies/demand_clamp/frames.py": '''
        """The clamp adds nothing to the DBC."""


        def messages():
            return []


        def signals():
            return []
    ''',
    # step 6: its KPIs from the run (here: the largest set-point BECU1 sent) and summary line
    "hil/studies/demand_clamp/kpis.py": '''
        """The clamp's KPIs; kpis.json key "demand_clamp"."""

        SIGNALS = {"p_set": ("BECU1_PRESS_CMD", "CylPressureSet")}


        def kpis(run):
            t, p_set = run.signals(SIGNALS)["p_set"]
            return {"max_pressure_set_Pa": float(p_set.max()) if p_set.size else None}


        def summary_lines(k):
            bar = k["max_pressure_set_Pa"] / 1e5
            return [f"demand clamp            BECU1 set-point at most {bar:.2f} bar"]


        KPI_INFO = {"max_pressure_set_Pa": ("largest set-point", "Pa", "BECU1_PRESS_CMD.CylPressureSet")}
    ''',
    # step 7: its figure (none for a run)
    "hil/studies/demand_clamp/plots.py": '''
        """The clamp draws no figure of its own."""


        def run_plots(run):
            return []
    ''',
    # step 8: its reproduction on the command line
    "hil/studies/demand_clamp/reproduce.py": '''
        """railhil reproduce demand-clamp: nothing to reproduce, a paper-less example."""


        def add_arguments(parser):
            pass


        def run(args):
            print("demand clamp: no paper to reproduce")
            return 0
    ''',
    # step 9: the descriptor
    "hil/studies/demand_clamp/__init__.py": '''
        """A clamp on each BECU's deceleration demand: the checklist's example study."""

        from hil.scenario.registry import Study
        from hil.studies.demand_clamp.scenario import DemandClampSpec

        STUDY = Study(name="demand_clamp", section="demand_clamp", spec=DemandClampSpec, package=__name__,
                      title="a clamp on each BECU's deceleration demand", paper="none: an example")
    ''',
}
# step 10: the registry line, the only line of an existing file that changes
REGISTRY_IMPORT = "from hil.studies import demand_clamp  # noqa: E402\n"
REGISTRY_LINE = "STUDIES = (*STUDIES, demand_clamp.STUDY)\n"


@pytest.fixture(scope="module")
def checkout(tmp_path_factory) -> Path:
    """A copy of railhil's source with the study written by the checklist and its registry line (the
    sources only: the copy runs pure Python, as a checkout that was never built)."""
    root = tmp_path_factory.mktemp("new-study")
    for package in PACKAGES:
        shutil.copytree(ROOT / package, root / package,
                        ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.pyd", "_build.json"))
    for name, text in STUDY_FILES.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text).lstrip())
    registry = root / "hil" / "studies" / "__init__.py"
    registry.write_text(registry.read_text() + "\n" + REGISTRY_IMPORT + REGISTRY_LINE)
    return root


def railhil(checkout: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", *args], cwd=checkout, capture_output=True, text=True,
                          timeout=600, env={"PYTHONPATH": str(checkout), "PATH": "/usr/bin:/bin",
                                            "MPLBACKEND": "Agg", "HOME": str(checkout)})


def test_only_the_registry_changes_among_the_existing_files(checkout):
    changed = [p.relative_to(checkout).as_posix() for package in PACKAGES
               for p in (checkout / package).rglob("*") if p.is_file() and "__pycache__" not in p.parts
               and (ROOT / p.relative_to(checkout)).exists()
               and (ROOT / p.relative_to(checkout)).read_bytes() != p.read_bytes()]
    assert changed == ["hil/studies/__init__.py"]


def test_the_new_study_clamps_the_demand_in_a_lockstep_run(checkout):
    scenario = checkout / "clamped.toml"
    scenario.write_text((checkout / "scenarios" / "default.toml").read_text()
                        + f"\n[demand_clamp]\nmax_decel_mps2 = {CLAMP_MPS2}\n")
    done = railhil(checkout, "run", str(scenario), "--lockstep", "--out", str(checkout / "run"), "-q")
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    kpis = json.loads((checkout / "run" / "kpis.json").read_text())
    clamped = BecuParams()
    ceiling = (clamped.car_mass_kg * CLAMP_MPS2 * clamped.wheel_radius_m / clamped.brake_gain_Nm_per_Pa
               + clamped.brake_preload_Pa)                    # Becu.pressure_for_decel of the clamp
    assert kpis["demand_clamp"]["max_pressure_set_Pa"] <= ceiling + 100.0     # the DBC's resolution
    assert kpis["demand_clamp"]["max_pressure_set_Pa"] > 0.9 * ceiling        # it did brake, clamped
    assert "demand clamp            BECU1 set-point at most" in done.stdout
    assert kpis["stopping_distance_m"] > 357.563                              # the golden default's: longer


def test_the_new_study_reproduces_on_the_command_line(checkout):
    done = railhil(checkout, "reproduce", "demand-clamp")
    assert done.returncode == 0 and "no paper to reproduce" in done.stdout, done.stderr[-2000:]
