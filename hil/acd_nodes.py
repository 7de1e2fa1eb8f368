"""The nodes of seed 002's anti-collision study:
hil.runtime.assembly hands a scenario with a [acd] section to this module.

`node_names` gets the foundation's node list (PLANT first) and returns this study's; `build_node`
returns the study's own node for `name`, or None to let hil.runtime.assembly build the foundation's.

What the [acd] section adds to a run (seed 002 §IV–§V, §IX, §X):

- **PLANT** stays the foundation's PlantController (a subclass, `WorldPlant`, with the same truth,
  standstill and glance) and gets the world around the train (`World`, every `WORLD_TICK_US`):
  the track in WGS-84 with route sections, the leading train U1 (plant_sim.leader, scripted), the
  wayside signals with their aspects over time, and the radio link (latency, jitter, loss, outages,
  `RadioLink`) to the control centre (`CentreModel`: steps 3–6 of the paper, the same pairing
  function as the TCP service hil.links.control_centre).  The follower's radio box puts what it last got
  on CAN: RADIO_LEADER_POS/INFO (LeaderId 0: no leader on the section) and RADIO_SIGNAL.  The plant
  also sends ACD_GNSS_TRUTH: the true antenna position, the feed of the GPS receiver model (in a
  real HIL, the GNSS simulator's feed from the vehicle model; no such frame exists on a train).
- **ACD** (`AcdDevice`): the GPS receiver (plant_sim.gps: noise, dropouts, instability) writes NMEA
  RMC+GGA (or the framed binary) onto a serial line through pyserial — ``loop://`` in lockstep, a
  real pseudo-terminal pair in real time — and the device reads it back, checksums verified, garbage
  counted and ignored (hil.links.nmea).  Fixes with a GGA/binary HDOP above `max_hdop` are dropped (the
  instability episodes report HDOP 4, plant_sim.gps).  The firmware (firmware_py.acd, steps 1–12,
  with or without §X's prediction) sends ACD_BRAKE_REQ to the BCU.
- **BCU**: the foundation's Bcu with `BcuParams.acd` (hil.runtime.assembly sets it for a scenario with [acd]):
  an EMERGENCY request is an emergency request (BCU_EMERGENCY.Source = 2, ACD); a SERVICE request asks
  for RequestedDecel, and the demand is the largest of the desk's step, precise stopping and the ACD's.

After a run, `judge` decides on plant truth: minimum gap to U1's last wagon, collision (gap ≤ 0),
red-signal overruns (the front passes a signal showing red), brake applications of the ACD and the
unnecessary ones.  `railhil reproduce acd campaign FILE` runs a campaign file's points
(hil.campaign.sweep's seeded draws) with prediction on and off and prints the figures.
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
import time
import zlib
from collections import deque
from collections.abc import Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np
from cantools.database.can import Database

from firmware_py.acd import (
    Acd,
    AcdParams,
    Aspect,
    TrainPosition,
    braking_distance_m,
    pair_on_sections,
)
from hil.can.codec import Codec
from hil.errors import RailhilError
from hil.links.gpsserial import GpsLinkReader, GpsLinkWriter, PtyLink, open_port
from hil.links.nmea import DEFAULT_UTC0, ReceivedFix
from hil.runtime.node import Binding, Node
from hil.runtime.plant_node import PlantController
from hil.scenario import Scenario
from hil.spec_acd import AcdSpec, GpsSpec, RadioSpec
from plant_sim.geo import TrackGeometry, polyline_from_legs
from plant_sim.gps import GpsModel, GpsParams
from plant_sim.leader import LeaderMotion, SpeedChange

WORLD_TICK_US = 100_000        # the world (U1, signals, radio) advances every 100 ms (chosen: the ACD cycle)
ACD_OFFSET_US = 7_000          # the ACD's phase in the 10 ms grid, after the BECUs (3.0-6.5 ms) (chosen)
ACD_NODE = "ACD"
PASSED_SIGNAL_M = 10.0         # a signal this far behind the own GPS position is passed (chosen: 4 σ of
#                                the NEO-6's 2.1 m per-axis σ, plant_sim.gps)
SECTION_SEARCH_M = 500.0       # own position search window around the last one on the track [m] (chosen)
RADIO_OUT = ("RADIO_LEADER_POS.Latitude", "RADIO_LEADER_POS.Longitude", "RADIO_LEADER_INFO.LeaderId",
             "RADIO_LEADER_INFO.RouteSection", "RADIO_LEADER_INFO.Speed", "RADIO_LEADER_INFO.TrainLength",
             "RADIO_LEADER_INFO.AgeOfReport", "RADIO_SIGNAL.SignalId", "RADIO_SIGNAL.Aspect",
             "RADIO_SIGNAL.SignalPos", "RADIO_SIGNAL.AgeOfAspect")
TRUTH_OUT = ("ACD_GNSS_TRUTH.TrackPos", "ACD_GNSS_TRUTH.Speed")
AGE_MAX_S = 25.5               # DBC maximum of AgeOfReport / AgeOfAspect
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


# --------------------------------------------------------------------------------------- the track
@functools.lru_cache(maxsize=16)
def _geometry(track_json: str) -> TrackGeometry:
    from hil.spec_acd import GeoTrackSpec

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
    changes = [SpeedChange(c.at_s, c.speed_kmh / 3.6, c.rate_mps2) for c in ld.profile]
    return LeaderMotion(ld.rear_m, ld.initial_speed_kmh / 3.6, changes, ld.length_m)


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


# ----------------------------------------------------------------------------------- the radio link
class RadioLink:
    """One hop of the radio (train → centre or centre → train), in simulated time: each message is
    lost with probability `loss`, or delivered latency + U(0, jitter) after it was sent, in order; a
    message sent or due inside an outage window is lost.  Seeded: the same draws every run."""

    def __init__(self, spec: RadioSpec, seed: int) -> None:
        self.spec = spec
        self.rng = np.random.Generator(np.random.PCG64(seed))
        self.outages_us = [(round(w.start_s * 1e6), round((w.start_s + w.duration_s) * 1e6))
                           for w in spec.outages]
        self.queue: deque[tuple[int, dict]] = deque()
        self.offered = self.lost = self.delivered = 0
        self._last_due = 0

    def _out(self, t_us: int) -> bool:
        return any(a <= t_us < b for a, b in self.outages_us)

    def send(self, t_us: int, msg: dict) -> None:
        self.offered += 1
        lost = self.rng.random() < self.spec.loss
        due = t_us + round((self.spec.latency_s + self.spec.jitter_s * self.rng.random()) * 1e6)
        if lost or self._out(t_us) or self._out(due):
            self.lost += 1
            return
        self._last_due = max(self._last_due, due)           # in order
        self.queue.append((self._last_due, msg))

    def receive(self, now_us: int) -> Iterator[dict]:
        while self.queue and self.queue[0][0] <= now_us:
            self.delivered += 1
            yield self.queue.popleft()[1]


class CentreModel:
    """The control centre in-process (lockstep): the latest report of each train (step 3), the pairing
    on each route section (steps 4–5, firmware_py.acd.pair_on_sections, as hil.links.control_centre), and
    what it sends: ("pair", leader) when a train's leader changes, the leader's report to its
    follower (step 6)."""

    def __init__(self) -> None:
        self.latest: dict[str, dict] = {}
        self.pairs: dict[str, tuple[str | None, str | None]] = {}
        self.reports = 0

    def report(self, rep: dict) -> list[tuple[str, dict]]:
        self.reports += 1
        old = self.latest.get(rep["train"])
        if old is not None and old["t"] > rep["t"]:
            return []                                        # older than what we have
        self.latest[rep["train"]] = rep
        new = pair_on_sections(TrainPosition(r["train"], r["lat"], r["lon"], r["section"], r["heading"])
                               for r in self.latest.values())
        out = []
        for train in sorted(new):
            if new[train][0] != self.pairs.get(train, (None, None))[0]:
                out.append((train, {"type": "pair", "leader": new[train][0]}))
                if new[train][0] is not None:
                    out.append((train, {"type": "leader_report", **self.latest[new[train][0]]}))
        self.pairs = new
        # the acknowledgement carries the reporting train's current pair, as hil.links.control_centre's does:
        # a lost "pair" message heals itself with the next report
        out.append((rep["train"], {"type": "pair", "leader": new.get(rep["train"], (None, None))[0]}))
        follower = new.get(rep["train"], (None, None))[1]
        if follower is not None:
            out.append((follower, {"type": "leader_report", **rep}))
        return out


class TcpCentre:
    """The real control centre (hil.links.control_centre: its own process, its SQLite file) over TCP, for
    real-time runs: one TrainClient per train (reports acknowledged, resent after a reconnection, so a
    restart of the centre loses none), on an asyncio loop in a thread of the PLANT process.  Radio
    latency and loss are the centre's own (`railhil control-centre --latency-ms --loss`)."""

    def __init__(self, address: str, trains: list[str]) -> None:
        import asyncio
        import threading

        from hil.links.control_centre import TrainClient

        host, _, port = address.rpartition(":")
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name="acd-radio", daemon=True)
        self.thread.start()
        self.clients = {t: TrainClient(t, host, int(port)) for t in trains}
        self._seen = {t: 0 for t in trains}

        async def start() -> None:
            for c in self.clients.values():
                await c.start()

        asyncio.run_coroutine_threadsafe(start(), self.loop).result(timeout=10.0)

    def report(self, rep: dict) -> None:
        """Queue a train's report (step 3); t [µs] goes out as s."""
        c = self.clients[rep["train"]]
        args = (rep["lat"], rep["lon"], rep["speed"], rep["section"], rep["length"], rep["heading"] % 360.0,
                rep["t"] * 1e-6)
        self.loop.call_soon_threadsafe(lambda: c.report(*args))

    def messages(self, train: str) -> list[dict]:
        """What the centre told `train` since the last call: its pair, then the leader reports."""
        c = self.clients[train]
        new = c.leader_reports[self._seen[train]:]          # list appends are atomic: a safe snapshot
        self._seen[train] += len(new)
        out: list[dict] = [{"type": "pair", "leader": c.leader}]
        out += [{**m, "type": "leader_report", "t": round(m["t"] * 1e6)} for m in new
                if m.get("t") is not None]
        return out

    def close(self) -> None:
        import asyncio

        async def stop() -> None:
            for c in self.clients.values():
                await c.close()

        asyncio.run_coroutine_threadsafe(stop(), self.loop).result(timeout=10.0)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout=5.0)


