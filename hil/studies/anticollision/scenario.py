"""The scenario section [acd] (seed 002: the anti-collision device, a leader train, signals and the radio
link) and the parameters it sets: the track, the leader's motion, the GPS receiver's and the ACD's.

Its presence in a scenario adds the ACD node and the world around the train to the run (nodes.py), and
makes the BCU obey the ACD's requests.

Positions along the track are track positions s [m] (the plant's x axis: length along the track
polyline `[acd.track]` from its first point); times are s of simulated time.  The own train (U2, the
follower) is the scenario's [train]; its GPS antenna is at the front of car 1.
"""

from __future__ import annotations

import functools
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field, field_validator, model_validator

from firmware_py.acd import AcdParams, Aspect
from hil.errors import RailhilError, ScenarioError
from hil.links.control_centre import read_keys
from hil.scenario.base import Strict
from hil.scenario.params import mps
from plant_sim.geo import TrackGeometry, polyline_from_legs
from plant_sim.gps import GpsParams
from plant_sim.leader import LeaderMotion, SpeedChange

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

Seconds = Annotated[float, Field(ge=0, le=3600)]


class Leg(Strict):
    """One straight (geodesic) leg of the track polyline."""

    azimuth_deg: Annotated[float, Field(ge=0, lt=360, description="direction at the leg's start, "
                                        "degrees clockwise from north")]
    length_m: Annotated[float, Field(gt=0, le=1_000_000, description="leg length [m]")]


class Section(Strict):
    """A route section ρ (seed 002 step 3): from track position `from_m` to the next section's."""

    from_m: float = Field(description="track position where the section starts [m]")
    id: Annotated[int, Field(ge=1, le=65_535, description="route section id (DBC RouteSection)")]


class GeoTrackSpec(Strict):
    """The track in WGS-84: a polyline from an origin along legs (plant_sim.geo.polyline_from_legs)."""

    origin_lat_deg: Annotated[float, Field(ge=-89, le=89, description="latitude of s = 0 [deg]")] = 56.9496
    origin_lon_deg: Annotated[float, Field(ge=-180, le=180, description="longitude of s = 0 [deg]")] = 24.1052
    legs: list[Leg] = Field(default_factory=lambda: [Leg(azimuth_deg=63.0, length_m=3000.0),
                                                     Leg(azimuth_deg=75.0, length_m=7000.0)],
                            description="the polyline's legs, in running order")
    sections: list[Section] = Field(default_factory=lambda: [Section(from_m=-1e6, id=1)],
                                    description="route sections, increasing from_m")

    @field_validator("sections")
    @classmethod
    def _increasing(cls, v):
        if not v:
            raise ValueError("give at least one route section")
        if any(b.from_m <= a.from_m for a, b in zip(v[:-1], v[1:], strict=True)):
            raise ValueError("sections must have increasing from_m")
        return v


class SpeedChangeSpec(Strict):
    """From `at_s` on, go to `speed_kmh` at `rate_mps2` (accelerating or braking), then hold it."""

    at_s: Seconds
    speed_kmh: Annotated[float, Field(ge=0, le=400, description="speed to reach [km/h]")]
    rate_mps2: Annotated[float, Field(gt=0, le=5, description="acceleration or deceleration [m/s^2]")] = 1.0


class LeaderSpec(Strict):
    """The leading train U1 (plant_sim.leader): scripted, on the same track ahead of the own train."""

    train_id: Annotated[int, Field(ge=1, le=255, description="U1's id (DBC LeaderId)")] = 1
    rear_m: float = Field(1000.0, description="track position of U1's last wagon at t = 0 [m]")
    length_m: Annotated[float, Field(gt=0, le=2000, description="U1's length [m]")] = 150.0
    initial_speed_kmh: Annotated[float, Field(ge=0, le=400)] = 60.0
    profile: list[SpeedChangeSpec] = Field(default_factory=list, description="speed changes in any order")


class AspectChange(Strict):
    at_s: Seconds
    aspect: Literal["red", "yellow", "green"]


class SignalSpec(Strict):
    """A wayside signal at `position_m`; its aspect is green until the first change."""

    id: Annotated[int, Field(ge=1, le=65_535, description="signal id (DBC SignalId)")]
    position_m: Annotated[float, Field(ge=0, le=167_772, description="track position [m] (DBC SignalPos)")]
    aspects: list[AspectChange] = Field(default_factory=list, description="aspect changes over time")

    @field_validator("aspects")
    @classmethod
    def _ordered(cls, v):
        if any(b.at_s < a.at_s for a, b in zip(v[:-1], v[1:], strict=True)):
            raise ValueError("aspect changes must be in time order")
        return v


class Window(Strict):
    """A time window [start_s, start_s + duration_s)."""

    start_s: Seconds
    duration_s: Annotated[float, Field(ge=0, le=600)]


