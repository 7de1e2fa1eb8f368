"""Sensor faults and stuck signals (issues #9, #19): injected at the source (`[[faults]]` kinds `sensor` and
`stuck`), detected and excluded by the BECU (SpeedSensorFault, AccelSensorFault, CylSensorFault) and the
BCU (CarsImplausible, Degraded), without releasing a brake; and no false detection in the fault-free
scenarios.  A stuck brake-cylinder pressure transducer (`sensor` = "pressure", mode "stuck": the physical
transducer, in the plant node) is detected in every injected case, its time to detect printed.

Lockstep runs through the public API (hil.report.run) on the real DBC; what the ECUs concluded is read back
from the run's BLF trace with python-can's reader and decoded by cantools; what the brakes did comes
from the plant's truth.
"""

import math
import random
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import ROOT

from firmware_py.bcu import BcuParams, disagreeing_cars
from firmware_py.becu import Becu
from firmware_py.rx import RxTable
from firmware_py.sensor_checks import (
    STEEPEST_GRADIENT_MPS2,
    AccelCheck,
    CylCheck,
    SensorCheckParams,
    SpeedCheck,
    accel_bias_check,
    cyl_sensor_check,
    speed_sensor_check,
    valve_pressure_rate,
)
from firmware_py.wsp import Wsp, vent_watchdog
from hil.can.dbc import load_dbc
from hil.can.e2e import Status
from hil.report.run import run_scenario_lockstep
from hil.runtime.node import StuckSignal
from hil.runtime.plant_node import SensorFault, faulty_reading
from hil.scenario import load_scenario, parse_scenario

STOP_30 = ROOT / "scenarios" / "stop_30kmh.toml"
SC = SensorCheckParams()
BP = BcuParams()
RATES = (1.0e6, 1.5e6, 2.0e6)      # BecuParams().valve_rates_Pa_per_s: fill, vent, dump at full opening
T0 = 1.5                     # fault window start [s]: the emergency brake is applied from 0.5 s
DIAG_PERIOD_S = 0.05         # BECUn_DIAG / BECUn_STATUS cycle (DBC GenMsgCycleTime)
BCU_STATUS_PERIOD_S = 0.1    # BCU_STATUS cycle (DBC)


# ------------------------------------------------------------------------------------- pure functions
def feed_speed_check(readings, v_ref, accel, span=0.01, p=SC):
    """Run speed_sensor_check over a list of readings [m/s]; returns the final state and when it failed."""
    state, prev, failed_at = SpeedCheck(), math.nan, None
    for k, w in enumerate(readings):
        state = speed_sensor_check(state, w, prev, v_ref(k), accel, span, p)
        prev = w
        if state.fault and failed_at is None:
            failed_at = k * span
    return state, failed_at


@pytest.mark.parametrize("readings, v_ref, accel, cause", [
    ([0.0] * 200, lambda k: 20.0, 0.0, "stands"),                     # reads 0 while the car runs at 20
    ([10.0] * 200, lambda k: 10.0, -1.3, "frozen"),                   # 10 m/s forever while braking
    ([10.0 - 0.013 * k for k in range(200)], lambda k: 10.0 - 0.013 * k, -1.3, ""),   # a live sensor
    ([0.0] * 200, lambda k: 2.0, 0.0, ""),                            # reads 0: the car is slower than moving
    ([0.5] * 200, lambda k: 0.5, -1.3, ""),                           # a frozen low reading is no evidence
])
def test_speed_sensor_check_table(readings, v_ref, accel, cause):
    state, _ = feed_speed_check(readings, v_ref, accel)
    assert state.fault == bool(cause) and state.cause == cause


def test_a_standing_wheel_fails_only_after_lock_s_and_a_slide_that_ends_does_not():
    _, failed_at = feed_speed_check([0.0] * 300, lambda k: 20.0, 0.0)
    assert failed_at == pytest.approx(SC.lock_s, abs=0.011)
    n_slide = round(0.9 * SC.lock_s / 0.01)                           # locked for 90 % of lock_s, then back
    state, _ = feed_speed_check([0.0] * n_slide + [20.0] * 50, lambda k: 20.0, 0.0)
    assert not state.fault and state.stand_s == 0.0


def test_a_gap_in_the_readings_is_not_time_the_wheel_stood():
    """The bus was blocked for 2 s (a babbling node): the first reading after it says "stands".  The
    2 s since the last reading (20 m/s) are no evidence the wheel stood: the timer starts at that
    reading, and the sensor fails only lock_s of standing readings later."""
    state = speed_sensor_check(SpeedCheck(), 20.0, 20.0, 20.0, 0.0, 0.01, SC)
    state = speed_sensor_check(state, 0.0, 20.0, 20.0, 0.0, 2.0, SC)               # after the gap
    assert state.stands and state.stand_s == 0.0 and not state.fault
    for _ in range(round(SC.lock_s / 0.01) - 1):
        state = speed_sensor_check(state, 0.0, 0.0, 20.0, 0.0, 0.01, SC)
    assert not state.fault and state.stand_s == pytest.approx(SC.lock_s - 0.01)
    assert speed_sensor_check(state, 0.0, 0.0, 20.0, 0.0, 0.02, SC).fault