# ----------------------------------------------------------------------------------------- the world
class World:
    """U1, the signals, the radio and the control centre, seen from the own train's radio box.

    `step(now_us, front_m, speed_mps)` (every WORLD_TICK_US, with the own train's true front position
    and speed) returns the radio box's CAN outputs.  Each train reports every `report_period_s`: U1
    the GPS position of its last wagon (receiver noise, plant_sim.gps), the own train its front (the
    position its ACD's GPS gives; here the truth: its error does not matter to the pairing).  The
    wayside sends the aspect of the next signal ahead of the own train on the same period."""

    def __init__(self, spec: AcdSpec, seed: int) -> None:
        self.spec = spec
        self.geo = geometry(spec)
        self.motion = leader_motion(spec)
        self.me = f"U{spec.train_id}"
        self.leader_name = None if spec.leader is None else f"U{spec.leader.train_id}"
        self.up = RadioLink(spec.radio, sub_seed(seed, "radio-up"))
        self.down = RadioLink(spec.radio, sub_seed(seed, "radio-down"))
        self.centre = CentreModel()
        self.tcp: TcpCentre | None = None             # real time with [acd] control_centre: opened at once
        noise = GpsParams(dropout_rate_per_h=0.0, instability_rate_per_h=0.0) if spec.gps.noise else \
            GpsParams(horiz_noise_std_m=0.0, speed_noise_std_mps=0.0, dropout_rate_per_h=0.0,
                      instability_rate_per_h=0.0)
        self.leader_gps = GpsModel(noise, sub_seed(seed, "leader-gps"))
        self.period_us = round(spec.radio.report_period_s * 1e6)
        self.next_report_us = 0
        self.signals = sorted(spec.signals, key=lambda s: s.position_m)
        # the radio box's state: what the own train last got
        self.leader_id = 0
        self.leader_rep: dict | None = None
        self.signal_msg: dict | None = None
        self.out: dict[str, float] = {k: 0.0 for k in RADIO_OUT + TRUTH_OUT}

    def _report(self, train: str, t_us: int, s_m: float, v: float, length: float, noisy: bool) -> dict:
        lat, lon, heading = self.geo.at(s_m)
        if noisy:
            fix = self.leader_gps.fix(t_us, lat, lon, v, heading)
            lat, lon, v, heading = fix.lat_deg, fix.lon_deg, fix.speed_mps, fix.heading_deg
        return {"train": train, "t": t_us, "lat": lat, "lon": lon, "speed": v, "heading": heading,
                "section": section_of(self.spec, s_m), "length": length}

    def next_signal(self, front_m: float):
        for sig in self.signals:
            if sig.position_m > front_m:
                return sig
        return None

    def _uplink(self, now_us: int, rep: dict) -> None:
        if self.tcp is None:
            self.up.send(now_us, rep)
        elif not self.up._out(now_us):                # a radio outage silences the real link too
            self.tcp.report(rep)

    def step(self, now_us: int, front_m: float, speed_mps: float) -> dict[str, float]:
        t_s = now_us / 1e6
        if self.spec.control_centre is not None and self.tcp is None:
            trains = [self.me] + ([self.leader_name] if self.motion is not None else [])
            self.tcp = TcpCentre(self.spec.control_centre, trains)
        if now_us >= self.next_report_us:
            self.next_report_us += self.period_us
            if self.motion is not None:
                s_l, v_l, _ = self.motion.state(t_s)
                self._uplink(now_us, self._report(self.leader_name, now_us, s_l, v_l, self.motion.length_m,
                                                  True))
            own_len = 1.0   # only the leader's length is used (the follower's is not relayed to anyone)
            self._uplink(now_us, self._report(self.me, now_us, front_m, speed_mps, own_len, False))
            sig = self.next_signal(front_m)
            self.down.send(now_us, {"type": "signal", "t": now_us,
                                    "id": 0 if sig is None else sig.id,
                                    "aspect": 0 if sig is None else int(aspect_at(sig, t_s)),
                                    "pos": 0.0 if sig is None else sig.position_m})
        for rep in self.up.receive(now_us):
            for train, msg in self.centre.report(rep):
                if train == self.me:
                    self.down.send(now_us, msg)
        received = list(self.down.receive(now_us))
        if self.tcp is not None and not self.down._out(now_us):
            received += self.tcp.messages(self.me)
        for msg in received:
            kind = msg["type"]
            if kind == "pair":
                self.leader_id = 0 if msg["leader"] is None else int(msg["leader"][1:])
                if self.leader_rep is not None and self.leader_rep["train"] != msg["leader"]:
                    self.leader_rep = None                # a report of a train that is not our leader
            elif kind == "leader_report" and self.leader_id and msg["train"] == f"U{self.leader_id}":
                if self.leader_rep is None or msg["t"] >= self.leader_rep["t"]:
                    self.leader_rep = msg
            elif kind == "signal":
                self.signal_msg = msg
        return self.outputs(now_us, front_m, speed_mps)

    def outputs(self, now_us: int, front_m: float, speed_mps: float) -> dict[str, float]:
        out = self.out
        rep = self.leader_rep
        if rep is not None and self.leader_id:
            out["RADIO_LEADER_POS.Latitude"] = rep["lat"]
            out["RADIO_LEADER_POS.Longitude"] = rep["lon"]
            out["RADIO_LEADER_INFO.LeaderId"] = self.leader_id
            out["RADIO_LEADER_INFO.RouteSection"] = rep["section"]
            out["RADIO_LEADER_INFO.Speed"] = min(max(rep["speed"], 0.0), 655.35)
            out["RADIO_LEADER_INFO.TrainLength"] = rep["length"]
            out["RADIO_LEADER_INFO.AgeOfReport"] = min((now_us - rep["t"]) / 1e6, AGE_MAX_S)
        else:
            out["RADIO_LEADER_INFO.LeaderId"] = 0
        sig = self.signal_msg
        if sig is not None:
            out["RADIO_SIGNAL.SignalId"] = sig["id"]
            out["RADIO_SIGNAL.Aspect"] = sig["aspect"]
            out["RADIO_SIGNAL.SignalPos"] = sig["pos"]
            out["RADIO_SIGNAL.AgeOfAspect"] = min((now_us - sig["t"]) / 1e6, AGE_MAX_S)
        out["ACD_GNSS_TRUTH.TrackPos"] = min(max(front_m, 0.0), 4_294_967.295)
        out["ACD_GNSS_TRUTH.Speed"] = min(max(speed_mps, 0.0), 655.35)
        return dict(out)


