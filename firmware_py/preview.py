"""Slip references with preview, seed 000 (Picasso, Caporale, Colaneri): the BECU's reference generators.

Pure logic, no I/O, time passed in as integer µs.

* Reference generators (seed 000 §2.2-2.3), all scaled by β (§3.3):
  - ``Lf``  Σ_i° = β σ°(x_1, v)                       leader-follower: car 1's optimum for every car
  - ``Bd``  Σ_i° = β σ°(x_i, v)                       blind decentralised: each car its own optimum
  - ``Dp``  Σ_i° = β σ°(x_1 − δ_i*, v̂)               distributed preview, eq. (9)-(11); car 1 = Bd
  - ``ideal`` the theoretical limit S° (the plant uses μ = μ°; the BECU sends its Bd reference)
* δ_i* = max(0, Δ_i − v ln 2/α) of eq. (9); v̂ the first-order-hold speed prediction of eq. (10) or its
  time-domain form of Remark 2.
* `PreviewBuffer`: the position-indexed store of what the cars ahead broadcast.
* `SigmaEstimator`: the online σ̄° estimator (a random-walk Kalman filter on θ, see its docstring).
* `PreviewBecu`: the paper-mode BECU controller built from them (`step(now_us, rx) -> dict`).

σ̄° denotes the speed-normalised optimum σ̄°(x) = σ°(x, v) k2(v) of eq. (2): what cars exchange, since it
describes the rail alone; each car rescales it by 1/k2 at the speed it will have there.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from firmware_py.rx import RxTable

LN2 = math.log(2.0)
METHODS = ("Lf", "Bd", "Dp", "ideal")
METHOD_CODE = {"Lf": 0, "Bd": 1, "Dp": 2, "ideal": 3}
SOURCE_CODE = {"oracle": 0, "estimate": 1}
NAN = float("nan")


# ------------------------------------------------------------------------------------ pure helpers
def k2(v_mps: float, pi2_s_per_m: float) -> float:
    """k2(v) = 1 + π2 v [-], seed 000 eq. (1)."""
    return 1.0 + pi2_s_per_m * v_mps


def delta_star(spacing_m: float, v_mps: float, alpha_per_s: float) -> float:
    """δ_i* = max(0, Δ_i − v ln 2 / α) [m], eq. (9) seed 000: how far behind car 1 car i reads σ°."""
    return max(0.0, spacing_m - v_mps * LN2 / alpha_per_s)        # eq. (9)


def predict_speed_eq10(v_mps: float, a_mps2: float, dist_m: float) -> float:
    """v̂ = v + v'(x_1) d, v' = v̇/v [m/s]: eq. (10), first-order hold in position; ≥ 0."""
    if v_mps <= 1e-3:
        return 0.0
    return max(0.0, v_mps + a_mps2 / v_mps * dist_m)               # eq. (10)


def predict_speed_remark2(v_mps: float, a_mps2: float, dist_m: float) -> float:
    """v̂(t + T) = v + v̇ T with ∫_0^T v̂ = d (Remark 2), i.e. v̂ = √(v² + 2 v̇ d) [m/s] (0 if the train stops
    before covering d)."""
    return math.sqrt(max(0.0, v_mps * v_mps + 2.0 * a_mps2 * dist_m))   # Remark 2, seed 000


PREDICTORS = {"eq10": predict_speed_eq10, "remark2": predict_speed_remark2}


@dataclass(frozen=True)
class RefParams:
    """One car's reference generator."""

    car: int                           # 1-based
    spacing_m: float                   # Δ_i = x_1 − x_i [m], 0 for car 1
    method: str = "Dp"                 # Lf | Bd | Dp | ideal
    beta: float = 1.0                  # β: scaling of the reference, seed 000 §3.3
    alpha_per_s: float = 1.5           # α the preview design assumes [1/s], eq. (9)
    pi2_s_per_m: float = 1.0 / 40.0    # π2 of k2(v) = 1 + π2 v, seed 000 §3
    prediction: str = "remark2"        # eq10 | remark2: speed prediction of eq. (10) / Remark 2
    sigma0: float = 0.001              # reference sent before the first measurement [-], seed 000 §3

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"RefParams.method must be one of {METHODS}, got {self.method!r}")
        if self.prediction not in PREDICTORS:
            raise ValueError(f"RefParams.prediction must be one of {tuple(PREDICTORS)}, "
                             f"got {self.prediction!r}")