def test_a_frozen_reading_fails_once_the_accelerometer_moved_frozen_dv():
    _, failed_at = feed_speed_check([10.0] * 200, lambda k: 10.0, -1.0)
    assert failed_at == pytest.approx(SC.frozen_dv_mps / 1.0, abs=0.011)


def test_speed_check_is_latched():
    state = SpeedCheck(True, "stands")
    assert speed_sensor_check(state, 10.0, 9.9, 10.0, 0.0, 0.01, SC) is state


def test_accel_bias_check_follows_a_first_order_filter_and_latches():
    state, t, failed_at = AccelCheck(), 0.0, None
    for _ in range(1000):                                  # accelerometer reads 0.8 more than the axle
        state = accel_bias_check(state, -1.0 + 0.8, -1.0, 0.01, SC)
        t += 0.01
        if state.fault and failed_at is None:
            failed_at = t
    assert SC.bias_limit_mps2 < state.bias_mps2 < 0.8            # latched at detection
    # above the limit after tau ln(0.8 / (0.8 - limit)), then for bias_hold_s
    expected = SC.bias_tau_s * math.log(0.8 / (0.8 - SC.bias_limit_mps2)) + SC.bias_hold_s
    assert failed_at == pytest.approx(expected, abs=0.02)
    assert accel_bias_check(state, 0.0, 0.0, 0.01, SC) is state


def test_the_bias_limit_is_above_the_steepest_gradient():
    assert STEEPEST_GRADIENT_MPS2 == pytest.approx(9.81 * math.sin(math.atan(0.060)))
    assert SC.bias_limit_mps2 > STEEPEST_GRADIENT_MPS2
    for _ in range(2000):                                    # a car standing on a 60 ‰ gradient
        quiet = accel_bias_check(AccelCheck(), STEEPEST_GRADIENT_MPS2, 0.0, 0.01, SC)
    assert not quiet.fault
    with pytest.raises(ValueError, match="steepest gradient"):
        SensorCheckParams(bias_limit_mps2=0.5)


@pytest.mark.parametrize("vent_s, tripped, venting, recovered, expected", [
    (0.0, False, True, False, (0.01, False)),
    (2.0, False, False, True, (0.0, False)),                # the vent ended: the timer restarts
    (4.995, False, True, False, (0.0, True)),               # past max_vent_s: refill
    (0.0, True, True, False, (0.0, True)),                  # stays in FILL while the wheel has not recovered
    (0.0, True, False, True, (0.0, False)),                 # re-armed once it has
])
def test_vent_watchdog_table(vent_s, tripped, venting, recovered, expected):
    got = vent_watchdog(vent_s, tripped, venting, recovered, 0.01, 4.999)
    assert got[0] == pytest.approx(expected[0]) and got[1] == expected[1]


def test_the_watchdog_does_not_count_the_time_a_vented_wheel_spins_up():
    assert vent_watchdog(4.995, False, True, False, 0.01, 4.999, spinning_up=True) == (4.995, False)
    assert vent_watchdog(4.995, False, True, False, 0.01, 4.999, spinning_up=False) == (0.0, True)


def test_a_locked_wheel_that_spins_up_slowly_stays_vented_until_it_is_back():
    """A wheel locked while the BECU's commands were lost (the actuator's fail-safe filled the cylinder,
    issue #19): when the commands return the wheel stands at 0 while the car runs at 20 m/s and
    decelerates at 0.5 m/s².  Vented, it spins up at 2 m/s² (low adhesion at full slide, seed 000 §2.1):
    ~7.7 s, longer than spin_up_s, bridge_max_s and the vent watchdog.  The reference speed bridges the
    whole spin-up and WSP keeps venting until the wheel is back; neither the spin-up rule, the bridge
    limit, the watchdog nor the accelerometer check takes the spinning wheel for the car's speed."""
    becu = Becu()
    dt, car_v, wheel_v, pressure = 0.01, 20.0, 20.0, 200e3
    base = {"CylPressure": pressure, "AccelLong": -0.5, "TargetDecel": 0.5, "Mode": 1, "EmergencyActive": 0}
    for k in range(200):                                       # 2 s rolling with the car
        car_v -= 0.5 * dt
        t = k * 10_000
        becu.step(t, RxTable.received({**base, "AxleSpeed": (car_v - 0.02 + 1e-3 * (k % 2)) / 0.46}, t))
    wheel_v, k0, back_at, min_gap = 0.0, 200, None, math.inf   # then the wheel stands (locked)
    for k in range(k0, k0 + 2000):
        car_v -= 0.5 * dt
        t = k * 10_000
        out = becu.step(t, RxTable.received({**base, "AxleSpeed": (wheel_v + 1e-3 * (k % 2)) / 0.46,
                                             "CylPressure": pressure + 10.0 * (k % 2)}, t))
        rate = valve_pressure_rate(out["ValveCmd"], out["WspValve"], pressure, 450e3, RATES)
        pressure = min(max(pressure + rate * dt, 0.0), 450e3)
        if k > k0 + 30 and back_at is None:                    # a lock shows after a few cycles
            min_gap = min(min_gap, car_v - becu.v_ref)
        if back_at is not None:                                # back: it rolls with the car
            wheel_v = car_v - 0.02
        elif pressure < 10e3 or wheel_v > 0.0:                 # torque-free: it spins up, else stays locked
            wheel_v = min(wheel_v + 2.0 * dt, car_v - 0.02)
            back_at = (k - k0) * dt if wheel_v >= car_v - 0.02 else None
    assert back_at is not None and back_at > max(becu.p.wsp.max_vent_s, becu.p.ref.bridge_max_s)
    assert becu.ref.resets == 0 and becu.wsp_watchdog_trips == 0
    assert out["SpeedSensorFault"] == 0 and out["AccelSensorFault"] == 0
    assert abs(min_gap) < 0.5                                   # the estimate stayed with the car
    assert out["WspActive"] == 0 and pressure > 100e3          # braking again, the wheel rolling