class WorldPlant(PlantController):
    """The foundation's PlantController plus the world around the train (`World`): same physics,
    truth, standstill and glance; its extra outputs are the radio box's and the GNSS feed's frames."""

    def __init__(self, plant, n_cars: int, db: Database, dbc_name: str, world: World) -> None:
        super().__init__(plant, n_cars, db, dbc_name)
        self.world = world
        self.outputs = tuple(self.outputs) + RADIO_OUT + TRUTH_OUT
        self.half_car_m = plant.params.train.car_pitch_m / 2.0     # antenna at the front of car 1
        self.next_world_us = 0

    def step(self, now_us: int, rx) -> dict[str, float]:
        out = super().step(now_us, rx)
        if now_us >= self.next_world_us:
            self.next_world_us += WORLD_TICK_US
            snap = self.plant.snapshot()                           # after this step's integration
            out.update(self.world.step(now_us, snap.x[0] + self.half_car_m, snap.v[0]))
        return out


# ------------------------------------------------------------------------------------------- the ACD
class _AcdRx(Mapping):
    """The node's RxTable plus the device's own inputs (Acd.LOCAL_INPUTS)."""

    def __init__(self, rx: Mapping[str, float], local: dict[str, float]) -> None:
        self.rx, self.local = rx, local

    def __getitem__(self, key: str) -> float:
        return self.local[key] if key in self.local else self.rx[key]

    def __iter__(self):
        return iter(self.rx)

    def __len__(self) -> int:
        return len(self.rx)

    def get(self, key, default=None):
        if key in self.local:
            return self.local[key]
        return self.rx.get(key, default)

    def age_us(self, name: str, now_us: int):
        age = getattr(self.rx, "age_us", None)
        return None if age is None else age(name, now_us)


