"""Brake ECU of one car (BECU), v1.

Chain: train deceleration demand (BCU_DEMAND.TargetDecel) -> brake-cylinder pressure set-point
(inverse of the brake model: force -> torque -> pressure on the squeeze line of seed 001 eq. (6))
-> PI pressure control of the EP valve (the shared PI primitive), with a basic wheel-slide protection
(WSP) that vents above a slip threshold and refills with hysteresis.  With the EP valve's flow this
loop behaves as seed 001's first-order cylinder (eq. 4).

Inputs (DBC signal names, bound by hil): AxleSpeed, CylPressure, AccelLong (the car's sensors),
TargetDecel and Mode (BCU_DEMAND), EmergencyActive (BCU_EMERGENCY).
Outputs: the pressure command frame (CylPressureSet, ValveCmd, WspValve), the status frame and the
diagnostics frame (governor; SpeedSensorFault, AccelSensorFault, CylSensorFault, AccelBiasEst).

Reference speed (SpeedEst, issue #19): a Kalman filter whose time update integrates the accelerometer
less its bias estimate (which holds g·sin θ, seed 004 eq. (1)) and whose measurement is the axle's r·ω
plus the creep its brake needs on nominal rail (seed 000 eq. (1)) (seed 004 §3.2, eqs. (19)–(23), linear
and scalar), unbiased; while the wheel slides (it reads more than a gate below the estimate, or WSP acts)
the axle is no measurement of the car's speed (seed 001 eq. (2)) and the estimate runs on the
accelerometer alone, so it does not follow a sliding wheel down.  See `reference_speed`, `creep_mps`.

With BecuParams.control = "decel" the set-point comes from seed 001's deceleration PI (eq. 16) instead,
optionally behind the reference governor (eq. 9, firmware_py.governor), which sets GovernorActive.

Deceleration feedback (seed 004 §5, firmware_py.decel_feedback): in "pressure" control the BCU's
pressure correction φ (BCU_BRAKE_CORR.FrictionPhi, eq. (34), an authenticated frame) divides the force
part of the set-point, P_c = preload + (P_c0 − preload)/φ, gated to `phi_limits`; φ = 1 (`apply_phi`)
unless the same frame's FbState says the feedback is ENGAGED or HELD (HELD keeps the engaged
correction, seed 004 §5), and when φ is not received, older than `phi_timeout_us`, not finite, in
emergency or on loss of command.

Sensor plausibility (issue #9): the wheel-speed sensor is declared failed (SpeedSensorFault, latched)
when its reading says the wheel stands while the accelerometer says the car moves for longer than a
real slide lasts, or when its reading is frozen while the accelerometer says the speed changed; the
speed estimate then runs on the accelerometer alone and WSP is inhibited (the brake stays applied).
The accelerometer's bias (accelerometer − the axle's acceleration, filtered) is AccelBiasEst; above a
limit for a time it is AccelSensorFault (latched) and the axle's acceleration replaces it.  A vent-time
watchdog refills a cylinder that WSP has kept vented too long.  While a vented wheel spins back up (its
axle accelerates faster than RefSpeedParams.spin_up_accel_mps2, as no braked car does, setting new highs:
`Becu._spin_up_check`) the clocks of the watchdog, of the reference speed's spin-up rule and of its slide
bridge stand still: a wheel locked at speed takes seconds to come back (issue #19: locked by the
actuator's fail-safe while commands were lost).  See `speed_sensor_check`, `accel_bias_check` and
`vent_watchdog`.  The brake-cylinder pressure transducer is declared failed (CylSensorFault, latched,
issue #19) when its reading stays identical while the EP or dump valve should have moved the pressure by
more than a limit; the pressure loop then runs on a model of the cylinder fed with the valve commands,
biased to brake (`cyl_sensor_check`, `valve_pressure_rate`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple

from firmware_py.constants import G_MPS2
from firmware_py.cycle import CycleTimer
from firmware_py.decel_feedback import FbState
from firmware_py.governor import (
    GovernorDecision,
    GovernorParams,
    GovernorSchedule,
    GovernorState,
    govern,
    play,
    warm_up,
)
from firmware_py.limits import clip, finite_or
from firmware_py.pi import PI, PIParams

# the BCU's feedback states in which its φ is a correction to apply (HELD keeps the engaged one)
PHI_STATES = (float(FbState.ENGAGED), float(FbState.HELD))


class Wsp(IntEnum):
    """WSP dump-valve state; values are the DBC choices of BECUn_PRESS_CMD.WspValve."""

    FILL = 0   # normal: the EP valve controls the cylinder
    HOLD = 1   # cylinder isolated, pressure held
    VENT = 2   # cylinder vented to atmosphere


@dataclass(frozen=True)
class WspParams:
    vent_slip_mps: float = 0.30          # slip speed that starts venting at standstill (chosen)
    vent_slip_per_speed: float = 0.03    # + this fraction of the speed: 1.05 m/s at 25 m/s (chosen;
    #                                      above the slip of peak adhesion of seed 000 at that speed)
    hold_fraction: float = 0.5           # VENT -> HOLD below this fraction of the vent threshold
    refill_fraction: float = 0.25        # HOLD -> FILL below this fraction of the vent threshold
    min_speed_mps: float = 1.0           # WSP inhibited below this speed (lets the train stop)
    # vent-time watchdog: a cylinder kept out of FILL (vent or hold) longer than this is refilled and WSP
    # stays off until the wheel has recovered. 5 s is the "standard five (5) second" WSP safety timer of
    # Canadian patent CA 2025196 (axle health discriminatory safety timer); UIC 541-05 limits continuous
    # venting too, but its figure was not found in the sources at hand
    max_vent_s: float = 5.0
    # "dump": vent to zero, refill to the demand (the limit cycle of seed 001 §II-C's WSP); "slip": keep the
    # slip near the adhesion peak (`slip_ceiling`, `early_vent`): refill only up to a pressure ceiling,
    # ceiling_fraction of the pressure at which the wheel began to slide (the adhesion the rail gave,
    # estimated), raised in FILL by ceiling_rise_Pa_per_s and dropped after ceiling_release_s in FILL
    # without a new slide (the rail has improved; on uniform low adhesion a slide mostly follows the
    # release: a longer release gains there and loses after a sudden change, docs/wsp-test.md);
    # vent early, once the slip passes early_vent_fraction of the vent threshold while the axle
    # decelerates faster than early_vent_decel_mps2, which no car does (a slide's onset: venting then
    # keeps the slide shallow)
    mode: str = "dump"
    ceiling_fraction: float = 0.9          # (chosen)
    ceiling_rise_Pa_per_s: float = 50e3    # 0.5 bar/s (chosen: railhil wsp-test)
    ceiling_release_s: float = 0.45        # [s] (chosen: railhil wsp-test, sudden change of adhesion)
    early_vent_fraction: float = 0.3       # (chosen)
    early_vent_decel_mps2: float = 2.5     # (chosen: SensorCheckParams.car_accel_max_mps2)


def slip_ceiling(ceiling_Pa: float, before: Wsp, now: Wsp, pressure_Pa: float, fill_s: float, dt_s: float,
                 p: WspParams) -> float:
    """Pure update of the slip mode's pressure ceiling [Pa] (inf: none): set at a slide's onset (FILL ->
    out of FILL) to ceiling_fraction × the cylinder pressure then; in FILL raised by ceiling_rise_Pa_per_s,
    none once `fill_s` (the time in FILL since the slide) passes ceiling_release_s."""
    if before == Wsp.FILL and now != Wsp.FILL:
        return p.ceiling_fraction * pressure_Pa
    if now == Wsp.FILL and math.isfinite(ceiling_Pa):
        return math.inf if fill_s > p.ceiling_release_s else ceiling_Pa + p.ceiling_rise_Pa_per_s * dt_s
    return ceiling_Pa


def early_vent(wanted: Wsp, slip_mps: float, speed_mps: float, axle_accel_mps2: float, p: WspParams) -> Wsp:
    """Pure: the slip mode vents at a slide's onset, before the vent threshold (WspParams, "slip")."""
    if (p.mode == "slip" and wanted == Wsp.FILL and speed_mps >= p.min_speed_mps
            and axle_accel_mps2 < -p.early_vent_decel_mps2
            and slip_mps > p.early_vent_fraction * vent_threshold(speed_mps, p)):
        return Wsp.VENT
    return wanted