def test_the_becu_refills_a_cylinder_vented_longer_than_the_watchdog_allows():
    """A wheel that reads 5 m/s slower than the accelerometer says, for 8 s, and a cylinder that WSP's
    dump valve does not empty (its transducer, alive, reads 200 kPa throughout, so neither the frozen-
    transducer check nor the reference speed's spin-up rule ends the slide): WSP vents, the watchdog
    refills after max_vent_s, and the brake stays applied."""
    becu = Becu()
    limit = becu.p.wsp.max_vent_s
    base = {"AxleSpeed": 20 / 0.46, "CylPressure": 200e3, "AccelLong": 0.0, "TargetDecel": 1.0, "Mode": 1,
            "EmergencyActive": 0}
    becu.step(0, RxTable.received(base, 0))
    venting = []
    for k in range(1, 800):
        t = k * 10_000
        values = {**base, "AxleSpeed": 15 / 0.46 + 1e-3 * (k % 2),   # alive, 5 m/s slip
                  "CylPressure": 200e3 + 10.0 * (k % 2)}             # alive, not vented
        out = becu.step(t, RxTable.received(values, t))
        venting.append(out["WspActive"])
    vented_s = sum(venting) * 0.01
    assert vented_s == pytest.approx(limit, abs=0.02) and venting[-1] == 0 and becu.wsp_watchdog_trips == 1
    assert out["CylSensorFault"] == 0


@pytest.mark.parametrize("noise_mps", [0.1, 0.3])
def test_a_noisy_wheel_reading_does_not_hold_off_the_watchdog(noise_mps):
    """The previous case with a noisy wheel-speed signal (σ = 0.1 and 0.3 m/s, 10 and 30 times the plant's):
    its difference quotient often looks like a wheel accelerating at several m/s², but noise sets ever
    fewer new highs (of the smoothed reading), so the time the watchdog counts as a spin-up stays short
    and it still refills within 5 % of max_vent_s (5.11 and 5.21 s; on the acceleration alone: 5.9 and
    7.7 s)."""
    becu, rng = Becu(), random.Random(1)
    base = {"AxleSpeed": 20 / 0.46, "CylPressure": 200e3, "AccelLong": 0.0, "TargetDecel": 1.0, "Mode": 1,
            "EmergencyActive": 0}
    becu.step(0, RxTable.received(base, 0))
    vented_s = 0.0
    for k in range(1, 800):
        t = k * 10_000
        out = becu.step(t, RxTable.received({**base, "AxleSpeed": (15 + rng.gauss(0.0, noise_mps)) / 0.46,
                                             "CylPressure": 200e3 + 10.0 * (k % 2)}, t))
        if becu.wsp_watchdog_trips:
            break
        vented_s += 0.01 * out["WspActive"]
    assert becu.wsp_watchdog_trips == 1
    assert becu.p.wsp.max_vent_s <= vented_s < 1.05 * becu.p.wsp.max_vent_s