@dataclass
class GpsInputStats:
    """What the ACD's GPS input stage did (besides hil.links.nmea's byte/sentence counters)."""

    fixes_written: int = 0
    corrupted: int = 0           # fixes whose bytes were damaged on the line (injected)
    accepted: int = 0            # epochs taken as the own position
    no_fix: int = 0              # epochs the receiver reported without a fix
    high_hdop: int = 0           # epochs dropped for HDOP > max_hdop (instability)
    unmatched: int = 0           # RMC whose GGA never came (damaged): dropped


class AcdDevice:
    """The ACD node's controller: GPS receiver model → serial line → NMEA/binary reader → firmware Acd.

    step(now_us, rx) -> ACD_BRAKE_REQ signals.  Inputs: the radio frames, RADIO_SIGNAL's id and
    position, ACD_GNSS_TRUTH (for the receiver model only; the firmware sees the serial line)."""

    OUTPUTS = Acd.OUTPUTS
    SIGNAL = ("RADIO_SIGNAL.SignalId", "RADIO_SIGNAL.SignalPos")

    def __init__(self, spec: AcdSpec, seed: int, serial: str = "loop") -> None:
        self.spec = spec
        self.geo = geometry(spec)
        self.acd = Acd(acd_params(spec))
        self.inputs = tuple(Acd.INPUTS) + self.SIGNAL + TRUTH_OUT
        self.outputs = self.OUTPUTS
        self.gps = GpsModel(gps_params(spec.gps), sub_seed(seed, "own-gps"))
        self.fix_period_us = self.gps.p.period_us
        self.next_fix_us = 0
        self.serial = serial
        self.rng = np.random.Generator(np.random.PCG64(sub_seed(seed, "serial-garbage")))
        self.stats = GpsInputStats()
        self.link: PtyLink | None = None
        self.writer: GpsLinkWriter | None = None
        self.reader: GpsLinkReader | None = None
        self.fix: tuple[float, float, float, int] | None = None     # lat, lon, speed, t_us of the fix
        self.own_s: float | None = None
        self._pending: ReceivedFix | None = None
        self._signal_cache: tuple[float, float, float] | None = None
        self.report: dict = {}       # the GPS line's figures, refreshed every epoch (run.json node_stats)

    # the serial line -----------------------------------------------------------------------------
    def open(self) -> None:
        """Open the line: pyserial loop:// (lockstep) or a real pseudo-terminal pair (real time)."""
        proto = self.spec.gps.protocol
        if self.serial == "pty":
            self.link = PtyLink()
            self.writer = GpsLinkWriter(self.link.device, proto)
            self.reader = GpsLinkReader(self.link.port, proto)
        else:
            port = open_port("loop://")
            self.writer, self.reader = GpsLinkWriter(port, proto), GpsLinkReader(port, proto)
        self.report.update(serial=self.serial, protocol=proto,
                           port=self.link.port_name if self.link is not None else "loop://")

    def _refresh_report(self) -> None:
        self.report.update(vars(self.stats), line=self.reader.stats.summary(),
                           bytes_dropped=self.writer.bytes_dropped)

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()
        if self.link is not None:
            self.link.close()
        elif self.reader is not None:
            self.reader.port.close()

    def _damage(self, data: bytes) -> bytes:
        """A fix's bytes as a noisy line delivers them, with probability garbage_per_fix: one byte
        changed (bad checksum/CRC), cut short (truncated), or random bytes in front (noise)."""
        rng = self.rng                       # the same draws for every fix: reproducible
        u, kind, where, nbytes = rng.random(), rng.integers(3), rng.random(), rng.integers(1, 40)
        noise = self.rng.integers(0, 256, size=40, dtype=np.uint8).tobytes()[:nbytes]
        if u >= self.spec.gps.garbage_per_fix:
            return data
        self.stats.corrupted += 1
        k = 1 + int(where * (len(data) - 4))
        if kind == 0:
            return data[:k] + bytes([data[k] ^ 0x5A]) + data[k + 1:]
        if kind == 1:
            return data[:k] + data[min(len(data), k + 10 + int(nbytes)):]
        return noise + data

    def _receiver(self, now_us: int, rx: Mapping[str, float]) -> None:
        """The GPS module: a fix at every epoch due, from the true antenna position, onto the line."""
        s_true, v_true = rx[TRUTH_OUT[0]], rx[TRUTH_OUT[1]]
        age = getattr(rx, "age_us", lambda *_: 0)(TRUTH_OUT[0], now_us)
        while self.next_fix_us <= now_us:
            t_fix = self.next_fix_us
            self.next_fix_us += self.fix_period_us
            if not (s_true == s_true and v_true == v_true) or age is None:
                continue                                  # no truth yet (the first frames)
            s = s_true + v_true * (t_fix - (now_us - age)) * 1e-6    # the truth moved on since its frame
            lat, lon, heading = self.geo.at(s)
            fix = self.gps.fix(t_fix, lat, lon, v_true, heading)
            self.stats.fixes_written += 1
            self.writer.write_bytes(self._damage(self.writer.encoder.encode(fix)))

    def _take(self, f: ReceivedFix) -> None:
        """An epoch's position accepted as the own fix (step 1-2)."""
        t_us = f.sim_time_us(DEFAULT_UTC0)
        if t_us is None:
            return
        self.fix = (f.lat_deg, f.lon_deg, f.speed_mps, t_us)
        self.stats.accepted += 1
        lo = None if self.own_s is None else (self.own_s - SECTION_SEARCH_M, self.own_s + SECTION_SEARCH_M)
        self.own_s = self.geo.locate(f.lat_deg, f.lon_deg, lo)[0]

    def _epoch(self, rmc: ReceivedFix, gga: ReceivedFix | None) -> None:
        if not rmc.valid or (gga is not None and gga.quality == 0):
            self.stats.no_fix += 1
        elif gga is not None and not gga.hdop <= self.spec.gps.max_hdop:
            self.stats.high_hdop += 1
        else:
            self._take(rmc)

    def _read(self) -> None:
        for f in self.reader.poll():
            if f.source == "BIN":
                self._epoch(f, f)
            elif f.source == "RMC":
                if self._pending is not None:
                    self.stats.unmatched += 1             # its GGA was damaged: not judged, dropped
                self._pending = f
            elif f.source == "GGA":
                rmc, self._pending = self._pending, None
                if rmc is not None and rmc.tod_s == f.tod_s:
                    self._epoch(rmc, f)
                elif rmc is not None:
                    self.stats.unmatched += 1

    def _signal(self, rx: Mapping[str, float]) -> tuple[float, float]:
        sid, pos = rx[self.SIGNAL[0]], rx[self.SIGNAL[1]]
        if not (sid == sid and pos == pos) or round(sid) == 0:
            return math.nan, math.nan
        if self.own_s is not None and self.own_s - pos > PASSED_SIGNAL_M:
            return math.nan, math.nan                     # behind us: passed
        if self._signal_cache is None or self._signal_cache[0] != pos:
            lat, lon, _ = self.geo.at(pos)
            self._signal_cache = (pos, lat, lon)
        return self._signal_cache[1], self._signal_cache[2]

    def step(self, now_us: int, rx: Mapping[str, float]) -> dict[str, float]:
        if self.writer is None:
            self.open()
        written = self.stats.fixes_written
        self._receiver(now_us, rx)
        self._read()
        if self.stats.fixes_written != written:
            self._refresh_report()
        local: dict[str, float] = {"OwnFixValid": 0.0}
        if self.fix is not None:
            lat, lon, speed, t_us = self.fix
            local.update(OwnLatitude=lat, OwnLongitude=lon, OwnSpeed=speed, OwnFixValid=1.0,
                         OwnFixAge=(now_us - t_us) * 1e-6)
        local["OwnRouteSection"] = math.nan if self.own_s is None else section_of(self.spec, self.own_s)
        local["SignalLatitude"], local["SignalLongitude"] = self._signal(rx)
        return self.acd.step(now_us, _AcdRx(rx, local))


