"""Fail-safe braking: loss of command brakes (BECU on a lost demand, actuators on a lost pressure
command), on plant truth."""

import numpy as np
from conftest import DEFAULT

from hil.runtime.run import run_scenario_lockstep
from hil.scenario import load_scenario, parse_scenario

T0 = 5.0


def mild_braking(*faults):
    """60 km/h, brake step 2 (0.29 m/s²): room above for the fail-safe to show."""
    base = load_scenario(DEFAULT)
    return parse_scenario({**base.model_dump(), "max_duration_s": T0 + 1.0,
                           "train": {**base.train.model_dump(), "initial_speed_kmh": 60.0},
                           "desk": [{"at_s": 0.5, "brake_step": 2}], "faults": list(faults)})


def pressures(report):
    cols = report.outcome.truth.columns()
    return cols["t_s"], np.column_stack([cols[f"p_Pa_{i}"] for i in range(1, 7)])


def test_a_silent_bcu_makes_every_becu_brake_within_100_ms(tmp_path):
    """The BCU goes bus-off at T0: every BECU loses its demand after 3 cycles and brakes at the
    emergency deceleration; every car's cylinder pressure is well up within 100 ms (plant truth)."""
    base = run_scenario_lockstep(mild_braking(), tmp_path / "base")
    off = run_scenario_lockstep(mild_braking({"kind": "bus_off", "node": "BCU", "from_s": T0,
                                              "to_s": T0 + 1.0}), tmp_path / "off")
    t, p = pressures(off)
    _, p0 = pressures(base)
    at = np.searchsorted(t, T0 + 0.1)
    assert np.all(p[at] > p0[at] + 30e3), (p[at], p0[at])       # pressure rising in every car
    before = np.searchsorted(t, T0 - 0.01)
    assert np.allclose(p[before], p0[before])                    # and not before the fault
    statuses = {row[2] for row in off.outcome.node_stats["BECU3"]["e2e_events"]}
    assert "NONEWDATA" in statuses


def test_a_corrupted_demand_stream_brakes_and_normal_control_returns(tmp_path):
    fault = {"kind": "corruption", "message": "BCU_DEMAND", "from_s": T0, "to_s": T0 + 0.3}
    report = run_scenario_lockstep(mild_braking(fault), tmp_path / "run")
    t, p = pressures(report)
    base = run_scenario_lockstep(mild_braking(), tmp_path / "base")
    _, p0 = pressures(base)
    during = np.searchsorted(t, T0 + 0.25)
    assert np.all(p[during] > p0[during] + 50e3)
    after = np.searchsorted(t, T0 + 0.9)                          # commands back: pressure comes down
    assert np.all(p[after] < p[during])


def test_a_car_without_pressure_commands_brakes_on_its_own(tmp_path):
    fault = {"kind": "deletion", "message": "BECU2_PRESS_CMD", "from_s": T0, "to_s": T0 + 0.3}
    report = run_scenario_lockstep(mild_braking(fault), tmp_path / "run")
    base = run_scenario_lockstep(mild_braking(), tmp_path / "base")
    t, p = pressures(report)
    _, p0 = pressures(base)
    at = np.searchsorted(t, T0 + 0.1)
    assert p[at, 1] > p0[at, 1] + 30e3                            # car 2 fills ...
    assert np.allclose(p[at, [0, 2, 3, 4, 5]], p0[at, [0, 2, 3, 4, 5]], rtol=0.05, atol=5e3)  # others not
