"""The nodes of the anti-collision device (seed 002), for a scenario with an [acd] section.

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
- **BCU**: the foundation's Bcu with the ACD's requests as a demand source (`bcu_stages`,
  firmware_py.acd.AcdBrakeRequest): an EMERGENCY request is an emergency request (BCU_EMERGENCY.Source =
  2, ACD); a SERVICE request asks for RequestedDecel, and the demand is the largest of the desk's step,
  precise stopping and the ACD's.

After a run, kpis.py judges it on plant truth; reproduce.py runs the randomized campaign.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np
from cantools.database.can import Database

from firmware_py.acd import (
    Acd,
    AcdBrakeRequest,
    AcdRequestParams,
    TrainPosition,
    pair_on_sections,
)
from firmware_py.bcu import DemandSource, Follower
from firmware_py.rx import RxTable
from hil.can.codec import Codec
from hil.links.control_centre import TrainClient
from hil.links.gpsserial import GpsLinkReader, GpsLinkWriter, PtyLink, ServedPty, open_port
from hil.links.nmea import DEFAULT_UTC0, ReceivedFix
from hil.runtime import assembly
from hil.runtime.assembly import building_for_realtime
from hil.runtime.node import Binding, Node
from hil.runtime.plant_node import PlantController
from hil.scenario import Scenario
from hil.scenario.params import RunParams
from hil.studies.anticollision.scenario import (
    AcdSpec,
    RadioSpec,
    acd_params,
    aspect_at,
    centre_keys,
    geometry,
    gps_params,
    leader_motion,
    section_of,
    spec_of,
    sub_seed,
)
from plant_sim.gps import GpsModel, GpsParams

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
    latency and loss are the centre's own (`railhil control-centre --latency-ms --loss`).  With `keys`
    (train -> key, [acd] control_centre_keys) each client signs its train's hello and reports and takes
    only what the centre signed with that key (a centre run with --keys); without, the open protocol."""

    def __init__(self, address: str, trains: list[str], keys: Mapping[str, bytes] | None = None) -> None:
        import asyncio
        import threading


        host, _, port = address.rpartition(":")
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name="acd-radio", daemon=True)
        self.thread.start()
        self.clients = {t: TrainClient(t, host, int(port), key=None if keys is None else keys[t])
                        for t in trains}
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


class LeaderView:
    """What a train's radio knows of its leader: the leader the control centre paired it with (step 5) and
    that train's latest report (step 6); `take` reads a message of the centre's (hil.links.control_centre
    or CentreModel: "pair", "leader_report")."""

    def __init__(self) -> None:
        self.leader_id = 0                     # 0: no leader on the section
        self.report: dict | None = None

    def take(self, msg: dict) -> bool:
        """True when `msg` was the leader's report (a newer one, taken)."""
        kind = msg["type"]
        if kind == "pair":
            self.leader_id = 0 if msg["leader"] is None else int(msg["leader"][1:])
            if self.report is not None and self.report["train"] != msg["leader"]:
                self.report = None                # a report of a train that is not our leader
        elif kind == "leader_report" and self.leader_id and msg["train"] == f"U{self.leader_id}":
            if self.report is None or msg["t"] >= self.report["t"]:
                self.report = msg
                return True
        return False

    def signals(self, out: dict[str, float], age_s: float) -> None:
        """RADIO_LEADER_POS/INFO's signals into `out`, the report `age_s` old; LeaderId 0 without one."""
        rep = self.report
        if rep is not None and self.leader_id:
            out["RADIO_LEADER_POS.Latitude"] = rep["lat"]
            out["RADIO_LEADER_POS.Longitude"] = rep["lon"]
            out["RADIO_LEADER_INFO.LeaderId"] = self.leader_id
            out["RADIO_LEADER_INFO.RouteSection"] = rep["section"]
            out["RADIO_LEADER_INFO.Speed"] = min(max(rep["speed"], 0.0), 655.35)
            out["RADIO_LEADER_INFO.TrainLength"] = rep["length"]
            out["RADIO_LEADER_INFO.AgeOfReport"] = min(age_s, AGE_MAX_S)
        else:
            out["RADIO_LEADER_INFO.LeaderId"] = 0


