"""Precise stopping at a target point (seed 002, issue #5 item 3, issue 43): mode logic, the driver's brake
valve, the search's decisions, the odometer, the curve and its fluctuation KPIs, the reproduction's
verdicts, and seeded randomized lockstep runs of scenarios/precise_stop.toml for each method.

The randomized runs vary what the BCU does not know (issue #5 acceptance): train mass ±15 % (the BECUs'
inverse brake model assumes the nominal 40 t), gradient ±5 ‰ ([track] gradient), pad friction ±15 % (as the
brake torque gain [plant] brake_gain_Nm_per_Pa = μ_pad × clamp force per Pa × friction radius, which
scales with μ_pad; the BECUs assume the nominal gain); the stop point lies 1500 m ahead as in the paper's
test (§VII).  The stop error is judged on the plant's truth.  `make test` runs one run per method;
`make test-slow` the 20-run table.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from firmware_py.brake_valve import BrakeValve, BrakeValveParams, ValvePosition
from firmware_py.stopping import (
    AdaptiveSearch,
    Curve,
    Odometer,
    StoppingController,
    StoppingParams,
    StopState,
    braked_path,
    braking_curve,
    search_step,
    step_position,
    stop_state_transition,
)
from hil.studies.precise_stop.kpis import curve_fluctuations
from hil.studies.precise_stop.reproduce import (
    GOAL_DIFF_FACTOR,
    GOAL_P95_M,
    METHODS,
    NO_BALISES,
    run_campaign,
    table,
    table_lines,
    verdicts,
)

ROOT = Path(__file__).resolve().parents[3]
SCENARIO = ROOT / "scenarios" / "precise_stop.toml"

S = StopState
V = ValvePosition


# ---------------------------------------------------------------------------------------- mode logic
@pytest.mark.parametrize("state, kw, expected", [
    (S.OFF, dict(target_valid=False), S.OFF),
    (S.OFF, dict(), S.ARMED),
    (S.OFF, dict(curve_reached=True), S.FOLLOWING),
    (S.OFF, dict(standstill=True), S.OFF),                      # brake-only: a standing train stays
    (S.OFF, dict(new_target=True, standstill=True), S.OFF),
    (S.ARMED, dict(), S.ARMED),
    (S.ARMED, dict(curve_reached=True), S.FOLLOWING),
    (S.ARMED, dict(emergency=True, curve_reached=True), S.OFF),
    (S.FOLLOWING, dict(curve_reached=True), S.FOLLOWING),
    (S.FOLLOWING, dict(), S.FOLLOWING),                          # once on the curve, stay on it
    (S.FOLLOWING, dict(standstill=True), S.STOPPED),
    (S.FOLLOWING, dict(target_valid=False), S.OFF),
    (S.FOLLOWING, dict(emergency=True), S.OFF),
    (S.FOLLOWING, dict(new_target=True), S.ARMED),              # a new, farther target: coast again
    (S.FOLLOWING, dict(new_target=True, curve_reached=True), S.FOLLOWING),
    (S.STOPPED, dict(standstill=True), S.STOPPED),
    (S.STOPPED, dict(), S.STOPPED),                              # holding brake until the target changes
    (S.STOPPED, dict(new_target=True), S.ARMED),
    (S.STOPPED, dict(target_valid=False, standstill=True), S.OFF),
])
def test_stop_state_transition_table(state, kw, expected):
    args = dict(target_valid=True, new_target=False, emergency=False, standstill=False, curve_reached=False)
    args.update(kw)
    assert stop_state_transition(state, **args) == expected


@pytest.mark.parametrize("direction, q_now, q_before, expected", [
    (1, 5.0, 6.0, (1, True)),          # improved: repeat the work step
    (-1, 5.0, 6.0, (-1, True)),
    (1, 6.1, 6.0, (1, True)),          # ΔQ within δ = 0.2: not deteriorated, repeat
    (1, 6.5, 6.0, (-1, True)),         # deteriorated by more than δ: the opposite step
    (-1, 6.5, 6.0, (1, True)),
    (1, 0.5, 0.4, (1, False)),         # inside the insensitivity zone (1 m): lap, direction kept
    (1, 0.9, 0.1, (-1, False)),        # ... the direction still learns from ΔQ
])
def test_search_step_table(direction, q_now, q_before, expected):
    assert search_step(direction, q_now, q_before, threshold=0.2, dead_zone=1.0) == expected


@pytest.mark.parametrize("direction, move, k, expected", [
    (1, True, 0, V.SERVICE),           # a work step: V (brake harder) ...
    (1, True, 4, V.SERVICE),
    (1, True, 5, V.LAP),               # ... for step_scans = 5 scans, then IV (lap) to the period's end
    (1, True, 14, V.LAP),
    (-1, True, 0, V.RELEASE),          # the opposite step: II (release)
    (-1, True, 5, V.LAP),
    (1, False, 0, V.LAP),              # inside the insensitivity zone: lap all period
    (-1, False, 3, V.LAP),
])
def test_step_position_table(direction, move, k, expected):
    assert step_position(direction, move, k, step_scans=5) == expected


# --------------------------------------------------------------------------------- driver's brake valve
@pytest.mark.parametrize("demand0, position, dt, expected", [
    (0.0, V.SERVICE, 1.0, 0.2),        # V: up at the service rate
    (0.5, V.SERVICE, 0.1, 0.52),
    (0.95, V.SERVICE, 1.0, 1.0),       # ... clipped at full service
    (0.5, V.LAP, 10.0, 0.5),           # IV: held
    (0.5, V.RELEASE, 1.0, 0.4),        # II: down at the release rate
    (0.05, V.RELEASE, 1.0, 0.0),       # ... clipped at 0
    (0.5, 3, 1.0, 0.5),                # not a position the PLC uses: held (lap)
    (0.5, 5.0, 1.0, 0.7),              # a position decoded as a float (a CAN signal) is the same position
    (0.5, V.SERVICE, math.nan, 0.5),   # a bad time step changes nothing
    (0.5, V.SERVICE, -1.0, 0.5),
])
def test_brake_valve_table(demand0, position, dt, expected):
    valve = BrakeValve(BrakeValveParams(service_rate_mps3=0.2, release_rate_mps3=0.1, max_decel_mps2=1.0),
                       demand0)
    assert valve.step(dt, position) == pytest.approx(expected)
    assert valve.demand == pytest.approx(expected)


def test_brake_valve_integrates_the_same_positions_to_the_same_demand_at_any_cycle():
    """The BCU (10 ms) and a PLC model of the valve (100 ms scans) turn the same positions into the same
    demand: the search's own model of what it applied is the BCU's command."""
    p = BrakeValveParams()
    positions = [V.SERVICE] * 7 + [V.LAP] * 5 + [V.RELEASE] * 3 + [V.SERVICE] * 40
    bcu, plc = BrakeValve(p), BrakeValve(p)
    for pos in positions:
        for _ in range(10):
            bcu.step(0.01, pos)
        plc.step(0.1, pos)
        assert bcu.demand == pytest.approx(plc.demand, abs=1e-9)
    assert plc.demand == p.max_decel_mps2


# ------------------------------------------------------------------------------- the search's decisions
CURVE = Curve(t0_us=0, x0_m=0.0, v0_mps=20.0, d0_m=400.0, a_mps2=0.5)


def on_curve(now_us: int, ahead_m: float = 0.0) -> tuple[float, float, float]:
    """(S, V, a) of a train `ahead_m` ahead of the curve, at the curve's speed and deceleration."""
    s_th, v_th, a_th = CURVE.state(now_us)
    return s_th + ahead_m, v_th, a_th


