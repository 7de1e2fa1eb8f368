"""Observer-driven distributed consensus braking, seed 003 §3: one controller per car (BECU) and the BCU's
virtual leader.

Each BECU knows the world only through CAN: its own car's speed v_i and displacement x_i (the car's
sensor frame), the speeds of all other cars (complete graph L_a, eq. (6)) and the displacements of its
neighbours (path graph L_b, eq. (7)) from their BECUs' frames, and the desired curve v*(t) (eq. (9)) from
the BCU.  Its command is u_i = u_i1 + u_i2 + u_i3 (eq. (24)) with the braking force F_a,i = K_b,i u_i.

How the paper's equations are read here (the paper mixes units; these readings make Table 2's gains
give the behaviour the paper reports — convergence < 0.04 s, observer settling in 20 ms):

- The law is written per unit mass: every term is an acceleration [m/s²] and u_i = (m_i / K_b,i) ·
  (u_i1 + u_i2 + u_i3) [N per unit of K_b].  Then eq. (30)'s error dynamics hold as printed.
- Relative displacements in the α₂ term and in the potential field are in centimetres (the unit in
  which the paper states θ₁ = −1 cm and θ₂ = 1 cm): ξ_ij = (x_i − x_j − r_ij)/1 cm, where r_ij is the
  rest offset of the two car centres (x_i − x_j − r_ij is the coupler's Δl of eq. (1), sign per side).
- Eq. (26) as printed, 1/(|x|² − θ₁²) + 1/(θ₂² − |x|²), is identically zero when θ₁ = −θ₂; it is read
  as the barrier U(ξ) = 1/(ξ − θ₁)² + 1/(θ₂ − ξ)², which is finite inside (θ₁, θ₂), grows without bound
  at both edges and is flat (∇U = 0) at the band's middle.  A sampled controller cannot use an
  unbounded term: δ∇U is saturated at `u2_max_mps2` and ξ is clipped inside the band (chosen).
- Eq. (29)'s "v*" is read as the desired curve's deceleration a* = −v̇*, the feed-forward of eq. (9),
  and its compensation k_d φ̂ as the estimate itself (φ̂ per unit mass cancels φ_i/m_i in eq. (28));
  k_d = 50 s⁻¹ of Table 2 is the bandwidth of the filter that extracts φ̂ from the observer's switching
  term (the equivalent control of eq. (21)): its 1/k_d = 20 ms is the paper's observer settling time.

Time is passed in (integer µs); no I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import ClassVar

from firmware_py.rx import RxTable

KMH = 1.0 / 3.6                       # m/s per km/h


@dataclass(frozen=True)
class ConsensusGains:
    """Gains of eqs. (25)-(29), Table 2 of seed 003, in the per-unit-mass reading of the module doc."""

    alpha1_per_s: float = 120.0       # α₁ [m/s² per m/s of speed difference], Table 2
    alpha2_per_s2_cm: float = 100.0   # α₂ [m/s² per cm of relative displacement], Table 2
    k_per_s: float = 36.0             # k_i [m/s² per m/s of tracking error], Table 2
    kd_per_s: float = 50.0            # k_di [1/s], Table 2: bandwidth of the φ̂ filter (module doc)
    delta_mps2_cm3: float = 2.0       # δ [m/s² · cm³], Table 2
    theta1_cm: float = -1.0           # θ₁ [cm], Table 2
    theta2_cm: float = 1.0            # θ₂ [cm], Table 2
    u2_max_mps2: float = 100.0        # |δ Σ ∇U| saturation per car [m/s²], chosen (sampled barrier)
    band_clip: float = 0.02           # ξ is kept 2 % of the band's width inside each edge, chosen
    # Sampled-data limit (chosen, not in the paper): the law is continuous-time; run every T with about one
    # more T of bus latency, a velocity gain λ = n α₁ + k is stable only while λ·2T stays below ~1.  With
    # loop_gain ρ the BECU scales α₁, k by s = min(1, ρ / (λ 2T)) and α₂, δ, u2_max by s² (stiffness ∝ λ²).
    # None: the paper's gains unscaled (what its 1 ms simulation without a bus uses).
    loop_gain: float | None = None

    def __post_init__(self) -> None:
        if not self.theta1_cm < self.theta2_cm:
            raise ValueError(f"theta1_cm {self.theta1_cm} must be below theta2_cm {self.theta2_cm}")
        for name in ("alpha1_per_s", "alpha2_per_s2_cm", "k_per_s", "kd_per_s", "delta_mps2_cm3",
                     "u2_max_mps2"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class ObserverParams:
    """Sliding-mode disturbance observer, eq. (11) seed 003.  Gains chosen to satisfy eq. (18)."""

    gamma1_mps: float = 0.5           # γ_i1 [m/s] ≥ |e_i2|, eq. (18), chosen
    gamma2_mps2: float = 2.0          # γ_i2 [m/s²] ≥ |φ_i|/m_i, eq. (18): Davis ≤ 0.2, couplers ≤ 0.05,
    #                                   case-3 disturbance 0.5 m/s² (chosen, with margin)
    filter_per_s: float = 50.0        # φ̂ filter bandwidth [1/s] = k_d of Table 2 (module doc)
    layer_mps: float = 0.005          # least boundary-layer half-width [m/s], chosen: 5 quanta of the DBC's
    #                                   1 mm/s speed, so that quantisation does not drive the switching


@dataclass(frozen=True)
class ConsensusBecuParams:
    """One car's consensus BECU."""

    car: int                          # 1-based; car 1 leads
    n_cars: int
    mass_kg: float                    # m_i, Table 2
    pitch_m: float                    # rest distance of car centres 2d + l0 [m], eq. (1)
    brake_gain: float = 1.0           # K_b,i [N per unit of u], eq. (3): 1 = u in newtons (chosen)
    gains: ConsensusGains = field(default_factory=ConsensusGains)
    observer: ObserverParams = field(default_factory=ObserverParams)
    compensate: bool = True           # use φ̂ in u_i3 (eq. (29)); False: the paper's "without observer"
    u_max: float = 8.19e6             # |u| limit [units of u] = the DBC range of ForceCmd
    stale_us: int = 50_000            # an input older than this counts as missing [µs], chosen
    period_us: int = 1_000            # the BECU's own cycle [µs] (its frame's DBC cycle)
    sample_period_us: int = 1_000     # period of the sensor frames [µs] (their DBC cycle): a neighbour's
    #                                   position sampled k periods earlier is moved on by v_j k T


