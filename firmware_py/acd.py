"""Anti-collision device (ACD), seed 002 §V steps 1–12, and the control centre's pairing (steps 4–5).

The device of seed 002 (§IV: SAT receiver, radio Ri, embedded controller Ci) brakes its train U2 when
the distance ΔS to the last wagon of the train U1 ahead on the same route section is at or below the
braking distance B (steps 7–10), and releases when U1 moves on (steps 11–12); §IX adds a red signal
whose distance, at or under the braking distance, "immediately activates the train brakes"; §X asks
for "a position and distance prediction routine to handle lost or late data due to unstable radio
signal" — built here as dead reckoning with a growing uncertainty margin.

Definitions (SI units; positions WGS-84 degrees, latitude + north, longitude + east):

- ΔS (step 7): great-circle distance [m] from the own GPS antenna (the locomotive) to the leader's last
  wagon (DBC RADIO_LEADER_POS), by the haversine formula (`haversine_m`).
- Prediction.  Each position is moved to `now` from the time it was measured.  Own train: the worst
  case is that it kept accelerating at `own_accel_max_mps2` since its last valid fix (age a_o):
  advance_max = v_o a_o + ½ a_acc a_o², speed v_w = v_o + a_acc a_o.  Leader: its worst case is that
  it braked at `leader_decel_max_mps2` since its report (age a_l) — it never reverses:
  advance_min = v_l a_l − ½ a_l_max a_l² until it stands, then v_l² / (2 a_l_max).
  Nominal gap ΔS_nom = ΔS − v_o a_o + v_l a_l (both at constant speed); conservative gap
  ΔS_c = ΔS − advance_max + advance_min; uncertainty margin U = ΔS_nom − ΔS_c ≥ 0, growing with both
  ages.  Every decision uses ΔS_c: late radio data brakes earlier, lost radio data leaves the leader
  as a standing obstacle at its furthest-back possible position.
- B (step 8): braking distance [m] at the worst-case own speed v_w: B = v_w t_r + v_w² / (2 a_s),
  reaction time t_r (ACD cycle, BCU, brake build-up), service deceleration a_s; B_e the same with the
  emergency deceleration a_e and the shorter reaction time of the emergency path t_re.
- Brake (steps 9–10): SERVICE when ΔS_c ≤ B + margin; EMERGENCY when ΔS_c ≤ B_e + emergency margin
  (even emergency braking now leaves no more than that smaller margin: a service stop aimed at the
  margin never ends in emergency, see `emergency_margin_m`).  The same for a red signal (§IX), its
  distance from the own position (a signal report older than `signal_fresh_s` counts as red: fail-safe).
- Hold: braking stays on while the release condition does not hold.  Emergency never steps down to
  service: it holds until released.
- Without prediction (`AcdParams.predict` False, the paper's plain algorithm, for comparison): the ages
  are taken as 0 — ΔS from the last fix and the last report as they are, B at the fix's speed; the
  freshness rules (no release on a late report, a stale signal counts as red) stay.
- Release (steps 11–12): the leader moves away (fresh report, v_l ≥ `leader_moving_mps`: the paper's
  "v_u1 > 0" above GPS speed noise, and v_l above the own speed: the gap grows) and
  ΔS_c > B + `release_hysteresis_m`, or there is no leader on the
  own route section any more; and no red signal within reach; and the data are fresh.
- Adaptive braking (step 10, "adaptive smooth braking"): RequestedDecel = v_w² / (2 (D − margin −
  v_w t_r)) — the deceleration that stops the train the margin short of the obstacle at distance D —
  clipped to [min_decel, a_s]; a_e in emergency.

Outputs are the DBC's ACD_BRAKE_REQ signals: Request (NONE/SERVICE/EMERGENCY = AcdMode),
RequestedDecel [m/s²], DistanceToObstacle [m] (conservative, to the leader's last wagon or a red
signal; the DBC maximum when nothing is ahead).  `Acd.step` records the full `AcdDecision` (cause, B,
nominal gap, uncertainty) in `Acd.last` for tests and plots.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from enum import IntEnum
from typing import ClassVar

from firmware_py.bcu import Demand, Train
from firmware_py.limits import clip, finite_or
from firmware_py.rx import RxTable

# WGS-84 defining constants (NIMA TR8350.2, 3rd ed., table 3.1) and the IUGG mean radius
# R1 = (2a + b) / 3 of the ellipsoid (H. Moritz, "Geodetic Reference System 1980", J. Geodesy 74 (2000)
# 128–133): the radius of the sphere the device computes on.
WGS84_A_M = 6_378_137.0
WGS84_F = 1.0 / 298.257_223_563
MEAN_EARTH_RADIUS_M = (2.0 * WGS84_A_M + WGS84_A_M * (1.0 - WGS84_F)) / 3.0


def haversine_m(lat1_deg: float, lon1_deg: float, lat2_deg: float, lon2_deg: float,
                radius_m: float = MEAN_EARTH_RADIUS_M) -> float:
    """Great-circle distance [m] between two points [deg] on a sphere of `radius_m` [m].

    Seed 002 §IX: the device "calculates the distance between them according to the formula of distance
    between points on a sphere" (the formula is an image in the paper, unnumbered).  Written here in its
    haversine form (R. W. Sinnott, "Virtues of the Haversine", Sky and Telescope 68 (2), 1984, 159),
    which keeps full precision at the metre distances of trains:
        h = sin²(Δφ/2) + cos φ1 · cos φ2 · sin²(Δλ/2),   d = 2 R · asin(√h)
    (h is clamped to [0, 1] against round-off).
    """
    phi1, phi2 = math.radians(lat1_deg), math.radians(lat2_deg)
    s_dphi = math.sin((phi2 - phi1) / 2.0)
    s_dlmb = math.sin(math.radians(lon2_deg - lon1_deg) / 2.0)
    h = s_dphi * s_dphi + math.cos(phi1) * math.cos(phi2) * s_dlmb * s_dlmb
    return 2.0 * radius_m * math.asin(math.sqrt(clip(h, 0.0, 1.0)))


def braking_distance_m(speed_mps: float, decel_mps2: float, reaction_s: float) -> float:
    """B [m] (step 8): distance run during the reaction time t_r [s] at speed v [m/s], then braking at a
    constant deceleration a [m/s²] to standstill: B = v t_r + v² / (2 a)."""
    v = max(speed_mps, 0.0)
    return v * reaction_s + v * v / (2.0 * decel_mps2)


def min_advance_m(speed_mps: float, age_s: float, decel_max_mps2: float) -> float:
    """Shortest distance [m] a train at `speed_mps` can have run `age_s` [s] later if it braked at up to
    `decel_max_mps2` and never reverses: v t − ½ a t² until it stands (t = v/a), then v² / (2 a)."""
    v, t = max(speed_mps, 0.0), max(age_s, 0.0)
    t_stop = v / decel_max_mps2
    if t >= t_stop:
        return v * v / (2.0 * decel_max_mps2)
    return v * t - 0.5 * decel_max_mps2 * t * t


def max_advance_m(speed_mps: float, age_s: float, accel_max_mps2: float) -> float:
    """Longest distance [m] a train at `speed_mps` can have run `age_s` [s] later accelerating at up to
    `accel_max_mps2`: v t + ½ a t²."""
    v, t = max(speed_mps, 0.0), max(age_s, 0.0)
    return v * t + 0.5 * accel_max_mps2 * t * t


def required_decel_mps2(speed_mps: float, distance_m: float, margin_m: float, reaction_s: float) -> float:
    """Deceleration [m/s²] that stops a train at `speed_mps` `margin_m` short of an obstacle at
    `distance_m`, braking after `reaction_s`: v² / (2 (D − margin − v t_r)); +inf when that distance is
    used up, 0 at standstill."""
    v = max(speed_mps, 0.0)
    if v == 0.0:
        return 0.0
    room = distance_m - margin_m - v * reaction_s
    return math.inf if room <= 0.0 else v * v / (2.0 * room)


class AcdMode(IntEnum):
    """Values are the DBC choices of ACD_BRAKE_REQ.Request (NONE/SERVICE/EMERGENCY)."""

    MONITORING = 0
    SERVICE = 1
    EMERGENCY = 2


class Cause(IntEnum):
    """What the ACD brakes for (diagnostic; not in the DBC)."""

    NONE = 0
    LEADER = 1
    RED_SIGNAL = 2


class Aspect(IntEnum):
    """Values are the DBC choices of RADIO_SIGNAL.Aspect."""

    UNKNOWN = 0
    RED = 1
    YELLOW = 2
    GREEN = 3


def acd_mode_transition(mode: AcdMode, *, brake: bool, emergency: bool, clear: bool) -> AcdMode:
    """Pure mode logic (steps 9–12).  `brake`: an obstacle is within B + margin; `emergency`: within
    B_e + margin; `clear`: the release condition of steps 11–12 holds for every obstacle.  Braking holds
    until clear; emergency never steps down to service."""
    if emergency:
        return AcdMode.EMERGENCY
    if brake:
        return AcdMode.SERVICE if mode == AcdMode.MONITORING else mode
    if mode != AcdMode.MONITORING and clear:
        return AcdMode.MONITORING
    return mode


@dataclass(frozen=True)
class AcdParams:
    cycle_us: int = 100_000                  # ACD cycle: DESIGN.md node table, DBC ACD_BRAKE_REQ 100 ms
    service_decel_mps2: float = 1.0          # a_s: the BCU's full service, BcuParams step 7 (1.0 m/s²)
    emergency_decel_mps2: float = 1.3        # a_e: BcuParams.emergency_decel_mps2
    min_decel_mps2: float = 2.0 / 7.0        # smallest service request: BCU brake step 2 (chosen)
    # t_r: ACD cycle 0.1 s + BCU cycle 0.01 s + the BCU's jerk-limited ramp to full service (1 m/s³:
    # 1 s, equivalent to a 0.5 s dead time) + cylinder lag 0.05 s (seed 001 §IV) ≈ 0.66 s, rounded up
    # (chosen)
    reaction_s: float = 1.0
    # t_re: ACD cycle 0.1 s + BCU cycle 0.01 s + cylinder lag 0.05 s; the BCU's emergency has no jerk
    # limit (firmware_py/bcu.py) ≈ 0.16 s, rounded up (chosen)
    emergency_reaction_s: float = 0.3
    margin_m: float = 50.0                   # brake when ΔS ≤ B + margin (chosen: GPS 2.5 m CEP and §IX
    #                                          "signal instability" jumps of tens of m, plant_sim/gps.py)
    # emergency when ΔS ≤ B_e + this (chosen; < margin_m so that a service stop aimed at the margin does
    # not end in emergency: v²/2a_s + margin > v t_re + v²/2a_e + this at every v for the defaults)
    emergency_margin_m: float = 20.0
    release_hysteresis_m: float = 100.0      # release only when ΔS > B + this (chosen, > margin)
    leader_moving_mps: float = 0.5           # step 11 "v_u1 > 0" above GPS speed noise: 5 σ of the NEO-6's
    #                                          0.1 m/s (plant_sim/gps.py)
    leader_decel_max_mps2: float = 1.5       # hardest braking assumed of the leader (chosen: above our own
    #                                          emergency 1.3 m/s², trains with track brakes reach more)
    own_accel_max_mps2: float = 1.0          # hardest own acceleration while the fix is old (chosen: EMU
    #                                          starting acceleration ~1 m/s²)
    leader_fresh_s: float = 3.0              # a leader report older than this is late: no release on it
    #                                          (3 cycles of RADIO_LEADER_INFO, 1000 ms in the DBC)
    signal_fresh_s: float = 3.0              # an older signal report counts as red (3 cycles of RADIO_SIGNAL)
    leader_pos_is_front: bool = False        # False: RADIO_LEADER_POS is the last wagon (DBC).  True: it is
    #                                          the leader's locomotive (paper step 6): ΔS = d − λ, a lower
    #                                          bound of the gap on any track (triangle inequality)
    no_obstacle_m: float = 167_772.15        # DistanceToObstacle when nothing is ahead: the DBC maximum
    # §X's prediction (dead reckoning with the uncertainty margin). False: the paper's plain algorithm,
    # ΔS and B from the last fix and the last report as they are, whatever their age (for comparison)
    predict: bool = True

    def __post_init__(self) -> None:
        for name in ("service_decel_mps2", "emergency_decel_mps2", "min_decel_mps2", "leader_decel_max_mps2"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"AcdParams.{name} must be > 0, got {getattr(self, name)!r}")
        if not self.min_decel_mps2 <= self.service_decel_mps2 <= self.emergency_decel_mps2:
            raise ValueError("AcdParams: need min_decel_mps2 <= service_decel_mps2 <= emergency_decel_mps2")
        if not 0.0 <= self.emergency_margin_m <= self.margin_m:
            raise ValueError(f"AcdParams: need 0 <= emergency_margin_m <= margin_m, got "
                             f"{self.emergency_margin_m!r} and {self.margin_m!r}")
        if not self.release_hysteresis_m > self.margin_m >= 0.0:
            raise ValueError(f"AcdParams: need release_hysteresis_m > margin_m >= 0, got "
                             f"{self.release_hysteresis_m!r} and {self.margin_m!r}")


@dataclass(frozen=True)
class OwnFix:
    """The own train's last valid GPS fix (steps 1–2): position [deg], speed [m/s], age [s] at `now`."""

    lat_deg: float
    lon_deg: float
    speed_mps: float
    age_s: float