def test_search_applies_the_brake_to_the_curve_then_searches():
    """V until the valve's demand reaches a_c (0.5 m/s² at 0.3 m/s³: 16 scans of 100 ms), then work
    periods of 15 scans: 5 scans of V or II, then IV."""
    p = StoppingParams(method="adaptive")
    search = AdaptiveSearch(p, CURVE, diff=False)
    out = [search.scan(k * p.scan_us, *on_curve(k * p.scan_us, ahead_m=5.0)) for k in range(16)]
    assert out == [V.SERVICE] * 16
    assert search.model.demand == pytest.approx(0.48)          # a_c to within one scan of the rate
    out = [search.scan(k * p.scan_us, *on_curve(k * p.scan_us, ahead_m=5.0)) for k in range(16, 16 + 15)]
    assert out == [V.SERVICE] * 5 + [V.LAP] * 10               # Q = 5 m ≥ 2 m: the first work step
    assert search.model.demand == pytest.approx(0.63)
    assert search.scan(31 * p.scan_us, math.nan, 20.0, 0.5) == V.LAP and search.scans == 15   # no measurement
    assert search.quality == pytest.approx(5.0)


def run_search(diff: bool, ahead: list[float]) -> list[ValvePosition]:
    """The work steps a search takes when Q (a train `ahead[n]` metres ahead of the curve at work period n,
    on its speed and deceleration) is as given: the first position of each period."""
    p = StoppingParams(method="adaptive_diff" if diff else "adaptive")
    search = AdaptiveSearch(p, CURVE, diff=diff)
    search.applying = False
    steps = []
    for n, e in enumerate(ahead):
        for k in range(p.work_scans):
            now = (n * p.work_scans + k) * p.scan_us
            pos = search.scan(now, *on_curve(now, e))
            if k == 0:
                steps.append(pos)
    return steps