@dataclass(frozen=True)
class Reference:
    sigma: float           # Σ_i° [-]
    delta_m: float         # δ_i* [m]
    v_pred_mps: float      # the speed σ̄° was rescaled at [m/s]
    preview_miss: bool     # no preview data at x_1 − δ_i*: own σ̄° used


def reference(p: RefParams, v_mps: float, a_mps2: float, own_bar: float, lead_bar: float,
              preview_bar: float | None) -> Reference:
    """Σ_i° of the chosen generator [-] (seed 000 §2.2-2.3), from σ̄° of the car itself (`own_bar`), of
    car 1 (`lead_bar`) and at x_1 − δ_i* (`preview_bar`, None: not available)."""
    if p.method == "Lf":
        return Reference(p.beta * lead_bar / k2(v_mps, p.pi2_s_per_m), 0.0, v_mps, False)
    if p.method in ("Bd", "ideal") or p.car == 1:
        return Reference(p.beta * own_bar / k2(v_mps, p.pi2_s_per_m), 0.0, v_mps, False)
    delta = delta_star(p.spacing_m, v_mps, p.alpha_per_s)                          # eq. (9)
    v_hat = PREDICTORS[p.prediction](v_mps, a_mps2, p.spacing_m - delta)          # eq. (10)
    if preview_bar is None:
        return Reference(p.beta * own_bar / k2(v_mps, p.pi2_s_per_m), delta, v_mps, True)
    return Reference(p.beta * preview_bar / k2(v_hat, p.pi2_s_per_m), delta, v_hat, False)   # eq. (11)


# ------------------------------------------------------------------------------------ preview buffer
class PreviewBuffer:
    """σ̄° the cars ahead broadcast, indexed by the track position it was measured at.

    One list per source car (positions only grow while the train runs forward).  `lookup(x)` reads the
    value at x from the car closest ahead (largest car number) that has passed x: the freshest pass over
    that piece of rail; linear between the two samples around x.  `prune(x)` forgets what lies more than
    `keep_behind_m` behind x (the reader has passed it)."""

    def __init__(self, tolerance_m: float = 2.0, keep_behind_m: float = 5.0) -> None:
        self.tolerance_m = tolerance_m       # x may lie this far ahead of a car's newest sample [m]
        self.keep_behind_m = keep_behind_m
        self._pos: dict[int, list[float]] = {}
        self._val: dict[int, list[float]] = {}

    def add(self, car: int, position_m: float, value: float) -> None:
        pos = self._pos.setdefault(car, [])
        val = self._val.setdefault(car, [])
        if pos and position_m <= pos[-1]:
            if position_m == pos[-1]:
                val[-1] = value               # standing still: the newest value at that point
            return
        pos.append(position_m)
        val.append(value)

    def lookup(self, x_m: float) -> float | None:
        for car in sorted(self._pos, reverse=True):
            pos = self._pos[car]
            if not pos or pos[-1] + self.tolerance_m < x_m or pos[0] > x_m:
                continue
            val = self._val[car]
            j = bisect.bisect_right(pos, x_m)
            if j >= len(pos):
                return val[-1]
            if j == 0:
                return val[0]
            x0, x1 = pos[j - 1], pos[j]
            w = (x_m - x0) / (x1 - x0)
            return val[j - 1] + w * (val[j] - val[j - 1])
        return None

    def prune(self, x_m: float) -> None:
        cut = x_m - self.keep_behind_m
        for car, pos in self._pos.items():
            j = bisect.bisect_left(pos, cut)
            if j > 64:                        # in chunks: amortised O(1) per sample
                del pos[:j - 1]
                del self._val[car][:j - 1]

    def __len__(self) -> int:
        return sum(len(p) for p in self._pos.values())


