"""railhil's pytest plugin (hil.pytest_plugin): the temporal assertions on table data, the hil_run fixture
on real lockstep (and real-time) runs, a deliberately failing assertion through pytester naming its first
violating time (and in the JUnit XML), and the examples/ file passing."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
from conftest import DEFAULT, ROOT

from hil.pytest_plugin import Condition, Signal, TemporalAssertionError, eventually, never, within

pytest_plugins = ["pytester"]


def sig(values, dt=0.1, name="x"):
    return Signal(name, np.arange(len(values)) * dt, values)


# ---------------------------------------------------------------------------------------------- within
@pytest.mark.parametrize("values, low, high, after, first", [
    ([0, 1, 2, 3, 2, 1], 0, 2, None, "0.3000"),        # the first sample above high
    ([5, 1, 2, 1, 9, 1], 0, 2, 0.1, "0.4000"),         # before `after`: not judged
    ([1, 1, -1, 1], 0, 2, None, "0.2000"),             # below low
    ([1, 1, float("nan"), 1], 0, 2, None, "0.2000"),   # NaN is outside any range
])
def test_within_names_the_first_sample_outside(values, low, high, after, first):
    with pytest.raises(TemporalAssertionError, match=rf"at t = {first} s \(first violation"):
        within(sig(values), low, high, after=after)


def test_within_holds_and_an_empty_window_fails():
    within(sig([0, 1, 2, 1, 0]), 0, 2)
    within(sig([9, 1, 2, 1, 9]), 0, 2, after=0.1, before=0.3)
    with pytest.raises(TemporalAssertionError, match="no sample after 5 s"):
        within(sig([0, 1]), 0, 2, after=5.0)


# ------------------------------------------------------------------------------------------------ never
def test_never_with_duration_reports_start_plus_duration():
    s = sig([0, 3, 3, 0, 3, 3, 3, 3, 0])              # stretches > 2: 0.1-0.3 (0.2 s), 0.4-0.8 (0.4 s)
    never(s > 2, for_longer_than=0.45)
    never(s > 3)
    with pytest.raises(TemporalAssertionError, match=r"violation at t = 0\.6500 s .*from t = 0\.4000 s"):
        never(s > 2, for_longer_than=0.25)             # the first stretch is short enough, the second not
    with pytest.raises(TemporalAssertionError, match=r"holds at t = 0\.1000 s"):
        never(s > 2)
    never(s > 2, after=0.35, for_longer_than=0.45)     # the second stretch alone: 0.4 s


def test_never_counts_a_stretch_from_after_and_up_to_before():
    s = sig([3, 3, 3, 3, 3, 3, 0])                     # holds 0-0.6 s
    with pytest.raises(TemporalAssertionError, match=r"first violation at t = 0\.3500 s"):
        never(s > 2, after=0.25, for_longer_than=0.1)  # counted from 0.25 s, not from the first sample
    never(s > 2, before=0.05, for_longer_than=0.1)     # cut at 0.05 s: held 0.05 s only


# ------------------------------------------------------------------------------------------- eventually
def test_eventually_returns_when_it_began_and_fails_at_the_deadline():
    s = sig([0, 0, 1, 1, 0, 1, 1, 1, 1])
    assert eventually(s > 0.5) == pytest.approx(0.2)
    assert eventually(s > 0.5, for_at_least=0.25) == pytest.approx(0.5)
    with pytest.raises(TemporalAssertionError, match=r"violated at t = 0\.4000 s \(the deadline\).*longest "
                                                     r"from t = 0\.2000 s for 0\.2000 s"):
        eventually(s > 0.5, before=0.4, for_at_least=0.25)
    with pytest.raises(TemporalAssertionError, match=r"violated at t = 0\.8000 s \(the end of the data\)"):
        eventually(s > 2)


def test_conditions_combine_on_the_union_of_sample_times():
    a = Signal("a", [0.0, 1.0, 2.0], [0, 1, 1])
    b = Signal("b", [0.5, 1.5], [1, 0])
    both = (a > 0.5) & (b > 0.5)
    assert isinstance(both, Condition)
    assert list(both.t) == [0.5, 1.0, 1.5, 2.0] and list(both.values) == [False, True, False, False]
    assert eventually(both) == 1.0
    diff = abs(a - b)
    assert list(diff.values) == [1, 0, 1, 1]
    with pytest.raises(TemporalAssertionError, match=r"holds at t = 0\.5000 s"):
        never((a < 0.5) | ~(b < 0.5))


# ------------------------------------------------------------------------------------- the fixture itself
def test_hil_run_decodes_signals_and_truth(hil_run):
    run = hil_run(DEFAULT, {"max_duration_s": 12.0})
    assert run is hil_run(str(DEFAULT), {"max_duration_s": 12.0})    # lockstep runs are shared in a session
    assert run.kpis["simulated_s"] == pytest.approx(12.0, abs=0.01) and not run.kpis["stopped"]
    demand = run.signal("BCU_DEMAND.TargetDecel")
    import json

    bus = json.loads((run.out_dir / "run.json").read_text())["bus_timing"]
    assert len(demand) == bus["messages"]["BCU_DEMAND"]["frames"]       # every frame in the trace, decoded
    assert demand.t[0] >= 0 and demand.t[-1] <= run.kpis["simulated_s"]
    v = run.truth("v_mps_1")
    assert v.at(0.0) == pytest.approx(run.scenario.train.initial_speed_kmh / 3.6, rel=1e-6)
    assert v.at(11.0) < v.at(1.0)
    with pytest.raises(KeyError, match="v_mps_1"):
        run.truth("v_mps1")
    from hil.errors import BindingError
    with pytest.raises(BindingError, match="has no signal 'TargetDecl'"):
        run.signal("BCU_DEMAND.TargetDecl")


def test_hil_run_rejects_a_bad_override_naming_the_key(hil_run):
    from hil.errors import ScenarioError

    with pytest.raises(ScenarioError, match="train.inital_speed_kmh"):
        hil_run(DEFAULT, {"train.inital_speed_kmh": 60})


FAILING = """
from hil.pytest_plugin import never