@dataclass(frozen=True)
class LeaderReport:
    """The leader's last report (step 6): id, position [deg] of its last wagon (of its locomotive with
    AcdParams.leader_pos_is_front), speed [m/s], route section ρ, length λ [m], age [s] at `now`."""

    leader_id: int
    lat_deg: float
    lon_deg: float
    speed_mps: float
    route_section: int
    length_m: float
    age_s: float


@dataclass(frozen=True)
class SignalReport:
    """The next signal: aspect (Aspect), position [deg], age of the report [s] at `now`."""

    aspect: int
    lat_deg: float
    lon_deg: float
    age_s: float


@dataclass(frozen=True)
class AcdInputs:
    own: OwnFix | None                 # None: no valid fix yet
    own_section: int | None            # None: unknown (every leader counts)
    leader: LeaderReport | None        # None: no leader known (or LeaderId 0)
    signal: SignalReport | None        # None: no signal known


@dataclass(frozen=True)
class AcdDecision:
    """One cycle's result: the new mode, the DBC outputs, and what they came from."""

    mode: AcdMode
    cause: Cause
    requested_decel_mps2: float        # ACD_BRAKE_REQ.RequestedDecel
    distance_m: float                  # ACD_BRAKE_REQ.DistanceToObstacle (conservative)
    speed_worst_mps: float             # v_w
    braking_distance_m: float          # B at v_w, service
    emergency_distance_m: float        # B_e at v_w, emergency
    leader_gap_m: float                # ΔS_c, NaN without a leader on the section
    leader_gap_nominal_m: float        # ΔS_nom
    uncertainty_m: float               # U = ΔS_nom − ΔS_c
    signal_distance_m: float           # conservative distance to the signal, NaN without one
    leader_late: bool                  # the leader report is older than leader_fresh_s