# ------------------------------------------------------------------------------------ σ̄° estimator
@dataclass(frozen=True)
class EstimatorParams:
    """The online σ̄° estimator: a one-parameter family of adhesion curves and its forgetting.

    `family`: θ of the rail conditions in order from the most to the least adhesive (the hil layer gives
    plant_sim.params.RAIL_CONDITIONS extra_dry, dry, wet, extra_wet: a BECU's commissioning library);
    the estimator's candidates are θ interpolated linearly between neighbours, `steps` per pair."""

    family: tuple[tuple[float, float, float], ...] = ((0.2976, 6.548, 7.440), (0.3542, 11.03, 8.616),
                                                      (0.7129, 34.77, 14.51), (1.229, 81.12, 17.65))
    steps: int = 20                    # candidates between two neighbouring conditions
    memory_m: float = 3.0              # residuals fade as exp(−distance / memory_m) [m]
    sigma_min: float = 0.002           # no update below this slip: every curve gives μ ≈ 0 there [-]
    pi1_s_per_m: float = 1.0 / 40.0    # k1(v) = 1 + π1 v, seed 000 §3
    pi2_s_per_m: float = 1.0 / 40.0    # k2(v) = 1 + π2 v


class SigmaEstimator:
    """σ̄° from the car's own measured slip σ and adhesion μ (its braking force over its weight).

    The rail is one point c of a one-parameter family of curves μ(θ(c), σ, v) (extra dry ... extra wet,
    θ linear between the named conditions); each measurement adds (μ − μ(θ(c), σ, v))² to every
    candidate's cost, costs fade with the distance run (memory_m), and the cheapest candidate gives
    σ̄° = σ̄°(θ(ĉ)) in closed form (seed 000 §2.1).  One parameter is identifiable from a single
    operating point (μ at a given σ falls monotonically along the family), so the estimate does not
    depend on the slip moving; a free three-parameter fit of θ (recursive least squares on
    √(k2σ)/(k1μ) = θ1 + θ2 k2σ + θ3 (k2σ)², tried first) is not identifiable while the slip sits near one
    value, and drifted to a wrong peak that the slip then followed (a dual-control trap)."""

    def __init__(self, p: EstimatorParams = EstimatorParams()) -> None:
        self.p = p
        fam = np.asarray(p.family, dtype=float)
        w = np.linspace(0.0, 1.0, p.steps + 1)[:-1]
        rows = [fam[k] + (fam[k + 1] - fam[k]) * wk for k in range(len(fam) - 1) for wk in w] + [fam[-1]]
        th = np.asarray(rows)
        self.t1, self.t2, self.t3 = th[:, 0], th[:, 1], th[:, 2]
        self.bars = (-self.t2 + np.sqrt(self.t2 ** 2 + 12.0 * self.t1 * self.t3)) / (6.0 * self.t3)  # §2.1
        self.cost = np.zeros(len(th))
        self.best = int(np.argmin(np.abs(self.bars - float(np.median(self.bars)))))   # prior: mid-family
        self.bar = float(self.bars[self.best])
        self.last_x: float | None = None
        self.updates = 0

    @property
    def condition(self) -> float:
        """The estimated place in the family: 0 = the first condition, 1 = the next, ... [-]."""
        return self.best / self.p.steps

    def update(self, x_m: float, v_mps: float, sigma: float, mu: float) -> float:
        """One measurement at track position x_m [m], speed v [m/s], slip σ [-] and adhesion μ [-];
        returns σ̄° [-]."""
        p = self.p
        if self.last_x is not None:
            self.cost *= math.exp(-abs(x_m - self.last_x) / p.memory_m)
        self.last_x = x_m
        if not (sigma > p.sigma_min and math.isfinite(sigma) and math.isfinite(mu)):
            return self.bar
        s = (1.0 + p.pi2_s_per_m * v_mps) * sigma                                     # k2(v) σ
        pred = np.sqrt(s) / (self.t1 + s * (self.t2 + self.t3 * s)) / (1.0 + p.pi1_s_per_m * v_mps)  # eq. (1)
        self.cost += (pred - mu) ** 2
        self.best = int(np.argmin(self.cost))
        self.bar = float(self.bars[self.best])
        self.updates += 1
        return self.bar