def test_a_vented_wheel_that_does_not_spin_up_is_trusted_again():
    """The same wheel, 5 m/s below the accelerometer's speed, with a cylinder that the dump valve empties:
    a wheel without brake torque spins up (seed 001 eq. (3) with τ = 0), so after spin_up_s without
    torque the reference speed takes the wheel (the accelerometer was wrong) and WSP stops venting."""
    becu = Becu()
    rp = becu.p.ref
    base = {"AxleSpeed": 20 / 0.46, "CylPressure": 200e3, "AccelLong": 0.0, "TargetDecel": 1.0, "Mode": 1,
            "EmergencyActive": 0}
    becu.step(0, RxTable.received(base, 0))
    venting, pressure = [], 200e3
    for k in range(1, 200):
        t = k * 10_000
        out = becu.step(t, RxTable.received({**base, "AxleSpeed": 15 / 0.46 + 1e-3 * (k % 2),
                                             "CylPressure": pressure + 10.0 * (k % 2)}, t))
        venting.append(out["WspActive"])
        rate = valve_pressure_rate(out["ValveCmd"], out["WspValve"], pressure, 450e3, RATES)   # plant_sim's
        pressure = min(max(pressure + rate * 0.01, 0.0), 450e3)
    empty_s = (200e3 - rp.torque_free_Pa) / 2e6                 # until the pressure is below torque_free_Pa
    vented_s = sum(venting) * 0.01
    assert vented_s == pytest.approx(empty_s + rp.spin_up_s, abs=0.03)
    # the wheel's speed (the bias estimate took up a little of the 5 m/s step the accelerometer did not see)
    assert venting[-1] == 0 and becu.ref.resets == 1 and becu.v_ref == pytest.approx(15.0, abs=0.05)
    assert becu.wsp_watchdog_trips == 0 and out["CylSensorFault"] == 0


@pytest.mark.parametrize("valve, wsp, p, expected", [
    (0.5, Wsp.FILL, 100e3, 0.5e6),             # EP valve filling
    (-0.5, Wsp.FILL, 100e3, -0.75e6),          # ... venting
    (0.5, Wsp.HOLD, 100e3, 0.0),               # the dump valve isolates the cylinder
    (0.5, Wsp.VENT, 100e3, -2.0e6),            # ... or dumps it
    (1.0, Wsp.FILL, 450e3, 0.0),               # nothing beyond p̄ ...
    (-1.0, Wsp.FILL, 0.0, 0.0),                # ... or below 0
])
def test_valve_pressure_rate_table(valve, wsp, p, expected):
    assert valve_pressure_rate(valve, wsp, p, 450e3, RATES) == expected


def feed_cyl_check(readings, valve, wsp=Wsp.FILL, span=0.01):
    """Run cyl_sensor_check over readings [Pa] with one valve command; (final state, time it failed)."""
    state, prev, before, failed_at = CylCheck(), math.nan, math.nan, None
    for k, r in enumerate(readings):
        if prev == prev:
            state = cyl_sensor_check(state, r, prev, before, valve, wsp, span, 450e3, RATES, SC)
        before, prev = prev, r
        if state.fault and failed_at is None:
            failed_at = k * span
    return state, failed_at


@pytest.mark.parametrize("readings, valve, wsp, fails", [
    ([0.0] * 20, 1.0, Wsp.FILL, True),                        # reads 0 while the valve fills at full
    ([300e3] * 20, -1.0, Wsp.FILL, True),                     # reads 300 kPa while it vents at full
    ([300e3] * 20, 0.0, Wsp.VENT, True),                      # ... while the dump valve vents
    ([300e3 + 10 * (k % 2) for k in range(20)], 1.0, Wsp.FILL, False),   # a live transducer
    ([0.0] * 100, -1.0, Wsp.FILL, False),                     # venting an empty cylinder: no evidence
    ([445e3] * 100, 1.0, Wsp.FILL, False),                    # filling at the reservoir's pressure: none
    ([200e3] * 100, 0.01, Wsp.FILL, False),                   # within the valve's dead band: none
    ([200e3] * 100, 1.0, Wsp.HOLD, False),                    # the cylinder isolated: none
])
def test_cyl_sensor_check_table(readings, valve, wsp, fails):
    state, _ = feed_cyl_check(readings, valve, wsp)
    assert state.fault == fails


def test_a_frozen_transducer_fails_once_the_valves_moved_the_limit_and_the_model_starts_there():
    state, failed_at = feed_cyl_check([0.0] * 20, 1.0)               # 1 MPa/s: 50 kPa in 50 ms
    assert failed_at == pytest.approx(SC.cyl_frozen_dp_Pa / RATES[0] + 0.01, abs=0.011)
    assert state.base_Pa == 0.0 and state.moved_Pa == pytest.approx(state.evidence_Pa)
    # a transducer that jumps to 450 kPa and stays there while the cylinder held 300 kPa: faster than any
    # valve moves a cylinder, so the pressure when it froze is the reading before the jump
    state, _ = feed_cyl_check([300e3, 300.5e3, 450e3] + [450e3] * 10, -1.0)
    assert state.fault and state.base_Pa == 300.5e3 and state.moved_Pa < 0.0
    assert cyl_sensor_check(state, 1.0, 2.0, 3.0, 1.0, Wsp.FILL, 0.01, 450e3, RATES, SC) is state   # latched