@pytest.mark.parametrize("ahead, expected", [
    ([5.0, 4.0, 3.0], [V.SERVICE, V.SERVICE, V.SERVICE]),          # improving: the step is repeated
    ([5.0, 6.0, 7.0], [V.SERVICE, V.RELEASE, V.SERVICE]),          # deteriorating: the opposite step
    ([5.0, 5.2, 5.4], [V.SERVICE, V.SERVICE, V.SERVICE]),          # within δ = 0.3 m: not deteriorated
    ([5.0, 1.0, -1.5, 3.0], [V.SERVICE, V.LAP, V.LAP, V.SERVICE]),  # insensitivity zone (2 m): lap
    ([-5.0, -6.0, -4.0], [V.SERVICE, V.RELEASE, V.RELEASE]),        # Q = |e|: the sign is found by trial
])
def test_plain_search_decisions_table(ahead, expected):
    assert run_search(False, ahead) == expected


def test_differentiation_unit_predicts_the_deviation_and_judges_against_its_trend():
    """Q = |e + T_d·ė + T_d²/2·ë| (T_d = 12 s) while neither the train nor the curve stops within T_d; a
    train at the curve's position but 0.5 m/s fast is predicted 6 m ahead although e = 0 now; and the
    unit expects the deviation's own drift over the work period, so a drift is not a step's failure."""
    p = StoppingParams(method="adaptive_diff")
    search = AdaptiveSearch(p, CURVE, diff=True)
    s, v, a = on_curve(5_000_000)
    td = p.diff_horizon_s
    for de, dv, da in ((0.0, 0.0, 0.0), (3.0, 0.0, 0.0), (0.0, 0.5, 0.0), (0.0, 0.0, -0.02),
                       (1.0, -0.2, 0.01)):
        expected = de + td * dv + 0.5 * td * td * (-da)
        assert search.predicted_deviation(5_000_000, s + de, v + dv, a + da) == pytest.approx(expected)
    # at 2 m/s braking at 0.5 m/s² the train stops in 4 s (4 m): the prediction ends at its standstill
    assert braked_path(2.0, 0.5, 12.0) == pytest.approx(4.0)
    assert braked_path(20.0, 0.0, 2.0) == pytest.approx(40.0)
    # a train 0.5 m/s fast on the curve's deceleration drifts 0.5 m/s ahead: after one work period (1.5 s)
    # the unit expects Q 0.75 m larger, the plain search the same Q
    q = abs(search.predicted_deviation(5_000_000, s, v + 0.5, a))
    assert search.expected_quality(5_000_000, s, v + 0.5, a, q) == pytest.approx(q + 0.75)
    plain = AdaptiveSearch(StoppingParams(method="adaptive"), CURVE, diff=False)
    assert plain.expected_quality(5_000_000, s, v + 0.5, a, 3.0) == 3.0