# ------------------------------------------------------------------------------------ the BECU
class PreviewBecu:
    """Paper-mode BECU i: receives the train state and its car's adhesion frame from the plant and the
    σ̄° broadcasts of the other cars; sends its slip reference Σ_i° and its own σ̄° broadcast.

    `source` "oracle": σ̄° under the car is the plant's true value (the paper's assumption);
    "estimate": `SigmaEstimator` on the car's own slip and adhesion (and cars ahead broadcast estimates).
    """

    def __init__(self, p: RefParams, n_cars: int, source: str = "oracle",
                 estimator: EstimatorParams | None = None) -> None:
        if source not in SOURCE_CODE:
            raise ValueError(f"source must be one of {tuple(SOURCE_CODE)}, got {source!r}")
        self.p, self.n, self.source = p, n_cars, source
        i = p.car
        self.estimator = SigmaEstimator(estimator or EstimatorParams()) if source == "estimate" else None
        self.buffer = PreviewBuffer()
        self._train = ("PLANT_TRAIN.Speed", "PLANT_TRAIN.Accel", "PLANT_TRAIN.HeadPos")
        self._adh = (f"PLANT_CAR{i}_ADH.Slip", f"PLANT_CAR{i}_ADH.AdhesionUsed",
                     f"PLANT_CAR{i}_ADH.SigmaOptBarTrue")
        self._ahead = [(j, f"BECU{j}_PREVIEW.SigmaOptBar", f"BECU{j}_PREVIEW.Position",
                        f"BECU{j}_PREVIEW.Valid") for j in range(1, i)]
        self.inputs = self._train + self._adh + tuple(k for _, *keys in self._ahead for k in keys)
        ref, pv = f"BECU{i}_SLIP_REF", f"BECU{i}_PREVIEW"     # the reference; the car's own σ̄° broadcast
        self.k_slip_ref, self.k_preview_dist = f"{ref}.SlipRef", f"{ref}.PreviewDist"
        self.k_pred_speed, self.k_method = f"{ref}.PredSpeed", f"{ref}.Method"
        self.k_ref_source, self.k_preview_miss = f"{ref}.Source", f"{ref}.PreviewMiss"
        self.k_sigma_bar, self.k_position = f"{pv}.SigmaOptBar", f"{pv}.Position"
        self.k_bar_source, self.k_valid = f"{pv}.Source", f"{pv}.Valid"
        self.OUTPUTS = (self.k_slip_ref, self.k_preview_dist, self.k_pred_speed, self.k_method,
                        self.k_ref_source, self.k_preview_miss, self.k_sigma_bar, self.k_position,
                        self.k_bar_source, self.k_valid)
        self._version = -1
        self._out: dict[str, float] = self._idle()

    def _idle(self) -> dict[str, float]:
        source = SOURCE_CODE[self.source]
        return {self.k_slip_ref: self.p.sigma0, self.k_preview_dist: 0.0, self.k_pred_speed: 0.0,
                self.k_method: METHOD_CODE[self.p.method], self.k_ref_source: source, self.k_preview_miss: 0,
                self.k_sigma_bar: 0.0, self.k_position: 0.0, self.k_bar_source: source, self.k_valid: 0}

    def step(self, now_us: int, rx: RxTable) -> dict[str, float]:
        if rx.version == self._version:
            return self._out                      # nothing new since the last cycle
        self._version = rx.version
        lead = NAN
        for j, kv, kp, kvalid in self._ahead:             # what the cars ahead broadcast: into the buffer
            val, pos, ok = rx[kv], rx[kp], rx[kvalid]
            if ok == 1 and math.isfinite(val) and math.isfinite(pos):
                self.buffer.add(j, pos, val)
                if j == 1:
                    lead = val
        v, a, x1 = [rx[k] for k in self._train]
        sigma, mu, true_bar = [rx[k] for k in self._adh]
        if not (math.isfinite(v) and math.isfinite(a) and math.isfinite(x1) and math.isfinite(true_bar)):
            return self._out
        p = self.p
        x_own = x1 - p.spacing_m
        if self.estimator is not None:
            own = self.estimator.update(x_own, v, sigma, mu)
        else:
            own = true_bar
        if math.isnan(lead):                              # car 1 itself, or nothing from car 1 yet
            lead = own
        preview = None
        if p.method == "Dp" and p.car > 1:
            preview = self.buffer.lookup(x1 - delta_star(p.spacing_m, v, p.alpha_per_s))
            self.buffer.prune(x_own)
        ref = reference(p, v, a, own, lead, preview)
        source = SOURCE_CODE[self.source]
        self._out = {self.k_slip_ref: min(max(ref.sigma, 0.0), 0.65), self.k_preview_dist: ref.delta_m,
                     self.k_pred_speed: ref.v_pred_mps, self.k_method: METHOD_CODE[p.method],
                     self.k_ref_source: source, self.k_preview_miss: int(ref.preview_miss),
                     self.k_sigma_bar: own, self.k_position: x_own, self.k_bar_source: source,
                     self.k_valid: 1}
        return self._out
