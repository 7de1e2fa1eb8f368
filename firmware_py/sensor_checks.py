"""Plausibility of a car's sensors in its BECU: the wheel-speed sensor (stands, frozen), the accelerometer's
bias, the brake-cylinder pressure transducer (frozen while the valves move the pressure), and the spin-up
check of a vented wheel.

The wheel-speed sensor is declared failed (SpeedSensorFault, latched) when its reading says the wheel stands
while the accelerometer says the car moves for longer than a real slide lasts, or when its reading is frozen
while the accelerometer says the speed changed; the speed estimate then runs on the accelerometer alone and
WSP is inhibited (the brake stays applied).  The accelerometer's bias (accelerometer − the axle's
acceleration, filtered) is AccelBiasEst; above a limit for a time it is AccelSensorFault (latched) and the
axle's acceleration replaces it.  The pressure transducer is declared failed (CylSensorFault, latched) when
its reading stays identical while the EP or dump valve should have moved the pressure by more than a limit;
the pressure loop then runs on a model of the cylinder fed with the valve commands, biased to brake.

The checks are pure functions of their state (`speed_sensor_check`, `accel_bias_check`, `cyl_sensor_check`);
`SensorMonitor` holds their state for one BECU and runs them on each fresh sensor frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from firmware_py.constants import G_MPS2
from firmware_py.limits import clip
from firmware_py.wsp import Wsp

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


class SensorMonitor:
    """The sensor checks of one BECU and their state, run on each fresh sensor frame (the BECU's pipeline,
    firmware_py.becu, calls them and applies what they decide).

    `valve_rates` = (EP fill, EP vent, dump) [Pa/s] at full opening; `derate`: the fraction by which the
    model of the cylinder that replaces a failed transducer fills slower and vents faster than that data,
    so that a brake ECU that fails, brakes."""

    def __init__(self, p: SensorCheckParams, spin_up_accel_mps2: float, p_max_Pa: float,
                 valve_rates: tuple[float, float, float], derate: float) -> None:
        self.p, self.spin_up_accel_mps2, self.p_max_Pa = p, spin_up_accel_mps2, p_max_Pa
        self.valve_rates, self.derate = valve_rates, derate
        self.speed_check = SpeedCheck()
        self.accel_check = AccelCheck()
        self.cyl_check = CylCheck()
        self.speed_fault_us: int | None = None     # when SpeedSensorFault latched (diagnostic)
        self.accel_fault_us: int | None = None     # when AccelSensorFault latched (diagnostic)
        self.cyl_fault_us: int | None = None       # when CylSensorFault latched (diagnostic)
        self.axle_accel = 0.0         # d(r·ω)/dt, filtered [m/s²]
        self.spinning_up = False      # the last reading was a new high while the vented axle accelerated
        self.p_model = math.nan       # once the transducer failed: the modelled cylinder pressure [Pa]
        self._wheel_prev = math.nan   # previous fresh wheel reading r·ω [m/s]
        self._wheel_smooth = math.nan  # the wheel reading smoothed (SPIN_UP_SMOOTHING) [m/s] ...
        self._wheel_low = math.nan    # ... its lowest since WSP left FILL [m/s] ...
        self._wheel_high = math.nan   # ... the highest since that low [m/s]
        self._anchor_wheel = math.nan  # bias filter: wheel reading at its last update [m/s] ...
        self._accel_sum = 0.0         # ... the accelerometer integrated since [m/s] ...
        self._span_s = 0.0            # ... over this time [s] ...
        self._span_tainted = False    # ... begun in a slide, and the wheel has spun up since: no evidence
        self._span_in_slide = False   # the span began while the wheel slid
        self._span_slid = False       # the axle decelerated faster than the car can within the span
        self._cyl_prev = (math.nan, math.nan)   # the two previous fresh pressure readings [Pa]

    def car_accel(self) -> float:
        """The car's acceleration [m/s²] once the accelerometer failed: the axle's, bounded to what the car
        itself can do (a sliding wheel decelerates far faster)."""
        limit = self.p.car_accel_max_mps2
        return clip(self.axle_accel, -limit, limit)

    def check_wheel_and_accel(self, now_us: int, wheel_v: float, accel: float, span_s: float, creep: float,
                              v_ref: float, wheel_off: bool) -> float | None:
        """Plausibility of the wheel-speed sensor and the accelerometer on a fresh sensor frame (after the
        speed estimate of this cycle, before WSP).  The bias compares the accelerometer with the car's
        speed as the wheel gives it, r·ω plus its creep (`creep`, m/s): the creep's build-up as the brake
        applies is not the accelerometer's bias.  `v_ref`: the reference speed; `wheel_off`: WSP is out of
        FILL or the reference speed bridges a slide.  Returns the speed [m/s] to re-anchor the reference
        speed to when a check latched now (a frozen wheel: where it would have got to; a biased
        accelerometer: the wheel), else None."""
        sc = self.p
        prev = self._wheel_prev
        self._wheel_prev = wheel_v
        car_v = wheel_v + creep
        if not math.isfinite(prev) or span_s <= 0.0:
            self._anchor_wheel = car_v
            return None
        gain = min(span_s / sc.axle_accel_tau_s, 1.0)
        self.axle_accel += gain * ((wheel_v - prev) / span_s - self.axle_accel)
        ac = self.accel_check
        before = self.speed_check
        corrected = accel - ac.bias_mps2 if not ac.fault else self.car_accel()
        check = speed_sensor_check(before, wheel_v, prev, v_ref, corrected, span_s, sc)
        self.speed_check = check
        if check.fault:
            if before.fault:
                return None                          # no axle to compare the accelerometer with
            self.speed_fault_us = now_us
            return max(wheel_v + check.frozen_dv_mps, 0.0) if check.cause == "frozen" else None
        self._accel_sum += accel * span_s
        self._span_s += span_s
        # a span begun mid-slide in which the wheel spins back up holds the slide's recovery, not its onset:
        # the wheel's speed change over it is not the car's (the slip's rise and fall do not cancel)
        self._span_tainted |= self._span_in_slide and self.axle_accel > self.spin_up_accel_mps2
        self._span_slid |= self.axle_accel < -sc.car_accel_max_mps2
        if check.stands or check.frozen_s > 0.0:
            return None                              # the wheel is not trusted yet: wait for the span's end
        sliding = (v_ref - car_v > sc.slide_gate_mps or wheel_off
                   or abs(self.axle_accel) > sc.car_accel_max_mps2)   # the wheel does what the car cannot
        if sliding and self._span_s < (sc.slide_span_max_s if self._span_slid else sc.span_max_s):
            return None                              # bridge the slide: update once the wheel is back
        span = self._span_s
        wheel_rate = (car_v - self._anchor_wheel) / span
        rising = wheel_rate > self.spin_up_accel_mps2                  # a vented wheel coming back
        if not (sliding and (abs(wheel_rate) > sc.car_accel_max_mps2 or rising) or self._span_tainted):
            self.accel_check = accel_bias_check(ac, self._accel_sum / span, wheel_rate, span, sc)
        self._anchor_wheel, self._accel_sum, self._span_s = car_v, 0.0, 0.0
        self._span_in_slide, self._span_tainted, self._span_slid = sliding, False, False
        if self.accel_check.fault and not ac.fault:
            self.accel_fault_us = now_us
            return wheel_v                           # drop what the biased accelerometer integrated
        return None

    def spin_up(self, wheel_v: float, wsp_fill: bool) -> None:
        """On a fresh wheel reading: is the vented wheel spinning back up (`spin_up_accel_mps2`)?  Its axle
        accelerates faster than a braked car can (as of the last reading: `axle_accel`), and the reading,
        smoothed (SPIN_UP_SMOOTHING), is the highest since its lowest since WSP left FILL (the wheel may
        lock after the vent began, while its commands are lost).  The new-high condition keeps a noisy
        sensor from passing for a spinning wheel: noise sets new records ever more rarely (the n-th reading
        of a standing signal is one with probability 1/n), a wheel spinning up sets one every reading."""
        w = self._wheel_smooth
        w = wheel_v if not math.isfinite(w) else w + SPIN_UP_SMOOTHING * (wheel_v - w)
        self._wheel_smooth = w
        if wsp_fill or not math.isfinite(self._wheel_high) or w < self._wheel_low:
            self._wheel_high = self._wheel_low = w
            self.spinning_up = False
            return
        high = w > self._wheel_high
        self._wheel_high = max(self._wheel_high, w)
        self.spinning_up = high and self.axle_accel > self.spin_up_accel_mps2

    def check_cylinder(self, now_us: int, pressure: float, span_s: float, valve_sent: float,
                       wsp_sent: int) -> bool:
        """Plausibility of the pressure transducer on a fresh sensor frame, against the valve commands sent
        over the span (`cyl_sensor_check`).  True when it failed now: the model of the cylinder then starts
        where the valves should have taken the pressure since the reading froze (the caller restarts the
        pressure PI, wound up on the frozen reading)."""
        prev, prev2 = self._cyl_prev
        self._cyl_prev = (pressure, prev)
        if not math.isfinite(prev) or span_s <= 0.0:
            return False
        before = self.cyl_check
        self.cyl_check = cyl_sensor_check(before, pressure, prev, prev2, valve_sent, wsp_sent, span_s,
                                          self.p_max_Pa, self.valve_rates, self.p)
        if self.cyl_check.fault and not before.fault:
            self.cyl_fault_us = now_us
            self.p_model = clip(self.cyl_check.base_Pa + self.cyl_check.moved_Pa, 0.0, self.p_max_Pa)
            return True
        return False

    def modelled_pressure(self, dt_s: float, valve_sent: float, wsp_sent: int) -> float:
        """The cylinder pressure [Pa] the loop runs on once its transducer failed: the model fed with the
        commands sent last cycle (`valve_pressure_rate`), derated to brake."""
        fill, vent, dump = self.valve_rates
        d = self.derate
        rate = valve_pressure_rate(valve_sent, wsp_sent, self.p_model, self.p_max_Pa,
                                   (fill * (1.0 - d), vent * (1.0 + d), dump * (1.0 + d)))
        self.p_model = clip(self.p_model + rate * dt_s, 0.0, self.p_max_Pa)
        return self.p_model
