"""The brake control of one car, as an external BECU: pure, no bus, no clock (time is passed in).

Chain, each cycle (10 ms):

1. target deceleration: BCU_DEMAND.TargetDecel; at least the emergency deceleration while
   BCU_EMERGENCY.EmergencyActive = 1, and also when the demand is lost (no usable BCU_DEMAND for more
   than 3 cycles: a corrupt, forged, stale and missing demand all age it);
2. cylinder-pressure set-point from the inverse brake model: force F = m·a, torque τ = F·r, pressure
   p = τ/ᾱ + preload on the squeeze line, clipped to 0..p̄; the BCU's friction correction φ
   (BCU_BRAKE_CORR.FrictionPhi, sent only by a train with deceleration feedback) divides the force part
   while the same frame's FbState is ENGAGED or HELD and the frame is at most 300 ms old, except in
   emergency and on loss of command;
3. the brake-cylinder pressure transducer, on each new PLANT_CARn_SENSORS frame: it is stuck when its
   reading repeats while the valves this ECU commanded should have moved the pressure (CylSensorFault);
   the PI then runs on a model of the cylinder fed with those commands, biased to brake;
4. reference speed (SpeedEst): a scalar Kalman filter, seed 004 §3.2 eqs. (19)–(23), that integrates the
   accelerometer less its bias and takes the axle's r·ω plus the creep its brake needs (seed 000 eq. (1))
   as the measurement of the car's speed; while the wheel slides (it reads more than a gate below the
   estimate, or WSP acts) it runs on the accelerometer alone;
5. the wheel-speed sensor and the accelerometer, on each new sensor frame: the wheel-speed sensor has
   failed when it says the wheel stands, or repeats its reading, while the accelerometer says the car
   moves or changes speed (SpeedSensorFault; the reference speed then runs on the accelerometer and WSP
   is off); the accelerometer's bias (AccelBiasEst, used from the next cycle) is its reading less the
   wheel's acceleration, filtered over spans the wheel does not slide, and a fault (AccelSensorFault)
   when large for long (the wheel's acceleration then replaces it);
6. wheel-slide protection: slip speed = reference − r·ω (seed 001 eq. (2)); VENT above 0.30 m/s + 3 % of
   the speed, HOLD below half of that, FILL below a quarter; off below 1 m/s; a cylinder kept out of FILL
   for 5 s is refilled until the wheel recovers;
7. PI control of the EP valve opening (ValveCmd, −1..+1) on the pressure error, with conditional
   anti-windup; frozen, and the valve closed, while WSP holds or vents; restarted from an empty
   integrator when WSP hands the cylinder back.

This is railhil's BECU (firmware_py/becu.py) in its "pressure" control, step for step: the numbers are
those of that ECU and of the plant of the train it joins (railhil's defaults for the default scenario:
a 40 t car); each constant says where it comes from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple

G_MPS2 = 9.81                 # standard gravity [m/s²]
SPIN_UP_SMOOTHING = 0.2       # the spin-up check's smoothing of the wheel reading per reading (τ = 50 ms)


class Wsp(IntEnum):
    """WSP dump-valve state: the DBC choices of BECUn_PRESS_CMD.WspValve."""

    FILL = 0
    HOLD = 1
    VENT = 2


class FbState(IntEnum):
    """The BCU's deceleration feedback state: the DBC choices of BCU_BRAKE_CORR.FbState."""

    OFF = 0
    MONITOR = 1
    ENGAGED = 2       # correcting through φ
    HELD = 3          # released (WSP, or the band not met): the engaged correction is kept


# the states in which the BCU's φ is a correction to apply (the DBC comment of FbState)
PHI_STATES = (FbState.ENGAGED, FbState.HELD)


@dataclass(frozen=True)
class RefSpeedParams:
    """The reference speed's filter and the wheel's creep (railhil's RefSpeedParams and CreepParams)."""

    accel_std_mps2: float = 0.12          # process noise: the accelerometer less its bias [m/s²]
    wheel_std_mps: float = 0.02           # measurement noise: r·ω as the car's speed [m/s]
    # the wheel slides when it reads more than this below the estimate (railhil's
    # BecuParams.wheel_trust_slip_mps): above what an accelerometer error within its fault limit moves the
    # estimate off the axle (0.7 m/s² × τ = 0.17 s), below WSP's lowest vent threshold
    wheel_trust_slip_mps: float = 0.15
    agree_mps: float = 0.03               # the wheel agrees: at most this below the estimate (3 σ)
    rollback_s: float = 1.0               # a slide found this soon after the last agreement restarts there
    torque_free_Pa: float = 10e3          # below this cylinder pressure the wheel has no brake torque ...
    spin_up_s: float = 0.5                # ... and spins up to the car's speed within this: the wheel is
    #                                       taken again after it (the estimate was wrong)
    bridge_max_s: float = 6.0             # a slide is bridged at most this long (> the 5 s WSP watchdog)
    # a wheel accelerating faster than this is spinning back up to the car's speed (from a lock it takes
    # seconds): that time counts towards neither spin_up_s, bridge_max_s nor the vent watchdog [m/s²]
    spin_up_accel_mps2: float = 1.0
    # the creep: seed 000 eq. (1) with θ of the plant's "dry" rail (plant_sim.params.RAIL_CONDITIONS)
    theta: tuple[float, float, float] = (0.35416, 11.030, 8.6158)
    pi1_s_per_m: float = 1.0 / 40.0       # k1(v) = 1 + v/40, seed 000 §3
    pi2_s_per_m: float = 1.0 / 40.0       # k2(v) = 1 + v/40, seed 000 §3
    v_eps_mps: float = 0.5                # σ = s / max(v, v_eps) at low speed (the plant's adhesion)