def test_differentiation_unit_repeats_a_step_that_beat_the_drift():
    """The train drifts ahead of the curve (too little brake): the plain search sees Q grow and alternates
    V and II; the unit sees that V did better than the drift it expected and keeps braking harder."""
    p = StoppingParams(method="adaptive_diff")
    tw = p.work_scans * p.scan_us * 1e-6
    decisions = {}
    for diff in (False, True):
        search = AdaptiveSearch(p, CURVE, diff=diff)
        search.applying = False
        steps, e, de, da = [], 3.0, 0.5, -0.05             # ahead, faster, braking 0.05 m/s² too little
        for n in range(4):
            for k in range(p.work_scans):
                now = (n * p.work_scans + k) * p.scan_us
                s_th, v_th, a_th = CURVE.state(now)
                pos = search.scan(now, s_th + e, v_th + de, a_th + da)
                if k == 0:
                    steps.append(pos)
            e, de = e + de * tw, de - da * tw                # the deviation's drift over the period ...
            # ... and the step's effect on the deceleration
            da += 0.075 if steps[-1] == V.SERVICE else -0.075 if steps[-1] == V.RELEASE else 0.0
        decisions[diff] = steps
    assert decisions[False] == [V.SERVICE, V.RELEASE, V.SERVICE, V.RELEASE]
    assert decisions[True][:3] == [V.SERVICE, V.SERVICE, V.SERVICE]


def test_controller_command_is_the_valve_integral_of_the_positions_it_chose():
    """What a PLC would send (the positions, one per 100 ms scan) through the BCU's BrakeValve gives the
    controller's own command every 10 ms cycle: railhil's search and a PLC running it stop alike."""
    p = StoppingParams(method="adaptive_diff", start_position_m=0.0)
    ctl = StoppingController(p)
    bcu_valve = BrakeValve(p.valve)
    x, v = 0.0, 20.0
    for k in range(3000):
        now = k * 10_000
        ctl.odometer.sample(now, v)
        out = ctl.step(now, 0.01, target_valid=True, target_m=400.0, emergency=False, standstill=False,
                       train_speed_mps=v)
        assert out.valve == ctl.valve_position
        if out.state == StopState.FOLLOWING:
            assert bcu_valve.step(0.01, out.valve) == pytest.approx(out.command_mps2, abs=1e-9)
        v = max(v - 0.9 * out.command_mps2 * 0.01, 0.0)
        x += v * 0.01
    assert ctl.state == StopState.FOLLOWING and out.command_mps2 > 0.0
    assert StoppingController(StoppingParams(method="pi")).valve_position is None


# ----------------------------------------------------------------------------------------- odometer
def test_odometer_integrates_a_braking_train_exactly_up_to_its_latency():
    """A train passing x0 at t = 0 at 20 m/s and braking at 0.5 m/s² from t = 2 s, speed samples every
    50 ms that describe the train 5 ms before they arrive: the odometer's position equals the kinematics."""
    lat = 0.005

    def kin(t):                                     # exact position [m] and speed [m/s]
        if t <= 2.0:
            return 100.0 + 20.0 * t, 20.0
        tb = min(t - 2.0, 40.0)
        return 140.0 + 20.0 * tb - 0.25 * tb * tb, 20.0 - 0.5 * tb

    odo = Odometer(100.0, 0, lat)
    assert odo.position(0) == 100.0
    worst = 0.0
    for k in range(1, 900):
        t_rx_us = k * 50_000 + 1_300
        odo.sample(t_rx_us, kin(t_rx_us * 1e-6 - lat)[1])
        for now_us in (t_rx_us, t_rx_us + 30_000):
            worst = max(worst, abs(odo.position(now_us) - kin(now_us * 1e-6)[0]))
    # trapezoid error of a piecewise-linear speed: at most a·dt²/8 per kink, plus the extrapolation's a·h²/2
    assert worst < 0.5 * (0.035 ** 2) + 0.01


def test_odometer_anchor_on_a_balise_removes_the_drift():
    """A speed estimate 1 % high makes the odometer run ahead; a balise passed at a known time puts it back
    on the balise's position, and the drift starts again from there only."""
    odo = Odometer(0.0, 0, latency_s=0.0)
    v_true = 20.0
    for k in range(0, 101):                              # 10 s of samples every 0.1 s, 1 % high
        odo.sample(k * 100_000, v_true * 1.01)
    assert odo.position(10_000_000) == pytest.approx(202.0)       # 2 m ahead of the truth (200 m)
    shift = odo.anchor(190.0, 9_500_000)                 # the balise at 190 m was passed at 9.5 s
    assert shift == pytest.approx(190.0 - 20.2 * 9.5)
    assert odo.position(9_500_000) == pytest.approx(190.0)
    assert odo.position(10_000_000) == pytest.approx(190.0 + 20.2 * 0.5)
    assert odo.anchor(float("nan"), 9_600_000) == 0.0 and odo.position(9_500_000) == pytest.approx(190.0)
    fresh = Odometer(0.0, 0, latency_s=0.0)              # before any speed sample: a new reference point
    fresh.anchor(50.0, 2_000_000)
    fresh.sample(3_000_000, 10.0)
    assert fresh.position(3_000_000) == pytest.approx(60.0)


