"""Controllers: the shared PI primitive, pure mode transitions (keyword tables), step tests."""

import math

import pytest

from firmware_py.bcu import Bcu, BcuMode, bcu_mode_transition
from firmware_py.becu import Becu
from firmware_py.pi import PI, PIParams
from firmware_py.rx import RxTable
from firmware_py.stopping import StoppingDemand, StoppingParams, StopState
from firmware_py.wsp import Wsp, WspParams, wsp_transition


def test_pi_integrates_and_saturates_without_windup():
    pi = PI(PIParams(kp=1.0, ki=10.0, out_min=-1.0, out_max=1.0))
    for _ in range(100):
        out = pi.update(5.0, 0.01)
    assert out == 1.0 and pi.saturated
    i_at_limit = pi.i
    for _ in range(100):
        pi.update(5.0, 0.01)
    assert pi.i == i_at_limit                      # conditional anti-windup: no further integration
    # the error reverses: the output leaves the limit at once (no wound-up integrator to unwind)
    assert pi.update(-0.5, 0.01) < 1.0


def test_pi_freeze_and_bumpless_handover():
    pi = PI(PIParams(kp=2.0, ki=1.0, out_min=-10, out_max=10))
    pi.update(1.0, 0.1)
    i = pi.i
    pi.update(3.0, 0.1, freeze=True)
    assert pi.i == i and pi.frozen
    pi.handover(last_output=4.0, error=0.5)
    assert pi.update(0.5, 0.0) == pytest.approx(4.0)


P = WspParams()


@pytest.mark.parametrize("state, slip, speed, expected", [
    (Wsp.FILL, 0.1, 25.0, Wsp.FILL),          # normal adhesion
    (Wsp.FILL, 1.2, 25.0, Wsp.VENT),          # above 0.30 + 0.03*25 = 1.05 m/s
    (Wsp.VENT, 0.8, 25.0, Wsp.VENT),          # still above the hold fraction 0.525
    (Wsp.VENT, 0.5, 25.0, Wsp.HOLD),          # recovering: hold the pressure
    (Wsp.HOLD, 0.4, 25.0, Wsp.HOLD),          # between refill (0.2625) and hold thresholds
    (Wsp.HOLD, 0.2, 25.0, Wsp.FILL),          # recovered: refill
    (Wsp.HOLD, 1.1, 25.0, Wsp.VENT),          # slips again while holding
    (Wsp.VENT, 5.0, 0.5, Wsp.FILL),           # below min speed: WSP inhibited, train may stop
])
def test_wsp_transition_table(state, slip, speed, expected):
    assert wsp_transition(state, slip, speed, P) == expected


@pytest.mark.parametrize("mode, step, emergency, standstill, expected", [
    (BcuMode.RELEASED, 0, False, False, BcuMode.RELEASED),
    (BcuMode.RELEASED, 3, False, False, BcuMode.SERVICE),
    (BcuMode.SERVICE, 0, False, False, BcuMode.RELEASED),
    (BcuMode.SERVICE, 7, True, False, BcuMode.EMERGENCY),
    (BcuMode.EMERGENCY, 0, False, False, BcuMode.EMERGENCY),    # latched while moving
    (BcuMode.EMERGENCY, 0, False, True, BcuMode.RELEASED),      # released at standstill
    (BcuMode.EMERGENCY, 2, False, True, BcuMode.SERVICE),
])
def test_bcu_mode_transition_table(mode, step, emergency, standstill, expected):
    assert bcu_mode_transition(mode, step, emergency, standstill) == expected


@pytest.mark.parametrize("mode, step, emergency, standstill, stop_demand, expected", [
    (BcuMode.RELEASED, 0, False, False, True, BcuMode.SERVICE),   # precise stopping brakes
    (BcuMode.SERVICE, 0, False, True, True, BcuMode.SERVICE),     # ... and holds the train at the point
    (BcuMode.SERVICE, 0, False, False, False, BcuMode.RELEASED),
    (BcuMode.SERVICE, 0, True, False, True, BcuMode.EMERGENCY),   # emergency has priority
    (BcuMode.EMERGENCY, 0, False, False, True, BcuMode.EMERGENCY),
])
def test_bcu_mode_transition_with_precise_stopping(mode, step, emergency, standstill, stop_demand, expected):
    assert bcu_mode_transition(mode, step, emergency, standstill, stop_demand) == expected