@dataclass(frozen=True)
class SensorParams:
    """Plausibility limits of the car's sensors (railhil's SensorCheckParams, issues #9 and #19)."""

    # wheel-speed sensor "stands": below stand_mps while the estimate is above moving_mps, for lock_s
    stand_mps: float = 0.3
    moving_mps: float = 3.0
    lock_s: float = 1.0
    # wheel-speed sensor "frozen": the same reading (≥ frozen_min_mps) while the accelerometer less its
    # bias integrates to more than frozen_dv_mps
    frozen_dv_mps: float = 0.5
    frozen_min_mps: float = 1.0
    # accelerometer bias: first-order filter (τ = bias_tau_s) of accelerometer − the wheel's acceleration;
    # a fault above bias_limit_mps2 (more than the steepest gradient's g·sin θ, 0.588 m/s²) for bias_hold_s
    bias_tau_s: float = 1.5
    bias_limit_mps2: float = 0.7
    bias_hold_s: float = 0.5
    # the filter is updated over spans the wheel does not slide (slip below slide_gate_mps, WSP in FILL, the
    # wheel's acceleration within what the car can do); a span closes after span_max_s whatever the slip,
    # one in which the axle decelerated faster than the car can (a slide's onset) after slide_span_max_s
    slide_gate_mps: float = 0.1
    span_max_s: float = 1.0
    slide_span_max_s: float = 30.0
    axle_accel_tau_s: float = 0.1         # the wheel's acceleration, filtered (stands in for a failed
    #                                       accelerometer) ...
    car_accel_max_mps2: float = 2.5       # ... bounded to what the car can do (0.25 g)
    # pressure transducer "stuck": its reading repeats while the valves should have moved the pressure by
    # more than cyl_frozen_dp_Pa; EP valve openings below cyl_valve_min, fills within cyl_margin_Pa of p̄
    # and vents within it of 0 are no evidence; a step beyond the fastest valve's plus cyl_noise_Pa is the
    # transducer jumping to where it stuck
    cyl_frozen_dp_Pa: float = 50e3
    cyl_valve_min: float = 0.02
    cyl_margin_Pa: float = 20e3
    cyl_noise_Pa: float = 5e3


@dataclass(frozen=True)
class CarParams:
    """The car and its brake, and the gains of this ECU."""

    cycle_us: int = 10_000                # BECUn_PRESS_CMD's GenMsgCycleTime (DBC), 10 ms
    car_mass_kg: float = 40_000.0         # [train] mass_kg of scenarios/default.toml (load-weighed)
    wheel_radius_m: float = 0.46          # r, the plant's TrainParams.wheel_radius_m (Ø 920 mm wheel)
    brake_gain_Nm_per_Pa: float = 0.08    # ᾱ, slope of the plant's squeeze line (BrakeParams, seed 001 eq. 6)
    brake_preload_Pa: float = 30e3        # −β̄/ᾱ, the return spring: no torque below it (BrakeParams)
    p_max_Pa: float = 450e3               # p̄, the reservoir pressure (BrakeParams.p_max_Pa)
    # EP valve fill and vent, WSP dump valve, at full opening [Pa/s]: the plant's valves
    # (docs/external-ecu.md, "How the plant reads BECUn_PRESS_CMD")
    valve_rates_Pa_per_s: tuple[float, float, float] = (1.0e6, 1.5e6, 2.0e6)
    # EP valve PI: opening per Pa of pressure error; with the valve's 1 MPa/s at full opening kp gives a
    # 50 ms closed-loop time constant (railhil's BecuParams.pressure_pi)
    kp_per_Pa: float = 2.0e-5
    ki_per_Pa_s: float = 4.0e-5
    # CylSensorFault: the cylinder model assumes the valves fill this fraction slower and vent it faster
    # than their data, so that the real cylinder ends at or above the set-point (railhil's cyl_model_derate)
    cyl_model_derate: float = 0.1
    # wheel-slide protection (railhil's WspParams)
    vent_slip_mps: float = 0.30           # vent threshold at standstill [m/s]
    vent_slip_per_speed: float = 0.03     # + this fraction of the reference speed
    hold_fraction: float = 0.5            # VENT -> HOLD below this fraction of the vent threshold
    refill_fraction: float = 0.25         # HOLD -> FILL below this fraction
    wsp_min_speed_mps: float = 1.0        # WSP off below this speed: lets the train stop
    max_vent_s: float = 5.0               # vent-time watchdog (a 5 s WSP safety timer)
    emergency_decel_mps2: float = 1.3     # the BCU's emergency deceleration (BcuParams.emergency_decel_mps2)
    failsafe_cycles: int = 3              # cycles without a usable demand before loss of command
    phi_limits: tuple[float, float] = (0.6, 1.6)   # the authority of the BCU's φ over this car
    phi_timeout_us: int = 300_000         # φ older than 3 BCU_BRAKE_CORR cycles (100 ms, DBC) is not applied
    ref: RefSpeedParams = field(default_factory=RefSpeedParams)
    sensors: SensorParams = field(default_factory=SensorParams)