def test_the_becu_runs_the_pressure_loop_on_its_model_once_the_transducer_failed():
    """The transducer reads 0 while the BECU fills for a 1.0 m/s² demand (set-point 260 kPa): CylSensorFault
    within 0.1 s, then the loop closes on the model of the cylinder, derated to brake: the valve closes
    once the modelled pressure reaches the set-point, by when the plant's cylinder (nominal valves) holds
    at least the set-point."""
    becu = Becu()
    base = {"CylPressure": 0.0, "AccelLong": -1.0, "TargetDecel": 1.0, "Mode": 1, "EmergencyActive": 0}
    p_true, failed_at = 0.0, None
    for k in range(100):
        t = k * 10_000
        out = becu.step(t, RxTable.received({**base, "AxleSpeed": (20 - 0.01 * k) / 0.46}, t))
        u = out["ValveCmd"]
        p_true = min(max(p_true + 0.01 * u * (1e6 if u > 0 else 1.5e6), 0.0), 450e3)
        if out["CylSensorFault"] and failed_at is None:
            failed_at = k * 0.01
    assert failed_at is not None and failed_at <= 0.1
    assert becu.checks.p_model == pytest.approx(out["CylPressureSet"], rel=0.01)
    assert abs(out["ValveCmd"]) < 0.01
    assert out["CylPressureSet"] <= p_true <= 1.15 * out["CylPressureSet"]
    assert out["SpeedSensorFault"] == 0 and out["AccelSensorFault"] == 0


@pytest.mark.parametrize("speeds, trusted, expected", [
    ([10.0, 10.1, 40.0, 9.9, 10.0, 10.2], [True] * 6, [False, False, True, False, False, False]),
    ([10.0, 40.0, 10.0], [True] * 3, [False, True, False]),            # 3 cars: the stuck one only
    ([10.0, 40.0], [True] * 2, [False, False]),                        # 2 cars: nobody can tell
    ([10.0, math.nan, 40.0, 10.0], [True] * 4, [False, False, True, False]),   # a silent car does not vote
    ([10.0, 40.0, 41.0, 10.0, 10.0], [True, False, True, True, True], [False, True, True, False, False]),
])
def test_disagreeing_cars_table(speeds, trusted, expected):
    assert disagreeing_cars(speeds, trusted, BP.implausible_mps) == expected


def test_the_bcu_excludes_a_car_after_3_status_cycles_and_latches():
    from firmware_py.bcu import Bcu
    bcu = Bcu(4)
    values = {"BrakeStep": 7, "EmergencyReq": 0, **{f"BECU{i}_STATUS.SpeedEst": 20.0 for i in range(1, 5)}}
    out = bcu.step(0, RxTable.received(values, 0))
    assert out["CarsImplausible"] == 0 and out["Degraded"] == 0 and out["TrainSpeedEst"] == 20.0
    stuck = {**values, "BECU3_STATUS.SpeedEst": 35.0}
    flagged_us = next(t for t in range(10_000, 1_000_000, 10_000)
                      if bcu.step(t, RxTable.received(stuck, t))["CarsImplausible"])
    assert BP.implausible_after_us < flagged_us - 10_000 <= BP.implausible_after_us + 10_000
    t = flagged_us + 10_000
    out = bcu.step(t, RxTable.received(values, t))             # back in line: still excluded (latched)
    assert out["CarsImplausible"] == 0b100 and out["Degraded"] == 1 and out["TrainSpeedEst"] == 20.0
    t += 10_000
    out = bcu.step(t, RxTable.received({**values, "BECU1_DIAG.AccelSensorFault": 1}, t))
    assert out["Degraded"] == 1


def test_faulty_reading_and_stuck_signal():
    bias = SensorFault(0, "AccelLong", "bias", 0.8, 0, 10)
    assert faulty_reading(-1.0, bias, 0.001, False) == pytest.approx(-0.2)
    assert faulty_reading(0.1, SensorFault(0, "AxleSpeed", "bias", -0.5, 0, 10), 0.005, True) == 0.0
    stuck = SensorFault(0, "AxleSpeed", "stuck", None, 0, 10, last=42.0)
    assert faulty_reading(3.0, stuck, 0.005, True) == 42.0
    seen = []
    signal = StuckSignal("SpeedEst", 100, 200, None, seen.append)
    for t, v in ((0, 5.0), (90, 6.0), (100, 7.0), (150, 8.0), (200, 9.0)):
        values = {"SpeedEst": v}
        signal.apply(values, t)
        assert values["SpeedEst"] == (6.0 if 100 <= t < 200 else v)
    assert seen == [100, 150]


# ------------------------------------------------------------------------------------- lockstep runs
def emergency_stop(*faults, seconds=9.0):
    """stop_30kmh with the desk's emergency brake at 0.5 s instead of step 7."""
    base = load_scenario(STOP_30)
    return parse_scenario({**base.model_dump(), "max_duration_s": seconds,
                           "desk": [{"at_s": 0.5, "emergency": True}], "faults": list(faults)})