def test_slides_are_short(hil_run):
    run = hil_run({scenario!r}, {{"max_duration_s": 12.0}})
    never(run.truth("slip_speed_mps_4") > 0.5, for_longer_than=0.05)
"""


def test_a_failing_temporal_assertion_names_its_first_violating_time(pytester, tmp_path):
    pytester.makepyfile(test_failing=FAILING.format(scenario=str(DEFAULT)))
    out = tmp_path / "runs"
    junit = tmp_path / "junit.xml"
    result = pytester.runpytest_inprocess(f"--hil-out={out}", f"--junitxml={junit}", "-p", "no:cacheprovider")
    result.assert_outcomes(failed=1)
    # the expected time, computed here from the run's own truth: first stretch of slip > 0.5 m/s on car 4
    # lasting more than 0.05 s, plus 0.05 s
    (run_dir,) = out.iterdir()
    from hil.runtime.truth import read_truth_csv

    cols = read_truth_csv(run_dir / "truth.csv")
    t, on = cols["t_s"], cols["slip_speed_mps_4"] > 0.5
    edges = np.diff(np.concatenate([[0], on.astype(int), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    first = next(t[a] for a, b in zip(starts, ends, strict=True) if t[min(b, len(t) - 1)] - t[a] > 0.05)
    expected = f"first violation at t = {first + 0.05:.4f} s"
    result.stdout.fnmatch_lines([f"*TemporalAssertionError: never: truth.slip_speed_mps_4 > 0.5 held for "
                                 f"longer than 0.05 s: {expected}*"])
    failure = ET.parse(junit).getroot().find(".//testcase/failure")
    assert failure is not None and expected in failure.get("message")


def test_the_examples_pass(pytester):
    result = pytester.runpytest_inprocess(str(ROOT / "examples" / "test_example_hil.py"), "-p",
                                          "no:cacheprovider")
    result.assert_outcomes(passed=4)


@pytest.mark.realtime
def test_hil_run_in_real_time_decodes_the_bus(hil_run):
    run = hil_run(DEFAULT, {"max_duration_s": 3.0}, mode="realtime")
    assert run.kpis["mode"] == "realtime"
    demand = run.signal("BCU_DEMAND.TargetDecel")     # decoded from the recorder's trace
    assert len(demand) > 0 and demand.t[0] >= 0.0
    within(demand, 0.0, 1.0)                           # the full service step at most
    eventually(demand > 0.0, after=0.5)                # the BCU answered the desk's brake step
    assert run.truth("v_mps_1").t[-1] == pytest.approx(3.0, abs=0.01)   # the plant ran its 3 s
