"""Jitter injection: node release jitter, drift and start delay, per-message extra delay, CANoe node
attributes from the DBC; all seeded."""

import shutil

import can
import cantools
import numpy as np
import pytest
from conftest import DEFAULT

from hil.can.dbc import DEFAULT_DBC
from hil.errors import ScenarioError
from hil.report.run import run_scenario_lockstep
from hil.runtime.release import NodeRelease, dbc_node_timing
from hil.scenario import load_scenario, parse_scenario

BECU1_CMD = 0x031
BECU2_CMD = 0x032

CANOE_ATTRIBUTES = """
BA_DEF_ BU_  "CANoeJitterMin" INT 0 100;
BA_DEF_ BU_  "CANoeJitterMax" INT 0 100;
BA_DEF_ BU_  "CANoeDrift" INT 0 100;
BA_DEF_ BU_  "CANoeStartDelay" INT 0 100000;
BA_DEF_DEF_  "CANoeJitterMin" 0;
BA_DEF_DEF_  "CANoeJitterMax" 0;
BA_DEF_DEF_  "CANoeDrift" 0;
BA_DEF_DEF_  "CANoeStartDelay" 0;
BA_ "CANoeJitterMax" BU_ BECU2 5;
BA_ "CANoeDrift" BU_ BECU2 1;
BA_ "CANoeStartDelay" BU_ BECU2 3;
"""


def short(seconds=2.0, base=None, **update):
    """The default scenario (or `base`), `seconds` long, with `update` validated as a scenario file is."""
    scenario = base if base is not None else load_scenario(DEFAULT)
    return parse_scenario({**scenario.model_dump(), "max_duration_s": seconds, **update})


def times(out_dir, frame_id):
    with can.LogReader(str(out_dir / "trace.blf")) as reader:
        return np.array([m.timestamp for m in reader if m.arbitration_id == frame_id])


def run(scenario, path):
    run_scenario_lockstep(scenario, path)
    return path


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return run(short(), tmp_path_factory.mktemp("base"))


def test_release_jitter_spreads_the_periods_but_loses_no_frame(base, tmp_path):
    jittered = short(nodes={"BECU1": {"jitter_min_us": -400, "jitter_max_us": 400}})
    out = run(jittered, tmp_path / "j")
    p_base, p_jit = np.diff(times(base, BECU1_CMD)), np.diff(times(out, BECU1_CMD))
    assert len(times(out, BECU1_CMD)) == len(times(base, BECU1_CMD))
    assert np.std(p_base) < 20e-6                            # only arbitration moves it, a few µs
    assert 0.2e-3 < np.std(p_jit) < 0.5e-3                   # U(-0.4, 0.4) ms on both ends: σ ≈ 0.33 ms
    assert np.all(np.abs(p_jit - 0.010) < 0.8e-3 + 0.3e-3)  # range 0.8 ms, plus a frame of queuing
    assert abs(np.mean(p_jit) - 0.010) < 50e-6               # jitter does not accumulate
    p2 = np.diff(times(out, BECU2_CMD))
    assert np.std(p2) < 0.1e-3                               # the other cars keep their clocks


def test_jitter_is_seeded(tmp_path):
    jittered = short(1.0, nodes={"BECU1": {"jitter_min_us": -400, "jitter_max_us": 400}})
    a = run(jittered, tmp_path / "a") / "trace.blf"
    b = run(jittered, tmp_path / "b") / "trace.blf"
    c = run(jittered.model_copy(update={"seed": 99}), tmp_path / "c") / "trace.blf"
    assert a.read_bytes() == b.read_bytes() != c.read_bytes()


def test_drift_and_start_delay(base, tmp_path):
    drifted = short(nodes={"BECU1": {"drift_ppm": 10_000, "start_delay_us": 5_000}})
    t = times(run(drifted, tmp_path / "d"), BECU1_CMD)
    assert abs(np.mean(np.diff(t)) - 0.0101) < 5e-6          # 1 % slower clock
    assert t[0] - times(base, BECU1_CMD)[0] == pytest.approx(0.005, abs=0.5e-3)


