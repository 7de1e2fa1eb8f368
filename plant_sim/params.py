"""Plant parameters: frozen dataclasses built once, every constant with its unit and its source.

Sources are the papers in `seeds/`: seed 000 (Picasso et al., adhesion curve), seed 001 (Danielson &
Di Cairano, wheel/brake dynamics), seed 003 (consensus braking, couplers and resistances), seed 004
(Wang et al., accelerometer). Values the papers do not give are marked "representative value, chosen"
with the reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from plant_sim.errors import PlantConfigError

G_MPS2 = 9.81       # standard gravity [m/s²], as the papers round it: the one definition of plant_sim


def theta_from_peak(sigma_opt: float, mu_opt: float, theta2: float = 0.0) -> tuple[float, float, float]:
    """θ = (θ1, θ2, θ3) of μ̄(θ, σ) = √σ / (θ1 + θ2 σ + θ3 σ²) whose peak is (σ̄°, μ̄°) = (sigma_opt, mu_opt).

    The maximiser of seed 000 §2.1, σ̄° = (−θ2 + √(θ2² + 12 θ1 θ3)) / (6 θ3), is the positive root of
    dμ̄/dσ = 0  ⇔  θ1 − θ2 σ − 3 θ3 σ² = 0.  With the peak value μ̄° = √σ̄° / (θ1 + θ2 σ̄° + θ3 σ̄°²) this
    is linear in (θ1, θ3) for a given θ2:
        θ3 = (√σ̄°/μ̄° − 2 θ2 σ̄°) / (4 σ̄°²),   θ1 = θ2 σ̄° + 3 θ3 σ̄°².
    """
    s, m = float(sigma_opt), float(mu_opt)
    if not (0.0 < s < 1.0 and 0.0 < m < 2.0 and math.isfinite(theta2)):
        raise PlantConfigError(f"theta_from_peak: need 0 < sigma_opt < 1 and 0 < mu_opt < 2, finite theta2; "
                               f"got sigma_opt={sigma_opt!r}, mu_opt={mu_opt!r}, theta2={theta2!r}")
    theta3 = (math.sqrt(s) / m - 2.0 * theta2 * s) / (4.0 * s * s)
    theta1 = theta2 * s + 3.0 * theta3 * s * s
    if theta3 <= 0.0 or theta1 <= 0.0:
        raise PlantConfigError(f"theta_from_peak: theta2={theta2!r} too large for the peak "
                               f"({sigma_opt!r}, {mu_opt!r}): need theta2 < 1/(2 mu_opt sqrt(sigma_opt)) = "
                               f"{1.0 / (2.0 * m * math.sqrt(s)):.4g}")
    return (theta1, float(theta2), theta3)


def theta2_for_locked_ratio(sigma_opt: float, mu_opt: float, locked_ratio: float) -> float:
    """θ2 such that the curve with peak (σ̄°, μ̄°) keeps μ̄(θ, 1) = locked_ratio · μ̄° for a locked wheel (σ = 1).

    With θ1, θ3 from `theta_from_peak`, θ1 + θ2 + θ3 = 1/(locked_ratio μ̄°) is linear in θ2.
    """
    s, m = float(sigma_opt), float(mu_opt)
    a = math.sqrt(s) / m
    const = (1.0 + 3.0 * s * s) * a / (4.0 * s * s)        # θ1 + θ3 at θ2 = 0
    slope = (1.0 + s) - (1.0 + 3.0 * s * s) / (2.0 * s)     # d(θ1 + θ2 + θ3)/dθ2
    return (1.0 / (locked_ratio * m) - const) / slope


# Rail conditions of seed 000 §3 ("extra dry" ... "extra wet"). The paper gives no numbers; we choose the
# peak (σ̄°, μ̄°) at v = 0 and, through θ2, the adhesion left to a locked wheel (σ = 1, v = 0):
# LOCKED_RATIO = 0.2 (representative value, chosen: with θ2 = 0 this curve family leaves a locked
# wheel only ~2 % of the peak adhesion, i.e. a sliding wheel would not brake at all; real sliding
# wheel/rail friction is a sizeable fraction of the peak. 0.2 is feasible for all four conditions, the
# family allows at most 2√σ̄°/(1+σ̄°) ≈ 0.24 for extra_wet).
LOCKED_RATIO = 0.2
RAIL_PEAKS: dict[str, tuple[float, float]] = {
    # name: (σ̄° [-], μ̄° [-]) at v = 0; representative values, chosen (seed 000 §3 names the conditions
    # from extra dry to extra wet but gives no numbers); at speed v both scale by 1/k(v), eq. (2)
    "extra_dry": (0.04, 0.35),
    "dry": (0.03, 0.25),
    "wet": (0.02, 0.10),
    "extra_wet": (0.015, 0.05),
}
# Resulting θ (rounded) and peaks, checked by tests/plant/test_adhesion.py:
#   extra_dry θ = (0.2976, 6.548, 7.440)   σ̄° = 0.040  μ̄° = 0.350   μ̄(θ, σ=1) = 0.070
#   dry       θ = (0.3542, 11.03, 8.616)   σ̄° = 0.030  μ̄° = 0.250   μ̄(θ, σ=1) = 0.050
#   wet       θ = (0.7129, 34.77, 14.51)   σ̄° = 0.020  μ̄° = 0.100   μ̄(θ, σ=1) = 0.020
#   extra_wet θ = (1.229, 81.12, 17.65)    σ̄° = 0.015  μ̄° = 0.050   μ̄(θ, σ=1) = 0.010
RAIL_CONDITIONS: dict[str, tuple[float, float, float]] = {
    name: theta_from_peak(s, m, theta2_for_locked_ratio(s, m, LOCKED_RATIO))
    for name, (s, m) in RAIL_PEAKS.items()
}


def _require(ok: bool, cls: str, msg: str) -> None:
    if not ok:
        raise PlantConfigError(f"{cls}: {msg}")


@dataclass(frozen=True)
class AdhesionParams:
    """Speed dependence of the adhesion curve, eq. (1) seed 000: k_i(v) = 1 + π_i v."""

    pi1_s_per_m: float = 1.0 / 40.0   # k1(v) = 1 + v/40, seed 000 §3 (μ° halves at 40 m/s)
    pi2_s_per_m: float = 1.0 / 40.0   # k2(v) = 1 + v/40, seed 000 §3 (σ° halves at 40 m/s)
    # flat adhesion μ = constant_mu for σ ≥ CONST_MU_RAMP_SIGMA (test hook "constant adhesion"); None = curve
    constant_mu: float | None = None
    # Seed 001's slip-speed adhesion curve family instead of seed 000's (θ and v are then ignored):
    # (μ̂ [-], ŝ [m/s]) = peak value and its slip speed; μ(s) = 2 μ̂ (s/ŝ) / (1 + (s/ŝ)²), monotone below
    # the peak and concave for s < √3 ŝ (adhesion.mu_slip_speed_scalar). Seed 001 §IV: f_max = 0.2 M g,
    # i.e. μ̂ = 0.2; ŝ = 0.155 m/s is the parameter set of issue #4. None = seed 000's curve.
    slip_speed_peak: tuple[float, float] | None = None
    # With slip_speed_peak: beyond the peak μ(s) never falls below this fraction of μ̂, the friction of a
    # sliding wheel [-]. 0 = seed 001's curve, which leaves a locked wheel at 58 m/s μ = 0.001 (μ̂ = 0.2): no
    # torque to spin it back up for minutes. Seed 000's rail curves leave a locked wheel 0.2 of the peak
    # (LOCKED_RATIO, chosen above for the same reason).
    slip_speed_slide_ratio: float = 0.0

    def __post_init__(self) -> None:
        _require(self.pi1_s_per_m >= 0.0 and self.pi2_s_per_m >= 0.0, "AdhesionParams",
                 f"pi1_s_per_m, pi2_s_per_m must be >= 0, got {self.pi1_s_per_m}, {self.pi2_s_per_m}")
        _require(self.constant_mu is None or 0.0 <= self.constant_mu < 2.0, "AdhesionParams",
                 f"constant_mu must be None or in [0, 2), got {self.constant_mu!r}")
        if self.slip_speed_peak is not None:
            mu_pk, s_pk = (float(v) for v in self.slip_speed_peak)
            _require(0.0 < mu_pk < 2.0 and 0.0 < s_pk < 10.0, "AdhesionParams",
                     f"slip_speed_peak must be (mu_peak in (0, 2), slip_peak_mps in (0, 10)), "
                     f"got {self.slip_speed_peak!r}")
            _require(self.constant_mu is None, "AdhesionParams",
                     "give at most one of constant_mu and slip_speed_peak")
            object.__setattr__(self, "slip_speed_peak", (mu_pk, s_pk))
        _require(0.0 <= self.slip_speed_slide_ratio < 1.0, "AdhesionParams",
                 f"slip_speed_slide_ratio must be in [0, 1), got {self.slip_speed_slide_ratio!r}")


@dataclass(frozen=True)
class TrainParams:
    """The train: n cars in a row, car 1 leading, couplers between neighbours, one lumped wheelset per car."""

    masses_kg: tuple[float, ...] = (40_000.0,) * 6   # representative value, chosen: loaded metro car
    car_pitch_m: float = 25.0             # car centres' distance, couplers at rest (2d + l0, eq. 1 seed 003)
    coupler_k_N_per_m: float = 80_000.0   # κ, seed 003 Table 2
    coupler_eps_per_m2: float = -0.5      # ε, seed 003 Table 2
    coupler_c_Ns_per_m: float = 2.0e4     # damping, representative value, chosen: ζ ≈ 0.25 for two 40 t cars
    # Draft-gear travel and solid end stop (representative values, chosen): seed 003's spring alone
    # would stretch ~0.5 m under the ~40 kN a car-to-car brake difference gives, and with ε < 0 its
    # force falls past |Δl| = 0.82 m (cars could pass through each other). Real couplers go solid
    # after ~0.1 m of travel; the stop stiffness keeps ω·dt ≈ 0.03 at dt = 1 ms. Its damping grows with
    # the penetration b (Hunt–Crossley contact, force k b + χ |b| ḃ, continuous at separation): ζ ≈ 0.5
    # for two 40 t cars 5 mm into the stop, as a friction draft gear absorbs the impact.
    coupler_stroke_m: float = 0.10
    coupler_stop_k_N_per_m: float = 1.0e7
    coupler_stop_chi_Ns_per_m2: float = 1.0e8
    # Davis resistance f_r = c0 + c1 v + c2 v² per car, eq. (4) seed 003 (representative values, chosen:
    # ≈ 3 kN for a 40 t car at 25 m/s, the lead car's nose adds aerodynamic drag)
    davis_c0_N: float = 800.0
    davis_c1_Ns_per_m: float = 25.0
    davis_c2_Ns2_per_m2: float = 3.0
    davis_c2_lead_Ns2_per_m2: float = 8.0
    wheel_radius_m: float = 0.46          # r, representative value, chosen: new metro wheel Ø 920 mm
    wheel_inertia_kgm2: float = 600.0     # J of one lumped wheelset per car (4 axles incl. discs), chosen
    g_mps2: float = G_MPS2                # gravity

    def __post_init__(self) -> None:
        object.__setattr__(self, "masses_kg", tuple(float(m) for m in self.masses_kg))
        _require(len(self.masses_kg) >= 1 and all(math.isfinite(m) and m > 0 for m in self.masses_kg),
                 "TrainParams", f"masses_kg must hold one positive mass per car, got {self.masses_kg!r}")
        for name in ("car_pitch_m", "coupler_k_N_per_m", "wheel_radius_m", "wheel_inertia_kgm2", "g_mps2",
                     "coupler_stroke_m", "coupler_stop_k_N_per_m"):
            val = getattr(self, name)
            _require(val > 0.0 and not math.isnan(val), "TrainParams", f"{name} must be > 0, got {val!r}")
        for name in ("coupler_c_Ns_per_m", "coupler_stop_chi_Ns_per_m2", "davis_c0_N", "davis_c1_Ns_per_m",
                     "davis_c2_Ns2_per_m2", "davis_c2_lead_Ns2_per_m2"):
            val = getattr(self, name)
            _require(math.isfinite(val) and val >= 0.0, "TrainParams", f"{name} must be >= 0, got {val!r}")
        _require(math.isfinite(self.coupler_eps_per_m2), "TrainParams", "coupler_eps_per_m2 must be finite")

    @property
    def n_cars(self) -> int:
        return len(self.masses_kg)


@dataclass(frozen=True)
class BrakeParams:
    """Pneumatic brake per car: EP valve, WSP dump valve, cylinder, pressure → torque hysteresis."""

    p_max_Pa: float = 450e3                # reservoir pressure p̄, eq. (5) seed 001 (value chosen)
    fill_rate_Pa_per_s: float = 1.0e6      # EP valve capacity at full opening, representative value, chosen
    vent_rate_Pa_per_s: float = 1.5e6      # EP valve exhaust at full opening, representative value, chosen
    wsp_vent_rate_Pa_per_s: float = 2.0e6  # WSP dump valve, representative value, chosen (dumps in ~0.2 s)
    # Hysteresis lines of eqs. (6)/(10a) seed 001: squeeze τ = ᾱ p + β̄, release τ = α̲ p + β̲.
    # Representative values, chosen: 0.08 N·m/Pa gives 33.6 kN·m (≈ 0.19 g on a 40 t car) at p̄; the
    # squeeze line crosses 0 at the 30 kPa return-spring preload; the release line lies 20 kPa above.
    alpha_squeeze_Nm_per_Pa: float = 0.08
    beta_squeeze_Nm: float = -0.08 * 30e3
    alpha_release_Nm_per_Pa: float = 0.08
    beta_release_Nm: float = -0.08 * 30e3 + 0.08 * 20e3
    # How the cylinder is filled. "valve": the EP valve's opening (ValveCmd) at the rates above, the BECU
    # closes the pressure loop. "lag": the cylinder has its own integrated pressure controller (seed 001
    # §II-B) and follows the set-point u (CylPressureSet) as the first-order lag of eq. (4) with
    # ṗ = (u − p)/Tp, seed 001 §IV; the WSP dump valve still holds (HOLD) or vents (VENT: u = 0, §II-C).
    pressure_model: str = "valve"
    tp_s: float = 0.05                     # Tp, cylinder time constant of the "lag" model, seed 001 §IV

    def __post_init__(self) -> None:
        _require(self.pressure_model in ("valve", "lag"), "BrakeParams",
                 f"pressure_model must be 'valve' or 'lag', got {self.pressure_model!r}")
        _require(math.isfinite(self.tp_s) and self.tp_s > 0.0, "BrakeParams",
                 f"tp_s must be > 0, got {self.tp_s!r}")
        for name in ("p_max_Pa", "fill_rate_Pa_per_s", "vent_rate_Pa_per_s", "wsp_vent_rate_Pa_per_s",
                     "alpha_squeeze_Nm_per_Pa", "alpha_release_Nm_per_Pa"):
            val = getattr(self, name)
            _require(math.isfinite(val) and val > 0.0, "BrakeParams", f"{name} must be > 0, got {val!r}")
        # the release line must not lie below the squeeze line anywhere in [0, p̄]
        for p in (0.0, self.p_max_Pa):
            sq = self.alpha_squeeze_Nm_per_Pa * p + self.beta_squeeze_Nm
            rel = self.alpha_release_Nm_per_Pa * p + self.beta_release_Nm
            _require(rel >= sq, "BrakeParams", f"release line below squeeze line at p = {p} Pa")


@dataclass(frozen=True)
class PadParams:
    """Disc/pad friction that varies during a stop (seed 004 §4.1) and the disc's temperature rise.

    eq. (24): F_b(t) = P_c(t) · θ · μ_d(t): the brake's torque is the pressure → torque line of
    `BrakeParams` (which assumes μ_nominal) times μ_d(t)/μ_nominal.
    eq. (25): μ_d(t) = μ_d0 · (n_v e^{m_v v_d(t)} + 1) · (n_T e^{m_T T_d(t)} + 1), with v_d the sliding
    speed of the pad on the disc (ω · friction radius) and T_d the disc's temperature rise.
    Temperature: C dT_d/dt = η τ ω − G T_d (braking power into the disc surface, less what conduction
    into the disc body and convection take away).  The paper gives the form but no numbers; the values
    below are representative values, chosen so that a 60 km/h stop at 1.32 m/s² drifts by about ±20 %
    around μ_nominal (low while the disc is cold, higher at low speed), and a 180 km/h stop, whose disc
    heats up early, much less (seed 004 Fig. 14: "as the initial speed increases, the alteration
    becomes less prominent").
    """

    mu_nominal: float = 0.35             # μ_d0 of eq. (32): the mean coefficient the brake is designed for
    mu_steady: float = 0.35              # μ_d0 of eq. (25): steady-state coefficient (hot disc, high speed)
    n_v: float = 0.25                    # speed factor amplitude [-] (μ +25 % as v_d → 0), chosen
    m_v_s_per_m: float = -0.25           # speed factor exponent [s/m], chosen
    n_T: float = -0.22                   # temperature factor amplitude [-] (cold disc: μ −22 %), chosen
    m_T_per_K: float = -1.0 / 35.0       # temperature factor exponent [1/K], chosen
    friction_radius_m: float = 0.25      # effective pad radius on the disc: v_d = ω r_f (chosen)
    # disc surfaces of one car (8 discs): effective heat capacity of the layer that the pad heats, and the
    # conductance that takes heat into the disc body (time constant C/G = 30 s) (chosen)
    heat_capacity_J_per_K: float = 1.0e5
    cooling_W_per_K: float = 1.0e5 / 30.0
    heat_fraction: float = 1.0           # η: share of the braking power that goes into the discs
    initial_temp_rise_K: float = 0.0     # T_d at the start of the run (a disc warm from a previous stop)

    def __post_init__(self) -> None:
        for name in ("mu_nominal", "mu_steady", "friction_radius_m", "heat_capacity_J_per_K"):
            val = getattr(self, name)
            _require(math.isfinite(val) and val > 0.0, "PadParams", f"{name} must be > 0, got {val!r}")
        for name in ("n_v", "m_v_s_per_m", "n_T", "m_T_per_K", "cooling_W_per_K", "heat_fraction",
                     "initial_temp_rise_K"):
            _require(math.isfinite(getattr(self, name)), "PadParams", f"{name} must be finite")
        _require(self.n_v > -1.0 and self.n_T > -1.0, "PadParams",
                 f"n_v and n_T must be > -1 (friction stays positive), got {self.n_v}, {self.n_T}")
        _require(self.cooling_W_per_K >= 0.0 and 0.0 <= self.heat_fraction <= 1.0, "PadParams",
                 "cooling_W_per_K must be >= 0 and heat_fraction in [0, 1]")


@dataclass(frozen=True)
class SensorParams:
    """What the car's sensors add to the truth: white noise (std) and quantisation (quantum)."""

    axle_speed_noise_std_rad_s: float = 0.02   # representative value, chosen (tooth-wheel jitter)
    axle_speed_quantum_rad_s: float = 0.005    # representative value, chosen
    pressure_noise_std_Pa: float = 1000.0      # representative value, chosen (≈ 0.2 % of 450 kPa span)
    pressure_quantum_Pa: float = 10.0          # representative value, chosen
    accel_noise_std_mps2: float = 0.02         # representative value, chosen (MEMS, seed 004 §3)
    accel_quantum_mps2: float = 0.001          # representative value, chosen

    def __post_init__(self) -> None:
        for name in ("axle_speed_noise_std_rad_s", "pressure_noise_std_Pa", "accel_noise_std_mps2"):
            val = getattr(self, name)
            _require(math.isfinite(val) and val >= 0.0, "SensorParams", f"{name} must be >= 0, got {val!r}")
        for name in ("axle_speed_quantum_rad_s", "pressure_quantum_Pa", "accel_quantum_mps2"):
            val = getattr(self, name)
            _require(math.isfinite(val) and val > 0.0, "SensorParams", f"{name} must be > 0, got {val!r}")


@dataclass(frozen=True)
class PlantParams:
    """Everything the plant needs; dt_us is the fixed physics step (1 ms, seed 003 §4 samples at 1 ms)."""

    train: TrainParams = field(default_factory=TrainParams)
    brake: BrakeParams = field(default_factory=BrakeParams)
    adhesion: AdhesionParams = field(default_factory=AdhesionParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    dt_us: int = 1000
    pad: PadParams | None = None         # variable pad friction, seed 004 eqs. (24)–(25); None = constant

    def __post_init__(self) -> None:
        _require(isinstance(self.dt_us, int) and not isinstance(self.dt_us, bool) and self.dt_us > 0,
                 "PlantParams", f"dt_us must be a positive int number of microseconds, got {self.dt_us!r}")

    @property
    def n_cars(self) -> int:
        return self.train.n_cars

