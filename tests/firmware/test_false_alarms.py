"""No false alarms (issue #19, point 3): the BECU's reference speed leans on the accelerometer while its wheel
slides (firmware_py.becu.reference_speed), and the BCU judges a car implausible only on evidence a real
slide cannot produce (firmware_py.bcu.Bcu._vote); healthy runs raise no plausibility or sensor-fault flag.

* The pure functions: the reference speed unbiased on a noisy axle, a slide bridged on the accelerometer,
  an accelerometer error within its fault limit taken for no slide; the vote's two sides.
* The default lockstep run (the session's `default_lockstep`): SpeedEst against the plant's truth at the
  instants a wheel slips, and no flag; two more seeds of default and stop_30kmh.
* `make test-slow`: 50 healthy lockstep runs, default and stop_30kmh with 25 seeds each, on two worker
  processes (hil.campaign.jobs.map_jobs), with no flag in any.

A flag is BCU_STATUS.CarsImplausible ≠ 0 or BECUn_DIAG.SpeedSensorFault / AccelSensorFault / CylSensorFault
= 1 in any frame of the run's trace.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT

from firmware_py.bcu import Bcu, BcuParams, disagreement
from firmware_py.becu import Becu, BecuParams
from firmware_py.reference_speed import RefMode, RefSpeed, RefSpeedParams, reference_speed
from firmware_py.rx import RxTable
from firmware_py.sensor_checks import SensorCheckParams
from hil.can.codec import loaded_dbc
from hil.report.kpis import read_run_trace
from hil.scenario import load_scenario, parse_scenario

DEFAULT = ROOT / "scenarios" / "default.toml"
STOP_30 = ROOT / "scenarios" / "stop_30kmh.toml"
DIAG_FLAGS = ("SpeedSensorFault", "AccelSensorFault", "CylSensorFault")
SLIP_S_MPS = 0.1          # a wheel slips: slip speed above seed 001's s̄ = 0.1 m/s (the stable-slip bound)
MOVING_MPS = 0.5          # ... of a car that moves
GATE = BecuParams().wheel_trust_slip_mps   # the slide gate [m/s]
RP = RefSpeedParams()
DT = 0.01                 # BECU cycle [s]


# ------------------------------------------------------------------------------------- run summaries
def run_flags(decoded, n_cars: int) -> dict[str, float]:
    """{flag.carN: first time [s]} of every flag the run's trace holds (empty: none)."""
    flags: dict[str, float] = {}
    for i in range(1, n_cars + 1):
        table = decoded.table(f"BECU{i}_DIAG")
        for sig in DIAG_FLAGS:
            on = np.flatnonzero(table.columns[sig] >= 0.5)
            if on.size:
                flags[f"{sig}.car{i}"] = round(float(table.t[on[0]]), 3)
    status = decoded.table("BCU_STATUS")
    bits = status.columns["CarsImplausible"].astype(np.int64)
    for k in range(n_cars):
        on = np.flatnonzero(bits >> k & 1)
        if on.size:
            flags[f"CarsImplausible.car{k + 1}"] = round(float(status.t[on[0]]), 3)
    return flags


def speed_errors(decoded, cols: dict, n_cars: int) -> tuple[np.ndarray, np.ndarray]:
    """SpeedEst − the car's true speed [m/s] of every BECUn_STATUS frame sent while any wheel of the train
    slips (truth: slip speed > SLIP_S_MPS, car moving), and of those of a car whose own wheel slips; the
    truth (sampled every 10 ms) interpolated at the frame's time."""
    t = cols["t_s"]
    slip = np.column_stack([cols[f"slip_speed_mps_{i}"] for i in range(1, n_cars + 1)])
    any_slip = slip.max(axis=1)
    anys, own = [], []
    for i in range(1, n_cars + 1):
        table = decoded.table(f"BECU{i}_STATUS")
        ts, est = table.t, table.columns["SpeedEst"]
        v = np.interp(ts, t, cols[f"v_mps_{i}"])
        moving = v > MOVING_MPS
        err = est - v
        anys.append(err[moving & (np.interp(ts, t, any_slip) > SLIP_S_MPS)])
        own.append(err[moving & (np.interp(ts, t, slip[:, i - 1]) > SLIP_S_MPS)])
    return np.concatenate(anys), np.concatenate(own)


def summarise(out_dir: Path, cols: dict, n_cars: int) -> dict:
    """A run's flags and SpeedEst errors over its slides, from its trace and truth."""
    db, codec = loaded_dbc()
    decoded = read_run_trace(out_dir / "trace.blf", db, codec)
    err, own = speed_errors(decoded, cols, n_cars)
    return {"flags": run_flags(decoded, n_cars), "slide_samples": int(err.size),
            "mean_err": float(err.mean()) if err.size else 0.0,
            "max_abs_err": float(np.abs(err).max()) if err.size else 0.0,
            "own_mean_err": float(own.mean()) if own.size else 0.0}