# ----------------------------------------------------------------------------- pure equation helpers
def desired_speed_mps(t_us: int, v0_mps: float, decel_mps2: float) -> float:
    """v*(t) = v*(t0) − a_r t [m/s], eq. (9) seed 003 (not below 0).  Table 2: v*(t0) = 90 km/h,
    a* = 3.5 km/(h·s) = 0.972 m/s²."""
    return max(0.0, v0_mps - decel_mps2 * t_us * 1e-6)    # eq. (9)


def potential(xi: float, theta1: float, theta2: float) -> float:
    """U(ξ) = 1/(ξ − θ₁)² + 1/(θ₂ − ξ)², eq. (26) as read in the module doc [cm⁻²], θ₁ < ξ < θ₂."""
    return 1.0 / (xi - theta1) ** 2 + 1.0 / (theta2 - xi) ** 2


def potential_gradient(xi: float, theta1: float, theta2: float) -> float:
    """∇U(ξ) = −2/(ξ − θ₁)³ + 2/(θ₂ − ξ)³ [cm⁻³], eq. (26) differentiated; > 0 for ξ above the middle."""
    return -2.0 / (xi - theta1) ** 3 + 2.0 / (theta2 - xi) ** 3


def consensus_term(v_i: float, v_others: list[float], xi_neighbours: list[float],
                   alpha1: float, alpha2: float) -> float:
    """u_i1 = α₁ Σ_j a_ij (v_i − v_j) + α₂ Σ_j b_ij (x_i − x_j − θ_ij) [m/s²], eq. (25) seed 003.

    v_others: speeds of the cars i hears (a_ij = 1, the complete graph of eq. (6)); xi_neighbours:
    ξ_ij of its neighbours (b_ij = 1, the path graph of eq. (7)) in cm, measured from the band's middle
    (θ_ij = the rest offset)."""
    return alpha1 * sum(v_i - v_j for v_j in v_others) + alpha2 * sum(xi_neighbours)   # eq. (25)


