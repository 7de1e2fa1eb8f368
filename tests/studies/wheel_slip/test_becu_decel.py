"""BECU deceleration control (seed 001 eq. 16), its WSP (§II-C) and the governor in the loop.

Step tests with injected time and signals, the WSP transition table and the scenario keys. The lockstep
runs of scenarios/rg_*.toml against issue #4's acceptance are in tests/studies/wheel_slip/test_wheel_slip.py.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from firmware_py.becu import Becu, BecuParams
from firmware_py.pi import PIParams
from firmware_py.reference_speed import RefMode
from firmware_py.rx import RxTable
from firmware_py.wsp import Wsp, WspParams, wsp_transition
from hil.errors import ScenarioError
from hil.scenario import load_scenario, parse_scenario
from hil.scenario.params import run_params
from hil.studies.wheel_slip.scenario import reference_governor_params

ROOT = Path(__file__).resolve().parents[3]
G = 9.81
PAPER_WSP = WspParams(vent_slip_mps=0.1, vent_slip_per_speed=0.0, hold_fraction=1.0, refill_fraction=1.0)


@pytest.mark.parametrize("state, slip, speed, expected", [
    (Wsp.FILL, 0.09, 30.0, Wsp.FILL),         # stable-slip region: track
    (Wsp.FILL, 0.11, 30.0, Wsp.VENT),         # s > s̄ = 0.1: vent, u = 0
    (Wsp.VENT, 0.105, 30.0, Wsp.VENT),        # still above s̄
    (Wsp.VENT, 0.095, 30.0, Wsp.FILL),        # back in the adhesion region: track again, no hold phase
    (Wsp.VENT, 0.3, 0.5, Wsp.FILL),           # below the minimum speed WSP lets the train stop
])
def test_paper_wsp_transition_table(state, slip, speed, expected):
    assert wsp_transition(state, slip, speed, PAPER_WSP) == expected


def rx(t_us, accel=0.0, pressure=0.0, target=0.0, omega=30.0 / 0.46):
    """The BECU's inputs, received at t_us: every cycle a fresh sensor frame and demand."""
    return RxTable.received({"AxleSpeed": omega, "CylPressure": pressure, "AccelLong": accel,
                             "TargetDecel": target, "Mode": 1, "EmergencyActive": 0}, t_us)


def test_decel_mode_is_eq_16_through_the_shared_pi():
    pi = PIParams(kp=5e5 / G, ki=40e5 / G, out_min=0.0, out_max=450e3)
    becu = Becu(BecuParams(control="decel", decel_pi=pi, wsp=PAPER_WSP, reference=RefMode.LIFTED))
    e = 1.0                                                          # r = 1.0 m/s², measured 0
    out = becu.step(0, rx(0, target=1.0))
    # u = K_P e + K_I ∫e: first cycle integrates one nominal 10 ms cycle
    assert out["CylPressureSet"] == pytest.approx(pi.kp * e + pi.ki * e * 0.01, rel=1e-3)
    out = becu.step(10_000, rx(10_000, target=1.0))
    assert out["CylPressureSet"] == pytest.approx(pi.kp * e + pi.ki * e * 0.02, rel=1e-3)
    # deceleration above the request: the set-point falls
    out2 = becu.step(20_000, rx(20_000, target=1.0, accel=-2.0))
    assert out2["CylPressureSet"] < out["CylPressureSet"]
    assert "GovernorActive" not in out2                  # no governor stage: none of its signals


def test_decel_mode_vents_and_freezes_in_wsp():
    becu = Becu(BecuParams(control="decel", wsp=PAPER_WSP, reference=RefMode.LIFTED))
    for k in range(20):
        becu.step(k * 10_000, rx(k * 10_000, target=1.5, accel=-1.0))
    i_before = becu.decel_pi.i
    # the wheel slows 0.3 m/s below the vehicle: slip above s̄
    out = becu.step(200_000, rx(200_000, target=1.5, accel=-1.0, omega=(becu.v_ref - 0.01 - 0.3) / 0.46))
    assert out["WspValve"] == int(Wsp.VENT) and out["WspActive"] == 1
    assert out["CylPressureSet"] == 0.0 and becu.decel_pi.i == i_before and out["IntegratorSat"] == 1