def decode_trace(report, messages):
    """{message: (times [s], {signal: values})} of the run's BLF trace, read with python-can and
    decoded with cantools."""
    db = load_dbc()
    wanted = {db.get_message_by_name(m).frame_id: db.get_message_by_name(m) for m in messages}
    rows: dict[str, list] = {m: [] for m in messages}
    with can.LogReader(str(Path(report.out_dir) / "trace.blf")) as reader:
        for frame in reader:
            msg = wanted.get(frame.arbitration_id)
            if msg is not None:
                rows[msg.name].append((frame.timestamp, msg.decode(bytes(frame.data), decode_choices=False)))
    out = {}
    for name, got in rows.items():
        t = np.array([r[0] for r in got])
        signals = db.get_message_by_name(name).signals
        out[name] = (t, {sig.name: np.array([r[1][sig.name] for r in got]) for sig in signals})
    return out


def first_time(t, values):
    hits = np.flatnonzero(values >= 0.5)
    return t[hits[0]] if hits.size else None


def truth(report):
    return report.outcome.truth.columns()


def stop_of(cols, n):
    """(time the last car stopped [s], distance the leading car travelled [m]) from plant truth."""
    v = np.column_stack([cols[f"v_mps_{i}"] for i in range(1, n + 1)])
    moving = np.flatnonzero(v.max(axis=1) >= 0.01)
    k = moving[-1] + 1 if moving.size else 0
    assert k < len(v), "the train did not stop"
    return cols["t_s"][k], cols["x_m_1"][k] - cols["x_m_1"][0]


@pytest.fixture(scope="module")
def fault_free(tmp_path_factory):
    """The emergency stop without faults: the reference for distances and pressures."""
    return run_scenario_lockstep(emergency_stop(), tmp_path_factory.mktemp("ok") / "run")


def assert_brake_held_and_train_stopped(report, fault_free, car, detected_s):
    """After detection (plus the cylinder's refill), car `car`'s cylinder stays above 80 % of the
    fault-free run's until the train stands; the train stops within the fault-free emergency distance
    scaled by n/(n-1), i.e. no worse than that car having no brake at all for the whole stop."""
    n = 6
    cols, ref = truth(report), truth(fault_free)
    t_stop, dist = stop_of(cols, n)
    _, dist_ok = stop_of(ref, n)
    assert dist <= dist_ok * n / (n - 1), (dist, dist_ok)
    t = cols["t_s"]
    refill_s = 0.3                                       # EP valve at full flow (1 MPa/s) fills 300 kPa
    window = (t >= detected_s + refill_s) & (t < t_stop - 0.1)
    assert window.sum() > 10
    p = cols[f"p_Pa_{car}"][window]
    p_ok = np.interp(t[window], ref["t_s"], ref[f"p_Pa_{car}"])     # held at its last value once stopped
    assert np.all(p >= 0.8 * p_ok), (p.min(), p_ok.min())


DIAG = [f"BECU{i}_DIAG" for i in range(1, 7)]


@pytest.mark.parametrize("value, cause_bound_s", [
    (0.0, SC.lock_s),                                           # reads "stands": after lock_s
    (None, SC.frozen_dv_mps / (0.5 * BP.emergency_decel_mps2)),  # frozen: once the car lost frozen_dv
])
def test_a_stuck_wheel_speed_sensor_is_detected_and_the_brake_stays_applied(tmp_path, fault_free, value,
                                                                            cause_bound_s):
    fault = {"kind": "sensor", "car": 2, "sensor": "wheel_speed", "mode": "stuck", "from_s": T0, "to_s": 60.0}
    if value is not None:
        fault["value"] = value
    report = run_scenario_lockstep(emergency_stop(fault), tmp_path / "run")
    assert report.kpis["faults_injected"]["sensor"] > 0
    trace = decode_trace(report, DIAG)
    t, sig = trace["BECU2_DIAG"]
    detected = first_time(t, sig["SpeedSensorFault"])
    assert detected is not None
    assert detected - T0 <= cause_bound_s + 2 * DIAG_PERIOD_S, detected
    flags = report.kpis["plausibility_flags"]                  # the run's KPI says the same
    assert flags == {"SpeedSensorFault": {"car2": pytest.approx(detected, abs=1e-3)}}
    for other in DIAG[:1] + DIAG[2:]:                          # the other cars' sensors are fine
        assert not trace[other][1]["SpeedSensorFault"].any() and not trace[other][1]["AccelSensorFault"].any()
    assert_brake_held_and_train_stopped(report, fault_free, 2, detected)


@pytest.mark.parametrize("bias", [0.8, -0.8])
def test_an_accelerometer_bias_is_estimated_and_detected(tmp_path, fault_free, bias):
    fault = {"kind": "sensor", "car": 4, "sensor": "accelerometer", "mode": "bias", "value": bias,
             "from_s": T0, "to_s": 60.0}
    report = run_scenario_lockstep(emergency_stop(fault), tmp_path / "run")
    t, sig = decode_trace(report, ["BECU4_DIAG"])["BECU4_DIAG"]
    detected = first_time(t, sig["AccelSensorFault"])
    assert detected is not None
    # the first-order filter reaching the limit, plus the hold time, plus 10 % for the updates it skips
    # while a wheel slides or WSP acts, plus a DIAG frame
    bound = SC.bias_tau_s * math.log(abs(bias) / (abs(bias) - SC.bias_limit_mps2)) + SC.bias_hold_s
    assert detected - T0 <= 1.1 * bound + 2 * DIAG_PERIOD_S, detected
    assert sig["AccelBiasEst"][t >= detected][0] == pytest.approx(bias, abs=0.15)
    assert not sig["SpeedSensorFault"].any()
    assert_brake_held_and_train_stopped(report, fault_free, 4, detected)


