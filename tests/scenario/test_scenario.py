"""Scenario files are validated at load: one line naming the key, the value and what is allowed."""

from pathlib import Path

import pytest

from hil.errors import ScenarioError
from hil.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]


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
    from hil.scenario.params import build_track
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


# ------------------------------------------------------------------------------ railhil run --set KEY=VALUE
RG = ROOT / "scenarios" / "rg_low_adhesion.toml"


@pytest.mark.parametrize("text, key, value", [
    ("wheel_slip.governor=false", "wheel_slip.governor", False),
    ("train.initial_speed_kmh=120", "train.initial_speed_kmh", 120),
    ("becu.control=decel", "becu.control", "decel"),             # not TOML: taken as a string
    ('becu.control="decel"', "becu.control", "decel"),
    ("bcu.step_decel_mps2=[0.0, 1, 2, 3, 4, 5, 6, 7]", "bcu.step_decel_mps2", [0.0, 1, 2, 3, 4, 5, 6, 7]),
    (" seed = 3 ", "seed", 3),
])
def test_set_values_are_toml(text, key, value):
    from hil.scenario import parse_set

    assert parse_set(text) == (key, value)


def test_set_overrides_nested_keys_and_validates_them():
    base = load_scenario(RG)
    sc = load_scenario(RG, sets=["wheel_slip.governor=false", "train.initial_speed_kmh=100",
                                 "nodes.BECU1.drift_ppm=50", "desk.0.at_s=1.5",
                                 "wheel_slip.paper_figure=fig9"])
    assert base.wheel_slip.governor and not sc.wheel_slip.governor
    assert sc.train.initial_speed_kmh == 100.0 and sc.nodes["BECU1"].drift_ppm == 50.0
    assert sc.desk[0].at_s == 1.5 and sc.desk[0].brake_step == base.desk[0].brake_step
    assert sc.wheel_slip.paper_figure == "fig9"
    exclude = {"governor", "paper_figure"}
    assert sc.wheel_slip.model_dump(exclude=exclude) == base.wheel_slip.model_dump(exclude=exclude)
    assert sc.becu == base.becu


def test_keys_of_release_0_1_still_load_with_a_notice(tmp_path):
    """A study's key that moved into its own section (railhil 0.1's `[becu] governor`, `[bcu] stopping`,
    `[report] paper_figure`, ...) is read at its new place for one release, with a notice naming both."""
    from hil.scenario import RailhilDeprecation

    old = tmp_path / "old.toml"
    old.write_text(RG.read_text().replace("[wheel_slip]", "[report]").replace("governor = true", "")
                   .replace('paper_figure = "fig8"', 'paper_figure = "seed001_fig8"')
                   .replace("margin = 0.005", "")
                   .replace("slip_max_mps = 0.1              # s̄ of eq. (8)", "")
                   .replace("[becu]", "[becu]\ngovernor = true\nslip_max_mps = 0.1\ngovernor_margin = 0.005"))
    with pytest.warns(RailhilDeprecation) as notices:
        sc = load_scenario(old)
    said = " ".join(str(w.message) for w in notices)
    for old_key, new_key in (("becu.governor", "wheel_slip.governor"),
                             ("becu.slip_max_mps", "wheel_slip.slip_max_mps"),
                             ("becu.governor_margin", "wheel_slip.margin"),
                             ("report.paper_figure", "wheel_slip.paper_figure"),
                             ("report.steady_state_window_s", "wheel_slip.steady_state_window_s")):
        assert f"'{old_key}' is now '{new_key}'" in said
    assert sc.wheel_slip == load_scenario(RG).wheel_slip
    with pytest.warns(RailhilDeprecation, match="--set bcu.decel_feedback is now --set decel_feedback"):
        fb = load_scenario(ROOT / "scenarios" / "decel_feedback.toml", sets=["bcu.decel_feedback=false"])
    assert fb.decel_feedback.closed_loop is False
    stop = tmp_path / "stop.toml"
    stop.write_text((ROOT / "scenarios" / "precise_stop.toml").read_text()
                    .replace("[precise_stop]", "[bcu]").replace("method =", "stopping =")
                    .replace("planned_decel_mps2", "stop_decel_mps2"))
    shipped = load_scenario(ROOT / "scenarios" / "precise_stop.toml")
    with pytest.warns(RailhilDeprecation) as notices:
        assert load_scenario(stop).precise_stop == shipped.precise_stop
    said = " ".join(str(w.message) for w in notices)
    assert "'bcu.stopping' is now 'precise_stop.method'" in said and "'bcu.stop_decel_mps2'" in said
    unfitted = tmp_path / "unfitted.toml"                   # 0.1's "none": the function is not fitted
    unfitted.write_text(stop.read_text().replace('stopping = "pi"', 'stopping = "none"')
                        .replace("stop_decel_mps2 = 0.6", ""))
    with pytest.warns(RailhilDeprecation):
        assert load_scenario(unfitted).precise_stop is None


@pytest.mark.parametrize("text, needles", [
    ("wheel_slip.govrnor=false", ["wheel_slip.govrnor", "not a scenario key",
                                  "did you mean 'wheel_slip.governor'"]),
    ("bcu.jerk_limit=5", ["bcu.jerk_limit", "did you mean 'bcu.jerk_limit_mps3'"]),
    ("wheel_slip.governor=maybe", ["wheel_slip.governor", "'maybe'", "valid boolean",
                                   "--set wheel_slip.governor"]),
    ("becu.control=pid", ["becu.control", "'pid'", "'pressure' or 'decel'"]),
    ("train.cars=12", ["train.cars", "12", "less than or equal to 8"]),
    ("train.cars.x=1", ["train.cars", "is a value"]),
    ("desk.5.at_s=1", ["desk.5", "index below 1"]),
    ("wheel_slip.governor", ["KEY=VALUE"]),
])
def test_bad_set_is_one_line_naming_the_key(text, needles):
    with pytest.raises(ScenarioError) as err:
        load_scenario(RG, sets=[text])
    msg = str(err.value)
    assert "\n" not in msg
    for needle in needles:
        assert needle in msg, msg


def test_cli_bad_set_exits_2_with_one_line(capsys, tmp_path):
    from hil.cli.main import main

    code = main(["run", str(RG), "--set", "wheel_slip.slip_max=0.2", "--out", str(tmp_path / "run"), "-q"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0
    assert err.startswith("error: ") and "did you mean 'wheel_slip.slip_max_mps'" in err
    assert not (tmp_path / "run").exists()                  # nothing ran
