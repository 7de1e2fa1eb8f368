"""Scenario -> parameters in one place (hil/scenario/params.py): each parameter set built once per run,
speeds converted once, and no scenario key that becomes a parameter read anywhere else in hil."""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

import pytest

from hil.scenario import load_scenario, params

ROOT = Path(__file__).resolve().parents[2]
PARAMS = ROOT / "hil" / "scenario" / "params.py"
#: the modules that may read the keys below: the one place, and the scenario's own model and loader
SCENARIO_PLACE = {ROOT / "hil" / "scenario" / name for name in ("params.py", "model.py", "load.py")}
#: the scenario keys that become parameters (section -> keys; "*": every key of the section)
PARAMETER_KEYS = {
    "train": {"initial_speed_kmh", "start_position_m", "masses", "masses_kg", "mass_kg", "wheel_inertia_kgm2",
              "running_resistance"},
    "plant": {"pressure_model", "tp_s", "brake_gain_Nm_per_Pa", "brake_preload_Pa", "hysteresis_Pa",
              "adhesion", "mu_peak", "slip_peak_mps", "slide_ratio", "pad_friction", "pad_speed_amplitude",
              "pad_cold_amplitude", "disc_temp_rise_K"},
    "becu": {"*"},
    "bcu": {"*"},
    "sensors": {"*"},
    "track": {"rail", "rail_table", "gradient", "curves", "balises"},
}
#: what names a scenario object in hil's code
SCENARIO_NAMES = {"scenario", "sc"}


@pytest.mark.parametrize("name", ["default", "rg_low_adhesion", "decel_feedback", "precise_stop",
                                  "acd_anticollision", "preview_slip_full"])
def test_each_parameter_set_is_built_once_per_run(name, tmp_path, monkeypatch):
    """A lockstep run with its report builds the plant's, the track's, the BCU's parameters once and each
    BECU's once, however many nodes, stages, KPIs and figures ask for them."""
    from hil.report.run import run_scenario_lockstep

    calls: dict[str, int] = {}
    for builder in ("plant_params", "build_track", "bcu_params", "becu_params"):
        original = getattr(params, builder)

        def counted(*args, _original=original, _name=builder, **kw):
            calls[_name] = calls.get(_name, 0) + 1
            return _original(*args, **kw)

        monkeypatch.setattr(params, builder, counted)
    scenario = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    run_scenario_lockstep(scenario, tmp_path / "run")
    cars = scenario.train.cars
    assert calls == {"plant_params": 1, "build_track": 1, "bcu_params": 1, "becu_params": cars}


def test_the_run_parameters_are_built_once_for_a_scenario_and_anew_for_another():
    scenario = load_scenario(ROOT / "scenarios" / "default.toml")
    run = params.run_params(scenario)
    assert params.run_params(scenario) is run
    train = scenario.train.model_copy(update={"initial_speed_kmh": 120.0})
    faster = scenario.model_copy(update={"train": train})
    assert params.run_params(faster).initial_speed_mps == pytest.approx(120.0 / 3.6)
    assert run.initial_speed_mps == pytest.approx(scenario.train.initial_speed_kmh / 3.6)


def _code_numbers(path: Path) -> list[tuple[int, str]]:
    """The numbers written in a module's code (not in its strings or comments)."""
    tokens = tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
    return [(t.start[0], t.string) for t in tokens if t.type == tokenize.NUMBER]


def test_km_per_h_is_converted_in_one_place():
    """hil converts km/h and m/s with hil.scenario.params.mps/kmh only: 3.6 is written nowhere else."""
    found = [f"{p.relative_to(ROOT)}:{line}" for p in sorted((ROOT / "hil").rglob("*.py")) if p != PARAMS
             for line, number in _code_numbers(p) if ast.literal_eval(number) == 3.6]
    assert not found, f"km/h <-> m/s outside hil/scenario/params.py (use params.mps / params.kmh): {found}"


def _chain(node: ast.AST) -> list[str] | None:
    """`scenario.train.initial_speed_kmh` -> ["scenario", "train", "initial_speed_kmh"] (None: no name root;
    `self.scenario...` counts as rooted at "scenario")."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
    else:
        return None
    parts.reverse()
    if parts[0] == "self" and len(parts) > 1:
        parts = parts[1:]
    return parts


def _reads_outside(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    allowed = set()                                   # a study's `check`: cross-checks of the scenario
    if path.name == "scenario.py" and "studies" in path.parts:
        allowed = {id(n) for f in ast.walk(tree) if isinstance(f, ast.FunctionDef) and f.name == "check"
                   for n in ast.walk(f)}
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute) or id(node) in allowed:
            continue
        chain = _chain(node)
        if not chain or len(chain) != 3 or chain[0] not in SCENARIO_NAMES:
            continue
        _, section, key = chain
        keys = PARAMETER_KEYS.get(section, set())
        if "*" in keys or key in keys:
            found.append(f"{path.relative_to(ROOT)}:{node.lineno} {'.'.join(chain)}")
    return found


def test_no_scenario_key_that_becomes_a_parameter_is_read_outside_the_one_place():
    """The keys that become parameters are read by hil/scenario/params.py (and the scenario's model and
    loader, which validate them; and a study's `check`); everything else takes run_params(scenario)."""
    found = [hit for p in sorted((ROOT / "hil").rglob("*.py")) if p not in SCENARIO_PLACE
             for hit in _reads_outside(p)]
    assert not found, ("scenario keys read outside hil/scenario/params.py (take them from "
                       f"params.run_params(scenario)): {found}")


def test_the_key_check_finds_a_key_read_outside(tmp_path):
    """The check above is not vacuous: a module reading a parameter key is caught."""
    module = tmp_path / "hil" / "elsewhere.py"
    module.parent.mkdir()
    module.write_text("def v0(scenario):\n    return scenario.train.initial_speed_kmh / 3.6\n")
    global ROOT
    saved, ROOT = ROOT, tmp_path
    try:
        assert _reads_outside(module) == ["hil/elsewhere.py:2 scenario.train.initial_speed_kmh"]
    finally:
        ROOT = saved