#: stuck cylinder-pressure transducer cases: (car, injected at [s], stuck at [Pa] (None: its last reading),
#: when the valves start to move the pressure [s], bound on the time to detect from then [s], what)
CYL_CASES = [
    (2, 0.2, None, 0.5, 0.2, "before braking, at 0 kPa (found when the brake applies at 0.5 s)"),
    (3, 0.6, None, 0.6, 0.2, "during the pressure rise"),
    (1, 1.5, 0.0, 1.5, 0.2, "braking at ~330 kPa, reads 0 (open circuit)"),
    (4, 1.0, 100e3, 1.0, 0.2, "braking at ~330 kPa, reads 100 kPa"),
    (6, 1.5, 450e3, 1.5, 0.2, "braking at ~330 kPa, reads 450 kPa (short to supply)"),
    (5, 1.5, None, 1.5, 3.0, "braking, frozen at its reading of the set-point: found once the pressure "
                             "PI's integrator has moved the valve"),
]


@pytest.mark.parametrize("car, t0, value, moving_s, bound_s, what", CYL_CASES,
                         ids=[f"car{c[0]}-{c[1]}s-{c[2]}" for c in CYL_CASES])
def test_a_stuck_cylinder_pressure_sensor_is_detected_and_the_brake_stays_applied(
        tmp_path, fault_free, car, t0, value, moving_s, bound_s, what):
    """CylSensorFault latches within the bound after the valves start to move the pressure (every injected
    case: different cars, injection before braking, during the rise, at different stuck values; the times
    are printed); the BCU goes Degraded; the car's brake stays applied (the loop runs on the model of the
    cylinder) and no other flag is raised."""
    fault = {"kind": "sensor", "car": car, "sensor": "pressure", "mode": "stuck", "from_s": t0, "to_s": 60.0}
    if value is not None:
        fault["value"] = value
    report = run_scenario_lockstep(emergency_stop(fault), tmp_path / "run")
    assert report.kpis["faults_injected"]["sensor"] > 0
    trace = decode_trace(report, DIAG + ["BCU_STATUS"])
    t, sig = trace[f"BECU{car}_DIAG"]
    detected = first_time(t, sig["CylSensorFault"])
    assert detected is not None, what
    print(f"\nstuck CylPressure, car {car}, from {t0} s at {'its last reading' if value is None else value}: "
          f"{what}: CylSensorFault at {detected:.3f} s, {detected - moving_s:.3f} s after the valves move it "
          f"(bound {bound_s} s)")
    assert detected - moving_s <= bound_s
    flagged = report.kpis["plausibility_flags"]["CylSensorFault"]
    assert flagged == {f"car{car}": pytest.approx(detected, abs=1e-3)}
    for i, name in enumerate(DIAG, start=1):
        flags = ("SpeedSensorFault", "AccelSensorFault") + (("CylSensorFault",) if i != car else ())
        assert not any(trace[name][1][s].any() for s in flags), (name, flags)
    ts, st = trace["BCU_STATUS"]
    assert np.all(st["Degraded"][ts > detected + DIAG_PERIOD_S + BCU_STATUS_PERIOD_S] == 1)
    assert not st["CarsImplausible"].any()
    assert_brake_held_and_train_stopped(report, fault_free, car, detected)


def test_a_stuck_cylinder_pressure_sensor_is_detected_in_service_braking_with_wsp(tmp_path, default_lockstep):
    """The default run (service braking, the wet section): car 3's transducer frozen at its reading at 7 s,
    as WSP starts venting that car: found within 0.2 s (the dump valve should move the pressure), the train
    stops no later than without the fault (the loop on the model, derated to brake)."""
    car, t0 = 3, 7.0
    base = load_scenario(ROOT / "scenarios" / "default.toml")
    fault = {"kind": "sensor", "car": car, "sensor": "pressure", "mode": "stuck", "from_s": t0, "to_s": 90.0}
    report = run_scenario_lockstep(parse_scenario({**base.model_dump(), "faults": [fault]}), tmp_path / "run",
                                   plots=False)
    t, sig = decode_trace(report, [f"BECU{car}_DIAG"])[f"BECU{car}_DIAG"]
    detected = first_time(t, sig["CylSensorFault"])
    assert detected is not None
    print(f"\nstuck CylPressure, default, car {car}, from {t0} s at its last reading (WSP venting): "
          f"CylSensorFault at {detected:.3f} s, {detected - t0:.3f} s after the injection (bound 0.2 s)")
    assert detected - t0 <= 0.2
    assert report.outcome.reason == "standstill"
    assert report.kpis["stopping_distance_m"] <= default_lockstep.kpis["stopping_distance_m"] + 0.5