class RadioSpec(Strict):
    """The radio link between the trains and the control centre (GPRS in seed 002 §IX), both ways."""

    report_period_s: Annotated[float, Field(gt=0, le=10, description="how often each train reports "
                                            "and the wayside sends the next signal's aspect [s]")] = 1.0
    latency_s: Annotated[float, Field(ge=0, le=10, description="fixed delay per message and hop [s]")] = 0.3
    jitter_s: Annotated[float, Field(ge=0, le=10, description="extra delay, uniform in [0, jitter] "
                                     "[s]")] = 0.2
    loss: Annotated[float, Field(ge=0, lt=1, description="probability a message is lost, per hop")] = 0.0
    outages: list[Window] = Field(default_factory=list, description="no message gets through")


class GpsSpec(Strict):
    """The own train's GPS receiver (plant_sim.gps) and its serial line to the ACD (hil.links.gpsserial)."""

    rate_hz: Annotated[float, Field(ge=1, le=10, description="fix rate [Hz]")] = 1.0
    protocol: Literal["nmea", "binary"] = Field("nmea", description="NMEA RMC+GGA or the framed binary")
    noise: bool = Field(True, description="horizontal and speed noise of a u-blox NEO-6")
    instability: bool = Field(True, description="seed 002 §IX 'signal instability' episodes")
    random_dropouts: bool = Field(False, description="Poisson dropouts (tunnels) at plant_sim.gps's rate")
    dropouts: list[Window] = Field(default_factory=list, description="no fix in these windows")
    garbage_per_fix: Annotated[float, Field(ge=0, le=1, description="probability that a fix's bytes are "
                                            "corrupted on the line (bad checksum, cut short, noise)")] = 0.0
    max_hdop: Annotated[float, Field(gt=0, le=99.99, description="the ACD drops fixes with a higher HDOP "
                                     "(GGA / binary)")] = 2.5
    serial: Literal["auto", "loop", "pty"] = Field(
        "auto", description="the line: pyserial loop:// or a pseudo-terminal; auto = pty in real time")
    port: str | None = Field(
        None, description="real time: the GPS line is this serial port (a device path such as "
                          "/dev/ttyUSB0, or the pseudo-terminal a run printed): an ACD reads its fixes from "
                          "it, and a run whose ACD is external writes them to it (default: that run opens a "
                          "pseudo-terminal and prints its path)")


class AcdSpec(Strict):
    """[acd] of a scenario file."""

    train_id: Annotated[int, Field(ge=1, le=255, description="the own train's id")] = 2
    prediction: bool = Field(True, description="dead reckoning with an uncertainty margin (seed 002 §X); "
                                               "false: the paper's plain algorithm")
    margin_m: Annotated[float, Field(ge=0, le=1000, description="brake when ΔS <= B + margin [m]")] = 50.0
    release_hysteresis_m: Annotated[float, Field(gt=0, le=2000, description="release when ΔS > B + "
                                                 "this [m]")] = 100.0
    control_centre: str | None = Field(None, description="HOST:PORT of a running control centre (real time); "
                                       "default: the in-process model of hil.studies.anticollision.nodes")
    radio_link: Literal["can", "tcp"] = Field(
        "can", description="who holds the ACD's radio link to the control centre: \"can\" — the train's "
                           "radio box (the plant) puts what the centre sends on CAN (RADIO_LEADER_POS/INFO); "
                           "\"tcp\" — the ACD itself, to control_centre (real time: a device with its own "
                           "modem, as the paper's): it reports its own position and takes the leader's from "
                           "the centre (a run whose ACD is external leaves the own train's reports to it in "
                           "either case)")
    control_centre_keys: str | None = Field(
        None, description="key file of a control centre run with --keys (TOML, [trains] U1 = \"<64 hex "
                          "digits>\"), relative to the scenario file: the bench signs both trains' "
                          "reports and checks what the centre sends; default: the open protocol")
    track: GeoTrackSpec = Field(default_factory=GeoTrackSpec)
    leader: LeaderSpec | None = Field(default_factory=LeaderSpec, description="U1, the leading train")
    signals: list[SignalSpec] = Field(default_factory=list)
    radio: RadioSpec = Field(default_factory=RadioSpec)
    gps: GpsSpec = Field(default_factory=GpsSpec)

    @model_validator(mode="after")
    def _consistent(self) -> AcdSpec:
        if not self.release_hysteresis_m > self.margin_m:
            raise ValueError(f"release_hysteresis_m ({self.release_hysteresis_m}) must be > margin_m "
                             f"({self.margin_m})")
        if self.leader is not None and self.leader.train_id == self.train_id:
            raise ValueError(f"leader.train_id and train_id are both {self.train_id}; give two ids")
        if self.radio_link == "tcp" and self.control_centre is None:
            raise ValueError("radio_link = \"tcp\" (the ACD's own link to the control centre) needs "
                             "control_centre = \"HOST:PORT\" (real time)")
        if self.control_centre is not None:
            host, sep, port = self.control_centre.rpartition(":")
            if not (sep and host and port.isdigit() and 0 < int(port) < 65536):
                raise ValueError(f"control_centre {self.control_centre!r}: expected HOST:PORT")
        return self