def healthy_run(job: tuple[str, int, str]) -> dict:
    """One healthy lockstep run (scenario path, seed, run folder), in a worker process: its summary."""
    from hil.report.run import run_scenario_lockstep

    path, seed, out = job
    base = load_scenario(path)
    scenario = parse_scenario({**base.model_dump(), "seed": seed})
    report = run_scenario_lockstep(scenario, Path(out), plots=False)
    return {"scenario": Path(path).stem, "seed": seed, "end": report.outcome.reason,
            **summarise(report.out_dir, report.outcome.truth.columns(), scenario.train.cars)}


def table_lines(rows: list[dict]) -> list[str]:
    lines = [f"{'scenario':12s} {'runs':>4s} {'flagged':>7s} {'slide samples':>13s} {'mean err':>9s} "
             f"{'max |err|':>9s}"]
    for name in dict.fromkeys(r["scenario"] for r in rows):
        rs = [r for r in rows if r["scenario"] == name]
        n = sum(r["slide_samples"] for r in rs)
        mean = sum(r["mean_err"] * r["slide_samples"] for r in rs) / n if n else 0.0
        lines.append(f"{name:12s} {len(rs):4d} {sum(bool(r['flags']) for r in rs):7d} {n:13d} "
                     f"{mean:+9.4f} {max(r['max_abs_err'] for r in rs):9.3f}")
    return lines


# ------------------------------------------------------------------------------- the reference speed
def drive(wheel, accel, *, wsp_fill=None, torque_free=None, p=RP, gate=GATE, mode=RefMode.FILTERED):
    """Run reference_speed over arrays of axle readings [m/s] and accelerations [m/s²], one per cycle;
    returns the estimates and the sliding flags."""
    n = len(wheel)
    wsp_fill = np.ones(n, bool) if wsp_fill is None else wsp_fill
    torque_free = np.zeros(n, bool) if torque_free is None else torque_free
    s, est, sliding = RefSpeed(), np.empty(n), np.empty(n, bool)
    for k in range(n):
        s = reference_speed(s, wheel[k], accel[k], DT, True, bool(wsp_fill[k]), bool(torque_free[k]), gate, p,
                            mode=mode)
        est[k], sliding[k] = s.v_mps, s.sliding
    return est, sliding


def test_the_reference_speed_is_unbiased_on_a_noisy_axle():
    """20 s at 20 m/s, the axle read with plant_sim's noise (0.02 rad/s × 0.46 m) and resolution: the
    estimate's mean error is ~0 (the upper envelope it replaces ran +0.006 m/s high)."""
    rng = np.random.default_rng(19)
    n = 2000
    wheel = np.round((20.0 / 0.46 + 0.02 * rng.standard_normal(n)) / 0.005) * 0.005 * 0.46
    accel = 0.02 * rng.standard_normal(n)
    est, sliding = drive(wheel, accel)
    err = est[200:] - 20.0
    assert abs(err.mean()) < 0.001 and np.abs(err).max() < 0.02 and not sliding.any()


def test_a_slide_is_bridged_on_the_accelerometer():
    """The car brakes at 1 m/s² from 20 m/s; its wheel slides (slip growing at 4 m/s² to 2 m/s, held, then
    spinning up within 0.3 s), WSP venting from the moment the slip passes 0.6 m/s until it is back: the
    estimate stays with the car, not with the wheel, and the slide ends when the wheel is back."""
    n = 400
    t = np.arange(n) * DT
    v = 20.0 - 1.0 * t
    slip = np.where(t < 1.8, np.clip(4.0 * (t - 1.0), 0.0, 2.0), np.clip(2.0 - 7.0 * (t - 1.8), 0.0, 2.0))
    wsp_fill = ~((slip > 0.6) | ((t > 1.2) & (t < 2.1)))
    est, sliding = drive(v - slip, -np.ones(n), wsp_fill=wsp_fill)
    # the wheel was 2 m/s below for 0.5 s; the estimate followed only the onset before the slide gate
    # tripped (0.02 m/s), and that is undone then (rollback to the wheel's last agreement)
    assert np.abs(est - v).max() < 0.03 and np.abs(est - v)[t > 1.1].max() < 0.005
    assert sliding[(t > 1.1) & (t < 2.05)].all() and not sliding[t > 2.3].any()


def test_an_accelerometer_error_within_the_fault_limit_is_no_slide():
    """The accelerometer reads 0.7 m/s² (AccelSensorFault's limit) too little deceleration, uncorrected:
    the estimate leaves the axle by at most a·τ = 0.12 m/s, below the slide gate, and keeps taking it."""
    limit = SensorCheckParams().bias_limit_mps2
    n = 1000
    v = 20.0 - 1.0 * np.arange(n) * DT
    est, sliding = drive(v, np.full(n, -1.0 + limit))
    assert not sliding.any()
    assert np.abs(est - v).max() < GATE


