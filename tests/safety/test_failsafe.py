"""Fail-safe braking: loss of command brakes (BECU on a lost demand; actuators on a lost pressure
command, after holding the cylinder for a bounded time), on plant truth."""

import numpy as np
from conftest import DEFAULT

from firmware_py.wsp import WspParams
from hil.report.run import run_scenario_lockstep
from hil.runtime.plant_node import FAILSAFE_HOLD_S
from hil.scenario import load_scenario, parse_scenario
from hil.scenario.model import PlantSpec

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


def test_a_car_without_pressure_commands_holds_its_cylinder_then_brakes_on_its_own(tmp_path):
    """BECU2's pressure commands deleted from T0 for 1.5 s, with [plant] failsafe_hold_s = 0.5: after 3
    command cycles car 2's actuators hold its cylinder where the last command left it, 0.5 s later they
    fill it towards p̄; the other cars brake as without the fault."""
    fault = {"kind": "deletion", "message": "BECU2_PRESS_CMD", "from_s": T0, "to_s": T0 + 1.5}

    def held(scenario, hold_s):
        return parse_scenario({**scenario.model_dump(), "max_duration_s": T0 + 2.0,
                               "plant": {**scenario.plant.model_dump(), "failsafe_hold_s": hold_s}})

    report = run_scenario_lockstep(held(mild_braking(fault), 0.5), tmp_path / "run")
    base = run_scenario_lockstep(held(mild_braking(), 0.5), tmp_path / "base")
    t, p = pressures(report)
    _, p0 = pressures(base)
    stale = np.searchsorted(t, T0 + 0.05)                          # commands stale: held from here ...
    fill = np.searchsorted(t, T0 + 0.5)                            # ... at least to here
    assert np.ptp(p[stale:fill, 1]) < 1.0                          # held: the pressure does not move
    at = np.searchsorted(t, T0 + 0.04 + 0.5 + 0.1)
    assert p[at, 1] > p[stale, 1] + 50e3                           # then car 2 fills
    others = [0, 2, 3, 4, 5]
    assert np.allclose(p[at, others], p0[at, others], rtol=0.05, atol=5e3)   # the others do not


def test_with_no_hold_a_car_without_pressure_commands_brakes_at_once(tmp_path):
    """[plant] failsafe_hold_s = 0: car 2 fills 3 command cycles after its commands stop."""
    fault = {"kind": "deletion", "message": "BECU2_PRESS_CMD", "from_s": T0, "to_s": T0 + 0.3}
    scenario = mild_braking(fault)
    scenario = parse_scenario({**scenario.model_dump(), "plant": {**scenario.plant.model_dump(),
                                                                  "failsafe_hold_s": 0.0}})
    report = run_scenario_lockstep(scenario, tmp_path / "run")
    base = run_scenario_lockstep(mild_braking(), tmp_path / "base")
    t, p = pressures(report)
    _, p0 = pressures(base)
    at = np.searchsorted(t, T0 + 0.1)
    assert p[at, 1] > p0[at, 1] + 30e3                            # car 2 fills ...
    assert np.allclose(p[at, [0, 2, 3, 4, 5]], p0[at, [0, 2, 3, 4, 5]], rtol=0.05, atol=5e3)  # others not


def test_the_actuators_hold_no_longer_than_the_wsp_safety_timer():
    """The default hold is the WSP safety timer the BECU's vent watchdog enforces (5 s)."""
    assert FAILSAFE_HOLD_S == WspParams().max_vent_s == PlantSpec().failsafe_hold_s