def test_message_delay_fixed_and_random(base, tmp_path):
    fixed = short(messages={"BECU1_PRESS_CMD": {"delay_min_us": 2000, "delay_max_us": 2000}})
    shift = times(run(fixed, tmp_path / "f"), BECU1_CMD) - times(base, BECU1_CMD)
    assert np.all(np.abs(shift - 0.002) < 0.3e-3)            # 2 ms later, give or take arbitration
    spread = short(messages={"BECU1_PRESS_CMD": {"delay_min_us": 0, "delay_max_us": 3000}})
    shift = times(run(spread, tmp_path / "s"), BECU1_CMD) - times(base, BECU1_CMD)
    assert shift.min() > -0.3e-3 and shift.max() < 3.3e-3 and np.std(shift) > 0.5e-3


def test_canoe_node_attributes_from_the_dbc(base, tmp_path):
    dbc = tmp_path / "canoe.dbc"
    dbc.write_text(DEFAULT_DBC.read_text() + CANOE_ATTRIBUTES)
    db = cantools.database.load_file(str(dbc))
    t = dbc_node_timing(db, "BECU2", 10_000)
    assert (t.jitter_min_us, t.jitter_max_us, t.drift_ppm, t.start_delay_us) == (0, 500, 10_000.0, 3_000)
    scenario_file = tmp_path / "s.toml"
    shutil.copy(DEFAULT, scenario_file)
    with scenario_file.open("a") as f:
        f.write('\ndbc = "canoe.dbc"\n')
    text = scenario_file.read_text().replace('\ndbc = "canoe.dbc"\n', "")
    scenario_file.write_text('dbc = "canoe.dbc"\n' + text)
    scenario = short(2.0, base=load_scenario(scenario_file))
    t2 = times(run(scenario, tmp_path / "r"), BECU2_CMD)
    p = np.diff(t2)
    assert t2[0] > 3e-3 + 3.5e-3                              # start delay + its phase offset
    assert abs(np.mean(p) - 0.0101) < 0.1e-3                  # 1 % drift
    assert np.std(p) > 0.05e-3                                # 0..5 % of 10 ms jitter
    # the scenario's own value wins over the attribute
    quiet = short(2.0, base=scenario, nodes={"BECU2": {"jitter_min_us": 0, "jitter_max_us": 0,
                                                       "drift_ppm": 0, "start_delay_us": 0}})
    # ... same releases as the default DBC without the attributes: the same frame times
    assert np.array_equal(times(run(quiet, tmp_path / "q"), BECU2_CMD), times(base, BECU2_CMD))


def test_release_times_by_formula():
    r = NodeRelease("BECU1", 10_000, 3_000, start_delay_us=1_000, drift_ppm=100.0)
    got = [r.next() for _ in range(3)]
    assert got == [(4_000_000, 3_000, 4_000_000), (14_001_000, 13_000, 14_001_000),
                   (24_002_000, 23_000, 24_002_000)]


@pytest.mark.parametrize("update, needle", [
    ({"nodes": {"BECU9": {"jitter_max_us": 10}}}, "nodes.BECU9"),
    ({"nodes": {"PLANT": {"jitter_max_us": 10}}}, "nodes.PLANT"),
    ({"nodes": {"BECU1": {"jitter_min_us": -6000, "jitter_max_us": 6000}}}, "shorter than the node's period"),
    ({"messages": {"BECU1_PRES_CMD": {"delay_max_us": 10}}}, "closest: BECU1_PRESS_CMD"),
])
def test_bad_timing_keys_are_one_line_errors(tmp_path, update, needle):
    with pytest.raises(ScenarioError, match=needle.replace(".", r"\.")):
        run_scenario_lockstep(short(0.1, **update), tmp_path / "x")


def test_jitter_bounds_out_of_order_is_a_scenario_error():
    with pytest.raises(ScenarioError, match="nodes.BECU1.*jitter_max_us 5 is below jitter_min_us 10"):
        short(0.1, nodes={"BECU1": {"jitter_min_us": 10, "jitter_max_us": 5}})