def test_a_stuck_speed_estimate_is_excluded_by_the_bcu(tmp_path, fault_free):
    """BECU3's software reports SpeedEst = 40 m/s from T0: the frame is valid on the bus, the BCU
    finds it implausible after 3 status cycles, excludes it from the train speed, flags it."""
    fault = {"kind": "stuck", "message": "BECU3_STATUS", "signal": "SpeedEst", "value": 40.0,
             "from_s": T0, "to_s": 60.0}
    report = run_scenario_lockstep(emergency_stop(fault), tmp_path / "run")
    assert report.kpis["faults_injected"]["stuck"] > 0
    trace = decode_trace(report, ["BCU_STATUS", "BECU3_STATUS"])
    t3, s3 = trace["BECU3_STATUS"][0], trace["BECU3_STATUS"][1]["SpeedEst"]
    assert np.all(s3[t3 >= T0] == 40.0) and np.all(s3[t3 < T0] < 10.0)
    t, sig = trace["BCU_STATUS"]
    flagged = t[sig["CarsImplausible"] == 1 << 2]
    assert flagged.size
    bound = BP.implausible_after_us / 1e6 + DIAG_PERIOD_S + BCU_STATUS_PERIOD_S + 0.02
    assert flagged[0] - T0 <= bound, flagged[0]
    after = t >= flagged[0]
    assert np.all(sig["Degraded"][after] == 1) and np.all(sig["TrainSpeedEst"][after] < 10.0)
    assert not np.any(sig["CarsImplausible"][~after])
    for car in range(1, 7):
        assert_brake_held_and_train_stopped(report, fault_free, car, flagged[0])
    assert report.outcome.reason == "standstill"


def test_a_stuck_signal_is_valid_on_the_bus(tmp_path):
    """A stuck ValveCmd in BECU2's software: E2E and SecOC are computed over it, so the plant accepts
    every frame (no protection event) and applies the stuck value."""
    t1 = T0 + 0.3
    fault = {"kind": "stuck", "message": "BECU2_PRESS_CMD", "signal": "ValveCmd", "value": 0.0,
             "from_s": T0, "to_s": t1}
    report = run_scenario_lockstep(emergency_stop(fault, seconds=t1 + 0.2), tmp_path / "run")
    t, sig = decode_trace(report, ["BECU2_PRESS_CMD"])["BECU2_PRESS_CMD"]
    inside = (t >= T0) & (t < t1 + 0.001)          # sent in the window (+ its time on the bus)
    assert inside.sum() >= 29 and np.all(sig["ValveCmd"][inside] == 0.0)
    plant = report.outcome.node_stats["PLANT"]
    assert not [e for e in plant["e2e_events"] if e[1] == "BECU2_PRESS_CMD" and e[2] != Status.INITIAL.value]
    assert not plant["secoc_rejected"]
    assert report.kpis["faults_injected"]["stuck"] == inside.sum()


# ------------------------------------------------------------------------- no false detection, WSP works
def assert_no_detection(report, n):
    trace = decode_trace(report, [f"BECU{i}_DIAG" for i in range(1, n + 1)] + ["BCU_STATUS"])
    for i in range(1, n + 1):
        sig = trace[f"BECU{i}_DIAG"][1]
        assert not sig["SpeedSensorFault"].any() and not sig["AccelSensorFault"].any(), i
        assert not sig["CylSensorFault"].any(), i
        assert np.abs(sig["AccelBiasEst"]).max() < SC.bias_limit_mps2 / 2, i
    assert not trace["BCU_STATUS"][1]["CarsImplausible"].any()


def test_no_false_detection_in_the_default_run(default_lockstep):
    assert_no_detection(default_lockstep, 6)
    assert default_lockstep.kpis.get("faults_injected") is None


@pytest.mark.parametrize("path", [STOP_30] + sorted((ROOT / "scenarios").glob("rg_*.toml")),
                         ids=lambda p: p.stem)
def test_no_false_detection_in_the_short_scenarios(tmp_path, path):
    scenario = load_scenario(path)
    report = run_scenario_lockstep(scenario, tmp_path / "run")
    assert_no_detection(report, scenario.train.cars)


def test_wsp_still_works_on_low_adhesion(tmp_path):
    """rg_low_adhesion without the reference governor slides (seed 001 Fig. 8's ungoverned case): WSP
    vents many times, nothing is declared failed, the vent watchdog never fires."""
    base = load_scenario(ROOT / "scenarios" / "rg_low_adhesion.toml")
    scenario = parse_scenario({**base.model_dump(), "max_duration_s": 12.0,
                               "wheel_slip": {**base.wheel_slip.model_dump(), "governor": False}})
    report = run_scenario_lockstep(scenario, tmp_path / "run")
    assert_no_detection(report, 1)
    t, sig = decode_trace(report, ["BECU1_STATUS"])["BECU1_STATUS"]
    assert sig["WspActive"].sum() >= 20