class OwnRadio:
    """The ACD's own radio link to the control centre ([acd] radio_link = "tcp", real time): it reports the
    own train's GPS position every report_period_s (step 3) and takes the leader's reports (step 6) from
    the centre over TCP (a TrainClient as its own train, hil.links.control_centre), as a device with its
    own modem does.  The leader's report is aged on this process's clock: from its reception, plus the time
    it spent at the centre (`age`), so that no clock is shared with the bench."""

    def __init__(self, spec: AcdSpec, geo) -> None:
        self.spec, self.geo = spec, geo
        self.me = f"U{spec.train_id}"
        keys = centre_keys(spec)
        own_key = None if keys is None else {self.me: keys[self.me]}
        self.tcp = TcpCentre(spec.control_centre, [self.me], own_key)
        self.period_us = round(spec.radio.report_period_s * 1e6)
        self.next_report_us = 0
        self.leader = LeaderView()
        self.received_us = 0                     # when the leader's report in hand came [µs, own clock]

    def step(self, now_us: int, fix, own_s: float | None, out: dict[str, float]) -> None:
        if now_us >= self.next_report_us and fix is not None and own_s is not None:
            self.next_report_us = now_us + self.period_us
            lat, lon, speed, _ = fix
            self.tcp.report({"train": self.me, "t": now_us, "lat": lat, "lon": lon, "speed": speed,
                             "heading": self.geo.at(own_s)[2], "section": section_of(self.spec, own_s),
                             "length": 1.0})          # only a leader's length is used: the follower's is not
        for msg in self.tcp.messages(self.me):
            if self.leader.take(msg):
                self.received_us = now_us
        rep = self.leader.report
        age_s = 0.0 if rep is None else (now_us - self.received_us) / 1e6 + float(rep.get("age") or 0.0)
        self.leader.signals(out, age_s)

    def close(self) -> None:
        self.tcp.close()


# ----------------------------------------------------------------------------------------- the world
class World:
    """U1, the signals, the radio and the control centre, seen from the own train's radio box.

    `step(now_us, front_m, speed_mps)` (every WORLD_TICK_US, with the own train's true front position
    and speed) returns the radio box's CAN outputs.  Each train reports every `report_period_s`: U1
    the GPS position of its last wagon (receiver noise, plant_sim.gps), the own train its front (the
    position its ACD's GPS gives; here the truth: its error does not matter to the pairing).  The
    wayside sends the aspect of the next signal ahead of the own train on the same period."""

    def __init__(self, spec: AcdSpec, seed: int, own_reports: bool = True) -> None:
        self.spec = spec
        self.geo = geometry(spec)
        self.motion = leader_motion(spec)
        self.me = f"U{spec.train_id}"
        # False: the own train's ACD holds its radio link itself (an external ACD, [acd] radio_link = "tcp"):
        # the world reports the leader only and hears nothing for the own train
        self.own_reports = own_reports
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
        self.leader = LeaderView()
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
            trains = ([self.me] if self.own_reports else []) + ([self.leader_name] if self.motion else [])
            self.tcp = TcpCentre(self.spec.control_centre, trains, centre_keys(self.spec))
        if now_us >= self.next_report_us:
            self.next_report_us += self.period_us
            if self.motion is not None:
                s_l, v_l, _ = self.motion.state(t_s)
                self._uplink(now_us, self._report(self.leader_name, now_us, s_l, v_l, self.motion.length_m,
                                                  True))
            own_len = 1.0   # only the leader's length is used (the follower's is not relayed to anyone)
            if self.own_reports:
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
        if self.tcp is not None and self.own_reports and not self.down._out(now_us):
            received += self.tcp.messages(self.me)
        for msg in received:
            if msg["type"] == "signal":
                self.signal_msg = msg
            else:
                self.leader.take(msg)
        return self.outputs(now_us, front_m, speed_mps)

    def outputs(self, now_us: int, front_m: float, speed_mps: float) -> dict[str, float]:
        out = self.out
        rep = self.leader.report
        self.leader.signals(out, 0.0 if rep is None else (now_us - rep["t"]) / 1e6)
        sig = self.signal_msg
        if sig is not None:
            out["RADIO_SIGNAL.SignalId"] = sig["id"]
            out["RADIO_SIGNAL.Aspect"] = sig["aspect"]
            out["RADIO_SIGNAL.SignalPos"] = sig["pos"]
            out["RADIO_SIGNAL.AgeOfAspect"] = min((now_us - sig["t"]) / 1e6, AGE_MAX_S)
        out["ACD_GNSS_TRUTH.TrackPos"] = min(max(front_m, 0.0), 4_294_967.295)
        out["ACD_GNSS_TRUTH.Speed"] = min(max(speed_mps, 0.0), 655.35)
        return dict(out)