def test_balise_reader_interpolates_the_passage_and_reports_the_last_balise():
    from hil.runtime.plant_node import BaliseReader

    btm = BaliseReader((-10.0, 100.0, 100.5, 300.0), x0_m=0.0)  # the one behind the start is not reported
    out: dict[str, float] = {}
    btm.after_step(0, 1000, 99.0, out)
    assert out == {}                                      # nothing passed yet: the frame says BaliseValid 0
    btm.after_step(1000, 1000, 101.0, out)                # 99 → 101 m: 100 m at 1.5 ms, 100.5 m at 1.75 ms
    assert out["PLANT_BTM.BalisePos"] == 100.5 and out["PLANT_BTM.BaliseCount"] == 2
    assert out["PLANT_BTM.PassageAge"] == pytest.approx((2000 - 1750) * 1e-6)   # 100.5 passed at 1.75 ms
    btm.after_step(2000, 1000, 102.0, out)
    assert out["PLANT_BTM.PassageAge"] == pytest.approx((3000 - 1750) * 1e-6)
    assert out["PLANT_BTM.BaliseValid"] == 1


def test_odometer_ignores_stale_and_non_finite_samples():
    odo = Odometer(0.0, 0, 0.0)
    odo.sample(100_000, 10.0)
    x = odo.position(100_000)
    odo.sample(100_000, 50.0)                        # same reception time: not a new sample
    odo.sample(150_000, math.nan)
    assert odo.position(100_000) == x and odo.v == 10.0


def test_curve_ends_at_the_target():
    c = Curve(t0_us=1_000_000, x0_m=10.0, v0_mps=20.0, d0_m=400.0, a_mps2=0.5)
    s_end, v_end = c.at(1_000_000 + 40_000_000)
    assert s_end == pytest.approx(400.0) and v_end == pytest.approx(0.0)
    assert c.at(1_000_000 + 60_000_000) == (400.0, 0.0)
    assert c.at(1_000_000 + 10_000_000) == pytest.approx((175.0, 15.0))
    assert c.state(0) == pytest.approx((-20.0, 20.0, 0.0))        # before its start the curve coasts
    assert c.state(1_000_000 + 10_000_000) == pytest.approx((175.0, 15.0, 0.5))
    assert c.state(1_000_000 + 41_000_000) == (400.0, 0.0, 0.0)


def test_braking_curve_leads_by_half_the_valve_application():
    """The valve needs a_c / service rate to apply (2 s for 0.6 m/s² at 0.3 m/s³): the curve starts 1 s
    after the valve goes to V, 1 s of travel on, and still ends at the target; pi starts at once."""
    c = braking_curve(5_000_000, 100.0, 25.0, 545.0, StoppingParams(method="adaptive"))
    assert c.t0_us == 6_000_000 and c.x0_m == pytest.approx(125.0) and c.d0_m == pytest.approx(520.0)
    assert c.a_mps2 == pytest.approx(25.0 ** 2 / (2 * 520.0))
    assert c.x0_m + c.state(c.end_us)[0] == pytest.approx(645.0)
    pi = braking_curve(5_000_000, 100.0, 25.0, 545.0, StoppingParams(method="pi"))
    assert pi.t0_us == 5_000_000 and pi.d0_m == pytest.approx(545.0)


