"""The WSP type test (issue #21): its metrics against closed-form cases, its programme file's errors, and
one short programme run end to end through `railhil wsp-test`."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from hil.cli.main import main
from hil.typetest.metrics import (
    MetricParams,
    air_litres,
    demand_from_dry,
    ideal_stop,
    longest_not_rotating,
    run_metrics,
    slide,
    wsp_activations,
)
from hil.typetest.programme import ProgrammeError, load_programme, runs
from plant_sim.params import G_MPS2

DT = 0.01
T_CMD = 0.5
V0 = 20.0
MU = 0.05                                 # constant peak adhesion of the closed-form cases
A_ADH = MU * G_MPS2                       # 0.4905 m/s²


def braking(decel: float, cars: int = 2, v0: float = V0, tail_s: float = 1.0) -> dict[str, np.ndarray]:
    """Truth columns of a train at v0 braking at exactly `decel` from T_CMD to standstill, no slip."""
    t_stop = T_CMD + v0 / decel
    t = np.arange(0.0, t_stop + tail_s, DT)
    v = np.clip(v0 - decel * np.clip(t - T_CMD, 0.0, None), 0.0, None)
    x = np.concatenate(([0.0], np.cumsum((v[1:] + v[:-1]) / 2 * DT)))
    cols = {"t_s": t}
    for k in range(1, cars + 1):
        cols[f"x_m_{k}"] = x - 25.0 * (k - 1)
        cols[f"v_mps_{k}"] = v
        cols[f"slip_speed_mps_{k}"] = np.zeros_like(t)
        cols[f"p_Pa_{k}"] = np.where(t >= T_CMD, 3e5, 0.0)
        cols[f"wsp_valve_{k}"] = np.zeros(len(t), dtype=np.int64)
    return cols


def constant(x_m: float, v_mps: float) -> float:
    return A_ADH


def test_ideal_stop_at_constant_adhesion_is_v0_squared_over_2a():
    dry = demand_from_dry(braking(1.0), T_CMD)
    assert dry.plateau_mps2 == pytest.approx(1.0, rel=1e-3)
    assert dry.build_up_s < 0.05
    assert ideal_stop(V0, 0.0, dry, constant) == pytest.approx(V0 ** 2 / (2 * A_ADH), rel=2e-3)


def test_braking_at_the_adhesion_peak_has_no_extension_and_full_utilisation():
    dry = demand_from_dry(braking(1.0), T_CMD)
    m = run_metrics(braking(A_ADH), T_CMD, MetricParams(), dry, constant)
    assert m["stopped"]
    assert m["stopping_distance_m"] == pytest.approx(V0 ** 2 / (2 * A_ADH), rel=1e-3)
    assert m["extension_m"] == pytest.approx(0.0, abs=0.5)
    assert m["utilisation"] == pytest.approx(1.0, abs=2e-3)
    assert m["wsp_activations"] == 0 and m["slide_integral_m"] == 0.0 and m["longest_not_rotating_s"] == 0.0


def test_braking_below_the_peak_by_hand():
    dry = demand_from_dry(braking(1.0), T_CMD)
    m = run_metrics(braking(0.4), T_CMD, MetricParams(), dry, constant)
    s, s_ideal = V0 ** 2 / (2 * 0.4), V0 ** 2 / (2 * A_ADH)          # 500.0 m and 407.7 m
    assert m["extension_m"] == pytest.approx(s - s_ideal, abs=1.0)
    assert m["extension_pct"] == pytest.approx(100 * (s - s_ideal) / s_ideal, abs=0.3)   # 22.6 %
    assert m["utilisation"] == pytest.approx(0.4 / A_ADH, abs=3e-3)                   # 0.8155


def test_demand_below_the_adhesion_caps_the_ideal():
    """On good rail the ideal brakes at the demand, not at the adhesion peak."""
    dry = demand_from_dry(braking(1.0), T_CMD)
    m = run_metrics(braking(1.0), T_CMD, MetricParams(), dry, lambda x, v: 3.0)
    assert m["extension_m"] == pytest.approx(0.0, abs=0.3)
    assert m["utilisation"] == pytest.approx(1.0, abs=2e-3)


def test_air_slide_rotation_and_activations_by_hand():
    cols = braking(0.5)
    n = len(cols["t_s"])
    t = cols["t_s"]
    p = np.zeros(n)
    p[(t >= 1) & (t < 2)] = 3e5                      # filled, vented, filled, vented: 2 drops of 3 bar
    p[(t >= 3) & (t < 4)] = 3e5
    cols["p_Pa_1"], cols["p_Pa_2"] = p, np.zeros(n)
    params = MetricParams(slide_threshold_mps=0.5, rotation_threshold_mps=1.0, moving_mps=3.0,
                          cylinder_volume_l=12.0, atmosphere_Pa=101_325.0)
    assert air_litres(cols, 0, params) == pytest.approx(2 * 3e5 * 12.0 / 101_325.0)      # 71.05 L
    s = np.zeros(n)
    s[(t >= 2.0) & (t < 4.0)] = 1.5                  # 1 m/s above the threshold for 2 s: 2 m
    cols["slip_speed_mps_1"] = s
    largest, integral = slide(cols, 0, params)
    assert largest == 1.5
    assert integral == pytest.approx(2.0, abs=0.02)
    locked = (t >= 5.0) & (t < 6.5)                  # the wheel stands 1.5 s while the car runs ~17 m/s
    cols["slip_speed_mps_2"] = np.where(locked, cols["v_mps_2"], 0.0)
    assert longest_not_rotating(cols, 0, params) == pytest.approx(1.5, abs=DT)
    w = np.zeros(n, dtype=np.int64)
    w[(t >= 1) & (t < 2)] = 2
    w[(t >= 2) & (t < 3)] = 1                        # vent then hold: one activation
    w[(t >= 4) & (t < 5)] = 2                        # a second
    cols["wsp_valve_1"] = w
    assert wsp_activations(cols, 0) == 2


def test_a_train_that_does_not_stop_has_no_distance():
    cols = braking(1.0)
    for k in (1, 2):
        cols[f"v_mps_{k}"] = np.maximum(cols[f"v_mps_{k}"], 2.0)
    m = run_metrics(cols, T_CMD, MetricParams(), None, None)
    assert not m["stopped"] and m["stopping_distance_m"] is None and m["extension_m"] is None


# ------------------------------------------------------------------------------------- the programme
def test_shipped_programme_expands_to_valid_runs():
    prog = load_programme()
    specs = runs(prog)
    n = len(prog.spec.strategies) * len(prog.spec.speeds_kmh) * (len(prog.spec.conditions) + 1)
    assert len(specs) == n
    sudden = next(s for s in specs if s.condition == "sudden_change" and s.speed_kmh == 90.0)
    rail = sudden.scenario.track.rail
    nominal = (90 / 3.6) ** 2 / 2 / prog.spec.nominal_decel_mps2
    assert [r.condition for r in rail] == ["dry", "extra_wet", "dry"]
    assert rail[1].from_m == pytest.approx(0.2 * nominal) and rail[2].from_m == pytest.approx(0.6 * nominal)


def _write(tmp_path: Path, text: str) -> Path:
    base = Path(__file__).resolve().parents[2] / "scenarios" / "default.toml"
    p = tmp_path / "prog.toml"
    p.write_text(f'name = "t"\nbase = "{base}"\nspeeds_kmh = [40.0]\n' + text)
    return p


GOOD = ('[reference]\nrail = [{ from_m = -500.0, condition = "dry" }]\n'
        '[conditions.low]\nrail = [{ from_m = -500.0, condition = "wet" }]\n[strategies.dump]\n')


@pytest.mark.parametrize("text, expected", [
    (GOOD.replace("[strategies.dump]\n", ""), "key 'strategies' is missing"),
    (GOOD + "speed_kmh = 3\n", "key 'strategies.dump.speed_kmh' is not a programme key"),
    (GOOD.replace('from_m = -500.0, condition = "wet"', 'condition = "wet"'),
     "give exactly one of 'from_m'"),
    (GOOD.replace('"wet"', '"soapy"'), "conditions.low.rail.0.condition"),
    (GOOD + 'set = { "becu.no_such_key" = 1 }\n', "becu.no_such_key"),
    (GOOD + "[", "not valid TOML"),
    (GOOD + 'demand_from = "nope"\n', "strategies.dump.demand_from = 'nope': must name another strategy"),
    (GOOD + 'demand_from = "dump"\n', "strategies.dump.demand_from = 'dump': must name another strategy"),
])
def test_bad_programme_is_one_line_naming_the_key(tmp_path, text, expected):
    with pytest.raises(ProgrammeError, match="prog.toml") as info:
        runs(load_programme(_write(tmp_path, text)))
    assert expected in str(info.value) and "\n" not in str(info.value)


def test_cli_bad_input_exits_2_without_a_folder(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["wsp-test", "--strategy", "nope", "-o", str(out), "-q"]) == 2
    assert "--strategy nope: no such strategy; the programme has dump" in capsys.readouterr().err
    assert main(["wsp-test", str(tmp_path / "missing.toml"), "-o", str(out)]) == 2
    assert "no such programme file" in capsys.readouterr().err
    assert main(["wsp-test", "--speed", "77", "-o", str(out)]) == 2
    assert not out.exists()


def test_short_programme_end_to_end(tmp_path, capsys):
    """One strategy at 40 km/h on wet rail and its dry reference, through the CLI: the table, the figures,
    report.html; the dry run is its own ideal; on wet rail the dump WSP acts and stops longer."""
    prog = _write(tmp_path, GOOD)
    out = tmp_path / "out"
    assert main(["wsp-test", str(prog), "--jobs", "1", "-o", str(out), "-q"]) == 0
    printed = capsys.readouterr().out
    assert "## low" in printed and "extension [%]" in printed
    doc = json.loads((out / "results.json").read_text())
    by = {r["condition"]: r for r in doc["runs"]}
    assert by["reference"]["status"] == by["low"]["status"] == "ok"
    assert abs(by["reference"]["extension_pct"]) < 0.5
    assert by["low"]["wsp_activations"] > 0
    assert by["low"]["stopping_distance_m"] > by["reference"]["stopping_distance_m"]
    assert 0.3 < by["low"]["utilisation"] < 1.01 and by["low"]["extension_m"] > 0
    assert math.isfinite(by["low"]["air_free_l"]) and by["low"]["air_free_l"] > by["reference"]["air_free_l"]
    for name in ("table.md", "table.csv", "report.html", "wsp_low.png", "wsp_reference.png"):
        assert (out / name).is_file(), name
    assert (out / "dump" / "low-40kmh" / "truth.csv").is_file()
    # the same programme into the same folder reads the results; a changed threshold runs them again
    assert main(["wsp-test", str(prog), "--jobs", "1", "-o", str(out), "-q"]) == 0
    assert "(2 read from their folders, 0 run)" in capsys.readouterr().out
    again = json.loads((out / "results.json").read_text())
    distances = [r["stopping_distance_m"] for r in doc["runs"]]
    assert [r["stopping_distance_m"] for r in again["runs"]] == distances
    prog.write_text(prog.read_text() + "[metrics]\nslide_threshold_mps = 0.4\n")
    assert main(["wsp-test", str(prog), "--jobs", "1", "-o", str(out), "-q"]) == 0
    assert "(0 read from their folders, 2 run)" in capsys.readouterr().out
    assert main(["wsp-test", str(prog), "--jobs", "1", "-o", str(out), "-q", "--fresh"]) == 0
    assert "(0 read from their folders, 2 run)" in capsys.readouterr().out


GOVERNOR = ('[strategies.governor]\ndemand_from = "dump"\nset = { "becu.control" = "decel", '
            '"wheel_slip.governor" = true, "wheel_slip.margin" = 0.02 }\n')


def test_a_strategy_judged_against_another_brings_its_dry_references(tmp_path):
    prog = load_programme(_write(tmp_path, GOOD + GOVERNOR))
    specs = runs(prog, strategies=["governor"])
    assert [(s.strategy, s.condition) for s in specs] == [("dump", "reference"), ("governor", "reference"),
                                                          ("governor", "low")]
    assert prog.demand_source("governor") == "dump" and prog.demand_source("dump") == "dump"


def test_governor_judged_against_the_dump_strategys_demand(tmp_path, capsys):
    """The governor designed for extra-wet rail brakes below the demand on dry rail too: judged against the
    dump strategy's dry run its dry stop is extended (against its own it would be ~0); on wet rail it
    keeps every wheel below the slide threshold, the WSP never venting."""
    out = tmp_path / "out"
    prog = _write(tmp_path, GOOD + GOVERNOR)
    assert main(["wsp-test", str(prog), "--strategy", "governor", "--jobs", "2", "-o", str(out), "-q"]) == 0
    doc = json.loads((out / "results.json").read_text())
    by = {(r["strategy"], r["condition"]): r for r in doc["runs"]}
    assert set(by) == {("dump", "reference"), ("governor", "reference"), ("governor", "low")}
    assert abs(by["dump", "reference"]["extension_pct"]) < 0.5
    assert by["governor", "reference"]["extension_pct"] > 50.0
    low = by["governor", "low"]
    assert low["status"] == "ok" and low["wsp_activations"] == 0 and low["slide_integral_m"] == 0.0
    assert low["extension_pct"] > 20.0 and low["longest_not_rotating_s"] == 0.0


def test_slip_wsp_ceiling_is_learnt_at_the_slide_onset_rises_in_fill_and_is_released():
    from firmware_py.wsp import Wsp, WspParams, slip_ceiling

    p = WspParams(mode="slip", ceiling_fraction=0.9, ceiling_rise_Pa_per_s=20e3, ceiling_release_s=1.5)
    c = slip_ceiling(math.inf, Wsp.FILL, Wsp.FILL, 3e5, 0.0, 0.01, p)
    assert c == math.inf                                         # no slide yet: no ceiling
    c = slip_ceiling(c, Wsp.FILL, Wsp.VENT, 2e5, 0.0, 0.01, p)
    assert c == pytest.approx(1.8e5)                             # 0.9 x the pressure at the onset
    assert slip_ceiling(c, Wsp.VENT, Wsp.HOLD, 0.5e5, 0.0, 0.01, p) == c    # held while out of FILL
    assert slip_ceiling(c, Wsp.HOLD, Wsp.FILL, 1e5, 0.5, 0.5, p) == pytest.approx(1.8e5 + 10e3)  # 0.2 bar/s
    assert slip_ceiling(c, Wsp.FILL, Wsp.FILL, 1e5, 1.51, 0.01, p) == math.inf  # 1.5 s without a slide


def test_slip_wsp_vents_early_at_a_slides_onset_only():
    from firmware_py.wsp import Wsp, WspParams, early_vent, vent_threshold

    p = WspParams(mode="slip")
    v = 20.0
    vent_at = vent_threshold(v, p)                              # 0.3 + 0.03 x 20 = 0.9 m/s
    assert vent_at == pytest.approx(0.9)
    onset = 0.31 * vent_at
    assert early_vent(Wsp.FILL, onset, v, -3.0, p) == Wsp.VENT            # decelerating as no car does
    assert early_vent(Wsp.FILL, onset, v, -1.0, p) == Wsp.FILL            # a car's deceleration: no
    assert early_vent(Wsp.FILL, 0.29 * vent_at, v, -3.0, p) == Wsp.FILL   # slip below 0.3 x the threshold
    assert early_vent(Wsp.HOLD, onset, v, -3.0, p) == Wsp.HOLD            # WSP already acts
    assert early_vent(Wsp.FILL, onset, 0.5, -3.0, p) == Wsp.FILL          # below min_speed_mps: never
    assert early_vent(Wsp.FILL, onset, v, -3.0, WspParams()) == Wsp.FILL  # the dump WSP: never


def test_dump_wsp_has_no_ceiling():
    from firmware_py.becu import Becu, BecuParams

    assert BecuParams().wsp.mode == "dump" and Becu(BecuParams()).ceiling_Pa == math.inf


def test_a_controller_that_raises_fails_its_run(tmp_path, monkeypatch, capsys):
    """A BECU whose step() raises sends safe values and the run goes on; the programme must not take its
    stop for a result of the strategy."""
    from firmware_py.becu import Becu

    def broken(self, now_us, rx):
        raise TypeError("a bug")

    monkeypatch.setattr(Becu, "step", broken)
    prog = _write(tmp_path, GOOD.replace('condition = "wet"', 'condition = "dry"'))
    out = tmp_path / "out"
    assert main(["wsp-test", str(prog), "--jobs", "1", "-o", str(out), "-q"]) == 1
    doc = json.loads((out / "results.json").read_text())
    assert {r["status"] for r in doc["runs"]} == {"failed"}
    assert "exceptions in its step() (last: TypeError: a bug)" in doc["runs"][0]["error"]
    assert "## Failed runs" in capsys.readouterr().out


def test_pressure_loop_restarts_when_wsp_hands_the_cylinder_back():
    """A BECU on a cylinder filled by its own valve commands (the plant's valve rates, one cycle of
    latency): a slide vents it, the wheel comes back, the refill must settle on the set-point. With the
    integrator that earlier refills wound up kept through the vent, the cylinder overshot (0.17 bar here)
    and the brake's hysteresis kept the torque."""
    from firmware_py.becu import Becu, BecuParams
    from firmware_py.rx import RxTable
    from firmware_py.sensor_checks import valve_pressure_rate
    from firmware_py.wsp import Wsp

    p = BecuParams()
    becu = Becu(p)
    v, pressure, valve, wsp, top_after, states = 25.0, 0.0, 0.0, Wsp.FILL, 0.0, []
    for k in range(400):
        t_s = k * 0.01
        wheel = v - (3.0 if 2.0 <= t_s < 2.3 else 0.0)              # a 0.3 s slide at 2 s
        if k == 190:
            becu.pressure_pi.i = 0.4                                # what earlier refills left wound up
        t_us = k * 10_000
        rx = RxTable.received({"AxleSpeed": wheel / p.wheel_radius_m, "CylPressure": pressure,
                               "AccelLong": -1.0, "TargetDecel": 1.0, "Mode": 1, "EmergencyActive": 0}, t_us)
        out = becu.step(t_us, rx)
        pressure = max(0.0, min(p.p_max_Pa, pressure + 0.01 * valve_pressure_rate(
            valve, wsp, pressure, p.p_max_Pa, p.valve_rates_Pa_per_s)))   # last cycle's commands act
        valve, wsp = out["ValveCmd"], Wsp(out["WspValve"])
        states.append(wsp)
        v -= 0.01
        if t_s > 2.5:
            top_after = max(top_after, pressure - out["CylPressureSet"])
    assert Wsp.VENT in states                                        # the slide vented the cylinder
    assert states[-1] == Wsp.FILL
    assert top_after < 5e3                                           # refilled without overshoot [Pa]