class ServedGps:
    """The own train's GPS module served to an external ACD (real time, the ACD a device under test): the
    plant writes its fixes onto a serial line that the device opens — the port [acd.gps] names (wired to
    the device's GPS input), or a pseudo-terminal whose path the run prints."""

    def __init__(self, spec: AcdSpec, seed: int) -> None:
        self.stats = GpsInputStats()
        self.receiver = GpsReceiver(spec, seed, self.stats)
        self.pty: ServedPty | None = None
        if spec.gps.port is not None:
            self.port_name = spec.gps.port
            self.writer = GpsLinkWriter(open_port(spec.gps.port), spec.gps.protocol)
        else:
            self.pty = ServedPty()
            self.port_name = self.pty.port_name
            self.writer = GpsLinkWriter(self.pty.device, spec.gps.protocol)
        self.protocol, self.rate_hz = spec.gps.protocol, spec.gps.rate_hz
        self.report: dict = {"port": self.port_name, "protocol": self.protocol}   # refreshed at each fix

    def describe(self) -> str:
        what = "NMEA 0183 RMC+GGA" if self.protocol == "nmea" else "the framed binary protocol"
        return (f"the ACD's GPS line: {what} at {self.rate_hz:g} Hz on {self.port_name} (8N1; the external "
                "ACD reads its fixes there)")

    def write(self, now_us: int, truth_at: Callable[[int], tuple[float, float]]) -> None:
        """The fixes due by `now_us` onto the line (GpsReceiver.write)."""
        self.receiver.write(now_us, self.writer, truth_at)
        self.report.update(vars(self.stats), bytes_written=self.writer.bytes_written,
                           bytes_dropped=self.writer.bytes_dropped)

    def close(self) -> None:
        if self.pty is not None:
            self.pty.close()


class WorldPlant(PlantController):
    """The foundation's PlantController plus the world around the train (`World`): same physics,
    truth, standstill and glance; its extra outputs are the radio box's and the GNSS feed's frames.  With
    `gps` (an external ACD), it also writes the own train's GPS fixes onto the device's serial line."""

    def __init__(self, plant, n_cars: int, db: Database, dbc_name: str, world: World,
                 gps: ServedGps | None = None) -> None:
        super().__init__(plant, n_cars, db, dbc_name)
        self.world = world
        self.gps = gps
        self.outputs = tuple(self.outputs) + RADIO_OUT + TRUTH_OUT
        self.half_car_m = plant.params.train.car_pitch_m / 2.0     # antenna at the front of car 1
        self.next_world_us = 0

    def announce(self) -> list[str]:
        """What a real-time run prints before it starts: the GPS line an external ACD opens."""
        return [] if self.gps is None else [self.gps.describe()]

    def step(self, now_us: int, rx) -> dict[str, float]:
        out = super().step(now_us, rx)
        if now_us >= self.next_world_us:
            self.next_world_us += WORLD_TICK_US
            snap = self.plant.snapshot()                           # after this step's integration
            out.update(self.world.step(now_us, snap.x[0] + self.half_car_m, snap.v[0]))
        gps = self.gps
        if gps is not None and now_us >= gps.receiver.next_fix_us:
            snap = self.plant.snapshot()
            front, v = snap.x[0] + self.half_car_m, snap.v[0]
            gps.write(now_us, lambda t_fix: (front + v * (t_fix - now_us) * 1e-6, v))
        return out