def vent_threshold(speed_mps: float, p: WspParams) -> float:
    """The slip speed above which WSP vents at `speed_mps` [m/s]."""
    return p.vent_slip_mps + p.vent_slip_per_speed * speed_mps


def wsp_transition(state: Wsp, slip_mps: float, speed_mps: float, p: WspParams) -> Wsp:
    """Pure mode transition of the basic wheel-slide protection (vent / hold / refill with hysteresis).

    With refill_fraction ≥ hold_fraction there is no hold phase: VENT returns to FILL as soon as the slip
    is below the refill threshold, as seed 001 §II-C's WSP does (vent, u = 0, while s > s̄; track again
    once s is back in the adhesion region).
    """
    if speed_mps < p.min_speed_mps:
        return Wsp.FILL
    vent_at = vent_threshold(speed_mps, p)
    if slip_mps > vent_at:
        return Wsp.VENT
    if state == Wsp.VENT and p.refill_fraction >= p.hold_fraction:
        return Wsp.FILL if slip_mps < p.refill_fraction * vent_at else Wsp.VENT
    if state == Wsp.VENT:
        return Wsp.HOLD if slip_mps < p.hold_fraction * vent_at else Wsp.VENT
    if state == Wsp.HOLD:
        return Wsp.FILL if slip_mps < p.refill_fraction * vent_at else Wsp.HOLD
    return Wsp.FILL


def vent_watchdog(vent_s: float, tripped: bool, venting: bool, recovered: bool, dt_s: float,
                  max_vent_s: float, spinning_up: bool = False) -> tuple[float, bool]:
    """Pure vent-time watchdog: (time vented continuously [s], tripped).

    `venting`: WSP wants the cylinder out of FILL this cycle; `recovered`: the wheel's slip is back
    below the refill threshold; `spinning_up`: the vented wheel accelerates as only a wheel spinning back
    up to the car's speed does (RefSpeedParams.spin_up_accel_mps2, `Becu._spin_up_check`): the vent is
    working, the wheel is healthy, and that time does not count (the "axle health discriminatory" timer
    of CA 2025196: a wheel that takes seconds to spin up from a lock is not refilled onto the rail
    half-way).  Trips when venting lasts longer than `max_vent_s` otherwise; while tripped the caller
    keeps the cylinder in FILL; it re-arms once the wheel has recovered."""
    if tripped:
        return 0.0, not recovered
    vent_s = vent_s + dt_s * (not spinning_up) if venting else 0.0
    return (0.0, True) if vent_s > max_vent_s else (vent_s, False)


# Steepest gradient a scenario may declare: hil.scenario's GradientPoint.permille is bounded to ±60 ‰.
# On it the accelerometer legitimately reads g·sin(atan(0.060)) = 0.588 m/s² more than the axle's
# acceleration, so the bias limit must lie above that.
STEEPEST_GRADIENT_MPS2 = G_MPS2 * 0.060 / math.sqrt(1.0 + 0.060 ** 2)


@dataclass(frozen=True)
class SensorCheckParams:
    """Plausibility limits of the car's wheel-speed sensor and accelerometer (issue #9) and of its
    brake-cylinder pressure transducer (issue #19)."""

    # wheel-speed sensor, "stands": a reading below stand_mps while the speed estimate (accelerometer)
    # is above moving_mps for longer than lock_s.  A real slide ends within lock_s: WSP vents above a
    # few tenths of a m/s of slip and the wheel spins up within tenths of a second; the longest slide
    # to a standing wheel in the rg_* scenarios and the wet section of default is 0 s (chosen)
    stand_mps: float = 0.3                 # wheel reading that says the wheel stands [m/s] (chosen, ~1 km/h)
    moving_mps: float = 3.0                # ... while the car moves faster than this [m/s] (chosen)
    lock_s: float = 1.0                    # ... for longer than this [s] (chosen, see above)
    # wheel-speed sensor, "frozen": the same reading on every fresh frame while the accelerometer
    # (corrected by its bias estimate, which holds the gradient term) integrates to a speed change of
    # more than frozen_dv_mps.  With the sensor noise of the plant (0.002–0.02 rad/s std against a
    # 0.005 rad/s resolution) a live reading does not repeat for long at speed (chosen)
    frozen_dv_mps: float = 0.5             # [m/s]
    frozen_min_mps: float = 1.0            # only readings above this [m/s]: a standing wheel reads 0 forever
    # accelerometer bias: first-order filter (time constant bias_tau_s) of accelerometer − d(r·ω)/dt,
    # updated on fresh wheel frames while the wheel is not sliding (below); above bias_limit_mps2 for
    # longer than bias_hold_s it is a fault.  The limit must lie above STEEPEST_GRADIENT_MPS2
    # (0.588 m/s²), which the accelerometer legitimately reads on the steepest gradient a scenario
    # allows.  What a slide leaves in the filter (the slip that built up before the gate below closed,
    # Δslip/τ) was at most 0.29 m/s² in the wet section of default (seeds 1–3) and 0.04 m/s² in the
    # rg_* runs: on a gradient near 60 ‰ combined with such slides the limit can be reached (chosen;
    # a longer τ lowers that transient but slows detection: a 0.8 m/s² bias needs τ·ln 8 + hold)
    bias_tau_s: float = 1.5                # [s]
    bias_limit_mps2: float = 0.7           # [m/s²]
    bias_hold_s: float = 0.5               # [s]
    # "not sliding": estimated slip below slide_gate_mps, WSP in FILL and the axle's acceleration within
    # what the car can do (car_accel_max_mps2, below); a slide is bridged (one update over the whole
    # span once the wheel is back, so the slip's rise and fall cancel), but a span is closed after
    # span_max_s whatever the slip (a biased accelerometer inflates the estimated slip)
    slide_gate_mps: float = 0.1            # [m/s] (chosen: a third of the WSP's lowest vent threshold)
    span_max_s: float = 1.0                # [s] (chosen)
    # ... except a span in which the axle decelerated faster than the car can (car_accel_max_mps2: a real
    # slide's onset, which a biased accelerometer cannot fake): it is bridged until the wheel is back, at
    # most slide_span_max_s.  Closed at span_max_s it held the slip's rise without its fall (the recovery's
    # spans are skipped): on extremely low adhesion slides outlast 1 s, the filter took them for a bias
    # (0.12 -> 0.67 -> 0.99 m/s² in two spans), AccelSensorFault inhibited WSP and a wheel locked for 105 s
    # (railhil wsp-test, dump WSP, 120 km/h).  Over a span that long what a slide leaves, Δslip / span, is
    # small (chosen)
    slide_span_max_s: float = 30.0         # [s]
    # the axle-derived acceleration that replaces a failed accelerometer: d(r·ω)/dt through a first-order
    # filter, bounded to what the car itself can do (a sliding wheel decelerates far faster), so that a
    # slide still shows as slip against the reference speed (chosen: 0.25 g, seed 001's r⁰)
    axle_accel_tau_s: float = 0.1          # [s]
    car_accel_max_mps2: float = 2.5        # [m/s²]
    # pressure transducer, "frozen": the same reading on every fresh frame while the valve commands this
    # BECU sent would have moved the pressure by more than cyl_frozen_dp_Pa in all (`cyl_sensor_check`).
    # A live transducer changes by at least its 10 Pa resolution long before (the plant's noise alone,
    # 1 kPa std, changes nearly every reading).  The limit lies above what the commands of the sensor
    # frame's and the cycle's latency move (2 × 10 ms at the full 1 MPa/s fill = 20 kPa, while a cylinder
    # at 0 reads 0) (chosen)
    cyl_frozen_dp_Pa: float = 50e3         # [Pa]
    cyl_valve_min: float = 0.02            # EP valve openings below this are no evidence [-] (chosen:
    #                                        a real valve's dead band)
    cyl_margin_Pa: float = 20e3            # a fill is no evidence within this of p̄, a vent none within
    #                                        this of 0: the pressure cannot move there [Pa] (chosen)
    cyl_noise_Pa: float = 5e3              # a reading's step beyond the valves' fastest change (the dump
    #                                        valve's) plus this is no pressure: the transducer jumped to
    #                                        where it froze [Pa] (chosen: 5 σ of the plant's 1 kPa noise)

    def __post_init__(self) -> None:
        if not self.bias_limit_mps2 > STEEPEST_GRADIENT_MPS2:
            raise ValueError(f"SensorCheckParams: bias_limit_mps2 {self.bias_limit_mps2} must be above "
                             f"{STEEPEST_GRADIENT_MPS2:.3f} m/s², the steepest gradient's g·sin θ")