def test_bcu_precise_stopping_brakes_along_the_curve_and_gives_way_to_emergency():
    """A BCU with the PI stopping method, a train at 20 m/s passing x = 0 at t = 0, target 300 m ahead:
    it coasts (ARMED) until the curve at 0.6 m/s² begins (333 m before the point: at once here, with the
    steeper a_c = 20²/(2·300)), then sends a service demand near a_c; emergency takes over.  The train
    decelerates as demanded (an ideal brake), its position is the sum of its speeds."""
    stopping = StoppingDemand(StoppingParams(method="pi"))
    bcu = Bcu(2, sources=[stopping])
    values = {"BrakeStep": 0, "EmergencyReq": 0, "BECU1_STATUS.SpeedEst": 20.0, "BECU2_STATUS.SpeedEst": 20.0,
              "TargetStopValid": 1, "TargetStopPos": 300.0}
    out, v, x = {}, 20.0, 0.0
    for k in range(300):
        values["BECU1_STATUS.SpeedEst"] = values["BECU2_STATUS.SpeedEst"] = v
        out = bcu.step(k * 10_000, RxTable.received(values, k * 10_000))
        v_next = v - out["TargetDecel"] * 0.01
        x, v = x + 0.005 * (v + v_next), v_next
    assert stopping.out.state == StopState.FOLLOWING and out["Mode"] == BcuMode.SERVICE
    assert out["TargetDecel"] == pytest.approx(20.0 ** 2 / (2 * 300.0), rel=0.1)
    assert stopping.controller.odometer.position(300 * 10_000) == pytest.approx(x, abs=0.3)
    out = bcu.step(3_000_000, RxTable.received({**values, "EmergencyReq": 1}, 3_000_000))
    assert out["Mode"] == BcuMode.EMERGENCY and stopping.out.state == StopState.OFF
    assert out["TargetDecel"] == 1.3


def test_bcu_without_target_does_not_brake():
    stopping = StoppingDemand(StoppingParams(method="adaptive_diff"))
    bcu = Bcu(2, sources=[stopping])
    values = {"BrakeStep": 0, "EmergencyReq": 0, "BECU1_STATUS.SpeedEst": 20.0, "BECU2_STATUS.SpeedEst": 20.0,
              "TargetStopValid": 0, "TargetStopPos": 0.0}
    out = {}
    for k in range(100):
        out = bcu.step(k * 10_000, RxTable.received(values, k * 10_000))
    assert out["Mode"] == BcuMode.RELEASED and out["TargetDecel"] == 0.0
    assert stopping.out.state == StopState.OFF


def rx_becu(t_us, **kw):
    """The BECU's inputs, received at t_us."""
    base = {"AxleSpeed": 25 / 0.46, "CylPressure": 0.0, "AccelLong": 0.0, "TargetDecel": 1.0,
            "Mode": 1, "EmergencyActive": 0}
    base.update(kw)
    return RxTable.received(base, t_us)


def test_becu_fills_towards_the_setpoint_for_the_demand():
    becu = Becu()
    out = becu.step(0, rx_becu(0))
    # m a r / alpha + preload = 40000*1.0*0.46/0.08 + 30e3
    assert out["CylPressureSet"] == pytest.approx(260e3)
    assert out["ValveCmd"] > 0 and out["WspValve"] == Wsp.FILL
    out = becu.step(10_000, rx_becu(10_000, CylPressure=300e3))
    assert out["ValveCmd"] < 0                                  # over pressure: vent through the EP valve