def acd_evaluate(p: AcdParams, mode: AcdMode, inp: AcdInputs) -> AcdDecision:
    """Steps 7–12 for one cycle (pure): the new mode and the outputs from the mode and the inputs."""
    nan = math.nan
    own = inp.own
    if own is None:                    # no position: nothing can be judged; hold whatever is on
        new = acd_mode_transition(mode, brake=False, emergency=False, clear=False)
        decel = p.emergency_decel_mps2 if new == AcdMode.EMERGENCY else (
            p.service_decel_mps2 if new == AcdMode.SERVICE else 0.0)
        return AcdDecision(new, Cause.NONE, decel, p.no_obstacle_m, nan, nan, nan, nan, nan, nan, nan, False)

    own_age = own.age_s if p.predict else 0.0       # without prediction: the fix as it is
    v_w = own.speed_mps + p.own_accel_max_mps2 * own_age
    own_adv_max = max_advance_m(own.speed_mps, own_age, p.own_accel_max_mps2)
    own_adv_nom = max(own.speed_mps, 0.0) * max(own_age, 0.0)
    b = braking_distance_m(v_w, p.service_decel_mps2, p.reaction_s)
    b_e = braking_distance_m(v_w, p.emergency_decel_mps2, p.emergency_reaction_s)

    gap = gap_nom = unc = nan
    late = False
    obstacles: list[tuple[float, Cause]] = []
    brake = emergency = False
    clear = True
    ld = inp.leader
    if ld is not None and (inp.own_section is None or ld.route_section == inp.own_section):
        d = haversine_m(own.lat_deg, own.lon_deg, ld.lat_deg, ld.lon_deg)
        if p.leader_pos_is_front:
            d -= ld.length_m
        late = ld.age_s > p.leader_fresh_s
        ld_age = ld.age_s if p.predict else 0.0
        gap_nom = d - own_adv_nom + max(ld.speed_mps, 0.0) * max(ld_age, 0.0)
        gap = d - own_adv_max + min_advance_m(ld.speed_mps, ld_age, p.leader_decel_max_mps2)
        unc = gap_nom - gap
        obstacles.append((gap, Cause.LEADER))
        brake |= gap <= b + p.margin_m
        emergency |= gap <= b_e + p.emergency_margin_m
        # "the leader moves away" (issue #7): faster than us, so the gap grows — a leader still braking to
        # a stop (moving, but slower) is no reason to release
        clear &= (not late and ld.speed_mps >= p.leader_moving_mps and ld.speed_mps > own.speed_mps
                  and gap > b + p.release_hysteresis_m)

    d_sig = nan
    sg = inp.signal
    if sg is not None:
        d_sig = haversine_m(own.lat_deg, own.lon_deg, sg.lat_deg, sg.lon_deg) - own_adv_max
        red = sg.aspect == Aspect.RED or sg.age_s > p.signal_fresh_s
        if red:
            obstacles.append((d_sig, Cause.RED_SIGNAL))
            brake |= d_sig <= b + p.margin_m
            emergency |= d_sig <= b_e + p.emergency_margin_m
            clear = False

    new = acd_mode_transition(mode, brake=brake, emergency=emergency, clear=clear)
    nearest, cause = min(obstacles, default=(p.no_obstacle_m, Cause.NONE))
    if new == AcdMode.MONITORING:
        decel, cause = 0.0, Cause.NONE
    elif new == AcdMode.EMERGENCY:
        decel = p.emergency_decel_mps2
    else:
        need = required_decel_mps2(v_w, nearest, p.margin_m, p.reaction_s)
        decel = clip(need, p.min_decel_mps2, p.service_decel_mps2)
    return AcdDecision(new, cause, decel, clip(nearest, 0.0, p.no_obstacle_m), v_w, b, b_e, gap, gap_nom,
                       unc, d_sig, late)