ASPECTS = {"red": Aspect.RED, "yellow": Aspect.YELLOW, "green": Aspect.GREEN}


class AcdStudyError(RailhilError, ValueError):
    """A bad option or file of the ACD study's tools (campaign file, run folder)."""


def sub_seed(seed: int, what: str) -> int:
    """A seed of its own for each random part of a run (GPS, radio...), from the scenario's seed."""
    return (int(seed) * 1_000_003 + zlib.crc32(what.encode())) % (1 << 63)


def spec_of(scenario: Scenario) -> AcdSpec:
    spec = scenario.acd
    if spec is None:
        raise AcdStudyError(f"scenario {scenario.name!r} has no [acd] section")
    return spec


@functools.lru_cache(maxsize=16)
def _geometry(track_json: str) -> TrackGeometry:
    t = GeoTrackSpec.model_validate_json(track_json)
    legs = [(g.azimuth_deg, g.length_m) for g in t.legs]
    pts = polyline_from_legs(t.origin_lat_deg, t.origin_lon_deg, legs)
    return TrackGeometry(pts, where="[acd.track]")


def geometry(spec: AcdSpec) -> TrackGeometry:
    """The track polyline of [acd.track] (cached: the same track is built once per process)."""
    return _geometry(spec.track.model_dump_json())


def section_of(spec: AcdSpec, s_m: float) -> int:
    """Route section id at track position s [m]: the last section starting at or before s (the first
    one before them all)."""
    sid = spec.track.sections[0].id
    for sec in spec.track.sections:
        if sec.from_m <= s_m:
            sid = sec.id
    return sid


def leader_motion(spec: AcdSpec) -> LeaderMotion | None:
    ld = spec.leader
    if ld is None:
        return None
    changes = [SpeedChange(c.at_s, mps(c.speed_kmh), c.rate_mps2) for c in ld.profile]
    return LeaderMotion(ld.rear_m, mps(ld.initial_speed_kmh), changes, ld.length_m)


def aspect_at(signal, t_s: float) -> Aspect:
    """A signal's aspect at t_s [s]: green until its first change."""
    out = Aspect.GREEN
    for ch in signal.aspects:
        if ch.at_s <= t_s:
            out = ASPECTS[ch.aspect]
    return out


def acd_params(spec: AcdSpec) -> AcdParams:
    return AcdParams(predict=spec.prediction, margin_m=spec.margin_m,
                     release_hysteresis_m=spec.release_hysteresis_m,
                     emergency_margin_m=min(AcdParams().emergency_margin_m, spec.margin_m))


def gps_params(g: GpsSpec) -> GpsParams:
    windows = tuple((w.start_s, w.start_s + w.duration_s) for w in g.dropouts if w.duration_s > 0)
    kw: dict = {"rate_hz": g.rate_hz, "outages_s": windows}
    if not g.noise:
        kw.update(horiz_noise_std_m=0.0, speed_noise_std_mps=0.0)
    if not g.instability:
        kw["instability_rate_per_h"] = 0.0
    if not g.random_dropouts:
        kw["dropout_rate_per_h"] = 0.0
    return GpsParams(**kw)


def centre_keys(spec: AcdSpec) -> dict[str, bytes] | None:
    """The keys of the run's trains (U<train_id> and U<leader.train_id>) from [acd] control_centre_keys,
    None without; a bad file, or a train of the run without a key in it, is one error line naming the
    file and the train."""
    if spec.control_centre_keys is None:
        return None

    keys = read_keys(spec.control_centre_keys, "[acd] control_centre_keys")
    trains = [f"U{spec.train_id}"] + ([] if spec.leader is None else [f"U{spec.leader.train_id}"])
    missing = [t for t in trains if t not in keys]
    if missing:
        raise AcdStudyError(f"control-centre key file {spec.control_centre_keys} (from [acd] "
                            f"control_centre_keys): no key for train {missing[0]} (the run reports as "
                            f"{' and '.join(trains)}; it has {', '.join(sorted(keys))})")
    return {t: keys[t] for t in trains}


def resolve_paths(scenario: Scenario, base: Path) -> Scenario:
    """The scenario with [acd] control_centre_keys resolved beside the scenario file (as [secoc] key_file
    is), its keys checked when a control centre is named: a bad key file is one line at load."""
    spec = scenario.acd
    if spec is None or spec.control_centre_keys is None:
        return scenario
    spec = spec.model_copy(update={"control_centre_keys": str((base / spec.control_centre_keys).resolve())})
    if spec.control_centre is not None:
        try:
            centre_keys(spec)
        except RailhilError as exc:
            raise ScenarioError(str(exc)) from None
    return scenario.model_copy(update={"acd": spec})
