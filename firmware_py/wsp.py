"""Wheel-slide protection (WSP) of a BECU: the dump valve's vent / hold / refill with hysteresis, the
slip mode's pressure ceiling and early vent, and the vent-time watchdog.

The basic WSP vents above a slip threshold and refills with hysteresis, as seed 001 §II-C's (vent, u = 0,
while s > s̄; track again once s is back in the adhesion region).  The slip mode (`WspMode.SLIP`) keeps the
slip near the adhesion peak instead.  A vent-time watchdog refills a cylinder that WSP has kept vented too
long (`vent_watchdog`).  Every function here is pure; the BECU's pipeline (firmware_py.becu) holds the state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum, StrEnum


class Wsp(IntEnum):
    """WSP dump-valve state; values are the DBC choices of BECUn_PRESS_CMD.WspValve."""

    FILL = 0   # normal: the EP valve controls the cylinder
    HOLD = 1   # cylinder isolated, pressure held
    VENT = 2   # cylinder vented to atmosphere


class WspMode(StrEnum):
    """How WSP refills (WspParams.mode)."""

    DUMP = "dump"      # vent to zero, refill to the demand: the limit cycle of seed 001 §II-C's WSP
    SLIP = "slip"      # keep the slip near the adhesion peak: a refill ceiling and an early vent


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
    mode: WspMode | str = WspMode.DUMP      # the enum or its value ("slip")
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
    if (p.mode == WspMode.SLIP and wanted == Wsp.FILL and speed_mps >= p.min_speed_mps
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
    up to the car's speed does (RefSpeedParams.spin_up_accel_mps2, `SensorMonitor.spin_up`): the vent is
    working, the wheel is healthy, and that time does not count (the "axle health discriminatory" timer
    of CA 2025196: a wheel that takes seconds to spin up from a lock is not refilled onto the rail
    half-way).  Trips when venting lasts longer than `max_vent_s` otherwise; while tripped the caller
    keeps the cylinder in FILL; it re-arms once the wheel has recovered."""
    if tripped:
        return 0.0, not recovered
    vent_s = vent_s + dt_s * (not spinning_up) if venting else 0.0
    return (0.0, True) if vent_s > max_vent_s else (vent_s, False)