@dataclass(frozen=True)
class Inputs:
    """The latest usable values of the received signals (NaN: never received) and their ages [µs]."""

    axle_speed_rad_s: float = math.nan    # PLANT_CARn_SENSORS.AxleSpeed
    cyl_pressure_Pa: float = math.nan     # PLANT_CARn_SENSORS.CylPressure
    accel_mps2: float = math.nan          # PLANT_CARn_SENSORS.AccelLong
    target_decel_mps2: float = math.nan   # BCU_DEMAND.TargetDecel
    emergency: float = math.nan           # BCU_EMERGENCY.EmergencyActive
    friction_phi: float = math.nan        # BCU_BRAKE_CORR.FrictionPhi
    fb_state: float = math.nan            # BCU_BRAKE_CORR.FbState
    demand_age_us: int | None = None      # time since the last usable BCU_DEMAND; None: none yet
    phi_age_us: int | None = None         # ... BCU_BRAKE_CORR; None: none yet (or not known)
    sensors_age_us: int | None = None     # ... PLANT_CARn_SENSORS; None: none yet, or not known (every
    #                                       step then has a new reading)


def finite_or(x: float, safe: float) -> tuple[float, bool]:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return safe, False
    return (x, True) if math.isfinite(x) else (safe, False)


def clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


# --- the set-point ---------------------------------------------------------------------------------------

def pressure_for_decel(decel_mps2: float, p: CarParams) -> float:
    """The set-point that gives `decel` on the squeeze line: F = m a, τ = F r, p = τ/ᾱ + preload."""
    if decel_mps2 <= 0.0:
        return 0.0
    torque = p.car_mass_kg * decel_mps2 * p.wheel_radius_m
    return clip(torque / p.brake_gain_Nm_per_Pa + p.brake_preload_Pa, 0.0, p.p_max_Pa)


def apply_phi(p_set_Pa: float, phi: float, p: CarParams) -> float:
    """The BCU's correction φ on the force part of the set-point (seed 004 eq. (34), P_c = P_c0/φ),
    φ gated to `phi_limits`."""
    pre = p.brake_preload_Pa
    if phi == 1.0 or p_set_Pa <= pre:
        return p_set_Pa
    return clip(pre + (p_set_Pa - pre) / clip(phi, *p.phi_limits), 0.0, p.p_max_Pa)


# --- the cylinder and its pressure transducer ------------------------------------------------------------

def valve_pressure_rate(valve_cmd: float, wsp: int, p_Pa: float, p_max_Pa: float,
                        rates: tuple[float, float, float]) -> float:
    """dp/dt [Pa/s] the valves give a cylinder at p_Pa: the EP valve fills at valve_cmd·fill or vents at
    valve_cmd·vent while WSP is in FILL; HOLD isolates the cylinder; VENT dumps it.  No flow beyond 0 and
    p̄ (seed 001 eq. (5a))."""
    fill, vent, dump = rates
    if wsp == Wsp.HOLD:
        return 0.0
    if wsp == Wsp.VENT:
        return -dump if p_Pa > 0.0 else 0.0
    if valve_cmd > 0.0:
        return valve_cmd * fill if p_Pa < p_max_Pa else 0.0
    return valve_cmd * vent if p_Pa > 0.0 else 0.0


class CylCheck(NamedTuple):
    fault: bool = False          # CylSensorFault, latched
    evidence_Pa: float = 0.0     # |pressure change| the valves should have made since the reading stuck
    moved_Pa: float = 0.0        # ... signed
    frozen: bool = False         # the reading repeats
    base_Pa: float = 0.0         # the pressure when it stuck