class SpeedCheck(NamedTuple):
    """State of the wheel-speed sensor check (`speed_sensor_check`)."""

    fault: bool = False
    cause: str = ""              # "stands" | "frozen" once latched
    stand_s: float = 0.0         # time the reading has said "stands" while the car moves [s]
    frozen_s: float = 0.0        # time the reading has been frozen (≥ frozen_min_mps) [s]
    frozen_dv_mps: float = 0.0   # bias-corrected accelerometer integrated over the frozen span [m/s]
    stands: bool = False         # the last reading said "stands" while the car moves


def speed_sensor_check(s: SpeedCheck, wheel_mps: float, prev_wheel_mps: float, v_ref_mps: float,
                       accel_mps2: float, span_s: float, p: SensorCheckParams) -> SpeedCheck:
    """The wheel-speed sensor check on one fresh reading (pure; latched once it fails).  Call it per
    new sensor frame only: a stale frame (none arrived this cycle) is not a frozen sensor.

    wheel_mps: r·ω of the reading; prev_wheel_mps: the previous reading; v_ref_mps: the car's speed
    estimate (from the accelerometer while the wheel disagrees); accel_mps2: accelerometer minus its
    bias estimate, over the span; span_s: time since the previous reading [s]."""
    if s.fault:
        return s
    # the time between two readings counts only when both stood: a gap in the readings (frames lost,
    # the bus blocked) is no evidence that the wheel stood through it
    stands = wheel_mps < p.stand_mps and v_ref_mps > p.moving_mps
    stand_s = (s.stand_s + span_s if s.stands else 0.0) if stands else 0.0
    if wheel_mps == prev_wheel_mps and wheel_mps >= p.frozen_min_mps:
        frozen_s, dv = s.frozen_s + span_s, s.frozen_dv_mps + accel_mps2 * span_s
    else:
        frozen_s, dv = 0.0, 0.0
    if stand_s > p.lock_s:
        return SpeedCheck(True, "stands", stand_s, frozen_s, dv, stands)
    if abs(dv) > p.frozen_dv_mps:
        return SpeedCheck(True, "frozen", stand_s, frozen_s, dv, stands)
    return SpeedCheck(False, "", stand_s, frozen_s, dv, stands)


class AccelCheck(NamedTuple):
    """State of the accelerometer bias check (`accel_bias_check`)."""

    fault: bool = False
    bias_mps2: float = 0.0       # filtered accelerometer − d(r·ω)/dt [m/s²] (AccelBiasEst)
    above_s: float = 0.0         # time |bias| has been above the limit [s]


def accel_bias_check(s: AccelCheck, accel_mean_mps2: float, wheel_accel_mps2: float, span_s: float,
                     p: SensorCheckParams) -> AccelCheck:
    """One update of the accelerometer bias check over `span_s` seconds since the last update (pure;
    latched once it fails).

    accel_mean_mps2: the accelerometer's mean over the span; wheel_accel_mps2: the wheel's speed
    change over the span divided by it.  Their difference is the bias plus g·sin θ plus the slip's
    rate of change, which averages out over a slide."""
    if s.fault or span_s <= 0.0:
        return s
    gain = min(span_s / p.bias_tau_s, 1.0)
    bias = s.bias_mps2 + gain * (accel_mean_mps2 - wheel_accel_mps2 - s.bias_mps2)
    above_s = s.above_s + span_s if abs(bias) > p.bias_limit_mps2 else 0.0
    return AccelCheck(above_s > p.bias_hold_s, bias, above_s)


class CylCheck(NamedTuple):
    """State of the pressure transducer check (`cyl_sensor_check`)."""

    fault: bool = False
    evidence_Pa: float = 0.0     # |pressure change| the valves should have made since the reading froze
    moved_Pa: float = 0.0        # ... signed
    frozen: bool = False         # the reading repeats
    base_Pa: float = 0.0         # the pressure when it froze: the model of the cylinder starts at
    #                              base_Pa + moved_Pa once the check fails


def valve_pressure_rate(valve_cmd: float, wsp_valve: int, p_Pa: float, p_max_Pa: float,
                        rates: tuple[float, float, float]) -> float:
    """dp/dt [Pa/s] the valves give a cylinder at p_Pa (pure): the EP valve's opening valve_cmd ∈ [−1, 1]
    fills at valve_cmd·fill (> 0) or vents at valve_cmd·vent (< 0) while the WSP dump valve is in FILL;
    HOLD isolates the cylinder; VENT dumps it at `dump`.  rates = (fill, vent, dump) [Pa/s] at full
    opening.  No flow beyond 0 and p̄ (seed 001 eq. (5a))."""
    fill, vent, dump = rates
    if wsp_valve == Wsp.HOLD:
        return 0.0
    if wsp_valve == Wsp.VENT:
        return -dump if p_Pa > 0.0 else 0.0
    if valve_cmd > 0.0:
        return valve_cmd * fill if p_Pa < p_max_Pa else 0.0
    return valve_cmd * vent if p_Pa > 0.0 else 0.0


def cyl_sensor_check(s: CylCheck, reading_Pa: float, prev_Pa: float, before_Pa: float, valve_cmd: float,
                     wsp_valve: int, span_s: float, p_max_Pa: float, rates: tuple[float, float, float],
                     p: SensorCheckParams) -> CylCheck:
    """The pressure transducer check on one fresh reading (pure; latched once it fails).  Call it per new
    sensor frame only: a stale frame is not a frozen transducer.

    prev_Pa, before_Pa: the two readings before this one; valve_cmd, wsp_valve: the commands this BECU sent
    over the span (its last ValveCmd and WspValve); span_s: time since the previous reading [s].  Evidence
    accumulates while the reading stays identical and the valves should move the pressure: an EP valve
    opening of at least cyl_valve_min filling below p̄ − margin or venting above the margin, or the dump
    valve venting above the margin; a reading that changes clears it.  Fails once the evidence exceeds
    cyl_frozen_dp_Pa.  The pressure when the reading froze (base_Pa) is the reading before the repeats,
    or the one before that if the transducer jumped there faster than any valve moves a cylinder."""
    if s.fault:
        return s
    if reading_Pa != prev_Pa:
        return CylCheck()
    if not s.frozen:                                     # the first repeat: where did it freeze?
        jumped = abs(prev_Pa - before_Pa) > max(rates) * span_s + p.cyl_noise_Pa
        s = CylCheck(frozen=True, base_Pa=before_Pa if jumped and math.isfinite(before_Pa) else prev_Pa)
    rate = valve_pressure_rate(valve_cmd, wsp_valve, reading_Pa, p_max_Pa, rates)
    if wsp_valve == Wsp.FILL and abs(valve_cmd) < p.cyl_valve_min:
        rate = 0.0                                       # the valve's dead band: no evidence
    elif rate > 0.0 and reading_Pa >= p_max_Pa - p.cyl_margin_Pa:
        rate = 0.0                                       # filling at the reservoir's pressure
    elif rate < 0.0 and reading_Pa <= p.cyl_margin_Pa:
        rate = 0.0                                       # venting an empty cylinder
    evidence = s.evidence_Pa + abs(rate) * span_s
    return CylCheck(evidence > p.cyl_frozen_dp_Pa, evidence, s.moved_Pa + rate * span_s, True, s.base_Pa)


# the spin-up check's smoothing of the wheel reading, a fraction per fresh reading: τ = 50 ms at 10 ms
# readings, a third of the plant's reading noise, below the 12 mm/s a wheel spinning up at 1.25 m/s² gains
# a reading (chosen)
SPIN_UP_SMOOTHING = 0.2