def _num(rx: RxTable, key: str) -> float:
    return finite_or(rx.get(key, math.nan), math.nan)[0]


class Acd:
    """step(now_us, rx) -> ACD_BRAKE_REQ signals.

    `rx` holds the DBC inputs `INPUTS` (the radio frames) and the own-train inputs `LOCAL_INPUTS`, which
    no DBC frame carries (the GPS comes over the serial line, hil.links.gpsserial; the route section and the
    signal's position over the radio): OwnLatitude/OwnLongitude [deg], OwnSpeed [m/s], OwnFixValid
    (0/1), OwnFixAge [s] (age of the fix when handed over), OwnRouteSection, SignalLatitude/
    SignalLongitude [deg].  A missing or non-finite value counts as not received.  The time since a radio
    frame arrived (`rx.age_us`) is added to the age of its report.  LeaderId 0 means "no leader" (the
    control centre knows nobody ahead).
    """

    OUTPUTS: ClassVar[tuple[str, ...]] = ("Request", "RequestedDecel", "DistanceToObstacle")
    # the leader's report (RADIO_LEADER_POS, RADIO_LEADER_INFO), in the order `inputs_from` reads it
    LEADER_INPUTS: ClassVar[tuple[str, ...]] = (
        "RADIO_LEADER_POS.Latitude", "RADIO_LEADER_POS.Longitude", "RADIO_LEADER_INFO.LeaderId",
        "RADIO_LEADER_INFO.RouteSection", "RADIO_LEADER_INFO.Speed", "RADIO_LEADER_INFO.TrainLength",
        "RADIO_LEADER_INFO.AgeOfReport")
    INPUTS: ClassVar[tuple[str, ...]] = LEADER_INPUTS + ("RADIO_SIGNAL.Aspect", "RADIO_SIGNAL.AgeOfAspect")
    LOCAL_INPUTS: ClassVar[tuple[str, ...]] = ("OwnLatitude", "OwnLongitude", "OwnSpeed", "OwnFixValid",
                                               "OwnFixAge", "OwnRouteSection", "SignalLatitude",
                                               "SignalLongitude")

    def __init__(self, params: AcdParams | None = None) -> None:
        self.p = params or AcdParams()
        self.inputs = self.INPUTS
        self.mode = AcdMode.MONITORING
        self.last: AcdDecision | None = None
        self._fix: tuple[float, float, float, int] | None = None   # lat, lon, speed, time of fix [µs]

    def _rx_age_s(self, rx: RxTable, keys: Iterable[str], now_us: int) -> float:
        ages = [a for k in keys if (a := rx.age_us(k, now_us)) is not None]
        return max(ages, default=0) * 1e-6

    def inputs_from(self, now_us: int, rx: RxTable) -> AcdInputs:
        """The cycle's AcdInputs from `rx` (keeps the last valid own fix)."""
        lat, lon, speed = _num(rx, "OwnLatitude"), _num(rx, "OwnLongitude"), _num(rx, "OwnSpeed")
        valid, fix_age = _num(rx, "OwnFixValid"), _num(rx, "OwnFixAge")
        if valid >= 0.5 and not (math.isnan(lat) or math.isnan(lon) or math.isnan(speed)):
            age_us = 0 if math.isnan(fix_age) else round(max(fix_age, 0.0) * 1e6)
            self._fix = (lat, lon, speed, now_us - age_us)
        own = None
        if self._fix is not None:
            flat, flon, fspeed, t_us = self._fix
            own = OwnFix(flat, flon, fspeed, (now_us - t_us) * 1e-6)
        section = _num(rx, "OwnRouteSection")

        leader = None
        report = [_num(rx, k) for k in self.LEADER_INPUTS]
        llat, llon, lid, lsec, lspeed, llen, lage = report
        if not any(math.isnan(v) for v in report) and round(lid) != 0:
            age = lage + self._rx_age_s(rx, self.LEADER_INPUTS, now_us)
            leader = LeaderReport(int(round(lid)), llat, llon, lspeed, int(round(lsec)), llen, age)

        signal = None
        aspect = _num(rx, "RADIO_SIGNAL.Aspect")
        slat, slon = _num(rx, "SignalLatitude"), _num(rx, "SignalLongitude")
        if not (math.isnan(aspect) or math.isnan(slat) or math.isnan(slon)):
            sent_age = _num(rx, "RADIO_SIGNAL.AgeOfAspect")
            signal = SignalReport(int(round(aspect)), slat, slon,
                                  (0.0 if math.isnan(sent_age) else sent_age)
                                  + self._rx_age_s(rx, ("RADIO_SIGNAL.Aspect",), now_us))
        return AcdInputs(own, None if math.isnan(section) else int(round(section)), leader, signal)

    def step(self, now_us: int, rx: RxTable) -> dict[str, float]:
        dec = acd_evaluate(self.p, self.mode, self.inputs_from(now_us, rx))
        self.mode, self.last = dec.mode, dec
        # output gate: only finite values inside the DBC ranges leave the ECU
        decel = clip(finite_or(dec.requested_decel_mps2, self.p.emergency_decel_mps2)[0], 0.0, 65.535)
        return {"Request": int(dec.mode), "RequestedDecel": decel, "DistanceToObstacle": dec.distance_m}