def test_the_accelerometer_reference_of_seed_001_runs_is_lifted_only():
    """RefMode.LIFTED ([becu] wheel_trust_slip_mps = 0, rg_* scenarios): the accelerometer's integral, lifted
    to a wheel that reads above it, never pulled down by one below."""
    est, _ = drive(np.array([10.0, 9.0, 9.0, 12.0, 11.0]), np.zeros(5), mode=RefMode.LIFTED)
    assert est.tolist() == [10.0, 10.0, 10.0, 12.0, 12.0]


def test_the_accelerometer_reference_runs_through_a_gap_in_the_sensor_frames():
    """RefMode.LIFTED (the rg_* scenarios): the bus is blocked for 2 s while the car decelerates at 1.76 m/s²,
    so no sensor frame arrives. The estimate runs on the last acceleration, not lifted to the last (stale)
    wheel reading every cycle: when the frames come back it is within 0.05 m/s of the car and WSP does not
    vent the rolling wheel (lifted to the stale reading, it stood 3.5 m/s above the car and WSP vented for
    the watchdog's 5 s: rg_low_adhesion's babbling cell of the threat matrix, issue #19)."""
    becu = Becu(BecuParams(reference=RefMode.LIFTED))
    rx = RxTable(Becu.INPUTS)
    names = [(n, n) for n in Becu.INPUTS]
    a, v0, wsp = -1.76, 58.0, []
    for k in range(400):
        t_us, v = k * 10_000, v0 + a * k * DT
        if not 100 <= k < 300:                                 # frames stop at 1 s and return at 3 s
            rx.update(names, {"AxleSpeed": (v - 0.02) / 0.46, "CylPressure": 248e3 + 10.0 * (k % 2),
                              "AccelLong": a, "TargetDecel": 1.76, "BCU_DEMAND.Mode": 1,
                              "EmergencyActive": 0}, t_us)
        out = becu.step(t_us, rx)
        if k == 299:
            assert abs(becu.v_ref - v) < 0.05, (becu.v_ref, v)
        wsp.append(out["WspValve"])
    assert max(wsp[300:]) == 0


def test_the_becu_reference_speed_rides_through_the_realtime_slide():
    """The slide that latched car 4 as implausible in a real-time `make run`: the wheel 1.6–2.4 m/s below
    the car for 0.6 s.  The BECU's SpeedEst stays within 0.05 m/s of the car, its cylinder (plant_sim's
    valves: fill 1, vent 1.5, dump 2 MPa/s; a live transducer) is vented and refilled, no sensor is
    declared failed, and the BCU, with five cars on the truth, flags nothing.  Outside the slide the wheel
    turns at the car's speed less the nominal creep of its brake (`Becu.creep`)."""
    becu, bcu = Becu(), Bcu(6)
    p, est = 0.0, []
    for k in range(300):
        t = k * DT
        v = 22.0 - 1.0 * t
        slip = becu.creep(p) if not 1.0 <= t < 1.6 else 1.6 + 0.8 * abs(math.sin(8.0 * t))
        reading = round(p, -1) + 10 * (k % 2)                  # a live transducer
        t_us = k * 10_000
        out = becu.step(t_us, RxTable.received({"AxleSpeed": (v - slip) / 0.46, "CylPressure": reading,
                                                "AccelLong": -1.0, "TargetDecel": 1.0, "Mode": 1,
                                                "EmergencyActive": 0}, t_us))
        u, w = out["ValveCmd"], out["WspValve"]
        p = min(max(p + DT * (-2e6 if w == 2 else 0.0 if w == 1 else u * (1e6 if u > 0 else 1.5e6)), 0.0),
                450e3)
        est.append(out["SpeedEst"] - v)
        speeds = {f"BECU{i}_STATUS.SpeedEst": out["SpeedEst"] if i == 4 else v for i in range(1, 7)}
        status = bcu.step(t_us, RxTable.received({"BrakeStep": 7, "EmergencyReq": 0, **speeds}, t_us))
        assert status["CarsImplausible"] == 0
        assert not (out["SpeedSensorFault"] or out["AccelSensorFault"] or out["CylSensorFault"])
    assert max(abs(e) for e in est) < 0.05