def potential_term(xi_neighbours: list[float], g: ConsensusGains) -> tuple[float, bool]:
    """u_i2 = δ Σ_j b_ij ∇U_ij(ξ_ij) [m/s²], eq. (27) seed 003, and whether it was saturated."""
    lo = g.theta1_cm + g.band_clip * (g.theta2_cm - g.theta1_cm)
    hi = g.theta2_cm - g.band_clip * (g.theta2_cm - g.theta1_cm)
    total = g.delta_mps2_cm3 * sum(potential_gradient(min(hi, max(lo, xi)), g.theta1_cm, g.theta2_cm)
                                   for xi in xi_neighbours)                             # eq. (27)
    if total > g.u2_max_mps2:
        return g.u2_max_mps2, True
    if total < -g.u2_max_mps2:
        return -g.u2_max_mps2, True
    return total, False


def anti_disturbance_term(v_err_mps: float, decel_mps2: float, phi_hat_mps2: float, k: float,
                          compensate: bool) -> float:
    """u_i3 = k_i v_ei + a* + φ̂_i [m/s²], eq. (29) seed 003 per unit mass (module doc); without
    compensation the φ̂ term is left out."""
    return k * v_err_mps + decel_mps2 + (phi_hat_mps2 if compensate else 0.0)          # eq. (29)


def command(mass_kg: float, brake_gain: float, u1: float, u2: float, u3: float) -> float:
    """u_i = (m_i / K_b,i)(u_i1 + u_i2 + u_i3), eq. (24) seed 003 [units of u, N when K_b = 1]."""
    return mass_kg / brake_gain * (u1 + u2 + u3)                                          # eq. (24)


SAMPLE_MODULO = 16                    # the sensor frames' Sample counter runs 0..15
POSITION_WRAP_M = 419.4304            # Position signals carry x modulo 2**22 × 0.1 mm (DBC)


def wrap_difference(d_m: float) -> float:
    """A difference of two wrapped positions brought into [−W/2, W/2) (W = POSITION_WRAP_M) [m]."""
    half = 0.5 * POSITION_WRAP_M
    return (d_m + half) % POSITION_WRAP_M - half


def relative_displacement_cm(x_i: float, x_j: float, rest_m: float) -> float:
    """ξ_ij = (x_i − x_j − r_ij) / 1 cm: the deformation of the coupler between cars i and j seen from car i
    (eq. (1) seed 003: Δl_i for j = i + 1, −Δl_j for j = i − 1) [cm]."""
    return wrap_difference(x_i - x_j - rest_m) * 100.0


def sign(x: float) -> float:
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