# ------------------------------------------------------------------------------------------- the ACD
@dataclass
class GpsInputStats:
    """What the ACD's GPS input stage did (besides hil.links.nmea's byte/sentence counters)."""

    fixes_written: int = 0
    corrupted: int = 0           # fixes whose bytes were damaged on the line (injected)
    accepted: int = 0            # epochs taken as the own position
    no_fix: int = 0              # epochs the receiver reported without a fix
    high_hdop: int = 0           # epochs dropped for HDOP > max_hdop (instability)
    unmatched: int = 0           # RMC whose GGA never came (damaged): dropped


class GpsReceiver:
    """The own train's GPS module: at every epoch a fix of the true antenna position (plant_sim.gps: noise,
    dropouts, instability), encoded (NMEA RMC+GGA or the framed binary) and written onto the serial line;
    with probability garbage_per_fix a fix's bytes are damaged on the line.  `write` takes the true track
    position and speed at a fix's time; the ACD runs it on the ACD_GNSS_TRUTH frames (its GPS inside the
    ACD node), the plant on its own state (an external ACD: the GPS feeds the device's serial port)."""

    def __init__(self, spec: AcdSpec, seed: int, stats: GpsInputStats) -> None:
        self.geo = geometry(spec)
        self.gps = GpsModel(gps_params(spec.gps), sub_seed(seed, "own-gps"))
        self.fix_period_us = self.gps.p.period_us
        self.next_fix_us = 0
        self.garbage_per_fix = spec.gps.garbage_per_fix
        self.rng = np.random.Generator(np.random.PCG64(sub_seed(seed, "serial-garbage")))
        self.stats = stats

    def write(self, now_us: int, writer: GpsLinkWriter,
              truth_at: Callable[[int], tuple[float, float]] | None) -> None:
        """A fix for each epoch due by `now_us`, from `truth_at(t_fix)` -> (track position [m], speed
        [m/s]); None: no truth yet, the epochs pass without a fix."""
        while self.next_fix_us <= now_us:
            t_fix = self.next_fix_us
            self.next_fix_us += self.fix_period_us
            if truth_at is None:
                continue
            s, v = truth_at(t_fix)
            lat, lon, heading = self.geo.at(s)
            fix = self.gps.fix(t_fix, lat, lon, v, heading)
            self.stats.fixes_written += 1
            writer.write_bytes(self._damage(writer.encoder.encode(fix)))

    def _damage(self, data: bytes) -> bytes:
        """A fix's bytes as a noisy line delivers them, with probability garbage_per_fix: one byte
        changed (bad checksum/CRC), cut short (truncated), or random bytes in front (noise)."""
        rng = self.rng                       # the same draws for every fix: reproducible
        u, kind, where, nbytes = rng.random(), rng.integers(3), rng.random(), rng.integers(1, 40)
        noise = self.rng.integers(0, 256, size=40, dtype=np.uint8).tobytes()[:nbytes]
        if u >= self.garbage_per_fix:
            return data
        self.stats.corrupted += 1
        k = 1 + int(where * (len(data) - 4))
        if kind == 0:
            return data[:k] + bytes([data[k] ^ 0x5A]) + data[k + 1:]
        if kind == 1:
            return data[:k] + data[min(len(data), k + 10 + int(nbytes)):]
        return noise + data


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
        self.serial = serial
        self.stats = GpsInputStats()
        self.receiver = GpsReceiver(spec, seed, self.stats)   # the GPS module (not with [acd.gps] port)
        self.link: PtyLink | None = None
        self.writer: GpsLinkWriter | None = None
        self.reader: GpsLinkReader | None = None
        self.fix: tuple[float, float, float, int] | None = None     # lat, lon, speed, t_us of the fix
        self.own_s: float | None = None
        self._pending: ReceivedFix | None = None
        self._signal_cache: tuple[float, float, float] | None = None
        self.report: dict = {}       # the GPS line's figures, refreshed every epoch (run.json node_stats)
        self.radio: OwnRadio | None = None   # [acd] radio_link = "tcp": the ACD's own link to the centre
        self._now_us = 0
        # what the firmware reads: the radio frames as the node received them, and the device's own inputs
        # (Acd.LOCAL_INPUTS, and the leader's report from its own link), received at the cycle's time
        self.acd_rx = RxTable(Acd.INPUTS + Acd.LOCAL_INPUTS)

    # the serial line -----------------------------------------------------------------------------
    def open(self) -> None:
        """Open the line: the port [acd.gps] names (the GPS is elsewhere: its fixes are read, stamped on
        reception), or pyserial loop:// (lockstep) or a real pseudo-terminal pair (real time) with the GPS
        module on its other end; and, with [acd] radio_link = "tcp", the ACD's own link to the control
        centre."""
        proto = self.spec.gps.protocol
        if self.spec.radio_link == "tcp" and self.radio is None:
            self.radio = OwnRadio(self.spec, self.geo)
        if self.spec.gps.port is not None:
            self.reader = GpsLinkReader(open_port(self.spec.gps.port), proto)
            self.report.update(serial="port", protocol=proto, port=self.spec.gps.port)
            return
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
                           bytes_dropped=None if self.writer is None else self.writer.bytes_dropped)

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()
        if self.link is not None:
            self.link.close()
        elif self.reader is not None:
            self.reader.port.close()
        if self.radio is not None:
            self.radio.close()

    def _receiver(self, now_us: int, rx: RxTable) -> None:
        """The GPS module: a fix at every epoch due, from the true antenna position (ACD_GNSS_TRUTH),
        onto the line."""
        s_true, v_true = rx[TRUTH_OUT[0]], rx[TRUTH_OUT[1]]
        age = rx.age_us(TRUTH_OUT[0], now_us)
        truth_at = None
        if s_true == s_true and v_true == v_true and age is not None:    # no truth yet: the first frames
            def truth_at(t_fix: int) -> tuple[float, float]:            # the truth moved on since its frame
                return s_true + v_true * (t_fix - (now_us - age)) * 1e-6, v_true
        self.receiver.write(now_us, self.writer, truth_at)

    def _take(self, f: ReceivedFix) -> None:
        """An epoch's position accepted as the own fix (step 1-2): at its UTC as simulated time, or, read
        from a port (the GPS elsewhere, on another clock), at its reception."""
        t_us = self._now_us if self.spec.gps.port is not None else f.sim_time_us(DEFAULT_UTC0)
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

    def _signal(self, rx: RxTable) -> tuple[float, float]:
        sid, pos = rx[self.SIGNAL[0]], rx[self.SIGNAL[1]]
        if not (sid == sid and pos == pos) or round(sid) == 0:
            return math.nan, math.nan
        if self.own_s is not None and self.own_s - pos > PASSED_SIGNAL_M:
            return math.nan, math.nan                     # behind us: passed
        if self._signal_cache is None or self._signal_cache[0] != pos:
            lat, lon, _ = self.geo.at(pos)
            self._signal_cache = (pos, lat, lon)
        return self._signal_cache[1], self._signal_cache[2]

    def step(self, now_us: int, rx: RxTable) -> dict[str, float]:
        if self.reader is None:
            self.open()
        self._now_us = now_us
        written, accepted = self.stats.fixes_written, self.stats.accepted
        if self.writer is not None:
            self._receiver(now_us, rx)
        self._read()
        if self.stats.fixes_written != written or self.stats.accepted != accepted:
            self._refresh_report()
        local = dict.fromkeys(Acd.LOCAL_INPUTS, math.nan)     # NaN: not received this cycle
        local["OwnFixValid"] = 0.0
        if self.fix is not None:
            lat, lon, speed, t_us = self.fix
            local.update(OwnLatitude=lat, OwnLongitude=lon, OwnSpeed=speed, OwnFixValid=1.0,
                         OwnFixAge=(now_us - t_us) * 1e-6)
        local["OwnRouteSection"] = math.nan if self.own_s is None else section_of(self.spec, self.own_s)
        local["SignalLatitude"], local["SignalLongitude"] = self._signal(rx)
        if self.radio is not None:                   # the leader from the ACD's own link, not from CAN
            self.radio.step(now_us, self.fix, self.own_s, local)
        acd_rx = self.acd_rx
        acd_rx.copy_from(rx, Acd.INPUTS)
        acd_rx.receive(local, now_us)
        return self.acd.step(now_us, acd_rx)