# --------------------------------------------------------------------------------------------- the vote
@pytest.mark.parametrize("speeds, expected", [
    ([20.0, 20.1, 23.0, 19.9, 20.0, 20.2], [0, 0, 1, 0, 0, 0]),           # above the median: +1
    ([20.0, 20.1, 17.0, 19.9, 20.0, 20.2], [0, 0, -1, 0, 0, 0]),          # below it: −1
    ([20.0, math.nan, 14.0, 20.0], [0, 0, -1, 0]),                        # a silent car does not vote
    ([20.0, 26.0], [0, 0]),                                               # two cars: nobody can tell
])
def test_disagreement_table(speeds, expected):
    assert disagreement(speeds, [True] * len(speeds), BcuParams().implausible_mps) == expected


def vote_until_flagged(offset_mps: float, seconds: float, then_mps: float | None = None, switch_s=math.inf):
    """Six cars at 20 m/s, car 3 `offset_mps` off (from `switch_s` on: `then_mps`), for `seconds`: the
    time [s] car 3 is flagged, or None."""
    bcu = Bcu(6)
    for k in range(round(seconds / DT)):
        off = offset_mps if k * DT < switch_s else then_mps
        speeds = {f"BECU{i}_STATUS.SpeedEst": 20.0 + (off if i == 3 else 0.0) for i in range(1, 7)}
        t_us = k * 10_000
        rx = RxTable.received({"BrakeStep": 7, "EmergencyReq": 0, **speeds}, t_us)
        if bcu.step(t_us, rx)["CarsImplausible"]:
            return k * DT
    return None


def test_the_vote_flags_an_estimate_above_the_train_at_once_and_one_below_after_a_slide_s_time():
    bp = BcuParams()
    above = vote_until_flagged(+3.0, 1.0)
    assert above == pytest.approx(bp.implausible_after_us / 1e6 + DT, abs=1.5 * DT)
    assert vote_until_flagged(-3.0, bp.slide_allow_us / 1e6 - 0.1) is None     # a slide may last that long
    below = vote_until_flagged(-3.0, bp.slide_allow_us / 1e6 + 1.0)
    assert below == pytest.approx(bp.slide_allow_us / 1e6 + DT, abs=1.5 * DT)
    # low for 5 s, then high: the timer of the high side starts when it becomes high
    assert vote_until_flagged(-3.0, 6.0, +3.0, 5.0) == pytest.approx(5.0 + bp.implausible_after_us / 1e6 + DT,
                                                                       abs=1.5 * DT)


# ------------------------------------------------------------------------------- lockstep runs, healthy
def test_speed_est_against_the_truth_over_the_default_runs_slides(default_lockstep):
    """Issue #19's acceptance: the BECUs' SpeedEst against the plant's true car speed at the instants any
    wheel slips (slip speed above s̄ = 0.1 m/s), every car's STATUS frame: mean error within ±0.01 m/s; the
    largest |error| printed and bounded (0.3 m/s: far below the BCU's 2 m/s vote)."""
    s = summarise(default_lockstep.out_dir, default_lockstep.outcome.truth.columns(), 6)
    print(f"\ndefault, seed 1: SpeedEst − v over {s['slide_samples']} STATUS frames at instants a wheel "
          f"slips: mean {s['mean_err']:+.4f} m/s, max |error| {s['max_abs_err']:.3f} m/s; over each car's "
          f"own slides: mean {s['own_mean_err']:+.4f} m/s")
    assert s["slide_samples"] > 500                       # the wet section makes every car slide
    assert abs(s["mean_err"]) <= 0.01
    assert s["max_abs_err"] < 0.3
    assert s["flags"] == {}


@pytest.mark.parametrize("path, seed", [(DEFAULT, 2), (STOP_30, 2), (STOP_30, 3)],
                         ids=["default-2", "stop_30kmh-2", "stop_30kmh-3"])
def test_no_flag_in_healthy_runs(tmp_path, path, seed):
    s = healthy_run((str(path), seed, str(tmp_path / "run")))
    assert s["end"] == "standstill" and s["flags"] == {}, s


@pytest.mark.slow
@pytest.mark.timeout(1800)              # 50 lockstep runs on two workers: ~3 min on a quiet 2-core host
def test_no_flag_in_50_healthy_runs(tmp_path):
    """Issue #19's acceptance: default and stop_30kmh, 25 seeds each, in lockstep: no plausibility or
    sensor-fault flag in any; the table (flagged runs, SpeedEst − v over the slides) printed."""
    from hil.campaign.jobs import map_jobs

    jobs = [(str(path), seed, str(tmp_path / f"{path.stem}-{seed}")) for path in (DEFAULT, STOP_30)
            for seed in range(1, 26)]
    rows = map_jobs(healthy_run, jobs, 2, "healthy runs", progress=False)
    print("\n" + "\n".join(table_lines(rows)))
    flagged = [(r["scenario"], r["seed"], r["flags"]) for r in rows if r["flags"]]
    assert not flagged
    assert all(r["end"] == "standstill" for r in rows)