class SlidingModeObserver:
    """Eq. (11) seed 003, explicit Euler at the controller's cycle T:

        x̂' = v̂ + γ₁ sw(e₁),   v̂' = −K_b u / m + γ₂ sw(e₂),   e₁ = x − x̂,  e₂ = v − v̂   (eqs. (11)-(12))

    and φ̂ (per unit mass, m/s²) the switching term γ₂ sw(e₂) low-pass filtered at `filter_per_s`: on the
    sliding surface its mean is φ_i/m_i (eqs. (21)-(22)).  When |e₂| exceeds γ₁ the gain condition (18)
    no longer holds (a skidding car loses more braking force than γ₂ covers) and the estimates restart on
    the measured state, else v̂ would wind up with the unrealised command (chosen; the paper's φ stays
    within γ₂).  sw is the sign function of eq. (11) with a
    boundary layer (chosen): sw(e) = sat(e / max(γ T, layer)), so that the sampled observer reaches the
    surface in one step instead of chattering around it by ±γ T (at T = 5 ms a pure sign gives a limit
    cycle whose φ̂ ripple exceeds φ itself), and the speed's quantum does not drive the switching."""

    def __init__(self, p: ObserverParams) -> None:
        self.p = p
        self.x_hat: float | None = None
        self.v_hat = 0.0
        self.phi_hat = 0.0

    def update(self, dt_s: float, x_m: float, v_mps: float, u_accel_mps2: float) -> float:
        """One step: correct with the measured x, v, then predict over the next `dt_s` with the nominal
        braking deceleration K_b u/m acting until then (the command sent the cycle before: the plant
        applies a command one cycle after it was computed); returns φ̂ [m/s²]."""
        p = self.p
        if self.x_hat is None:                  # first measurement: start on the surface
            self.x_hat, self.v_hat = x_m, v_mps
        e1 = wrap_difference(x_m - self.x_hat)  # eq. (12); x arrives modulo POSITION_WRAP_M
        e2 = v_mps - self.v_hat
        switch = p.gamma2_mps2 * switching(e2, max(p.gamma2_mps2 * dt_s, p.layer_mps))
        if abs(e2) > p.gamma1_mps:              # eq. (18) violated (|φ|/m > γ2, e.g. a skidding car's
            self.x_hat, self.v_hat = x_m, v_mps  # lost braking force): restart on the surface, φ̂ = ±γ2
            e1 = 0.0
        self.x_hat += dt_s * (self.v_hat + p.gamma1_mps * switching(e1, p.gamma1_mps * dt_s))   # eq. (11)
        self.x_hat %= POSITION_WRAP_M
        self.v_hat += dt_s * (-u_accel_mps2 + switch)                                          # eq. (11)
        a = min(1.0, dt_s * p.filter_per_s)
        self.phi_hat += a * (switch - self.phi_hat)                      # eqs. (21)-(22), filtered
        return self.phi_hat


def switching(e: float, layer: float) -> float:
    """sign(e) of eq. (11) with a boundary layer of half-width `layer`: e/layer inside, ±1 outside."""
    if layer <= 0.0:
        return sign(e)
    r = e / layer
    return 1.0 if r > 1.0 else (-1.0 if r < -1.0 else r)


def sampled_gains(g: ConsensusGains, n_cars: int, period_us: int) -> tuple[ConsensusGains, float]:
    """The gains a BECU running every `period_us` uses, and the scale s applied (ConsensusGains.loop_gain)."""
    if g.loop_gain is None:
        return g, 1.0
    lam = n_cars * g.alpha1_per_s + g.k_per_s        # fastest velocity mode of eqs. (25), (29) [1/s]
    s = min(1.0, g.loop_gain / (lam * 2.0 * period_us * 1e-6))
    return replace(g, alpha1_per_s=g.alpha1_per_s * s, k_per_s=g.k_per_s * s,
                   alpha2_per_s2_cm=g.alpha2_per_s2_cm * s * s, delta_mps2_cm3=g.delta_mps2_cm3 * s * s,
                   u2_max_mps2=g.u2_max_mps2 * s * s), s


def delayed_loop_poles(lam_t: float) -> tuple[complex, complex]:
    """Poles of the sampled velocity-disagreement mode with one sample of delay [-] (chosen model).

    The disagreement e of a pair of cars obeys ė = −λ e with λ = n α₁ + k (eqs. (25), (29)); sampled every T
    and acting one sample late (the speeds of the cars whose BECU frames come later in the cycle are one
    cycle old, and a command acts up to T after its sample): e_{k+1} = e_k − λT e_{k−1}, i.e.
    z² − z + λT = 0.  Both poles lie inside the unit circle iff 0 < λT < 1 (Jury: a₀ = λT < 1,
    1 + a₁ + a₀ = λT > 0, 1 − a₁ + a₀ = 2 + λT > 0).  ConsensusGains.loop_gain ρ sets λT = ρ/2."""
    disc = complex(1.0 - 4.0 * lam_t) ** 0.5
    return (1.0 + disc) / 2.0, (1.0 - disc) / 2.0


def _finite(x: float) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


