"""Seed 000's reference generators, preview buffer and σ̄° estimator (firmware_py.preview): pure logic."""

from __future__ import annotations

import math

import pytest

from firmware_py.preview import (
    EstimatorParams,
    PreviewBecu,
    PreviewBuffer,
    RefParams,
    SigmaEstimator,
    delta_star,
    k2,
    predict_speed_eq10,
    predict_speed_remark2,
    reference,
)
from firmware_py.rx import RxTable
from plant_sim.adhesion import mu_scalar
from plant_sim.params import RAIL_CONDITIONS, AdhesionParams
from plant_sim.reduced_train import sigma_opt_bar_scalar

LN2 = math.log(2.0)
FAMILY = tuple(RAIL_CONDITIONS[c] for c in ("extra_dry", "dry", "wet", "extra_wet"))


@pytest.mark.parametrize("spacing, v, alpha, expected", [
    (50.0, 30.0, 1.5, 50.0 - 30.0 * LN2 / 1.5),    # eq. (9): Δ − v ln2/α
    (10.0, 30.0, 1.5, 0.0),                        # Δ < v ln2/α: no preview, the head's σ°
    (50.0, 0.0, 1.5, 50.0),                        # standing: read at the car's own position
    (25.0, 20.0, 5.0, 25.0 - 20.0 * LN2 / 5.0),
])
def test_delta_star_is_eq9(spacing, v, alpha, expected):
    assert delta_star(spacing, v, alpha) == pytest.approx(expected, abs=1e-12)


def test_speed_predictions():
    # constant deceleration: Remark 2's v̂ is exact, √(v² + 2 a d); eq. (10) is its first-order expansion in d
    v, a, d = 30.0, -2.0, 20.0
    assert predict_speed_remark2(v, a, d) == pytest.approx(math.sqrt(v * v + 2 * a * d))
    assert predict_speed_eq10(v, a, d) == pytest.approx(v + a / v * d)
    assert abs(predict_speed_eq10(v, a, 1.0) - predict_speed_remark2(v, a, 1.0)) < 1e-3
    assert predict_speed_remark2(2.0, -2.0, 5.0) == 0.0           # stops before getting there
    assert predict_speed_eq10(0.0, -2.0, 5.0) == 0.0


@pytest.mark.parametrize("method, car, expected", [
    ("Lf", 2, 0.8 * 0.040 / k2(30.0, 1 / 40)),     # car 1's σ̄°, at the speed now
    ("Bd", 2, 0.8 * 0.020 / k2(30.0, 1 / 40)),     # own σ̄°
    ("ideal", 2, 0.8 * 0.020 / k2(30.0, 1 / 40)),
    ("Dp", 1, 0.8 * 0.020 / k2(30.0, 1 / 40)),     # car 1 has no preview: own
])
def test_reference_table(method, car, expected):
    p = RefParams(car=car, spacing_m=50.0 if car > 1 else 0.0, method=method, beta=0.8)
    ref = reference(p, 30.0, -2.0, own_bar=0.020, lead_bar=0.040, preview_bar=0.030)
    assert ref.sigma == pytest.approx(expected)
    assert ref.delta_m == 0.0 and not ref.preview_miss


def test_dp_reference_uses_preview_at_predicted_speed():
    p = RefParams(car=2, spacing_m=50.0, method="Dp", beta=1.0, alpha_per_s=1.5)
    v, a = 30.0, -2.0
    ref = reference(p, v, a, own_bar=0.020, lead_bar=0.040, preview_bar=0.030)
    d = delta_star(50.0, v, 1.5)
    v_hat = math.sqrt(v * v + 2 * a * (50.0 - d))                  # Remark 2 over Δ − δ*
    assert ref.delta_m == pytest.approx(d)
    assert ref.v_pred_mps == pytest.approx(v_hat)
    assert ref.sigma == pytest.approx(0.030 / (1 + v_hat / 40))    # eq. (11)
    miss = reference(p, v, a, own_bar=0.020, lead_bar=0.040, preview_bar=None)
    assert miss.preview_miss and miss.sigma == pytest.approx(0.020 / (1 + v / 40))