def cyl_sensor_check(s: CylCheck, reading_Pa: float, prev_Pa: float, before_Pa: float, valve_cmd: float,
                     wsp: int, span_s: float, p: CarParams) -> CylCheck:
    """The pressure transducer on one new reading (prev_Pa, before_Pa: the two before it), against the
    valve commands sent over the span: evidence grows while the reading repeats and the valves should
    move the pressure; a reading that changes clears it."""
    sc, rates = p.sensors, p.valve_rates_Pa_per_s
    if s.fault:
        return s
    if reading_Pa != prev_Pa:
        return CylCheck()
    if not s.frozen:                         # the first repeat: it stuck at prev_Pa, unless it jumped there
        jumped = abs(prev_Pa - before_Pa) > max(rates) * span_s + sc.cyl_noise_Pa
        s = CylCheck(frozen=True, base_Pa=before_Pa if jumped and math.isfinite(before_Pa) else prev_Pa)
    rate = valve_pressure_rate(valve_cmd, wsp, reading_Pa, p.p_max_Pa, rates)
    if wsp == Wsp.FILL and abs(valve_cmd) < sc.cyl_valve_min:
        rate = 0.0                           # the valve's dead band
    elif rate > 0.0 and reading_Pa >= p.p_max_Pa - sc.cyl_margin_Pa:
        rate = 0.0                           # filling at the reservoir's pressure
    elif rate < 0.0 and reading_Pa <= sc.cyl_margin_Pa:
        rate = 0.0                           # venting an empty cylinder
    evidence = s.evidence_Pa + abs(rate) * span_s
    return CylCheck(evidence > sc.cyl_frozen_dp_Pa, evidence, s.moved_Pa + rate * span_s, True, s.base_Pa)


# --- the wheel-speed sensor and the accelerometer --------------------------------------------------------

class SpeedCheck(NamedTuple):
    fault: bool = False          # SpeedSensorFault, latched
    cause: str = ""              # "stands" | "frozen"
    stand_s: float = 0.0         # time the reading has said "stands" while the car moves [s]
    frozen_s: float = 0.0        # time the reading has repeated [s]
    frozen_dv_mps: float = 0.0   # the accelerometer less its bias, integrated over that time [m/s]
    stands: bool = False         # the last reading said "stands" while the car moves


def speed_sensor_check(s: SpeedCheck, wheel_mps: float, prev_mps: float, v_ref_mps: float,
                       accel_mps2: float, span_s: float, sc: SensorParams) -> SpeedCheck:
    """The wheel-speed sensor on one new reading r·ω (prev_mps: the one before), against the reference
    speed and the accelerometer less its bias."""
    if s.fault:
        return s
    # the time between two readings counts only when both stood: a gap in the readings (frames lost,
    # the bus blocked) is no evidence that the wheel stood through it
    stands = wheel_mps < sc.stand_mps and v_ref_mps > sc.moving_mps
    stand_s = (s.stand_s + span_s if s.stands else 0.0) if stands else 0.0
    if wheel_mps == prev_mps and wheel_mps >= sc.frozen_min_mps:
        frozen_s, dv = s.frozen_s + span_s, s.frozen_dv_mps + accel_mps2 * span_s
    else:
        frozen_s, dv = 0.0, 0.0
    if stand_s > sc.lock_s:
        return SpeedCheck(True, "stands", stand_s, frozen_s, dv, stands)
    if abs(dv) > sc.frozen_dv_mps:
        return SpeedCheck(True, "frozen", stand_s, frozen_s, dv, stands)
    return SpeedCheck(False, "", stand_s, frozen_s, dv, stands)


class AccelCheck(NamedTuple):
    fault: bool = False          # AccelSensorFault, latched
    bias_mps2: float = 0.0       # AccelBiasEst: includes g·sin θ of the gradient
    above_s: float = 0.0         # time |bias| has been above the limit [s]


def accel_bias_check(s: AccelCheck, accel_mean_mps2: float, wheel_accel_mps2: float, span_s: float,
                     sc: SensorParams) -> AccelCheck:
    """One update of the bias filter over a span the wheel did not slide: the accelerometer's mean less the
    wheel's acceleration over it (seed 004 eq. (1): the accelerometer reads a + g·sin θ)."""
    if s.fault or span_s <= 0.0:
        return s
    gain = min(span_s / sc.bias_tau_s, 1.0)
    bias = s.bias_mps2 + gain * (accel_mean_mps2 - wheel_accel_mps2 - s.bias_mps2)
    above_s = s.above_s + span_s if abs(bias) > sc.bias_limit_mps2 else 0.0
    return AccelCheck(above_s > sc.bias_hold_s, bias, above_s)


# --- the reference speed ---------------------------------------------------------------------------------

def creep_mps(mu_used: float, v_mps: float, rp: RefSpeedParams) -> float:
    """The slip speed s = σ·max(v, v_eps) [m/s] at which a wheel transmits the adhesion `mu_used` on dry
    rail: seed 000 eq. (1), μ(σ, v) = μ̄(k2(v)·σ) / k1(v) with μ̄(x) = √x / (θ1 + θ2 x + θ3 x²) and
    k_i(v) = 1 + π_i v, inverted on its rising branch by the fixed point x = (μ k1 (θ1 + θ2 x + θ3 x²))²
    from 0, capped at the peak x° = (−θ2 + √(θ2² + 12 θ1 θ3)) / (6 θ3) (seed 000 §2.1)."""
    if not mu_used > 0.0:
        return 0.0
    t1, t2, t3 = rp.theta
    v = max(v_mps, 0.0)
    k1, k2 = 1.0 + rp.pi1_s_per_m * v, 1.0 + rp.pi2_s_per_m * v
    x_peak = (-t2 + math.sqrt(t2 * t2 + 12.0 * t1 * t3)) / (6.0 * t3)
    x = 0.0
    for _ in range(8):
        x = min((mu_used * k1 * (t1 + x * (t2 + t3 * x))) ** 2, x_peak)
    return x / k2 * max(v, rp.v_eps_mps)