# --- Steps 4–5: the control centre's pairing (served by hil.links.control_centre) --------------------------

@dataclass(frozen=True)
class TrainPosition:
    """A train's latest report as the control centre keeps it (step 3): id, position [deg] of its
    locomotive, route section ρ, heading [deg clockwise from north] or None when unknown."""

    train: str
    lat_deg: float
    lon_deg: float
    route_section: int
    heading_deg: float | None


def _along_m(ref: TrainPosition, t: TrainPosition, dn: float, de: float) -> float:
    """Position [m] of `t` along the unit direction (dn, de) (north, east) from `ref`, in the local
    tangent plane at `ref`."""
    north = MEAN_EARTH_RADIUS_M * math.radians(t.lat_deg - ref.lat_deg)
    east = MEAN_EARTH_RADIUS_M * math.cos(math.radians(ref.lat_deg)) * math.radians(t.lon_deg - ref.lon_deg)
    return north * dn + east * de


def pair_on_sections(trains: Iterable[TrainPosition]) -> dict[str, tuple[str | None, str | None]]:
    """Step 4–5 (pure): {train: (leader, follower)} — on each route section, the trains ordered along
    the running direction; each one's leader is the next train ahead, its follower the next behind.

    The running direction of a section is the mean of the unit heading vectors of its trains that
    report one; positions are projected on it in the local tangent plane of the section's first train
    (north = R Δφ, east = R cos φ0 Δλ: exact to < 1e-6 relative over a few km).  A section whose trains
    report no heading cannot be ordered: its trains get no leader and no follower."""
    out: dict[str, tuple[str | None, str | None]] = {}
    by_section: dict[int, list[TrainPosition]] = {}
    for t in trains:
        by_section.setdefault(t.route_section, []).append(t)
        out[t.train] = (None, None)
    for group in by_section.values():
        headings = [math.radians(t.heading_deg) for t in group if t.heading_deg is not None]
        if len(group) < 2 or not headings:
            continue
        dn = sum(math.cos(h) for h in headings)
        de = sum(math.sin(h) for h in headings)
        norm = math.hypot(dn, de)
        if norm == 0.0:
            continue
        dn, de = dn / norm, de / norm
        ref = group[0]
        order = sorted(group, key=lambda t: (_along_m(ref, t, dn, de), t.train))   # rear first
        for k, t in enumerate(order):
            leader = order[k + 1].train if k + 1 < len(order) else None
            follower = order[k - 1].train if k > 0 else None
            out[t.train] = (leader, follower)
    return out