def test_preview_buffer_interpolates_prefers_the_closest_car_ahead_and_prunes():
    buf = PreviewBuffer(tolerance_m=1.0, keep_behind_m=5.0)
    for k in range(200):
        buf.add(1, float(k), 0.01 + 0.0001 * k)            # car 1 measured every metre
    assert buf.lookup(10.5) == pytest.approx(0.01 + 0.0001 * 10.5)
    assert buf.lookup(199.5) == pytest.approx(0.01 + 0.0001 * 199)   # within tolerance of the newest
    assert buf.lookup(201.5) is None                        # nobody has been there
    for k in range(50):
        buf.add(2, float(k), 0.5)                           # car 2 passed 0..49 after car 1
    assert buf.lookup(20.0) == 0.5 and buf.lookup(100.0) == pytest.approx(0.02)
    buf.add(2, 49.0, 0.6)                                   # no new position: ignored, unless standing
    n = len(buf)
    buf.prune(150.0)
    assert len(buf) < n and buf.lookup(150.0) == pytest.approx(0.025)


@pytest.mark.parametrize("condition", ["extra_dry", "dry", "wet", "extra_wet"])
def test_estimator_finds_the_rail_from_slip_and_adhesion(condition):
    ad = AdhesionParams()
    theta = RAIL_CONDITIONS[condition]
    est = SigmaEstimator(EstimatorParams(family=FAMILY))
    v, x = 30.0, 0.0
    for k in range(100):                                    # slip near a fixed value: no excitation
        sigma = 0.01 + 0.0001 * (k % 3)
        x += 0.3
        est.update(x, v, sigma, mu_scalar(theta, sigma, v, ad))
    assert est.bar == pytest.approx(sigma_opt_bar_scalar(theta), rel=1e-6)


def test_estimator_tracks_a_change_of_rail_within_its_memory():
    ad = AdhesionParams()
    est = SigmaEstimator(EstimatorParams(family=FAMILY, memory_m=3.0))
    x, seen = 0.0, []
    for _k in range(400):
        x += 0.25
        theta = RAIL_CONDITIONS["dry" if x < 50.0 else "wet"]
        est.update(x, 25.0, 0.02, mu_scalar(theta, 0.02, 25.0, ad))
        seen.append((x, est.bar))
    wet = sigma_opt_bar_scalar(RAIL_CONDITIONS["wet"])
    assert all(b == pytest.approx(wet) for xx, b in seen if xx > 70.0)      # ~7 memory lengths on
    dry = sigma_opt_bar_scalar(RAIL_CONDITIONS["dry"])
    assert all(b == pytest.approx(dry) for xx, b in seen if xx < 50.0)


def _rx(becu: PreviewBecu, values: dict, t_us: int, table: RxTable | None = None) -> RxTable:
    table = table or RxTable(becu.inputs)
    table.update([(k, k) for k in values], values, t_us)
    return table


def test_preview_becu_step_oracle_dp_car2():
    p = RefParams(car=2, spacing_m=50.0, method="Dp", alpha_per_s=1.5)
    becu = PreviewBecu(p, 2, "oracle")
    out = becu.step(0, RxTable(becu.inputs))                # nothing received yet: σ(0), not valid
    assert out["BECU2_SLIP_REF.SlipRef"] == p.sigma0 and out["BECU2_PREVIEW.Valid"] == 0
    rx = None
    for k in range(300):                                    # car 1 broadcast σ̄°(x) = 0.02 + 1e-4 x
        x1 = float(k)
        rx = _rx(becu, {"BECU1_PREVIEW.SigmaOptBar": 0.02 + 1e-4 * x1, "BECU1_PREVIEW.Position": x1,
                        "BECU1_PREVIEW.Valid": 1}, k * 10_000, rx)
        becu.step(k * 10_000, rx)
    v, a, x1 = 20.0, -1.5, 299.0
    rx = _rx(becu, {"PLANT_TRAIN.Speed": v, "PLANT_TRAIN.Accel": a, "PLANT_TRAIN.HeadPos": x1,
                    "PLANT_CAR2_ADH.Slip": 0.01, "PLANT_CAR2_ADH.AdhesionUsed": 0.1,
                    "PLANT_CAR2_ADH.SigmaOptBarTrue": 0.02}, 3_000_000, rx)
    out = becu.step(3_000_000, rx)
    d = delta_star(50.0, v, 1.5)
    v_hat = predict_speed_remark2(v, a, 50.0 - d)
    assert out["BECU2_SLIP_REF.PreviewDist"] == pytest.approx(d)
    assert out["BECU2_SLIP_REF.SlipRef"] == pytest.approx((0.02 + 1e-4 * (x1 - d)) / (1 + v_hat / 40))
    assert out["BECU2_SLIP_REF.PreviewMiss"] == 0
    assert out["BECU2_PREVIEW.SigmaOptBar"] == 0.02 and out["BECU2_PREVIEW.Position"] == x1 - 50.0