def test_handover_restarts_from_the_vented_set_point():
    p = BecuParams(control="decel", wsp=PAPER_WSP, reference=RefMode.LIFTED, wsp_resume="handover")
    becu = Becu(p)
    for k in range(50):
        becu.step(k * 10_000, rx(k * 10_000, target=1.5, accel=-1.0))
    held = becu.step(500_000, rx(500_000, target=1.5, accel=-1.0, omega=(becu.v_ref - 0.5) / 0.46))
    assert held["CylPressureSet"] == 0.0
    back = becu.step(510_000, rx(510_000, target=1.5, accel=-1.0, omega=becu.v_ref / 0.46))
    assert back["WspValve"] == int(Wsp.FILL)
    assert 0.0 < back["CylPressureSet"] < 0.01 * 450e3      # bumpless from u = 0, not the frozen value


@pytest.mark.parametrize("bad, match", [
    (dict(control="speed"), "control"),
    (dict(wsp_resume="later"), "wsp_resume"),
])
def test_becu_params_validate(bad, match):
    with pytest.raises(ValueError, match=match):
        BecuParams(**bad)


# ------------------------------------------------------------------------------------- scenario keys
def _scenario(**sections):
    return parse_scenario({"train": {"cars": 1}, **sections}, "test.toml")


@pytest.mark.parametrize("sections, match", [
    (dict(wheel_slip={"governor": True}), "governor = true needs becu.control = 'decel'"),
    (dict(becu={"control": "decel"}, wheel_slip={"governor": True, "band_mps": 0.0}), "wheel_slip.band_mps"),
    (dict(becu={"control": "decel"}, wheel_slip={"governor": True, "slip_max_mps": 0.2},
          plant={"adhesion": "slip_speed"}), "below the adhesion peak"),
    (dict(bcu={"step_decel_mps2": [0.0, 1.0]}), "needs 8 values"),
    (dict(plant={"pressure_model": "hydraulic"}), "plant.pressure_model"),
    (dict(becu={"wsp_vent_slip_mps": 0.1}), "give both"),
    (dict(becu={"wsp_vent_slip_mps": 0.1, "wsp_refill_slip_mps": 0.2}), "above wsp_vent_slip_mps"),
    (dict(sensors={"accel_noise_std_mps2": -1.0}), "sensors.accel_noise_std_mps2"),
    (dict(becu={"wsp_ceiling_release_s": 0.4}), "needs wsp_mode = 'slip'"),
    (dict(becu={"wsp_mode": "slip", "wsp_ceiling_fraction": 1.2}), "becu.wsp_ceiling_fraction"),
])
def test_bad_keys_give_one_line_errors(sections, match):
    with pytest.raises(ScenarioError, match=match) as exc:
        _scenario(**sections)
    assert "\n" not in str(exc.value) and "test.toml" in str(exc.value)


def test_default_scenario_builds_the_foundations_becu():
    sc = load_scenario(ROOT / "scenarios" / "default.toml")
    assert run_params(sc).becu(1) == BecuParams()


def test_slip_wsp_ceiling_keys_reach_the_becu():
    bp = run_params(_scenario(becu={"wsp_mode": "slip", "wsp_ceiling_fraction": 0.85,
                                    "wsp_ceiling_rise_bar_per_s": 0.4, "wsp_ceiling_release_s": 0.6})).becu(1)
    assert (bp.wsp.mode, bp.wsp.ceiling_fraction, bp.wsp.ceiling_release_s) == ("slip", 0.85, 0.6)
    assert bp.wsp.ceiling_rise_Pa_per_s == pytest.approx(40e3)
    assert run_params(_scenario(becu={"wsp_mode": "slip"})).becu(1).wsp.ceiling_release_s == 0.45   # defaults


def test_rg_scenario_builds_the_governor_from_the_plant():
    sc = load_scenario(ROOT / "scenarios" / "rg_low_adhesion.toml")
    bp = run_params(sc).becu(1)
    gp = reference_governor_params(sc, 1, run_params(sc)).model
    assert bp.control == "decel" and gp is not None and gp.pi == bp.decel_pi
    # steady-state limit = μ(s̄) g less the margin, μ(0.1) = 0.1822 for the curve
    assert gp.decel_max_mps2 / G == pytest.approx(0.18222 * (1 - 0.005), abs=1e-4)
    assert gp.phi == pytest.approx(math.exp(-0.01 / 0.05))