# --------------------------------------------------------------------------------------- the nodes
def node_names(scenario: Scenario, names: list[str]) -> list[str]:
    return names if ACD_NODE in names else names + [ACD_NODE]


def _serial_kind(spec: AcdSpec) -> str:
    if spec.gps.serial != "auto":
        return spec.gps.serial
    import multiprocessing as mp

    # a real-time run builds each node in its own process named railhil-<node> (hil.runtime.realtime)
    return "pty" if mp.current_process().name == f"railhil-{ACD_NODE}" else "loop"


def build_node(name: str, scenario: Scenario, db: Database, codec: Codec,
               dbc_name: str = "DBC") -> Node | None:
    from hil.runtime import assembly

    spec = spec_of(scenario)
    n = scenario.train.cars
    if name == "PLANT":
        plant = assembly.build_plant(scenario)
        ctrl = WorldPlant(plant, n, db, dbc_name, World(spec, scenario.seed))
        rx_msgs = [f"BECU{i}_PRESS_CMD" for i in range(1, n + 1)]
        tx_msgs = [f"PLANT_CAR{i}_SENSORS" for i in range(1, n + 1)] + [
            "RADIO_LEADER_POS", "RADIO_LEADER_INFO", "RADIO_SIGNAL", "ACD_GNSS_TRUTH"]
        period, offset = plant.params.dt_us, assembly.PLANT_OFFSET_US
    elif name == ACD_NODE:
        ctrl = AcdDevice(spec, scenario.seed, _serial_kind(spec))
        rx_msgs = ["RADIO_LEADER_POS", "RADIO_LEADER_INFO", "RADIO_SIGNAL", "ACD_GNSS_TRUTH"]
        tx_msgs = ["ACD_BRAKE_REQ"]
        period, offset = ctrl.acd.p.cycle_us, ACD_OFFSET_US
    else:
        return None
    binding = Binding.build(db, name, ctrl.inputs, ctrl.outputs, rx_msgs, tx_msgs, dbc_name)
    node = Node(name, ctrl, binding, codec, db, period_us=period, offset_us=offset,
                safe_outputs=assembly.safe_outputs(ctrl))
    if isinstance(ctrl, AcdDevice):
        node.stats.gps_line = ctrl.report        # lands in RunOutcome.node_stats and run.json
    return node


