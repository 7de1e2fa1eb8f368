"""The car's reference speed in its BECU (SpeedEst): a Kalman filter whose time update integrates the
accelerometer less its bias estimate (which holds g·sin θ, seed 004 eq. (1)) and whose measurement is the
axle's r·ω plus the creep its brake needs on nominal rail (seed 000 eq. (1)) (seed 004 §3.2, eqs.
(19)–(23), linear and scalar), unbiased; while the wheel slides (it reads more than a gate below the
estimate, or WSP acts) the axle is no measurement of the car's speed (seed 001 eq. (2)) and the estimate
runs on the accelerometer alone, so it does not follow a sliding wheel down.  `RefMode.LIFTED` is seed
001's reference instead: the accelerometer's integral, lifted to the wheel when the wheel reads faster.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import NamedTuple


class RefMode(StrEnum):
    """Which reference speed a BECU keeps (BecuParams.reference)."""

    FILTERED = "filtered"   # the Kalman filter on the accelerometer and the axle, slides bridged
    LIFTED = "lifted"       # seed 001's runs: the accelerometer's integral, lifted to a faster wheel


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
    x_peak = (-t2 + math.sqrt(t2 * t2 + 12.0 * t1 * t3)) / (6.0 * t3)       # seed 000 §2.1
    x = 0.0
    for _ in range(8):
        x = min((mu_used * k1 * (t1 + x * (t2 + t3 * x))) ** 2, x_peak)
    return x / k2 * max(v, cp.v_eps_mps)


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
                    creep: float = 0.0, wheel_suspect: bool = False, spinning_up: bool = False,
                    mode: RefMode | str = RefMode.FILTERED) -> RefSpeed:
    """One cycle of the car's reference speed (pure).

    wheel_mps: the axle's r·ω; accel_mps2: the car's acceleration, the accelerometer less its bias
    estimate (seed 004 eq. (1): a_measure = a_actual + g sin θ; the estimate holds g sin θ and the
    sensor's bias); fresh: a new axle reading arrived; wsp_fill: WSP is in FILL; torque_free: the cylinder
    is below RefSpeedParams.torque_free_Pa; gate_mps: the slide gate (BecuParams.wheel_trust_slip_mps);
    creep: the slip speed the wheel needs for the adhesion its brake uses (`creep_mps`) [m/s];
    wheel_suspect: the wheel-speed sensor check is timing the reading ("stands" or "frozen",
    `speed_sensor_check`): a slide is then not ended by the spin-up rule, that check decides;
    spinning_up: the wheel is spinning back up to the car's speed (`SensorMonitor.spin_up`: its axle
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

    mode RefMode.LIFTED is the accelerometer reference of seed 001's runs: v⁻, lifted to the wheel when the
    wheel reads above it, never pulled down by it (a braked wheel is never faster than the car); no creep
    (gate_mps unused)."""
    if not math.isfinite(s.v_mps):
        return RefSpeed(wheel_mps + creep, p.wheel_std_mps ** 2, anchor_mps=wheel_mps + creep)
    v = max(s.v_mps + accel_mps2 * dt_s, 0.0)                      # eq. (19)
    var = s.var + (p.accel_std_mps2 * dt_s) ** 2                    # eq. (20)
    anchor = max(s.anchor_mps + accel_mps2 * dt_s, 0.0)
    anchor_s = s.anchor_s + dt_s
    if mode == RefMode.LIFTED:                                      # the accelerometer reference
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