REQUEST, REQUESTED_DECEL = "ACD_BRAKE_REQ.Request", "ACD_BRAKE_REQ.RequestedDecel"   # the ACD's request


@dataclass(frozen=True)
class AcdRequestParams:
    """The BCU's side of the ACD (`AcdBrakeRequest`)."""

    timeout_us: int = 300_000        # the ACD's request (100 ms cycle) is stale after 3 cycles (chosen)
    full_service_mps2: float = 1.0   # the most a SERVICE request may ask: the BCU's brake step 7 [m/s²]


class AcdBrakeRequest:
    """The BCU obeys the ACD (seed 002 §V, steps 10–12) as one of its demand sources
    (firmware_py.bcu.DemandSource): ACD_BRAKE_REQ.Request = EMERGENCY is an emergency request
    (BCU_EMERGENCY.Source = 2); SERVICE asks for RequestedDecel, bounded to full service (a bad deceleration
    asks for full service).  An ACD not heard from for `timeout_us` makes the train Degraded; its last
    request stays in force until the train stands (a lost or deleted request never releases a brake the
    ACD asked for, issue #19), and an ACD silent while asking for nothing requests nothing."""

    INPUTS: ClassVar[tuple[str, ...]] = (REQUEST, REQUESTED_DECEL)
    OUTPUTS: ClassVar[tuple[str, ...]] = ()
    SOURCE: ClassVar[int] = 2        # BCU_EMERGENCY.Source of an emergency the ACD asked for

    def __init__(self, params: AcdRequestParams) -> None:
        self.p = params
        self._last = (False, 0.0)    # the ACD's last usable request (emergency, decel)

    def demand(self, now_us: int, rx: RxTable, train: Train, out: dict[str, float]) -> Demand:
        emergency, decel, silent = self._request(now_us, rx, train.standstill)
        return Demand(decel, decel > 0.0, self.SOURCE if emergency else 0, silent)

    def _request(self, now_us: int, rx: RxTable, standstill: bool) -> tuple[bool, float, bool]:
        """(emergency requested, service deceleration requested [m/s²], silent) from ACD_BRAKE_REQ."""
        age = rx.age_us(REQUEST, now_us)
        request, ok = finite_or(rx[REQUEST], 0.0)
        if age is None or age > self.p.timeout_us or not ok:
            if standstill:
                self._last = (False, 0.0)
            return (*self._last, age is not None)          # never heard from: not (yet) silent
        full = self.p.full_service_mps2
        decel, ok_decel = finite_or(rx[REQUESTED_DECEL], full)
        if round(request) == 2:
            self._last = (True, 0.0)
        elif round(request) == 1:                          # a bad deceleration asks for full service
            self._last = (False, clip(decel if ok_decel else full, 0.0, full))
        else:
            self._last = (False, 0.0)
        return (*self._last, False)