# ------------------------------------------------------------------------------------ the judgement
@dataclass
class Judgement:
    """A run judged on plant truth (module docstring).  Distances in m, times in s."""

    min_gap_m: float                 # smallest gap front → U1's last wagon (inf without U1)
    collision: bool                  # the gap reached 0
    overruns: int                    # signals passed while red
    min_signal_m: float              # smallest distance to a red signal ahead (inf: none)
    applications: int                # ACD brake applications (Request rising from NONE)
    unnecessary: int                 # of which unnecessary (obstacle farther than B + hysteresis)
    first_brake_s: float             # first ACD request [s] (nan: none)
    stop_gap_m: float                # gap at the end of the run
    ends: list = field(default_factory=list)

    def as_dict(self) -> dict:
        d = dict(vars(self))
        d.pop("ends")
        return d


def judge(scenario: Scenario, cols: Mapping[str, np.ndarray], req_t_s: np.ndarray,
          req: np.ndarray) -> Judgement:
    """Judge a run from its truth columns (t_s, x_m_1, v_mps_1) and the ACD's Request frames (times
    [s] and values), recomputing U1 and the signals from the scenario."""
    from hil.runtime.plant_node import plant_params

    spec = spec_of(scenario)
    t = np.asarray(cols["t_s"])
    front = np.asarray(cols["x_m_1"]) + plant_params(scenario).train.car_pitch_m / 2.0
    v = np.asarray(cols["v_mps_1"])
    motion = leader_motion(spec)
    if motion is not None:
        gap = motion.rear_m(t) - front
        min_gap, stop_gap = float(gap.min()), float(gap[-1])
    else:
        gap = np.full_like(t, np.inf)
        min_gap = stop_gap = math.inf
    overruns, min_sig = 0, math.inf
    red_dist = np.full_like(t, np.inf)
    for sig in spec.signals:
        red = np.array([aspect_at(sig, ti) == Aspect.RED for ti in t])
        ahead = sig.position_m - front
        if red.any() and (ahead > 0).any():
            min_sig = min(min_sig, float(ahead[red & (ahead > -1.0)].min(initial=np.inf)))
        red_dist = np.where(red & (ahead > 0), np.minimum(red_dist, ahead), red_dist)
        crossed = np.flatnonzero((ahead[:-1] > 0) & (ahead[1:] <= 0))
        overruns += int(any(red[k + 1] for k in crossed))
    p = acd_params(spec)
    req = np.asarray(req)
    rises = np.flatnonzero((req[1:] > 0) & (req[:-1] == 0)) + 1
    if req.size and req[0] > 0:
        rises = np.concatenate([[0], rises])
    unnecessary = 0
    for k in rises:
        i = min(int(np.searchsorted(t, req_t_s[k])), len(t) - 1)
        b = braking_distance_m(float(v[i]), p.service_decel_mps2, p.reaction_s)
        if min(gap[i], red_dist[i]) > b + p.release_hysteresis_m:
            unnecessary += 1
    return Judgement(min_gap, min_gap <= 0.0, overruns, min_sig, int(rises.size), unnecessary,
                     float(req_t_s[rises[0]]) if rises.size else math.nan, stop_gap)