def test_becu_vents_on_slip_and_freezes_its_integrator():
    becu = Becu()
    becu.step(0, rx_becu(0))
    i_before = becu.pressure_pi.i
    out = becu.step(10_000, rx_becu(10_000, AxleSpeed=20 / 0.46, AccelLong=-1.0))   # 5 m/s slip
    assert out["WspValve"] == Wsp.VENT and out["WspActive"] == 1 and out["ValveCmd"] == 0.0
    assert becu.pressure_pi.i == i_before


def test_becu_treats_missing_inputs_safely():
    becu = Becu()
    out = becu.step(0, rx_becu(0, AxleSpeed=math.nan, TargetDecel=math.inf))
    assert out["InputMissing"] == 1
    assert all(math.isfinite(v) for v in out.values())


def test_bcu_steps_and_emergency():
    bcu = Bcu(2)
    values = {"BrakeStep": 7, "EmergencyReq": 0, "BECU1_STATUS.SpeedEst": 20.0,
              "BECU2_STATUS.SpeedEst": math.nan}                  # car 2 not heard from
    out = {}
    for k in range(200):                                  # 2 s: the jerk limit lets the target reach 1.0
        out = bcu.step(k * 10_000, RxTable.received(values, k * 10_000))
    assert out["TargetDecel"] == pytest.approx(1.0) and out["Mode"] == BcuMode.SERVICE
    assert out["CarsSilent"] == 0b10 and out["TrainSpeedEst"] == 20.0
    out = bcu.step(2_000_000, RxTable.received({**values, "EmergencyReq": 1}, 2_000_000))
    assert out["Mode"] == BcuMode.EMERGENCY and out["EmergencyActive"] == 1 and out["TargetDecel"] == 1.3


def test_bcu_integrates_the_driver_brake_valve_a_plc_sets():
    """DESK_CMD.BrakeValve (seed 002 §VII): V raises the demand at the valve's service rate, IV holds it,
    II lowers it; NONE is the brake step alone."""
    bcu = Bcu(1)
    rate = bcu.p.brake_valve.service_rate_mps3
    base = {"BrakeStep": 0, "EmergencyReq": 0, "BECU1_STATUS.SpeedEst": 20.0}
    t, out = 0, {}
    for position, seconds in ((5, 2.0), (4, 1.0), (2, 1.0)):     # V 2 s, IV 1 s, II 1 s
        for _ in range(round(seconds * 100)):
            out = bcu.step(t, RxTable.received({**base, "BrakeValve": position}, t))
            t += 10_000
        if position == 5:
            assert out["Mode"] == BcuMode.SERVICE
            assert out["TargetDecel"] == pytest.approx(2.0 * rate, abs=0.01)
        if position == 4:
            assert out["TargetDecel"] == pytest.approx(2.0 * rate, abs=0.01)
    assert out["TargetDecel"] == pytest.approx(1.0 * rate, abs=0.01)
    out = bcu.step(t, RxTable.received({**base, "BrakeValve": 0}, t))   # NONE: the valve is not used
    assert bcu.valve.demand == 0.0 and out["Mode"] == BcuMode.RELEASED


def test_bcu_brakes_when_the_plc_setting_the_valve_falls_silent():
    bcu = Bcu(1)
    base = {"BrakeStep": 0, "EmergencyReq": 0, "BECU1_STATUS.SpeedEst": 20.0}
    out = bcu.step(0, RxTable.received(base, 0))                 # never received: not used, no brake
    assert out["TargetDecel"] == 0.0 and out["Mode"] == BcuMode.RELEASED
    rx = RxTable.received({**base, "BrakeValve": 4}, 0)            # IV, last heard at 0
    for k in range(1, 101):                                       # 1 s: silent after 0.3 s
        rx.receive(base, k * 10_000)                              # the desk and the car still heard from
        out = bcu.step(k * 10_000, rx)
    assert out["TargetDecel"] > 0.0 and out["Mode"] == BcuMode.SERVICE
    rx.receive({**base, "BrakeValve": 9}, 1_010_000)
    out = bcu.step(1_010_000, rx)
    assert bcu.valve.demand > 0.1                                  # not a position: V
