"""Scenario files are validated at load: one line naming the key, the value and what is allowed."""

from pathlib import Path

import pytest

from hil.errors import ScenarioError
from hil.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]


def test_default_scenario_loads():
    s = load_scenario(ROOT / "scenarios" / "default.toml")
    assert s.train.cars == 6 and s.train.initial_speed_kmh == 90.0
    assert [seg.condition for seg in s.track.rail] == ["dry", "wet", "dry"]
    assert s.desk[0].brake_step == 7


@pytest.mark.parametrize("text, needles", [
    ("[train]\ncars = 12\n", ["train.cars", "12", "less than or equal to 8"]),
    ("[train]\ncarz = 3\n", ["train.carz", "not a scenario key"]),
    ("seed = 'x'\n", ["seed", "'x'", "integer"]),
    ("[track]\nrail = [{from_m = 0, condition = 'icy'}]\n", ["track.rail.0.condition", "icy", "dry"]),
    ("[track]\nrail = [{from_m = 10, condition = 'dry'}, {from_m = 5, condition = 'wet'}]\n",
     ["track.rail", "increase"]),
    ("[[desk]]\nat_s = 1\nbrake_step = 9\n", ["desk.0.brake_step", "9"]),
    ("[train\n", ["not valid TOML"]),
])
def test_bad_scenarios_give_one_line_naming_key_and_value(tmp_path, text, needles):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg
    for needle in needles:
        assert needle in msg, msg


def test_rail_condition_as_a_table_reaches_the_plant(tmp_path):
    from hil.plant_node import build_track
    from plant_sim.params import RAIL_CONDITIONS

    dry, wet = RAIL_CONDITIONS["dry"], RAIL_CONDITIONS["wet"]
    path = tmp_path / "table.toml"
    path.write_text(f"[track]\nrail_table = [{{ x_m = 0.0, theta = {list(dry)} }}, "
                    f"{{ x_m = 100.0, theta = {list(wet)} }}]\n")
    track = build_track(load_scenario(path))
    theta = track.theta_at([-10.0, 50.0, 200.0])
    assert theta[0] == pytest.approx(dry) and theta[2] == pytest.approx(wet)
    assert theta[1] == pytest.approx([(a + b) / 2 for a, b in zip(dry, wet, strict=True)])


def test_missing_file(tmp_path):
    with pytest.raises(ScenarioError, match="no such scenario file"):
        load_scenario(tmp_path / "nope.toml")