class RequestLog(can.Listener):
    """Keeps the ACD's ACD_BRAKE_REQ.Request of every frame on the bus (a python-can listener)."""

    def __init__(self, codec: Codec) -> None:
        self.fc = codec.by_name("ACD_BRAKE_REQ")
        self.t: list[float] = []
        self.req: list[int] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == self.fc.frame_id:
            self.t.append(msg.timestamp)
            self.req.append(int(self.fc.decode(bytes(msg.data))["Request"]))


def run_judged(scenario_json: str) -> dict:
    """One lockstep run in this process, no trace file, judged (a campaign worker's job)."""
    from hil.can.dbc import load_dbc
    from hil.runtime.lockstep import run_lockstep
    from hil.runtime.run import dbc_path_of

    scenario = Scenario.model_validate_json(scenario_json)
    t0 = time.perf_counter()
    db = load_dbc(dbc_path_of(scenario))
    codec = Codec(db)
    log = RequestLog(codec)
    outcome = run_lockstep(scenario, db, codec, log)
    j = judge(scenario, outcome.truth.columns(), np.asarray(log.t), np.asarray(log.req))
    return {**j.as_dict(), "seed": scenario.seed, "prediction": spec_of(scenario).prediction,
            "simulated_s": outcome.end_us / 1e6, "end": outcome.reason, "wall_s": time.perf_counter() - t0}


def judge_run_dir(run_dir: Path) -> dict:
    """Judge a run folder of `railhil run` (lockstep or real time): its scenario (run.json), plant truth
    (truth.csv) and the ACD's requests in its trace."""
    import json

    from hil.can.dbc import load_dbc
    from hil.report.kpis import read_signal
    from hil.runtime.run import TRACE_NAME, dbc_path_of

    run_dir = Path(run_dir)
    try:
        meta = json.loads((run_dir / "run.json").read_text())
        scenario = Scenario.model_validate(meta["scenario"])
        data = np.genfromtxt(run_dir / "truth.csv", delimiter=",", names=True)
    except (OSError, ValueError, KeyError) as exc:
        raise AcdStudyError(f"{run_dir}: not a readable run folder of `railhil run` "
                            f"(run.json, truth.csv, {TRACE_NAME}): {' '.join(str(exc).split())}") from None
    spec_of(scenario)
    db = load_dbc(dbc_path_of(scenario))
    speed = scenario.realtime.speed if meta.get("mode") == "realtime" else 1.0
    t, req, _ = read_signal(run_dir / TRACE_NAME, db, Codec(db), "ACD_BRAKE_REQ", "Request",
                            t0_s=float(meta.get("trace_t0_s", 0.0)), speed=speed)
    cols = {name: np.asarray(data[name]) for name in data.dtype.names}
    j = judge(scenario, cols, np.asarray(t), np.asarray(req))
    return {**j.as_dict(), "seed": scenario.seed, "prediction": spec_of(scenario).prediction,
            "simulated_s": float(cols["t_s"][-1]), "mode": meta.get("mode")}


# --------------------------------------------------------------------------- the randomized campaign
def campaign_scenarios(path: str | Path) -> list[Scenario]:
    """The points of a campaign file (hil.campaign.sweep: base, [set], [grid], seeded [random])."""
    from hil.campaign.sweep import CampaignError, expand, load_campaign

    try:
        points = expand(load_campaign(path))
    except CampaignError as exc:
        raise AcdStudyError(str(exc)) from None
    bad = [p.index for p in points if p.scenario.acd is None]
    if bad:
        raise AcdStudyError(f"{path}: point {bad[0]} has no [acd] section; expected an ACD base scenario")
    return [p.scenario for p in points]