@dataclass(frozen=True)
class CreepParams:
    """The nominal creep of a braked wheel (`creep_mps`): the adhesion curve of seed 000 §2.1, eq. (1),
    μ(θ, σ, v) = μ̄(θ, k2(v)·σ) / k1(v), μ̄(θ, σ) = √σ / (θ1 + θ2 σ + θ3 σ²), k_i(v) = 1 + π_i v, on the
    vehicle's nominal rail."""

    # θ of the project's "dry" rail (plant_sim.params.RAIL_CONDITIONS: peak σ̄° = 0.03, μ̄° = 0.25, values
    # chosen there for seed 000 §3's conditions): the rail the creep is compensated for.  On wetter rail the
    # same adhesion needs more creep, which the estimate then shows as its error (seed 000 §3)
    theta: tuple[float, float, float] = (0.35416, 11.030, 8.6158)
    pi1_s_per_m: float = 1.0 / 40.0        # k1(v) = 1 + v/40, seed 000 §3
    pi2_s_per_m: float = 1.0 / 40.0        # k2(v) = 1 + v/40, seed 000 §3
    v_eps_mps: float = 0.5                 # σ = s / max(v, v_eps) at low speed (plant_sim.adhesion's V_EPS)


def creep_mps(mu_used: float, v_mps: float, cp: CreepParams) -> float:
    """The slip speed s = σ·max(v, v_eps) [m/s] at which a wheel transmits the adhesion `mu_used` on the
    nominal rail (pure): seed 000 eq. (1) inverted on its rising branch, x = k2 σ from the fixed point
    x = (μ k1 (θ1 + θ2 x + θ3 x²))² started at 0 (it rises monotonically to the root below the peak),
    capped at the peak x° = (−θ2 + √(θ2² + 12 θ1 θ3)) / (6 θ3) (seed 000 §2.1)."""
    if not mu_used > 0.0:
        return 0.0
    t1, t2, t3 = cp.theta
    v = max(v_mps, 0.0)
    k1, k2 = 1.0 + cp.pi1_s_per_m * v, 1.0 + cp.pi2_s_per_m * v
    x_peak = _x_peak(tuple(cp.theta))
    x = 0.0
    for _ in range(8):
        y = (mu_used * k1 * (t1 + x * (t2 + t3 * x))) ** 2
        x = x_peak if x_peak < y else y                    # min(y, x_peak), without the builtin's call
    return x / k2 * max(v, cp.v_eps_mps)


@functools.cache
def _x_peak(theta: tuple[float, float, float]) -> float:
    """x° = k2 σ at the peak of seed 000's μ̄ (§2.1): (−θ2 + √(θ2² + 12 θ1 θ3)) / (6 θ3)."""
    t1, t2, t3 = theta
    return (-t2 + math.sqrt(t2 * t2 + 12.0 * t1 * t3)) / (6.0 * t3)


@dataclass(frozen=True)
class RefSpeedParams:
    """The car's reference speed SpeedEst (`reference_speed`, issue #19): a Kalman filter on the
    accelerometer and the axle, seed 004 §3.2 eqs. (19)–(23), that bridges the wheel's slides.  The
    slide gate is BecuParams.wheel_trust_slip_mps."""

    # process noise of the bias-corrected accelerometer: the sensor's noise, the body's vibration and what
    # the bias estimate (AccelBiasEst, which holds g·sin θ) has not caught up with yet [m/s²] (chosen)
    accel_std_mps2: float = 0.12
    # measurement noise of the axle's r·ω as a measure of the car's speed: the sensor's (0.02 rad/s ×
    # 0.46 m = 0.009 m/s in plant_sim) and the creep's variation [m/s] (chosen).  With accel_std_mps2 the
    # steady gain is ≈ accel_std·dt / wheel_std = 0.06 a 10 ms cycle: the estimate follows the axle with
    # τ ≈ wheel_std / accel_std = 0.17 s, so an accelerometer error a moves it off the axle by at most
    # a·τ: 0.12 m/s at the accelerometer fault limit (0.7 m/s², SensorCheckParams), below the slide gate;
    # only an error above gate/τ = 0.9 m/s² (a fault, detected) can look like a slide
    wheel_std_mps: float = 0.02
    # the wheel agrees with the estimate: it reads at most agree_mps below it (3 σ of the reading) [m/s]
    # (chosen); a slide ends when the wheel agrees again and WSP is back in FILL
    agree_mps: float = 0.03
    # a slide found within rollback_s of the wheel's last agreement restarts from the estimate it had then,
    # carried forward on the accelerometer: what the filter followed of the slide's onset is undone [s]
    # (chosen: a slide's slip grows by 1 m/s² and more, it passes the gate in ~0.3 s)
    rollback_s: float = 1.0
    # a wheel without brake torque (cylinder below torque_free_Pa) spins up to the car's speed: seed 001
    # eq. (3) with τ = 0 gives ṡ = −(1/M + r²/J) f(s) < 0.  Apart for spin_up_s without torque, it is the
    # estimate that is wrong (an accelerometer error) and the wheel is taken again (chosen: in the wet
    # section of default a vented wheel is back within 0.15 s; 10 kPa is a third of the return-spring
    # preload, below the release line's zero)
    torque_free_Pa: float = 10e3           # [Pa]
    spin_up_s: float = 0.5                 # [s]
    # ... but a wheel still accelerating faster than this is spinning up, not yet at the car's speed: a
    # wheel locked by the actuator's fail-safe while the BECU's commands were lost takes seconds to spin
    # back up from a lock (its adhesion is low at full slide, seed 000 §2.1): that time counts neither
    # towards spin_up_s nor bridge_max_s (issue #19).  Above the 0.588 m/s² a car may gain torque-free
    # on the steepest gradient (STEEPEST_GRADIENT_MPS2); a braked car never accelerates faster; the axle
    # of a braked wheel at the car's speed decelerates with the car [m/s²] (chosen)
    spin_up_accel_mps2: float = 1.0
    # whatever the wheel does, a slide is bridged at most this long: longer than the WSP vent watchdog
    # (WspParams.max_vent_s, 5 s) and the locked-wheel check (SensorCheckParams.lock_s, 1 s) (chosen)
    bridge_max_s: float = 6.0              # [s]


class RefSpeed(NamedTuple):
    """State of the reference speed (`reference_speed`)."""

    v_mps: float = math.nan          # the estimate [m/s]
    var: float = 0.0                 # its variance P [m²/s²]
    sliding: bool = False            # the wheel is bridged: the estimate runs on the accelerometer alone
    slide_s: float = 0.0             # time in the slide, the wheel not spinning up [s]
    free_s: float = 0.0              # ... of which without brake torque [s]
    anchor_mps: float = math.nan     # the estimate when the wheel last agreed, carried on the accelerometer
    anchor_s: float = 0.0            # time since the wheel last agreed [s]
    resets: int = 0                  # slides ended by spin_up_s or bridge_max_s (diagnostic)