# --------------------------------------------------------------------------------------- the nodes
def node_names(scenario: Scenario, names: list[str]) -> list[str]:
    return names if ACD_NODE in names else names + [ACD_NODE]


def _serial_kind(spec: AcdSpec) -> str:
    """The GPS line as configured; "auto": a pseudo-terminal in real time (whichever process hosts the ACD,
    or `railhil node ACD`), pyserial's loop:// in lockstep."""
    if spec.gps.serial != "auto":
        return spec.gps.serial

    return "pty" if building_for_realtime() else "loop"


def build_node(name: str, scenario: Scenario, db: Database, codec: Codec,
               dbc_name: str = "DBC") -> Node | None:
    spec = spec_of(scenario)
    n = scenario.train.cars
    if name == "PLANT":
        plant = assembly.build_plant(scenario)
        # an external ACD (real time, a device under test): its GPS from the plant, its radio its own
        external = assembly.building_for_realtime() and ACD_NODE in scenario.nodes \
            and scenario.nodes[ACD_NODE].external
        world = World(spec, scenario.seed, own_reports=spec.radio_link == "can" and not external)
        ctrl = WorldPlant(plant, n, db, dbc_name, world, ServedGps(spec, scenario.seed) if external else None)
        rx_msgs = [f"BECU{i}_PRESS_CMD" for i in range(1, n + 1)]
        tx_msgs = [f"PLANT_CAR{i}_SENSORS" for i in range(1, n + 1)] + [
            "RADIO_LEADER_POS", "RADIO_LEADER_INFO", "RADIO_SIGNAL", "ACD_GNSS_TRUTH"]
        period, offset = plant.params.dt_us, assembly.PLANT_OFFSET_US
    elif name == ACD_NODE:
        ctrl = AcdDevice(spec, scenario.seed, _serial_kind(spec))
        outside = ACD_NODE in scenario.nodes and scenario.nodes[ACD_NODE].external   # a device in its place
        if assembly.building_for_realtime() and not outside:   # its line and its radio open now, not in its
            ctrl.open()                                          # first cycle
        rx_msgs = ["RADIO_LEADER_POS", "RADIO_LEADER_INFO", "RADIO_SIGNAL", "ACD_GNSS_TRUTH"]
        tx_msgs = ["ACD_BRAKE_REQ", "ACD_STATUS"]
        period, offset = ctrl.acd.p.cycle_us, ACD_OFFSET_US
    else:
        return None
    binding = Binding.build(db, name, ctrl.inputs, ctrl.outputs, rx_msgs, tx_msgs, dbc_name)
    node = Node(name, ctrl, binding, codec, db, period_us=period, offset_us=offset,
                safe_outputs=assembly.safe_outputs(ctrl))
    if isinstance(ctrl, AcdDevice):
        node.stats.extra["gps_line"] = ctrl.report        # lands in RunOutcome.node_stats and run.json
    elif ctrl.gps is not None:
        node.stats.extra["gps_line"] = ctrl.gps.report    # the external ACD's line, as the plant wrote it
    return node


def bcu_messages(scenario: Scenario, rx: list[str], tx: list[str]) -> None:
    """The BCU receives the ACD's brake requests."""
    rx.append("ACD_BRAKE_REQ")


def bcu_stages(scenario: Scenario, run: RunParams, sources: list[DemandSource],
               followers: list[Follower]) -> None:
    """The BCU obeys the ACD's brake requests (seed 002 steps 10-12), up to its full service step."""
    sources.append(AcdBrakeRequest(AcdRequestParams(full_service_mps2=run.bcu.step_decel_mps2[-1])))