class RefSpeed(NamedTuple):
    v_mps: float = math.nan          # the estimate, SpeedEst [m/s]
    var: float = 0.0                 # its variance P [m²/s²]
    sliding: bool = False            # the wheel slides: the estimate runs on the accelerometer alone
    slide_s: float = 0.0             # time in the slide, the wheel not spinning up [s]
    free_s: float = 0.0              # ... of which without brake torque [s]
    anchor_mps: float = math.nan     # the estimate when the wheel last agreed, carried on the accelerometer
    anchor_s: float = 0.0            # time since the wheel last agreed [s]


def reference_speed(s: RefSpeed, wheel_mps: float, accel_mps2: float, dt_s: float, fresh: bool,
                    wsp_fill: bool, torque_free: bool, creep: float, wheel_suspect: bool,
                    rp: RefSpeedParams, spinning_up: bool = False) -> RefSpeed:
    """One cycle of the reference speed.  accel_mps2: the accelerometer less its bias; fresh: a new wheel
    reading r·ω = wheel_mps came; creep: the slip its brake needs (`creep_mps`); wheel_suspect: the
    wheel-speed sensor check is timing the reading (a slide is then not ended by the spin-up rule);
    spinning_up: the wheel spins back up (its axle accelerates faster than rp.spin_up_accel_mps2, its
    smoothed reading setting new highs): that time counts for neither spin_up_s nor bridge_max_s.

    Time update, seed 004 eqs. (19)–(20): v⁻ = v + a·dt, P⁻ = P + (σ_a·dt)².  Measurement z = r·ω + creep
    (seed 001 eq. (2), v = rω + s), eqs. (21)–(23): K = P⁻/(P⁻ + σ_w²), v = v⁻ + K·(z − v⁻),
    P = (1 − K)·P⁻.  A slide (z more than the gate below v⁻, or WSP out of FILL) is no measurement: the
    estimate runs on the accelerometer, restarting from the last agreement when that was recent; the
    slide ends when the wheel agrees again in FILL, or after spin_up_s without brake torque or
    bridge_max_s (the estimate was wrong: the wheel is taken)."""
    if not math.isfinite(s.v_mps):
        return RefSpeed(wheel_mps + creep, rp.wheel_std_mps ** 2, anchor_mps=wheel_mps + creep)
    v = max(s.v_mps + accel_mps2 * dt_s, 0.0)                      # eq. (19)
    var = s.var + (rp.accel_std_mps2 * dt_s) ** 2                   # eq. (20)
    anchor = max(s.anchor_mps + accel_mps2 * dt_s, 0.0)
    anchor_s = s.anchor_s + dt_s
    if not fresh:
        return s._replace(v_mps=v, var=var, anchor_mps=anchor, anchor_s=anchor_s,
                          slide_s=s.slide_s + dt_s * (s.sliding and not spinning_up),
                          free_s=s.free_s + dt_s * (s.sliding and torque_free and not spinning_up))
    z = wheel_mps + creep
    innovation = z - v
    sliding, slide_s, free_s = s.sliding, s.slide_s, s.free_s
    if not sliding and (innovation < -rp.wheel_trust_slip_mps or not wsp_fill):
        sliding, slide_s, free_s = True, 0.0, 0.0
        if anchor_s <= rp.rollback_s:
            v = max(v, anchor)                                      # undo the onset the filter followed
    elif sliding:
        slide_s += dt_s * (not spinning_up)
        free_s += dt_s * (torque_free and not spinning_up)
        if innovation >= -rp.agree_mps and wsp_fill:
            sliding = False                                         # the wheel is back
        elif (free_s > rp.spin_up_s and not wheel_suspect) or slide_s > rp.bridge_max_s:
            sliding, v, var = False, z, rp.wheel_std_mps ** 2       # the estimate was wrong
    if sliding:
        return RefSpeed(v, var, True, slide_s, free_s, anchor, anchor_s)
    gain = var / (var + rp.wheel_std_mps ** 2)                      # eq. (21)
    v = max(v + gain * (z - v), 0.0)                                # eq. (22)
    var = (1.0 - gain) * var                                        # eq. (23)
    if z - v >= -rp.agree_mps:
        anchor, anchor_s = v, 0.0
    return RefSpeed(v, var, False, 0.0, 0.0, anchor, anchor_s)


# --- wheel-slide protection ------------------------------------------------------------------------------

def wsp_transition(state: Wsp, slip_mps: float, speed_mps: float, p: CarParams) -> Wsp:
    """Vent / hold / refill with hysteresis on the slip speed (pure)."""
    if speed_mps < p.wsp_min_speed_mps:
        return Wsp.FILL
    vent_at = p.vent_slip_mps + p.vent_slip_per_speed * speed_mps
    if slip_mps > vent_at:
        return Wsp.VENT
    if state == Wsp.VENT:
        return Wsp.HOLD if slip_mps < p.hold_fraction * vent_at else Wsp.VENT
    if state == Wsp.HOLD:
        return Wsp.FILL if slip_mps < p.refill_fraction * vent_at else Wsp.HOLD
    return Wsp.FILL