def reference_speed(s: RefSpeed, wheel_mps: float, accel_mps2: float, dt_s: float, fresh: bool,
                    wsp_fill: bool, torque_free: bool, gate_mps: float, p: RefSpeedParams,
                    creep: float = 0.0, wheel_suspect: bool = False, spinning_up: bool = False) -> RefSpeed:
    """One cycle of the car's reference speed (pure).

    wheel_mps: the axle's r·ω; accel_mps2: the car's acceleration, the accelerometer less its bias
    estimate (seed 004 eq. (1): a_measure = a_actual + g sin θ; the estimate holds g sin θ and the
    sensor's bias); fresh: a new axle reading arrived; wsp_fill: WSP is in FILL; torque_free: the cylinder
    is below RefSpeedParams.torque_free_Pa; gate_mps: the slide gate (BecuParams.wheel_trust_slip_mps);
    creep: the slip speed the wheel needs for the adhesion its brake uses (`creep_mps`) [m/s];
    wheel_suspect: the wheel-speed sensor check is timing the reading ("stands" or "frozen",
    `speed_sensor_check`): a slide is then not ended by the spin-up rule, that check decides;
    spinning_up: the wheel is spinning back up to the car's speed (`Becu._spin_up_check`: its axle
    accelerates faster than RefSpeedParams.spin_up_accel_mps2, its smoothed reading setting new highs):
    the slide goes on, however long, and that time counts towards neither spin_up_s nor bridge_max_s.

    Time update, seed 004 eqs. (19)–(20) with A = 1, the accelerometer as input u_k and W = dt:
    v⁻ = v + a·dt, P⁻ = P + (σ_a·dt)².  Measurement update on a fresh reading z = w + creep (the car's speed
    as the wheel gives it, seed 001 eq. (2): v = rω + s), eqs. (21)–(23) with H = 1: K = P⁻/(P⁻ + σ_w²),
    v = v⁻ + K·(z − v⁻), P = (1 − K)·P⁻: unbiased, an axle's noise does not lift it.  Unless the wheel
    slides: its slip is then no creep, z no measurement of v (R = ∞), and the estimate runs on the
    accelerometer alone.  The slide starts when the wheel reads more than gate_mps below v⁻ or WSP leaves
    FILL, from the estimate of the wheel's last agreement (`rollback_s`); it ends when the wheel agrees
    again with WSP in FILL, or, the estimate being wrong, after spin_up_s without brake torque or after
    bridge_max_s (the wheel is then taken as the car's speed).

    gate_mps = 0 is the accelerometer reference of seed 001's runs: v⁻, lifted to the wheel when the wheel
    reads above it, never pulled down by it (a braked wheel is never faster than the car); no creep."""
    if not math.isfinite(s.v_mps):
        return RefSpeed(wheel_mps + creep, p.wheel_std_mps ** 2, anchor_mps=wheel_mps + creep)
    v = max(s.v_mps + accel_mps2 * dt_s, 0.0)                      # eq. (19)
    var = s.var + (p.accel_std_mps2 * dt_s) ** 2                    # eq. (20)
    anchor = max(s.anchor_mps + accel_mps2 * dt_s, 0.0)
    anchor_s = s.anchor_s + dt_s
    if gate_mps <= 0.0:                                             # the accelerometer reference
        v = max(v, wheel_mps) if fresh else v
        return RefSpeed(v, var, anchor_mps=v)
    if not fresh:
        return s._replace(v_mps=v, var=var, anchor_mps=anchor, anchor_s=anchor_s,
                          slide_s=s.slide_s + dt_s * (s.sliding and not spinning_up),
                          free_s=s.free_s + dt_s * (s.sliding and torque_free and not spinning_up))
    z = wheel_mps + creep
    innovation = z - v
    sliding, slide_s, free_s, resets = s.sliding, s.slide_s, s.free_s, s.resets
    if not sliding and (innovation < -gate_mps or not wsp_fill):
        sliding, slide_s, free_s = True, 0.0, 0.0
        if anchor_s <= p.rollback_s:
            v = max(v, anchor)                                      # undo the onset the filter followed
    elif sliding:
        slide_s += dt_s * (not spinning_up)
        free_s += dt_s * (torque_free and not spinning_up)
        if innovation >= -p.agree_mps and wsp_fill:
            sliding = False                                         # the wheel is back
        elif (free_s > p.spin_up_s and not wheel_suspect) or slide_s > p.bridge_max_s:
            sliding, v, var, resets = False, z, p.wheel_std_mps ** 2, resets + 1
    if sliding:
        return RefSpeed(v, var, True, slide_s, free_s, anchor, anchor_s, resets)
    gain = var / (var + p.wheel_std_mps ** 2)                       # eq. (21)
    v = max(v + gain * (z - v), 0.0)                                # eq. (22)
    var = (1.0 - gain) * var                                        # eq. (23)
    if z - v >= -p.agree_mps:
        anchor, anchor_s = v, 0.0
    return RefSpeed(v, var, False, 0.0, 0.0, anchor, anchor_s, resets)


@dataclass(frozen=True)
class BecuParams:
    cycle_us: int = 10_000                   # BECU cycle, DESIGN.md node table
    car_mass_kg: float = 40_000.0            # nominal car mass (load-weighed in service), chosen
    wheel_radius_m: float = 0.46             # nominal wheel radius
    brake_gain_Nm_per_Pa: float = 0.08       # squeeze-line slope alpha-bar, seed 001 eq. (6), brake data
    brake_preload_Pa: float = 30e3           # squeeze line offset -beta-bar/alpha-bar (return spring)
    p_max_Pa: float = 450e3                  # p-bar, seed 001 eq. (5)
    # EP valve flow 1 MPa/s at full opening: kp = 1/(Tp*rate) gives seed 001's Tp = 50 ms (eq. 4, §IV)
    pressure_pi: PIParams = field(default_factory=lambda: PIParams(
        kp=2.0e-5, ki=4.0e-5, out_min=-1.0, out_max=1.0))
    wsp: WspParams = field(default_factory=WspParams)
    # reference speed (`reference_speed`): the wheel slides when it reads more than this below the
    # estimate [m/s]; 0 = the accelerometer reference of seed 001's runs (the wheel only lifts it).  Above
    # the most an accelerometer error within its fault limit moves the estimate off the axle
    # (RefSpeedParams: 0.7 m/s² × 0.17 s = 0.12 m/s) and below WSP's lowest vent threshold (0.3 m/s); a slip
    # growing faster than gate/τ = 0.9 m/s² is caught as a slide, a slower one followed with a lag of at
    # most the gate (chosen)
    wheel_trust_slip_mps: float = 0.15
    ref: RefSpeedParams = field(default_factory=RefSpeedParams)
    # the wheel's creep the reference speed adds back (`creep_mps`, on the adhesion the car's brake uses:
    # squeeze-line torque of seed 001 eq. (6) / (r m g)); None: the estimate is the wheel's speed
    creep: CreepParams | None = field(default_factory=CreepParams)
    # EP valve fill and vent, WSP dump valve, at full opening [Pa/s]: the brake's valve data (plant_sim's
    # BrakeParams, representative values); kp = 1/(Tp·fill) of pressure_pi gives seed 001's Tp = 50 ms
    valve_rates_Pa_per_s: tuple[float, float, float] = (1.0e6, 1.5e6, 2.0e6)
    # CylSensorFault: the pressure loop runs on a model of the cylinder fed with the valve commands, which
    # assumes the valves fill this fraction slower and vent it faster than their data, so that the real
    # cylinder ends at or above the set-point: a brake ECU that fails, brakes (chosen)
    cyl_model_derate: float = 0.1
    emergency_decel_mps2: float = 1.3        # used when BCU_EMERGENCY is active and the demand lags
    # railway fail-safe, issue #9: a demand missing or unusable (E2E/SecOC) for this many cycles is
    # loss of command, and loss of command is braking at the emergency deceleration
    failsafe_cycles: int = 3
    # "pressure": feed-forward set-point from the demand (inverse brake model) + the pressure PI (v1).
    # "decel": seed 001's eq. (16), a PI on the deceleration error measured by the accelerometer whose
    # output is the cylinder pressure set-point u (CylPressureSet); the pressure PI still drives the EP
    # valve for plants without an integrated pressure controller.
    control: str = "pressure"
    # eq. (16) gains, issue #4's set: K_P = 5 bar/g, K_I = 40 bar/(g s), in Pa per m/s² (1 bar = 1e5 Pa,
    # g = 9.81 m/s²); output bounded to 0 ≤ u ≤ p̄, eq. (5b)
    decel_pi: PIParams = field(default_factory=lambda: PIParams(
        kp=5e5 / G_MPS2, ki=40e5 / G_MPS2, out_min=0.0, out_max=450e3))
    # reference governor of seed 001 eq. (9), decel mode only; a GovernorSchedule picks its model by SpeedEst
    governor: GovernorParams | GovernorSchedule | None = None
    # the car's running resistance as the governor knows it, Davis (c0 [N], c1 [N s/m], c2 [N s²/m²]), eq.
    # (4) seed 003: the measured deceleration's force less R(SpeedEst) is the friction; None: R = 0 (seed 001)
    running_resistance: tuple[float, float, float] | None = None
    # decel mode, leaving WSP: "freeze" resumes the PI where WSP froze it (the project's convention);
    # "handover" restarts it bumplessly from the vented set-point u = 0
    wsp_resume: str = "freeze"
    pressure_observer_gain: float = 0.1     # governor's cylinder observer: correction per cycle (chosen)
    sensors: SensorCheckParams = field(default_factory=SensorCheckParams)   # plausibility, issue #9
    # output gate on the BCU's pressure correction φ (seed 004 eq. (34)): the authority the BCU has over
    # this car's service-brake pressure, -38 %/+67 % (chosen; the BCU's own limits are the same)
    phi_limits: tuple[float, float] = (0.6, 1.6)
    # φ older than this is not applied: 3 cycles of BCU_BRAKE_CORR (100 ms, DBC), as the BCU judges a
    # silent car after 3 of its status cycles; a lost or deleted correction falls back to φ = 1
    phi_timeout_us: int = 300_000

    def __post_init__(self) -> None:
        if self.control not in ("pressure", "decel"):
            raise ValueError(f"BecuParams: control must be 'pressure' or 'decel', got {self.control!r}")
        if self.wsp_resume not in ("freeze", "handover"):
            raise ValueError(f"BecuParams: wsp_resume must be 'freeze' or 'handover', "
                             f"got {self.wsp_resume!r}")
        if self.governor is not None and self.control != "decel":
            raise ValueError("BecuParams: the reference governor needs control = 'decel'")


