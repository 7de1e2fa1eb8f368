"""Pneumatic brake: EP/WSP valves (eq. (5) seed 001) and the pressure → torque hysteresis (eq. (10a))."""

import numpy as np
import pytest

from plant_sim.brake import (
    WSP_FILL,
    WSP_HOLD,
    WSP_VENT,
    cylinder_pressure_scalar,
    cylinder_pressure_step,
    hysteresis_torque,
    hysteresis_torque_scalar,
    sanitize_valve_cmd,
    sanitize_wsp_valve,
    valve_table,
)
from plant_sim.params import BrakeParams

BP = BrakeParams()
A = BP.alpha_squeeze_Nm_per_Pa              # 0.08 N·m/Pa on both lines


def squeeze(p):
    return A * p + BP.beta_squeeze_Nm        # 0 at 30 kPa


def release(p):
    return A * p + BP.beta_release_Nm        # 0 at 10 kPa


# Keyword table in the manner of openpilot's test_longcontrol: the case, the previous torque, the
# pressure now, and the torque the hysteresis must give.
HYSTERESIS_CASES = [
    dict(case="rest: no pressure, no torque", tau_prev=0.0, p=0.0, tau=0.0),
    dict(case="below the return-spring preload", tau_prev=0.0, p=25e3, tau=0.0),
    dict(case="filling: on the squeeze line", tau_prev=0.0, p=100e3, tau=squeeze(100e3)),
    dict(case="filling further: rises on the squeeze line", tau_prev=squeeze(100e3), p=200e3,
         tau=squeeze(200e3)),
    dict(case="venting 10 kPa from the squeeze line: holds", tau_prev=squeeze(200e3), p=190e3,
         tau=squeeze(200e3)),
    dict(case="venting 20 kPa: reaches the release line", tau_prev=squeeze(200e3), p=180e3,
         tau=squeeze(200e3)),
    dict(case="venting further: falls on the release line", tau_prev=squeeze(200e3), p=150e3,
         tau=release(150e3)),
    dict(case="re-filling from the release line: holds", tau_prev=release(150e3), p=165e3,
         tau=release(150e3)),
    dict(case="re-filling 20 kPa: back on the squeeze line", tau_prev=release(150e3), p=170e3,
         tau=squeeze(170e3)),
    dict(case="venting below 10 kPa: released, never negative", tau_prev=release(15e3), p=5e3, tau=0.0),
    dict(case="vented to zero", tau_prev=300.0, p=0.0, tau=0.0),
    dict(case="full pressure", tau_prev=0.0, p=BP.p_max_Pa, tau=squeeze(BP.p_max_Pa)),
]


@pytest.mark.parametrize("row", HYSTERESIS_CASES, ids=[r["case"] for r in HYSTERESIS_CASES])
def test_hysteresis_table(row):
    assert hysteresis_torque_scalar(row["tau_prev"], row["p"], BP) == pytest.approx(row["tau"], abs=1e-9)
    got = hysteresis_torque(np.array([row["tau_prev"]]), np.array([row["p"]]), BP)
    assert got[0] == pytest.approx(row["tau"], abs=1e-9)


def test_hysteresis_vectorised_over_cars_matches_the_table():
    tau_prev = np.array([r["tau_prev"] for r in HYSTERESIS_CASES])
    p = np.array([r["p"] for r in HYSTERESIS_CASES])
    expected = np.array([r["tau"] for r in HYSTERESIS_CASES])
    assert hysteresis_torque(tau_prev, p, BP) == pytest.approx(expected, abs=1e-9)


def test_hysteresis_loop_over_a_pressure_cycle():
    """Up 0 → 400 kPa and back: torque monotone on each leg, flat for 20 kPa after the turn, never < 0."""
    up = np.linspace(0.0, 400e3, 401)
    down = np.linspace(400e3, 0.0, 401)[1:]
    tau, taus = np.zeros(1), []
    for p in np.concatenate([up, down]):
        tau = hysteresis_torque(tau, np.array([p]), BP)
        taus.append(tau[0])
    taus = np.array(taus)
    assert np.all(taus >= 0.0)
    assert np.all(np.diff(taus[:401]) >= 0.0) and np.all(np.diff(taus[400:]) <= 0.0)
    after_turn = taus[401:420]                      # the first 19 kPa of venting
    assert np.all(after_turn == taus[400])
    assert taus[-1] == 0.0