class BrakeControl:
    """One car's brake ECU: `step(now_us, inputs)` -> the DBC signals of BECUn_PRESS_CMD, _STATUS, _DIAG,
    _EST."""

    def __init__(self, params: CarParams | None = None) -> None:
        self.p = params or CarParams()
        self.ref = RefSpeed()         # the reference speed's state; SpeedEst is ref.v_mps
        self.wsp = Wsp.FILL
        self.vent_s = 0.0             # time out of FILL without a break [s]
        self.wsp_tripped = False      # the vent-time watchdog holds the cylinder in FILL
        self.integrator = 0.0         # EP valve PI
        self.last_us: int | None = None
        self.lost_cycles = 0          # cycles braked by loss of command (diagnostic)
        self.sensors_us: int | None = None   # reception time of the sensor frame used last cycle
        # pressure transducer
        self.cyl_check = CylCheck()
        self.cyl_prev = (math.nan, math.nan)   # the two previous new readings [Pa]
        self.p_model = math.nan       # once it is stuck: the modelled cylinder pressure [Pa]
        self.sent = (0.0, Wsp.FILL)   # ValveCmd and WspValve sent last cycle
        # wheel-speed sensor and accelerometer
        self.speed_check = SpeedCheck()
        self.accel_check = AccelCheck()
        self.wheel_prev = math.nan    # previous new r·ω [m/s]
        self.axle_accel = 0.0         # d(r·ω)/dt, filtered [m/s²]
        self.wheel_smooth = math.nan  # the reading smoothed (SPIN_UP_SMOOTHING) [m/s]; its lowest since
        self.wheel_low = math.nan     # WSP left FILL [m/s], the highest since
        self.wheel_high = math.nan    # that low, and whether the last one was a new high while the axle
        self.spinning_up = False      # accelerated
        self.span_start = math.nan    # the bias filter's span: the car's speed by the wheel at its start,
        self.span_accel = 0.0         # the accelerometer integrated since [m/s],
        self.span_in_slide = False    # it began in a slide,
        self.span_tainted = False     # ... and the wheel has spun up since: no evidence,
        self.span_s = 0.0             # and its length [s]
        self.span_slid = False        # the axle decelerated faster than the car can within the span

    def _dt_s(self, now_us: int) -> float:
        dt = self.p.cycle_us * 1e-6 if self.last_us is None else (now_us - self.last_us) * 1e-6
        self.last_us = now_us
        return dt

    def _new_sensor_frame(self, now_us: int, age_us: int | None, dt_s: float) -> tuple[bool, float]:
        """(a sensor frame came since the last cycle, the time since the one before [s])."""
        if age_us is None:
            return True, dt_s
        t_rx, last = now_us - age_us, self.sensors_us
        self.sensors_us = t_rx
        if last is None:
            return True, dt_s
        return t_rx != last, (t_rx - last) * 1e-6

    def _set_v_ref(self, v_mps: float) -> None:
        """Restart the reference speed at v_mps (a sensor check failed): no slide bridged from here."""
        self.ref = self.ref._replace(v_mps=v_mps, anchor_mps=v_mps, anchor_s=0.0, sliding=False, slide_s=0.0,
                                     free_s=0.0)

    def _creep(self, pressure_Pa: float) -> float:
        """The wheel's creep [m/s] for the adhesion its brake uses: the squeeze line's torque (seed 001
        eq. (6)) over r, over the car's weight."""
        p = self.p
        if not math.isfinite(self.ref.v_mps):
            return 0.0
        mu = p.brake_gain_Nm_per_Pa * (pressure_Pa - p.brake_preload_Pa) / (
            p.wheel_radius_m * p.car_mass_kg * G_MPS2)
        return creep_mps(mu, self.ref.v_mps, p.ref)

    def _check_cylinder(self, pressure: float, span_s: float) -> None:
        """The pressure transducer on a new reading; once it is stuck, the model of the cylinder starts
        where the valves should have taken the pressure, and the PI, wound up on the stuck reading,
        restarts."""
        prev, before = self.cyl_prev
        self.cyl_prev = (pressure, prev)
        if not math.isfinite(prev) or span_s <= 0.0:
            return
        was = self.cyl_check
        self.cyl_check = cyl_sensor_check(was, pressure, prev, before, *self.sent, span_s, self.p)
        if self.cyl_check.fault and not was.fault:
            self.p_model = clip(self.cyl_check.base_Pa + self.cyl_check.moved_Pa, 0.0, self.p.p_max_Pa)
            self.integrator = 0.0

    def _modelled_pressure(self, dt_s: float) -> float:
        """The cylinder pressure once its transducer is stuck: the valve commands sent last cycle through
        the valves' rates, derated to brake (fill slower, vent faster)."""
        p = self.p
        fill, vent, dump = p.valve_rates_Pa_per_s
        d = p.cyl_model_derate
        rate = valve_pressure_rate(*self.sent, self.p_model, p.p_max_Pa,
                                   (fill * (1.0 - d), vent * (1.0 + d), dump * (1.0 + d)))
        self.p_model = clip(self.p_model + rate * dt_s, 0.0, p.p_max_Pa)
        return self.p_model

    def _check_wheel_and_accel(self, wheel_v: float, accel: float, span_s: float, creep: float) -> None:
        """The wheel-speed sensor and the accelerometer's bias on a new sensor frame.  The bias compares the
        accelerometer with the car's speed as the wheel gives it, r·ω + creep, over spans the wheel does
        not slide (one update over a whole slide once the wheel is back: the slip's rise and fall cancel)."""
        sc = self.p.sensors
        prev, self.wheel_prev = self.wheel_prev, wheel_v
        car_v = wheel_v + creep
        if not math.isfinite(prev) or span_s <= 0.0:
            self.span_start = car_v
            return
        gain = min(span_s / sc.axle_accel_tau_s, 1.0)
        self.axle_accel += gain * ((wheel_v - prev) / span_s - self.axle_accel)
        ac, was = self.accel_check, self.speed_check
        corrected = accel - ac.bias_mps2 if not ac.fault else clip(self.axle_accel, -sc.car_accel_max_mps2,
                                                                     sc.car_accel_max_mps2)
        check = speed_sensor_check(was, wheel_v, prev, self.ref.v_mps, corrected, span_s, sc)
        self.speed_check = check
        if check.fault:
            if not was.fault:
                if check.cause == "frozen":          # the speed the frozen reading would have reached
                    self._set_v_ref(max(wheel_v + check.frozen_dv_mps, 0.0))
                self.wsp = Wsp.FILL
            return                                   # no wheel to compare the accelerometer with
        self.span_accel += accel * span_s
        self.span_s += span_s
        # begun mid-slide, the wheel spinning back up: the span holds the recovery, not the onset
        self.span_tainted |= self.span_in_slide and self.axle_accel > self.p.ref.spin_up_accel_mps2
        self.span_slid |= self.axle_accel < -sc.car_accel_max_mps2
        if check.stands or check.frozen_s > 0.0:
            return                                   # the wheel is not trusted yet: wait for the span's end
        sliding = (self.ref.v_mps - car_v > sc.slide_gate_mps or self.wsp != Wsp.FILL or self.ref.sliding
                   or abs(self.axle_accel) > sc.car_accel_max_mps2)
        if sliding and self.span_s < (sc.slide_span_max_s if self.span_slid else sc.span_max_s):
            return                                   # bridge the slide
        span = self.span_s
        wheel_rate = (car_v - self.span_start) / span
        rising = wheel_rate > self.p.ref.spin_up_accel_mps2            # a vented wheel coming back
        if not (sliding and (abs(wheel_rate) > sc.car_accel_max_mps2 or rising) or self.span_tainted):
            self.accel_check = accel_bias_check(ac, self.span_accel / span, wheel_rate, span, sc)
        self.span_start, self.span_accel, self.span_s = car_v, 0.0, 0.0
        self.span_in_slide, self.span_tainted, self.span_slid = sliding, False, False
        if self.accel_check.fault and not ac.fault:
            self._set_v_ref(wheel_v)                 # drop what the biased accelerometer integrated

    def _valve(self, error_Pa: float, dt_s: float, freeze: bool) -> tuple[float, bool]:
        """PI with conditional anti-windup: (opening −1..+1, saturated)."""
        p = self.p
        i_next = self.integrator if freeze else self.integrator + p.ki_per_Pa_s * error_Pa * dt_s
        unclipped = p.kp_per_Pa * error_Pa + i_next
        out = clip(unclipped, -1.0, 1.0)
        winding_up = (unclipped > 1.0 and error_Pa > 0.0) or (unclipped < -1.0 and error_Pa < 0.0)
        if not winding_up:
            self.integrator = i_next
        return out, unclipped != out

    def step(self, now_us: int, rx: Inputs) -> dict[str, float]:
        p, sc = self.p, self.p.sensors
        dt_s = self._dt_s(now_us)
        omega, ok1 = finite_or(rx.axle_speed_rad_s, 0.0)
        pressure, ok2 = finite_or(rx.cyl_pressure_Pa, 0.0)
        accel, ok3 = finite_or(rx.accel_mps2, 0.0)
        decel, ok4 = finite_or(rx.target_decel_mps2, 0.0)
        emergency, ok5 = finite_or(rx.emergency, 0.0)
        missing = not (ok1 and ok2 and ok3 and ok4 and ok5)
        if emergency >= 0.5:
            decel = max(decel, p.emergency_decel_mps2)
        lost = rx.demand_age_us is not None and rx.demand_age_us > p.failsafe_cycles * p.cycle_us
        if lost:                                          # loss of command brakes
            decel = max(decel, p.emergency_decel_mps2)
            self.lost_cycles += 1

        wheel_v = omega * p.wheel_radius_m
        fresh, span_s = self._new_sensor_frame(now_us, rx.sensors_age_us, dt_s)
        if fresh and ok1:            # the vented wheel spinning back up: the smoothed reading sets a new
            w = self.wheel_smooth    # high since its lowest while the axle accelerates (noise sets ever
            w = wheel_v if not math.isfinite(w) else w + SPIN_UP_SMOOTHING * (wheel_v - w)   # fewer)
            self.wheel_smooth = w
            if self.wsp == Wsp.FILL or not math.isfinite(self.wheel_high) or w < self.wheel_low:
                self.wheel_high = self.wheel_low = w
                self.spinning_up = False
            else:
                high = w > self.wheel_high
                self.wheel_high = max(self.wheel_high, w)
                self.spinning_up = high and self.axle_accel > p.ref.spin_up_accel_mps2
        spinning_up = self.spinning_up
        stuck = self.cyl_check.fault
        if fresh and ok2 and not stuck:
            self._check_cylinder(pressure, span_s)
        if self.cyl_check.fault:                          # the PI runs on the model of the cylinder
            pressure = self._modelled_pressure(dt_s) if stuck else self.p_model
        ac = self.accel_check
        car_accel = accel - ac.bias_mps2 if not ac.fault else clip(
            self.axle_accel, -sc.car_accel_max_mps2, sc.car_accel_max_mps2)
        creep = self._creep(pressure)
        if self.speed_check.fault:                        # no wheel: the accelerometer alone
            self._set_v_ref(max(self.ref.v_mps + (accel - ac.bias_mps2) * dt_s, 0.0))
        else:
            suspect = self.speed_check.stands or self.speed_check.frozen_s > 0.0
            self.ref = reference_speed(self.ref, wheel_v, car_accel, dt_s, fresh and ok1,
                                       self.wsp == Wsp.FILL, pressure <= p.ref.torque_free_Pa, creep,
                                       suspect, p.ref, spinning_up)
        if fresh and ok1 and ok3:
            self._check_wheel_and_accel(wheel_v, accel, span_s, creep)
        speed_fault = self.speed_check.fault
        v_ref = self.ref.v_mps
        slip = 0.0 if speed_fault else v_ref - wheel_v    # seed 001 eq. (2)

        if speed_fault:
            self.wsp = Wsp.FILL                           # a failed sensor never vents the brake
        else:
            wanted = wsp_transition(self.wsp, slip, v_ref, p)
            if self.wsp_tripped:                          # watchdog: re-armed once the wheel recovered
                self.vent_s, self.wsp_tripped = 0.0, wanted != Wsp.FILL
            else:
                # time the vented wheel spins back up does not count
                self.vent_s = self.vent_s + dt_s * (not spinning_up) if wanted != Wsp.FILL else 0.0
                if self.vent_s > p.max_vent_s:
                    self.vent_s, self.wsp_tripped = 0.0, True
            self.wsp = Wsp.FILL if self.wsp_tripped else wanted
        overridden = self.wsp != Wsp.FILL

        p_set = pressure_for_decel(decel, p)
        phi, phi_ok = finite_or(rx.friction_phi, 1.0)
        engaged = (finite_or(rx.fb_state, FbState.OFF)[0] in PHI_STATES
                   and (rx.phi_age_us is None or rx.phi_age_us <= p.phi_timeout_us))
        if phi_ok and engaged and emergency < 0.5 and not lost:
            p_set = apply_phi(p_set, phi, p)
        if self.sent[1] != Wsp.FILL and not overridden:
            self.integrator = 0.0                    # WSP hands back: the PI restarts (no overshoot)
        valve, saturated = self._valve(p_set - pressure, dt_s, freeze=overridden)
        if overridden:
            valve = 0.0                                   # the dump valve acts, the EP valve holds
        self.sent = (valve, self.wsp)
        return {
            "CylPressureSet": p_set,
            "ValveCmd": valve,
            "WspValve": int(self.wsp),
            "SpeedEst": max(v_ref, 0.0),
            "SlipSpeedEst": slip,
            "WspActive": int(overridden),
            "GovernorActive": 0,
            "IntegratorSat": int(saturated or overridden),
            "InputMissing": int(missing or lost),
            "OptSlipEst": 0.0,
            "OptSlipPos": 0.0,
            "GovernedDecel": decel,
            "GovernorMargin": 0.0,
            "GovernorFeasible": 1,
            "SpeedSensorFault": int(speed_fault),
            "AccelSensorFault": int(self.accel_check.fault),
            "CylSensorFault": int(self.cyl_check.fault),
            "AccelBiasEst": clip(self.accel_check.bias_mps2, -4.096, 4.094),   # the DBC signal's range
        }

    def safe_outputs(self) -> dict[str, float]:
        """What the ECU sends when its step fails: fill the cylinder (a brake ECU that fails brakes)."""
        return {"CylPressureSet": self.p.p_max_Pa, "ValveCmd": 1.0, "WspValve": int(Wsp.FILL),
                "InputMissing": 1, "GovernorFeasible": 1}