class Becu:
    """One car's brake ECU: step(now_us, rx) -> dict of output signals."""

    INPUTS = ("AxleSpeed", "CylPressure", "AccelLong", "TargetDecel", "BCU_DEMAND.Mode", "EmergencyActive")
    PHI_INPUTS = ("FrictionPhi", "FbState")     # BCU_BRAKE_CORR, where the train has deceleration feedback
    OUTPUTS = ("CylPressureSet", "ValveCmd", "WspValve", "SpeedEst", "SlipSpeedEst", "WspActive",
               "GovernorActive", "IntegratorSat", "InputMissing", "OptSlipEst", "OptSlipPos",
               "GovernedDecel", "GovernorMargin", "GovernorFeasible", "SpeedSensorFault", "AccelSensorFault",
               "CylSensorFault", "AccelBiasEst")

    def __init__(self, params: BecuParams | None = None) -> None:
        self.p = params or BecuParams()
        self.pressure_pi = PI(self.p.pressure_pi)
        self.decel_pi = PI(self.p.decel_pi)
        self._vented = False          # WSP overrode the decel PI last cycle
        self.u_sent = 0.0             # decel mode: the set-point sent last cycle [Pa]
        self.p_hat = 0.0              # decel mode: observed cylinder pressure [Pa]
        self.torque_est = 0.0         # brake torque: the governor's play model run on the measured pressure
        self.r_gov: float | None = None              # last governed reference [m/s²]
        self.decision: GovernorDecision | None = None   # last governor decision (diagnostic)
        self.wsp = Wsp.FILL
        self.ref = RefSpeed()         # the reference speed's state (`reference_speed`); v_ref is its estimate
        self.timer = CycleTimer(self.p.cycle_us)
        self.missing_inputs = 0       # cycles with a missing or non-finite input (diagnostic)
        self.failsafe_cycles = 0      # cycles braked by the fail-safe (diagnostic)
        # sensor plausibility (issue #9)
        self.speed_check = SpeedCheck()
        self.accel_check = AccelCheck()
        self.speed_fault_us: int | None = None     # when SpeedSensorFault latched (diagnostic)
        self.accel_fault_us: int | None = None     # when AccelSensorFault latched (diagnostic)
        self._wheel_prev = math.nan   # previous fresh wheel reading r·ω [m/s]
        self._rx_us: int | None = None   # reception time of the sensor frame used last cycle
        self._axle_accel = 0.0        # d(r·ω)/dt, filtered [m/s²]
        self._wheel_smooth = math.nan  # the wheel reading smoothed (SPIN_UP_SMOOTHING) [m/s] ...
        self._wheel_low = math.nan    # ... its lowest since WSP left FILL [m/s] ...
        self._wheel_high = math.nan   # ... the highest since that low [m/s] ...
        self._spinning_up = False     # ... and the last one was a new high while the axle accelerated
        self._anchor_wheel = math.nan  # bias filter: wheel reading at its last update [m/s] ...
        self._accel_sum = 0.0         # ... the accelerometer integrated since [m/s] ...
        self._span_s = 0.0            # ... over this time [s] ...
        self._span_tainted = False    # ... begun in a slide, and the wheel has spun up since: no evidence
        self._span_in_slide = False   # the span began while the wheel slid
        self._span_slid = False       # the axle decelerated faster than the car can within the span
        self.vent_s = 0.0             # WSP: time out of FILL without a break [s]
        self.wsp_tripped = False      # WSP: the vent-time watchdog holds the cylinder in FILL
        self.wsp_watchdog_trips = 0   # times the watchdog refilled a cylinder (diagnostic)
        if self.p.governor is not None:
            warm_up()                 # the governor's compiled prediction ready before the first cycle
        self.ceiling_Pa = math.inf    # slip-mode WSP: refill no higher than this [Pa] (slip_ceiling)
        self.fill_s = 0.0             # ... time in FILL since the last slide [s]
        # pressure transducer (issue #19)
        self.cyl_check = CylCheck()
        self.cyl_fault_us: int | None = None       # when CylSensorFault latched (diagnostic)
        self.p_model = math.nan       # once it has: the modelled cylinder pressure the loop runs on [Pa]
        self._cyl_prev = (math.nan, math.nan)   # the two previous fresh pressure readings [Pa]
        self._valve_sent = 0.0        # ValveCmd and WspValve sent last cycle
        self._wsp_sent = Wsp.FILL

    @property
    def v_ref(self) -> float:
        """The reference speed [m/s] (SpeedEst; NaN before the first cycle)."""
        return self.ref.v_mps

    @v_ref.setter
    def v_ref(self, v_mps: float) -> None:
        """Re-anchor the reference speed (a sensor check latched): no slide bridged from here."""
        self.ref = self.ref._replace(v_mps=v_mps, anchor_mps=v_mps, anchor_s=0.0, sliding=False, slide_s=0.0,
                                     free_s=0.0)

    def pressure_for_decel(self, decel_mps2: float) -> float:
        """Set-point that gives `decel` on the squeeze line: F = m a, tau = F r, p = tau/alpha + preload."""
        if decel_mps2 <= 0.0:
            return 0.0
        torque = self.p.car_mass_kg * decel_mps2 * self.p.wheel_radius_m
        return clip(torque / self.p.brake_gain_Nm_per_Pa + self.p.brake_preload_Pa, 0.0, self.p.p_max_Pa)

    def apply_phi(self, p_set_Pa: float, phi: float) -> float:
        """Seed 004 eq. (34): P_c = P_c0/φ on the force part of the set-point (above the return-spring
        preload, where the torque is proportional to the pressure, eq. (24)); φ gated to `phi_limits`."""
        pre = self.p.brake_preload_Pa
        if phi == 1.0 or p_set_Pa <= pre:
            return p_set_Pa
        lo, hi = self.p.phi_limits
        return clip(pre + (p_set_Pa - pre) / clip(phi, lo, hi), 0.0, self.p.p_max_Pa)

    def decel_control(self, r0: float, decel: float, pressure: float, dt_s: float,
                      overridden: bool) -> tuple[float, bool]:
        """Seed 001's loop: governor (eq. 9) -> PI on the deceleration error (eq. 16) -> set-point u.

        r0: requested deceleration [m/s²]; decel: measured deceleration (−AccelLong) [m/s²]; pressure:
        measured cylinder pressure [Pa]. Returns (u [Pa], governor active). While WSP overrides
        (`overridden`), the PI is frozen and u = 0 (vent, seed 001 §II-C).
        """
        p = self.p
        r = r0
        governed = False
        gp = p.governor
        if isinstance(gp, GovernorSchedule):
            gp = gp.at(self.v_ref)
        if gp is not None:
            # cylinder observer: the lag of eq. (4) run on the set-point this BECU sent, corrected towards
            # the measured pressure; the torque estimate is the play model (10a) on the observed pressure
            # (on the raw measurement, sensor noise would ratchet the estimated torque up)
            p_hat = self.u_sent + (self.p_hat - self.u_sent) * gp.phi
            self.p_hat = p_hat + p.pressure_observer_gain * (pressure - p_hat)
            self.torque_est = play(self.torque_est, self.p_hat, gp)
            c = p.running_resistance
            v = max(self.v_ref, 0.0) if math.isfinite(self.v_ref) else 0.0
            res = c[0] + v * (c[1] + c[2] * v) if c is not None else 0.0        # eq. (4), seed 003
            x = GovernorState(self.decel_pi.i, self.p_hat, self.torque_est, gp.mass_kg * decel - res, res)
            self.decision = govern(x, r0, gp, self.r_gov)
            r = self.r_gov = self.decision.r_mps2
            governed = self.decision.active
        if self._vented and not overridden and p.wsp_resume == "handover":
            # back from WSP: bumpless hand-over from the applied u = 0 (simple-pid's set_auto_mode), so
            # tracking restarts from the vented cylinder as in seed 001 §IV-A rather than from the
            # pre-slide set-point that just made the wheel slide
            self.decel_pi.handover(0.0, error=r - decel)
        self._vented = overridden
        u = self.decel_pi.update(r - decel, dt_s, freeze=overridden)  # eq. (16), e = r − v̇
        self.u_sent = 0.0 if overridden else u
        return self.u_sent, governed

    def demand_lost(self, now_us: int, rx: Mapping[str, float]) -> bool:
        """Loss of command: no usable brake demand for more than `failsafe_cycles` cycles.  Frames the
        E2E or SecOC check rejects never update the demand (hil.runtime.node), so a corrupt, forged, stale or
        missing demand all age it.  Needs the reception times of the node runtime's RxTable; a plain
        mapping (unit tests) never loses its command; neither does a BECU that never had one."""
        age_us = getattr(rx, "age_us", None)
        age = age_us("TargetDecel", now_us) if age_us is not None else None
        return age is not None and age > self.p.failsafe_cycles * self.p.cycle_us

    def phi_stale(self, now_us: int, rx: Mapping[str, float]) -> bool:
        """The correction φ was received more than `phi_timeout_us` ago (a plain mapping, as in unit tests,
        has no reception times: never stale)."""
        age_us = getattr(rx, "age_us", None)
        age = age_us("FrictionPhi", now_us) if age_us is not None else None
        return age is not None and age > self.p.phi_timeout_us

    def _fresh_sensor_frame(self, now_us: int, rx: Mapping[str, float], dt_s: float) -> tuple[bool, float]:
        """(a sensor frame arrived since the last cycle, time since the previous one [s]).  A plain
        mapping (unit tests) has no reception times: every cycle is a fresh frame, `dt_s` apart."""
        age_us = getattr(rx, "age_us", None)
        if age_us is None:
            return True, dt_s
        age = age_us("AxleSpeed", now_us)
        if age is None:
            return False, dt_s
        t_rx = now_us - age
        last, self._rx_us = self._rx_us, t_rx
        if last is None:
            return True, dt_s
        return t_rx != last, (t_rx - last) * 1e-6

    def _check_sensors(self, now_us: int, wheel_v: float, accel: float, span_s: float,
                       creep: float = 0.0) -> None:
        """Plausibility of the wheel-speed sensor and the accelerometer on a fresh sensor frame (after the
        speed estimate of this cycle, before WSP).  The bias compares the accelerometer with the car's
        speed as the wheel gives it, r·ω plus its creep (`creep`, m/s): the creep's build-up as the brake
        applies is not the accelerometer's bias."""
        sc = self.p.sensors
        prev = self._wheel_prev
        self._wheel_prev = wheel_v
        car_v = wheel_v + creep
        if not math.isfinite(prev) or span_s <= 0.0:
            self._anchor_wheel = car_v
            return
        gain = min(span_s / sc.axle_accel_tau_s, 1.0)
        self._axle_accel += gain * ((wheel_v - prev) / span_s - self._axle_accel)
        ac = self.accel_check
        before = self.speed_check
        corrected = accel - ac.bias_mps2 if not ac.fault else clip(self._axle_accel, -sc.car_accel_max_mps2,
                                                                     sc.car_accel_max_mps2)
        check = speed_sensor_check(before, wheel_v, prev, self.v_ref, corrected, span_s, sc)
        self.speed_check = check
        if check.fault:
            if not before.fault:
                self.speed_fault_us = now_us
                if check.cause == "frozen":          # the speed the frozen reading would have reached
                    self.v_ref = max(wheel_v + check.frozen_dv_mps, 0.0)
                self.wsp = Wsp.FILL
            return                                   # no axle to compare the accelerometer with
        self._accel_sum += accel * span_s
        self._span_s += span_s
        # a span begun mid-slide in which the wheel spins back up holds the slide's recovery, not its onset:
        # the wheel's speed change over it is not the car's (the slip's rise and fall do not cancel)
        self._span_tainted |= self._span_in_slide and self._axle_accel > self.p.ref.spin_up_accel_mps2
        self._span_slid |= self._axle_accel < -sc.car_accel_max_mps2
        if check.stands or check.frozen_s > 0.0:
            return                                   # the wheel is not trusted yet: wait for the span's end
        sliding = (self.v_ref - car_v > sc.slide_gate_mps or self.wsp != Wsp.FILL or self.ref.sliding
                   or abs(self._axle_accel) > sc.car_accel_max_mps2)   # the wheel does what the car cannot
        if sliding and self._span_s < (sc.slide_span_max_s if self._span_slid else sc.span_max_s):
            return                                   # bridge the slide: update once the wheel is back
        span = self._span_s
        wheel_rate = (car_v - self._anchor_wheel) / span
        rising = wheel_rate > self.p.ref.spin_up_accel_mps2            # a vented wheel coming back
        if not (sliding and (abs(wheel_rate) > sc.car_accel_max_mps2 or rising) or self._span_tainted):
            self.accel_check = accel_bias_check(ac, self._accel_sum / span, wheel_rate, span, sc)
        self._anchor_wheel, self._accel_sum, self._span_s = car_v, 0.0, 0.0
        self._span_in_slide, self._span_tainted, self._span_slid = sliding, False, False
        if self.accel_check.fault and not ac.fault:
            self.accel_fault_us = now_us
            self.v_ref = wheel_v                     # drop what the biased accelerometer integrated

    def _spin_up_check(self, wheel_v: float) -> None:
        """On a fresh wheel reading: is the vented wheel spinning back up (RefSpeedParams.spin_up_accel_mps2)?
        Its axle accelerates faster than a braked car can (as of the last reading: `_axle_accel`), and the
        reading, smoothed (SPIN_UP_SMOOTHING), is the highest since its lowest since WSP left FILL (the
        wheel may lock after the vent began, while its commands are lost).  The new-high condition keeps a
        noisy sensor from passing for a spinning wheel: noise sets new records ever more rarely (the n-th
        reading of a standing signal is one with probability 1/n), a wheel spinning up sets one every
        reading."""
        w = self._wheel_smooth
        w = wheel_v if not math.isfinite(w) else w + SPIN_UP_SMOOTHING * (wheel_v - w)
        self._wheel_smooth = w
        if self.wsp == Wsp.FILL or not math.isfinite(self._wheel_high) or w < self._wheel_low:
            self._wheel_high = self._wheel_low = w
            self._spinning_up = False
            return
        high = w > self._wheel_high
        self._wheel_high = max(self._wheel_high, w)
        self._spinning_up = high and self._axle_accel > self.p.ref.spin_up_accel_mps2

    def _check_cylinder(self, now_us: int, pressure: float, span_s: float) -> None:
        """Plausibility of the pressure transducer on a fresh sensor frame, against the valve commands sent
        over the span (`cyl_sensor_check`).  On failing: the model of the cylinder starts where the valves
        should have taken the pressure since the reading froze, and the pressure PI, wound up on the
        frozen reading, restarts."""
        prev, prev2 = self._cyl_prev
        self._cyl_prev = (pressure, prev)
        if not math.isfinite(prev) or span_s <= 0.0:
            return
        p = self.p
        before = self.cyl_check
        self.cyl_check = cyl_sensor_check(before, pressure, prev, prev2, self._valve_sent, self._wsp_sent,
                                          span_s, p.p_max_Pa, p.valve_rates_Pa_per_s, p.sensors)
        if self.cyl_check.fault and not before.fault:
            self.cyl_fault_us = now_us
            self.p_model = clip(self.cyl_check.base_Pa + self.cyl_check.moved_Pa, 0.0, p.p_max_Pa)
            self.pressure_pi.reset()

    def creep(self, pressure_Pa: float) -> float:
        """The wheel's creep [m/s] for the adhesion its brake uses at this cylinder pressure: the squeeze
        line's torque (seed 001 eq. (6)) over r, over the car's weight (`creep_mps`; 0 without CreepParams
        or before the first estimate)."""
        p = self.p
        if p.creep is None or not math.isfinite(self.v_ref):
            return 0.0
        mu = p.brake_gain_Nm_per_Pa * (pressure_Pa - p.brake_preload_Pa) / (
            p.wheel_radius_m * p.car_mass_kg * G_MPS2)
        return creep_mps(mu, self.v_ref, p.creep)

    def _modelled_pressure(self, dt_s: float) -> float:
        """The cylinder pressure [Pa] the loop runs on once its transducer failed: the model fed with the
        commands sent last cycle (`valve_pressure_rate`), derated to brake (BecuParams.cyl_model_derate)."""
        p = self.p
        fill, vent, dump = p.valve_rates_Pa_per_s
        d = p.cyl_model_derate
        rate = valve_pressure_rate(self._valve_sent, self._wsp_sent, self.p_model, p.p_max_Pa,
                                   (fill * (1.0 - d), vent * (1.0 + d), dump * (1.0 + d)))
        self.p_model = clip(self.p_model + rate * dt_s, 0.0, p.p_max_Pa)
        return self.p_model

    def step(self, now_us: int, rx: Mapping[str, float]) -> dict[str, float]:
        p = self.p
        dt_s = self.timer.dt_s(now_us)
        omega, ok1 = finite_or(rx["AxleSpeed"], 0.0)
        pressure, ok2 = finite_or(rx["CylPressure"], 0.0)
        accel, ok3 = finite_or(rx["AccelLong"], 0.0)
        decel, ok4 = finite_or(rx["TargetDecel"], 0.0)
        emergency, ok5 = finite_or(rx["EmergencyActive"], 0.0)
        missing = not (ok1 and ok2 and ok3 and ok4 and ok5)
        self.missing_inputs += missing
        if emergency >= 0.5:
            decel = max(decel, p.emergency_decel_mps2)
        lost = self.demand_lost(now_us, rx)
        if lost:                                                      # fail-safe: loss of command brakes
            decel = max(decel, p.emergency_decel_mps2)
            self.failsafe_cycles += 1

        wheel_v = omega * p.wheel_radius_m
        sc = p.sensors
        fresh, span_s = self._fresh_sensor_frame(now_us, rx, dt_s)
        if fresh and ok1:
            self._spin_up_check(wheel_v)
        spinning_up = self._spinning_up
        cyl_failed = self.cyl_check.fault
        if fresh and ok2 and not cyl_failed:
            self._check_cylinder(now_us, pressure, span_s)
        if self.cyl_check.fault:                     # the loop runs on the model of the cylinder
            pressure = self._modelled_pressure(dt_s) if cyl_failed else self.p_model
        # the car's acceleration: the accelerometer, or the axle's (bounded) once the accelerometer failed
        accel_used = accel if not self.accel_check.fault else clip(
            self._axle_accel, -sc.car_accel_max_mps2, sc.car_accel_max_mps2)
        creep = self.creep(pressure) if p.wheel_trust_slip_mps > 0.0 else 0.0   # none: seed 001's reference
        if self.speed_check.fault:                   # no wheel: the accelerometer alone, bias-corrected
            self.v_ref = max(self.v_ref + (accel - self.accel_check.bias_mps2) * dt_s, 0.0)
        else:                                        # the accelerometer less g·sin θ and its bias
            # seed 001's reference: the raw accelerometer, lifted to the axle on each fresh reading only (a
            # stale one is the wheel's past speed: lifted to it every cycle, the estimate stood still through
            # a gap in the sensor frames, and WSP vented a rolling wheel when they came back, issue #19)
            seed_001 = p.wheel_trust_slip_mps <= 0.0
            car_accel = (accel_used - self.accel_check.bias_mps2
                         if not self.accel_check.fault and not seed_001 else accel_used)
            suspect = self.speed_check.stands or self.speed_check.frozen_s > 0.0
            self.ref = reference_speed(self.ref, wheel_v, car_accel, dt_s, fresh and ok1,
                                       self.wsp == Wsp.FILL, pressure <= p.ref.torque_free_Pa,
                                       p.wheel_trust_slip_mps, p.ref, creep, suspect, spinning_up)
        if fresh and ok1 and ok3:
            self._check_sensors(now_us, wheel_v, accel, span_s, creep)
        speed_fault = self.speed_check.fault
        slip = 0.0 if speed_fault else self.v_ref - wheel_v          # eq. (2), seed 001
        if speed_fault:
            self.wsp = Wsp.FILL                      # WSP inhibited: a failed sensor never vents the brake
        else:
            wanted = wsp_transition(self.wsp, slip, self.v_ref, p.wsp)
            if p.wsp.mode == "slip":
                wanted = early_vent(wanted, slip, self.v_ref, self._axle_accel, p.wsp)
            self.vent_s, tripped = vent_watchdog(self.vent_s, self.wsp_tripped, wanted != Wsp.FILL,
                                                 wanted == Wsp.FILL, dt_s, p.wsp.max_vent_s, spinning_up)
            self.wsp_watchdog_trips += tripped and not self.wsp_tripped
            self.wsp_tripped = tripped
            before, self.wsp = self.wsp, Wsp.FILL if tripped else wanted
            if p.wsp.mode == "slip":
                self.fill_s = self.fill_s + dt_s if self.wsp == Wsp.FILL else 0.0
                active = self.v_ref >= p.wsp.min_speed_mps and not tripped
                self.ceiling_Pa = (slip_ceiling(self.ceiling_Pa, before, self.wsp, pressure, self.fill_s,
                                                dt_s, p.wsp) if active else math.inf)

        overridden = self.wsp != Wsp.FILL
        governed = False
        if p.control == "decel":
            p_set, governed = self.decel_control(decel, -accel_used, pressure, dt_s, overridden)
        else:
            p_set = self.pressure_for_decel(decel)
            phi, phi_ok = finite_or(rx.get("FrictionPhi", 1.0), 1.0)
            engaged = (finite_or(rx.get("FbState", 0.0), 0.0)[0] in PHI_STATES
                       and not self.phi_stale(now_us, rx))
            if phi_ok and engaged and emergency < 0.5 and not lost:      # seed 004 §5: not for emergency
                p_set = self.apply_phi(p_set, phi)
        if p_set > self.ceiling_Pa:                                   # slip-mode WSP: refill to the ceiling
            p_set = self.ceiling_Pa
        if self._wsp_sent != Wsp.FILL and not overridden:
            # WSP hands the cylinder back: the loop restarts with an empty integrator (the EP valve holds
            # at zero opening). Kept frozen, it held what it wound up during the refills before: the
            # cylinder overshot by up to 0.17 bar after each refill and the brake's hysteresis
            # (seed 001 eq. (10a)) kept the torque, 5 % above the demand (railhil wsp-test)
            self.pressure_pi.reset()
        valve = self.pressure_pi.update(p_set - pressure, dt_s, freeze=overridden)
        if overridden:
            valve = 0.0                                               # the dump valve acts, EP valve holds
        self._valve_sent, self._wsp_sent = valve, self.wsp
        return {
            "CylPressureSet": p_set,
            "ValveCmd": valve,
            "WspValve": int(self.wsp),
            "SpeedEst": max(self.v_ref, 0.0),
            "SlipSpeedEst": slip,
            "WspActive": int(overridden),
            "GovernorActive": int(governed),
            "IntegratorSat": int(self.pressure_pi.saturated or self.pressure_pi.frozen or (
                p.control == "decel" and (self.decel_pi.saturated or self.decel_pi.frozen))),
            "InputMissing": int(missing or lost),
            "OptSlipEst": 0.0,
            "OptSlipPos": 0.0,
            "GovernedDecel": self.r_gov if (self.r_gov is not None and governed) else decel,
            "GovernorMargin": clip(self.decision.margin_Nm, -65536.0, 65534.0) if self.decision else 0.0,
            "GovernorFeasible": int(self.decision.feasible) if self.decision else 1,
            "SpeedSensorFault": int(speed_fault),
            "AccelSensorFault": int(self.accel_check.fault),
            "CylSensorFault": int(self.cyl_check.fault),
            "AccelBiasEst": clip(self.accel_check.bias_mps2, -4.096, 4.094),   # the DBC signal's range
        }