def with_prediction(scenario: Scenario, on: bool) -> Scenario:
    acd = spec_of(scenario).model_copy(update={"prediction": on})
    return scenario.model_copy(update={"acd": acd})


def summarize(rows: list[dict]) -> list[str]:
    """Figures of a set of judged runs: collisions, overruns, min gap distribution, brakes."""
    gaps = np.array([r["min_gap_m"] for r in rows if math.isfinite(r["min_gap_m"])])
    q = np.percentile(gaps, [0, 5, 50, 95, 100]) if gaps.size else [math.nan] * 5
    lines = [f"runs {len(rows)}: collisions {sum(r['collision'] for r in rows)}, "
             f"red-signal overruns {sum(r['overruns'] for r in rows)}, "
             f"runs ended by {', '.join(sorted({r['end'] for r in rows}))}",
             "min gap to U1 [m]: min {:.1f}, p5 {:.1f}, median {:.1f}, p95 {:.1f}, max {:.1f}".format(*q),
             f"ACD brake applications {sum(r['applications'] for r in rows)}, unnecessary "
             f"{sum(r['unnecessary'] for r in rows)} (in {sum(r['unnecessary'] > 0 for r in rows)} runs)"]
    sig = [r["min_signal_m"] for r in rows if math.isfinite(r["min_signal_m"])]
    if sig:
        lines.append(f"closest approach to a red signal [m]: min {min(sig):.1f}, median {np.median(sig):.1f}")
    return lines


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of the ACD study's command (`railhil reproduce acd`)."""
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    c = sub.add_parser("campaign", help="run a campaign file's points with prediction on and off, judged "
                                        "on plant truth")
    c.add_argument("campaign", type=Path, help="campaign TOML (hil.campaign.sweep) over an ACD scenario")
    c.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    c.add_argument("--prediction", choices=("both", "on", "off"), default="both",
                   help="run the points with the ACD's prediction on, off, or both (default both)")
    c.add_argument("--limit", type=int, default=None, help="run only the first N points")
    c.add_argument("--csv", type=Path, default=None, help="write one row per run to this CSV file")
    j = sub.add_parser("judge", help="judge a run folder, or run a scenario in lockstep (no files) and "
                                     "judge it, on plant truth")
    j.add_argument("scenario", type=Path, help="scenario TOML with an [acd] section, or a run folder of "
                                               "`railhil run` (lockstep or --realtime)")
    j.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key, as railhil run --set")


def _progress(total: int):
    try:
        from tqdm import tqdm
    except ImportError:          # pragma: no cover - tqdm is a dependency
        return None
    return tqdm(total=total, unit="run", file=sys.stderr, disable=not sys.stderr.isatty())


def run(args: argparse.Namespace) -> int:
    from hil.scenario import load_scenario

    if args.command == "judge":
        if args.scenario.is_dir():
            r = judge_run_dir(args.scenario)
        else:
            scenario = load_scenario(args.scenario, sets=args.set)
            spec_of(scenario)
            r = run_judged(scenario.model_dump_json())
        for k, v in r.items():
            print(f"{k:>14}: {v}")
        return 0
    if args.jobs < 1:
        raise AcdStudyError(f"--jobs {args.jobs}: expected 1 or more worker processes")
    if args.limit is not None and args.limit < 1:
        raise AcdStudyError(f"--limit {args.limit}: expected 1 or more points")
    scenarios = campaign_scenarios(args.campaign)[:args.limit]
    modes = {"both": (True, False), "on": (True,), "off": (False,)}[args.prediction]
    jobs = [with_prediction(s, m).model_dump_json() for m in modes for s in scenarios]
    t0 = time.perf_counter()
    bar = _progress(len(jobs))
    rows: list[dict] = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for r in pool.map(run_judged, jobs, chunksize=1):
            rows.append(r)
            if bar is not None:
                bar.update()
    if bar is not None:
        bar.close()
    for m in modes:
        print(f"prediction {'on' if m else 'off'}:")
        for line in summarize([r for r in rows if r["prediction"] == m]):
            print("  " + line)
    if len(modes) == 2:                      # rows are in job order: the points with, then without
        def bad(r: dict) -> bool:
            return r["collision"] or r["overruns"] > 0

        n = len(scenarios)
        avoided = sum(bad(off) and not bad(on) for on, off in zip(rows[:n], rows[n:], strict=True))
        caused = sum(bad(on) and not bad(off) for on, off in zip(rows[:n], rows[n:], strict=True))
        print(f"points with a collision or overrun that prediction avoids: {avoided} (that it causes: "
              f"{caused})")
    print(f"{len(rows)} runs in {time.perf_counter() - t0:.0f} s wall, {args.jobs} jobs")
    if args.csv is not None:
        import csv

        with open(args.csv, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        print(f"wrote {args.csv}")
    return 0