def test_curve_fluctuations_of_a_train_on_the_curve_and_off_it():
    """A train exactly on the BCU's curve (BCU_STOP.RefSpeed every 100 ms) has no fluctuation; one 3 m ahead
    and 0.2 m/s fast has S 3 m, V 0.2 m/s; the deceleration counts from the brake's application on."""
    from hil.scenario import load_scenario

    sc = load_scenario(SCENARIO, sets=["precise_stop.method=adaptive_diff"])
    a_c, v0, t0, lead = 0.6, 25.0, 30.0, 1.0
    t = np.arange(0.0, 80.0, 0.01)
    tau = np.clip(t - t0, 0.0, v0 / a_c)
    x = 1500.0 - (v0 - a_c * tau) ** 2 / (2 * a_c) - np.where(t < t0, v0 * (t0 - t), 0.0)
    v = np.where(t < t0, v0, v0 - a_c * tau)
    cols = {"t_s": t, "x_m_1": x, "v_mps_1": v}
    decel = np.where((t >= t0) & (v > 0), a_c, 0.0)
    for i in range(1, sc.train.cars + 1):
        cols[f"a_mps2_{i}"] = -decel
    tr = np.arange(t0 - lead, 80.0, 0.1)
    vr = np.where(tr < t0, v0, np.clip(v0 - a_c * (tr - t0), 0.0, None))
    ref, to_go = (tr, vr), (tr, np.interp(tr, t, 1500.0 - x))
    i_stop = int(np.flatnonzero(v <= 0)[0])
    k = curve_fluctuations(sc, cols, ref, to_go, i_stop)
    assert k["curve_a_mps2"] == pytest.approx(a_c, rel=1e-6)
    assert k["curve_s_dev_max_m"] < 0.05 and k["curve_a_dev_max_mps2"] < 0.01
    assert k["curve_v_dev_max_mps"] < 0.05           # RefSpeed is sampled every 100 ms: the curve's corners
    off = dict(cols, x_m_1=x + 3.0, v_mps_1=v + 0.2)
    k = curve_fluctuations(sc, off, ref, to_go, i_stop)
    assert k["curve_s_dev_max_m"] == pytest.approx(3.0, abs=0.01)
    assert k["curve_v_dev_max_mps"] == pytest.approx(0.2, abs=0.01)
    no_curve = curve_fluctuations(sc, cols, (np.zeros(0), np.zeros(0)), to_go, i_stop)
    assert no_curve["curve_s_dev_max_m"] is None


# ------------------------------------------------------------------- controller on an ideal train
def ideal_stop(method: str, decel_gain: float, distance_m: float = 400.0, v0: float = 20.0,
               lag_s: float = 0.3) -> tuple[float, StoppingController]:
    """The controller alone on a point-mass train whose deceleration follows gain × command through a
    first-order lag (the brake): stop position − target [m]."""
    p = StoppingParams(method=method, start_position_m=0.0)
    ctl = StoppingController(p)
    x, v, a, dt_us = 0.0, v0, 0.0, 10_000
    for k in range(20_000):
        now = k * dt_us
        ctl.odometer.sample(now, v)
        out = ctl.step(now, dt_us * 1e-6, target_valid=True, target_m=distance_m, emergency=False,
                       standstill=v < 0.1, train_speed_mps=v)
        if out.state == StopState.STOPPED:
            break
        a += (decel_gain * out.command_mps2 - a) * (1.0 - math.exp(-dt_us * 1e-6 / lag_s))
        v_next = max(v - a * dt_us * 1e-6, 0.0)
        x += 0.5 * (v + v_next) * dt_us * 1e-6
        v = v_next
    return x - distance_m, ctl


# the worst |stop error| each method must keep on the ideal train (400 m ahead at 20 m/s): the plain search
# misses like the paper's (§VII: ±25–45 m, S ±100 m) and worse; with the unit, near the paper's ±2–7 m
IDEAL_BOUND_M = {"adaptive": 200.0, "adaptive_diff": 7.0, "pi": 0.3}


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("gain", [0.85, 1.0, 1.15])
def test_every_method_stops_near_the_point_on_an_ideal_train(method, gain):
    err, ctl = ideal_stop(method, gain)
    assert ctl.state == StopState.STOPPED
    assert abs(err) < IDEAL_BOUND_M[method]


def test_differentiation_unit_is_five_times_more_precise_and_pi_better_still():
    mean = {m: np.mean([abs(ideal_stop(m, g, d, v0)[0]) for g in (0.85, 1.0, 1.15)
                        for d, v0 in ((400.0, 25.0), (1000.0, 25.0))]) for m in METHODS}
    assert mean["pi"] < mean["adaptive_diff"] <= mean["adaptive"] / GOAL_DIFF_FACTOR


# ------------------------------------------------------------------------- randomized lockstep runs
# the campaign is the study's reproduction (railhil reproduce precise-stop): the same code runs here