class ConsensusBecu:
    """The consensus-braking BECU of car i: `step(now_us, rx) -> outputs` (DBC signals)."""

    def __init__(self, p: ConsensusBecuParams) -> None:
        self.p = p
        i, n = p.car, p.n_cars
        own = f"PLANT_CONS_CAR{i}"                      # the car's sensor frame
        self.k_own_speed, self.k_own_pos = f"{own}.Speed", f"{own}.Position"
        self.k_own_sample = f"{own}.Sample"
        # every other car j: (speed key, sample key) — the complete graph of eq. (6)
        self.others = [(f"BECU{j}_CONS.Speed", f"BECU{j}_CONS.Sample") for j in range(1, n + 1) if j != i]
        # neighbour j: (position key, speed key, sample key, rest offset r_ij = x_i − x_j at rest [m])
        self.neighbours = [(f"BECU{j}_CONS.Position", f"BECU{j}_CONS.Speed", f"BECU{j}_CONS.Sample",
                            (j - i) * p.pitch_m) for j in (i - 1, i + 1) if 1 <= j <= n]
        self.k_v_ref, self.k_a_ref = "CONS_REF.VRef", "CONS_REF.ARef"     # the virtual leader's v*, a*
        self.inputs = (self.k_own_speed, self.k_own_pos, self.k_own_sample,
                       *[k for o in self.others for k in o],
                       *[pos_key for pos_key, _, _, _ in self.neighbours],
                       self.k_v_ref, self.k_a_ref)
        out = f"BECU{i}_CONS"
        diag = f"BECU{i}_CONS_DIAG"
        self.k_force, self.k_speed, self.k_pos = f"{out}.ForceCmd", f"{out}.Speed", f"{out}.Position"
        self.k_sample = f"{out}.Sample"
        self.k_obs, self.k_sat = f"{out}.ObserverOn", f"{out}.BarrierSat"
        self.k_missing = f"{out}.InputMissing"
        self.k_phi, self.k_u1, self.k_u2, self.k_verr = (f"{diag}.PhiHat", f"{diag}.ConsensusAccel",
                                                         f"{diag}.PotentialAccel", f"{diag}.SpeedError")
        self.outputs = (self.k_force, self.k_speed, self.k_pos, self.k_sample, self.k_obs, self.k_sat,
                        self.k_missing,
                        self.k_phi, self.k_u1, self.k_u2, self.k_verr)
        self.observer = SlidingModeObserver(p.observer)
        self.gains, self.gain_scale = sampled_gains(p.gains, p.n_cars, p.period_us)
        # older than 7 sensor periods, a value cannot be aligned by the 4-bit Sample tag: missing
        self.stale_us = min(p.stale_us, (SAMPLE_MODULO // 2 - 1) * p.sample_period_us)
        self.u = 0.0                    # last command sent [units of u]
        self.last_us: int | None = None

    def _fresh(self, rx: RxTable, key: str, now_us: int,
               limit_us: int | None = None) -> float | None:
        value = rx[key]
        if not _finite(value):
            return None
        age = rx.age_us(key, now_us)
        if age is not None and age > (self.stale_us if limit_us is None else limit_us):
            return None
        return float(value)

    @staticmethod
    def _lag(own_sample: float, sample: float) -> int | None:
        """Sensor periods by which a value tagged `sample` is older than the own sample, in [−8, 7]
        (negative: newer, when the own sensor frame of this cycle has not arrived yet; None: untagged)."""
        if not (_finite(own_sample) and _finite(sample)):
            return None
        half = SAMPLE_MODULO // 2
        return (int(own_sample) - int(sample) + half) % SAMPLE_MODULO - half

    def step(self, now_us: int, rx: RxTable) -> dict[str, float]:
        p, g = self.p, self.gains
        dt_s = 0.0 if self.last_us is None else (now_us - self.last_us) * 1e-6
        self.last_us = now_us
        v_i = self._fresh(rx, self.k_own_speed, now_us)
        x_i = self._fresh(rx, self.k_own_pos, now_us)
        if v_i is None or x_i is None:  # no own sensor: keep braking at the last command (fail-safe)
            return {self.k_force: self.u, self.k_speed: 0.0, self.k_pos: 0.0, self.k_sample: 0, self.k_obs: 0,
                    self.k_sat: 0, self.k_missing: 1, self.k_phi: self.observer.phi_hat,
                    self.k_u1: 0.0, self.k_u2: 0.0, self.k_verr: 0.0}
        own_sample = rx[self.k_own_sample]
        v_ref = self._fresh(rx, self.k_v_ref, now_us, p.stale_us)    # a ramp: extrapolated, no sample tag
        a_ref = self._fresh(rx, self.k_a_ref, now_us, p.stale_us)
        if v_ref is None or a_ref is None:
            v_star, a_star = v_i, 0.0       # no virtual leader yet: consensus only
        else:
            age = rx.age_us(self.k_v_ref, now_us)
            v_star, a_star = max(0.0, v_ref - a_ref * (age or 0) * 1e-6), a_ref   # v* now, eq. (9)
        period_s = p.sample_period_us * 1e-6
        v_others = []
        for v_key, s_key in self.others:
            v_j = self._fresh(rx, v_key, now_us)
            lag = self._lag(own_sample, rx[s_key])
            if v_j is not None and lag is not None:
                v_others.append(v_j - a_star * lag * period_s)   # v_j at the instant v_i was sampled
        xi = []
        for key, v_key, s_key, rest in self.neighbours:
            x_j = self._fresh(rx, key, now_us)
            v_j = self._fresh(rx, v_key, now_us)
            lag = self._lag(own_sample, rx[s_key])
            if x_j is not None and v_j is not None and lag is not None:
                x_j += v_j * lag * period_s                          # x_j at the instant x_i was sampled
                xi.append(relative_displacement_cm(x_i, x_j, rest))
        phi_hat = self.observer.update(dt_s, x_i, v_i, p.brake_gain * self.u / p.mass_kg)
        u1 = consensus_term(v_i, v_others, xi, g.alpha1_per_s, g.alpha2_per_s2_cm)
        u2, saturated = potential_term(xi, g)
        v_err = v_i - v_star
        u3 = anti_disturbance_term(v_err, a_star, phi_hat, g.k_per_s, p.compensate)
        u = command(p.mass_kg, p.brake_gain, u1, u2, u3)
        u = max(-p.u_max, min(p.u_max, u))
        self.u = u
        complete = len(v_others) == len(self.others) and len(xi) == len(self.neighbours) and v_ref is not None
        return {self.k_force: u, self.k_speed: v_i, self.k_pos: x_i, self.k_sample: own_sample,
                self.k_obs: int(p.compensate),
                self.k_sat: int(saturated), self.k_missing: int(not complete), self.k_phi: phi_hat,
                self.k_u1: u1, self.k_u2: u2, self.k_verr: v_err}


@dataclass(frozen=True)
class VirtualLeaderParams:
    """The BCU's desired braking curve, eq. (9) seed 003 (Table 2 / §4)."""

    v0_mps: float = 90.0 * KMH        # v*(t0) = 90 km/h, §4
    decel_mps2: float = 3.5 * KMH     # a* = 3.5 km/(h·s), §4
    start_us: int = 0                 # t0 [µs]


class VirtualLeader:
    """The BCU as virtual leader: sends v*(t) and a* (eq. (9))."""

    outputs: ClassVar[tuple[str, ...]] = ("CONS_REF.VRef", "CONS_REF.ARef", "CONS_REF.Active")
    inputs: ClassVar[tuple[str, ...]] = ()

    def __init__(self, p: VirtualLeaderParams) -> None:
        self.p = p

    def step(self, now_us: int, rx: RxTable) -> dict[str, float]:
        p = self.p
        t_us = max(0, now_us - p.start_us)
        v = desired_speed_mps(t_us, p.v0_mps, p.decel_mps2)
        return {"CONS_REF.VRef": v, "CONS_REF.ARef": p.decel_mps2 if v > 0.0 else 0.0,
                "CONS_REF.Active": 1}