VALVE_CASES = [
    dict(case="EP fill at full opening", p=100e3, u=1.0, w=WSP_FILL,
         p_next=100e3 + BP.fill_rate_Pa_per_s * 1e-3),
    dict(case="EP half fill", p=100e3, u=0.5, w=WSP_FILL, p_next=100e3 + 0.5 * BP.fill_rate_Pa_per_s * 1e-3),
    dict(case="EP vent", p=100e3, u=-1.0, w=WSP_FILL, p_next=100e3 - BP.vent_rate_Pa_per_s * 1e-3),
    dict(case="EP closed", p=100e3, u=0.0, w=WSP_FILL, p_next=100e3),
    dict(case="WSP hold blocks filling", p=100e3, u=1.0, w=WSP_HOLD, p_next=100e3),
    dict(case="WSP hold blocks venting", p=100e3, u=-1.0, w=WSP_HOLD, p_next=100e3),
    dict(case="WSP vent overrides filling", p=100e3, u=1.0, w=WSP_VENT,
         p_next=100e3 - BP.wsp_vent_rate_Pa_per_s * 1e-3),
    dict(case="no pressure below ambient", p=500.0, u=-1.0, w=WSP_VENT, p_next=0.0),
    dict(case="no pressure above the reservoir", p=BP.p_max_Pa - 10.0, u=1.0, w=WSP_FILL, p_next=BP.p_max_Pa),
]


@pytest.mark.parametrize("row", VALVE_CASES, ids=[r["case"] for r in VALVE_CASES])
def test_valve_table(row):
    got = cylinder_pressure_scalar(row["p"], row["u"], row["w"], valve_table(BP, 1e-3))
    assert got == pytest.approx(row["p_next"], rel=1e-12)
    got = cylinder_pressure_step(np.array([row["p"]]), np.array([row["u"]]), np.array([row["w"]]), 1e-3, BP)
    assert got[0] == pytest.approx(row["p_next"], rel=1e-12)


def test_pressure_step_same_per_car_with_a_kept_table_or_a_0d_dt():
    rng = np.random.default_rng(3)
    p = rng.uniform(0, BP.p_max_Pa, 50)
    u = rng.uniform(-1, 1, 50)
    w = rng.integers(0, 3, 50)
    table = valve_table(BP, 1e-3)
    a = cylinder_pressure_step(p, u, w, 1e-3, BP)
    b = cylinder_pressure_step(p, u, w, np.array(1e-3), BP, table)
    c = [cylinder_pressure_scalar(p_i, u_i, w_i, table)
         for p_i, u_i, w_i in zip(p.tolist(), u.tolist(), w.tolist(), strict=True)]
    assert np.array_equal(a, b) and a.tolist() == c


def test_fill_faster_than_vent_takes_the_other_branch():
    bp = BrakeParams(fill_rate_Pa_per_s=3e6, vent_rate_Pa_per_s=1e6)
    got = cylinder_pressure_step(np.full(2, 1e5), np.array([0.5, -0.5]), np.zeros(2, int), 1e-3, bp)
    assert got == pytest.approx([1e5 + 1.5e3, 1e5 - 0.5e3])


def test_sanitizers_replace_and_count():
    u, n = sanitize_valve_cmd(np.array([np.nan, np.inf, -np.inf, 5.0, -0.3]))
    assert n == 3 and u.tolist() == [0.0, 0.0, 0.0, 1.0, -0.3]
    w, n = sanitize_wsp_valve(np.array([0.0, 1.0, 2.0, 3.0, -1.0, np.nan]))
    assert n == 3 and w.tolist() == [0, 1, 2, 0, 0, 0]