@pytest.mark.parametrize("plain, diff, best, expected", [
    (40.0, 5.0, 0.2, [True, True]),
    (20.0, 5.0, 0.2, [False, True]),            # the unit only 4x better
    (40.0, 5.0, 0.4, [True, False]),            # the baseline misses the platform goal
])
def test_reproduction_verdicts(plain, diff, best, expected):
    t = {m: {"p95": p} for m, p in (("adaptive", plain), ("adaptive_diff", diff), ("pi", best))}
    assert [ok for _, ok in verdicts(t)] == expected
    assert [ok for _, ok in verdicts({"adaptive_diff": {"p95": 1.0}})] == [None, None]   # not judged


def test_reproduction_exits_1_when_a_verdict_fails(tmp_path, monkeypatch, capsys):
    """`railhil reproduce precise-stop` exits 1 when the unit is less than 5 times better (here 4x), 0 with
    --exit-zero; the table says NOT met either way."""
    from hil.cli.main import main
    from hil.studies.precise_stop import reproduce

    def fake(out, methods, runs, distance_m, jobs=2, progress=False):
        err = {"adaptive": 20.0, "adaptive_diff": 5.0, "pi": 0.1, NO_BALISES: 0.2}
        return [{"method": m, "k": 0, "stop_error_m": err[m], "stopped": True, "jerk_p95_mps3": 0.2,
                 "curve_s_dev_max_m": err[m], "curve_v_dev_max_mps": 1.0, "curve_a_dev_max_mps2": None}
                for m in methods]
    monkeypatch.setattr(reproduce, "run_campaign", fake)
    args = ["reproduce", "precise-stop", "--runs", "1", "--out", str(tmp_path), "-q"]
    assert main(args) == 1
    assert "4.0x more precise, goal >= 5x (paper 5-10x) NOT met" in capsys.readouterr().out
    assert main(args + ["--exit-zero"]) == 0


@pytest.mark.timeout(900)                 # three lockstep runs on two workers: ~20 s, more on a loaded host
def test_precise_stop_short_runs_every_method(tmp_path):
    """One randomized run per method of the paper's test (the stop point 1500 m ahead of a train at 90 km/h;
    a lockstep run takes 5-10 s of wall time, so `make test` has one per method and `make test-slow` the
    table): each stops within a sanity bound, and the KPIs, the fluctuations about the curve among them,
    are in kpis.json."""
    results = run_campaign(tmp_path, METHODS, 1)
    print("\n" + "\n".join(table_lines(table(results))))
    bound = {"adaptive": 150.0, "adaptive_diff": 7.0, "pi": 0.3}
    for r in results:
        assert r["stopped"] and r["stop_error_m"] is not None
        assert abs(r["stop_error_m"]) < bound[r["method"]], r
        assert 0.0 < r["jerk_p95_mps3"] < 5.0
        assert r["curve_a_mps2"] == pytest.approx(0.6, rel=0.01)
        assert r["curve_s_dev_max_m"] >= abs(r["stop_error_m"]) - 0.05       # the stop is on the curve's end
        assert 0.0 < r["curve_v_dev_max_mps"] < 5.0 and 0.0 < r["curve_a_dev_max_mps2"] < 1.0


@pytest.mark.slow
@pytest.mark.timeout(7200)                # 80 lockstep runs on two workers: ~4 min on a 2-core host
def test_precise_stop_randomized_campaign(tmp_path):
    """Issue 43 acceptance: 20 seeded randomized runs per method of the paper's test (stop point 1500 m
    ahead, balises 200 m and 25 m before it; the PI once more without them).  Prints the table; asserts
    the verdicts: the differentiation unit ≥ 5 times more precise than the plain search (p95), and the goal
    (p95 |error| ≤ 0.3 m) for the best method, the PI; the unit's p95 within the paper's ±2–7 m."""
    results = run_campaign(tmp_path, METHODS + (NO_BALISES,), 20)
    t = table(results)
    print("\n" + "\n".join(table_lines(t)))
    assert all(r["stopped"] for r in results)
    best = min(t, key=lambda m: t[m]["p95"])
    assert best in ("pi", NO_BALISES)
    assert t["pi"]["p95"] <= GOAL_P95_M
    assert all(ok for _, ok in verdicts(t))
    assert t["adaptive_diff"]["p95"] <= 7.0
