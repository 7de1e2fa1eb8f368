"""The stopping program of seed 002 as a PLC runs it: one scan every 100 ms, the driver's brake valve out.

Written as a PLC engineer would write it from the paper, in plain Python and nothing else (no railhil, no
OPC UA: plc.py runs it on asyncua; railhil's lockstep runs it as the device's model).  Per scan it reads the
train's position S and speed V and the stop point it was given, and sets the driver's brake valve (§VII): II
release, IV lap with feeding, V service brake.

* The calculation block of the theoretical curve (§VI, Fig. 4): when the train reaches the point from which
  a stop at the planned deceleration a_p ends at the stop point, the curve starts from there:
  S_th(τ) = v0·τ − a_c·τ²/2, V_th(τ) = v0 − a_c·τ, a_th = a_c; the valve goes to V half its application
  time before, so that the brake's ramp is centred on the curve's start.
* The adaptive search with united attempt and work steps (§III, Fig. 2): every work period (15 scans) the
  quality Q is evaluated; a work step (V or II for 5 scans, then IV) repeats the last one if Q did not
  deteriorate by more than δ, else it is reversed; inside the insensitivity zone the valve stays in IV.
* The differentiation unit (Fig. 3, `diff=True`): the program differentiates the speed it reads (the
  deceleration a, low-passed) and evaluates Q on the deviation T_d ahead, e + T_d·ė + T_d²/2·ë, judging each
  step against where the deviation was heading.

Its constants are railhil's own search's (firmware_py/stopping.py, StoppingParams), so that the two stop
the train at the same point (tests/devices/test_plc_precise_stop.py).  Units: SI; time in integer
microseconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

RELEASE, LAP, SERVICE = 2, 4, 5          # the valve positions II, IV, V (DESK_CMD.BrakeValve's values)


@dataclass(frozen=True)
class ProgramParams:
    scan_us: int = 100_000               # the S7-200's scan for this program [µs]
    planned_decel_mps2: float = 0.6      # a_p, "a desired braking acceleration" set in the PLC (§VII)
    max_decel_mps2: float = 1.0          # full service
    service_rate_mps3: float = 0.3       # what V does to the brake demand per second (the BCU's valve)
    release_rate_mps3: float = 0.3       # what II does
    work_scans: int = 15                 # work period: 1.5 s
    step_scans: int = 5                  # a work step: V or II for 0.5 s
    threshold_m: float = 0.3             # δ
    dead_zone_m: float = 2.0             # the insensitivity zone on Q
    diff_horizon_s: float = 12.0         # T_d of the differentiation unit
    diff_tau_s: float = 0.25             # low-pass of the differentiated speed
    standstill_mps: float = 0.1          # below this the train stands


class Curve:
    """The theoretical curve (S_th, V_th) from its start: t0_us, x0_m, v0_mps, d0_m, a_mps2."""

    def __init__(self, t0_us: int, x0_m: float, v0_mps: float, d0_m: float, a_mps2: float) -> None:
        self.t0_us, self.x0_m, self.v0_mps, self.d0_m, self.a_mps2 = t0_us, x0_m, v0_mps, d0_m, a_mps2
        self.end_us = t0_us + (v0_mps / a_mps2 * 1e6 if a_mps2 > 0.0 else math.inf)

    def path(self, now_us: float) -> float:
        tau = (now_us - self.t0_us) * 1e-6
        if tau < 0.0:
            return self.v0_mps * tau                       # before its start the curve coasts
        if now_us >= self.end_us:
            return self.d0_m
        return self.v0_mps * tau - 0.5 * self.a_mps2 * tau * tau


def braked_path(v: float, a: float, h: float) -> float:
    """How far a train at v braking at a goes in h seconds, up to its standstill."""
    if a > 0.0:
        h = min(h, v / a)
    return v * h - 0.5 * a * h * h


class StoppingProgram:
    """The PLC program: `scan(now_us, position_m, speed_mps, target_m) -> valve position`, every scan_us;
    `step(now_us, rx)` is the same for railhil's lockstep (the device file's model)."""

    def __init__(self, diff: bool = True, p: ProgramParams | None = None) -> None:
        self.p, self.diff = p or ProgramParams(), diff
        self.curve: Curve | None = None
        self.target: float | None = None
        self.stopped = False
        self.demand = 0.0                  # what the valve positions sent so far make of the brake demand
        self.v_last: float | None = None
        self.decel = 0.0                   # the differentiated speed, low-passed [m/s²]
        self.applying = True
        self.scans = 0
        self.direction, self.move = 1, False
        self.q_expected: float | None = None
        self.next_us = 0

    # ---------------------------------------------------------------------------------- one scan
    def scan(self, now_us: int, position_m: float, speed_mps: float, target_m: float) -> int:
        p = self.p
        if not all(math.isfinite(x) for x in (position_m, speed_mps, target_m)):
            return self._send(LAP)                         # no valid input: hold what is applied
        v = max(speed_mps, 0.0)
        if self.v_last is not None:                        # the differentiation of the speed
            dt = p.scan_us * 1e-6
            self.decel += (1.0 - math.exp(-dt / p.diff_tau_s)) * ((self.v_last - v) / dt - self.decel)
        self.v_last = v
        if target_m != self.target:                        # a new stop point: a new curve
            self.target, self.curve, self.stopped = target_m, None, False
        if self.stopped or (self.curve is not None and v < p.standstill_mps):
            self.stopped = True
            return self._send(SERVICE)                     # at the stop point: hold the train
        togo = target_m - position_m
        if self.curve is None:
            lead = self._lead(p.planned_decel_mps2)
            if v < p.standstill_mps or togo > v * v / (2.0 * p.planned_decel_mps2) + v * lead:
                return self._send(RELEASE)                 # coasting to the curve (a brake program does
            #                                                not start a standing train)
            self._start_curve(now_us, position_m, v, togo)
        return self._send(self._search(now_us, position_m - self.curve.x0_m, v, self.decel))

    def _lead(self, decel: float) -> float:
        """Half the valve's application time to `decel`: the ramp is centred on the curve's start."""
        return 0.5 * min(decel, self.p.max_decel_mps2) / self.p.service_rate_mps3

    def _start_curve(self, now_us: int, x: float, v: float, togo: float) -> None:
        p = self.p
        lead = self._lead(max(p.planned_decel_mps2, v * v / (2.0 * max(togo, 0.01))))
        d0 = max(togo - v * lead, 0.01)
        a_c = max(p.planned_decel_mps2, v * v / (2.0 * d0))
        self.curve = Curve(now_us + round(lead * 1e6), x + v * lead, v, d0, a_c)
        self.applying, self.scans, self.direction, self.move, self.q_expected = True, 0, 1, False, None

    def _deviation(self, now_us: float, s: float, v: float, a: float) -> float:
        """e = S − S_th (Fig. 2), or with the differentiation unit the deviation T_d ahead (Fig. 3)."""
        if not self.diff:
            return s - self.curve.path(now_us)
        h = self.p.diff_horizon_s
        return s + braked_path(v, a, h) - self.curve.path(now_us + h * 1e6)

    def _search(self, now_us: int, s: float, v: float, a: float) -> int:
        p = self.p
        if self.applying:
            if self.demand + p.service_rate_mps3 * p.scan_us * 1e-6 <= self.curve.a_mps2 + 1e-9:
                return SERVICE                             # the first application, to a_c
            self.applying = False
        k = self.scans % p.work_scans
        if k == 0:                                         # one united attempt-and-work step
            e = self._deviation(now_us, s, v, a)
            q = abs(e) if math.isfinite(e) else math.inf
            if self.q_expected is None:
                self.move = q >= p.dead_zone_m
            else:
                if q - self.q_expected > p.threshold_m:    # deteriorated: the opposite step
                    self.direction = -self.direction
                self.move = q >= p.dead_zone_m             # inside the insensitivity zone: lap
            self.q_expected = q
            if self.diff:                                  # where Q goes in a work period without a step
                tw = p.work_scans * p.scan_us * 1e-6
                e_next = self._deviation(now_us + tw * 1e6, s + braked_path(v, a, tw), max(v - a * tw, 0.0),
                                         a)
                self.q_expected = abs(e_next) if math.isfinite(e_next) else math.inf
        self.scans += 1
        if not self.move or k >= p.step_scans:
            return LAP
        return SERVICE if self.direction > 0 else RELEASE

    def _send(self, position: int) -> int:
        """The valve position out, and what it does to the brake demand (to know when a_c is applied)."""
        dt = self.p.scan_us * 1e-6
        if position == SERVICE:
            self.demand = min(self.demand + self.p.service_rate_mps3 * dt, self.p.max_decel_mps2)
        elif position == RELEASE:
            self.demand = max(self.demand - self.p.release_rate_mps3 * dt, 0.0)
        return position

    # ---------------------------------------------------------------------------------- as a model
    def step(self, now_us: int, rx) -> dict:
        """railhil's lockstep model interface: the variables read in, the ones written out (one scan)."""
        stamp = rx.get("Stamp", math.nan)
        return {"Valve": self.scan(now_us, rx["Position"], rx["Speed"], rx["Target"]),
                "Target": rx["Target"] if math.isfinite(rx["Target"]) else 0.0,
                "Echo": stamp if stamp == stamp else 0}


class PlainSearch(StoppingProgram):
    """The search without the differentiation unit (Fig. 2)."""

    def __init__(self) -> None:
        super().__init__(diff=False)
