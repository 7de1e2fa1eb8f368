"""The control centre Cvc of seed 002 (§IV: controller Cvc, transmitter Rvc, database DB, coordination
algorithms ALG; §V steps 3–6) as a TCP service: asyncio, backed by an SQLite file.

- Step 3: trains report latitude, longitude, speed, route section and length (plus, optionally, their
  heading: it tells the running direction on a section).  Every report is committed to the database
  before it is acknowledged; the client keeps a report until its acknowledgement and sends it again
  after a reconnection or a timeout, and the database ignores a report it already has — so a restart
  of the control centre (even a kill) loses no report.
- Steps 4–5: on each route section, the trains are ordered along the running direction
  (firmware_py.acd.pair_on_sections); each train is told its leader's and its follower's id.
- Step 6 (in the paper train to train; here through the centre): every report of a leader is relayed
  to its follower, and a train that gets a new leader receives the leader's latest report at once.
- The radio link Ri–Rvc (GPRS in §IX) has injectable latency and loss, per direction (`LinkConfig`),
  applied to every message and counted (`LinkStats`).  Messages keep their order.

Protocol — line-delimited JSON: one UTF-8 JSON object per line, "\\n"-terminated, at most 64 KiB.

centre → train, first line of every connection
    {"type": "challenge", "nonce": "5f0e…"}           32 hex digits, fresh for each connection
train → centre
    {"type": "hello", "train": "U2", "nonce": "5f0e…", "mac": "…"}
                                                        on connecting: the centre answers with "pair"
    {"type": "report", "train": "U2", "session": "9f1c…", "seq": 0, "t": 12.5, "lat": 56.95,
     "lon": 24.105, "speed": 12.5, "section": 7, "length": 180.0, "heading": 63.0, "mac": "…"}
        session: any string the client picks once (a uuid); seq: 0, 1, 2… within the session; t: train
        time of the fix [s] or null; lat/lon: WGS-84 [deg] of the locomotive; speed [m/s] ≥ 0;
        section: route section ρ, int 0–65535; length λ [m], 0 < λ ≤ 6553.5 (the DBC's ranges);
        heading [deg clockwise from north, 0–360) or null.
centre → train
    {"type": "ack", "seq": 0, "session": "9f1c…", "leader": "U1", "follower": null, …}
                                                        the report is in the database (duplicates
                                                        too); leader/follower as in "pair"
    {"type": "pair", "train": "U2", "section": 7, "leader": "U1", "follower": null, …}
                                                        step 5: on hello and whenever it changes
    {"type": "leader_report", …the leader's report fields…, "age": 0.021, …}
                                                        step 6: age [s] the report spent at the centre
    {"type": "error", "error": "…"}                    a line the centre cannot use or refuses; the
                                                        link stays up
    (…: with keys, "nonce", "dseq" and "mac" as below)

Authentication (`--keys FILE`; without it the centre is open: it takes any client's word for any
train, says so on stderr when it starts and in its summary, and sends no "nonce"/"dseq"/"mac").
Each train has a secret key of 32 random bytes (the key file: TOML, `[trains]` `U1 = "<64 hex
digits>"`; `--make-keys FILE U1 U2` writes one).  A MAC is HMAC-SHA256 with the train's key, sent as
"mac": 64 lowercase hex digits, over the canonical encoding of every other field of the message:

    json.dumps({k: v for k, v in msg.items() if k != "mac"}, sort_keys=True, separators=(",", ":"),
               ensure_ascii=True, allow_nan=False).encode("ascii")

i.e. the JSON object with its keys sorted by code point, no spaces, non-ASCII characters as \\uXXXX,
integers as integers and every other number as Python's repr(float) writes it: the shortest digits
that read back as the same double, with ".0" on an integral value (12.0, 56.95, 0.021, 1e-05).  The
receiver re-encodes what it parsed, so a sender in C should send each number in that form and MAC the
text it sends.  Example: with the key 000102…1e1f (bytes 0 to 31) the report
{"type":"report","train":"U1","session":"s1","seq":0,"t":12.5,"lat":56.95,"lon":24.105,"speed":12.5,
"section":7,"length":180.0,"heading":63.0} is MAC'd over
{"heading":63.0,"lat":56.95,"length":180.0,"lon":24.105,"section":7,"seq":0,"session":"s1",
"speed":12.5,"t":12.5,"train":"U1","type":"report"}, giving
"mac": "5bdb3dbdcabf1093f711da0a1c08615aa9c99a91fee700d332a46e59dcd24d01".

- hello: MAC'd with its train's key over type, train and the connection's challenge nonce, so a
  client that is not that train cannot be paired or receive anything for it, and a recorded hello
  replayed on another connection is refused (its nonce is not that connection's).  One hello per
  connection.
- report: MAC'd over all its fields, "type", "train", "session" and "seq" among them, so a report
  cannot be moved to another train or replayed under another session; a verbatim replay is a
  duplicate (train, session, seq) that the database ignores.  It must be for the train the
  connection said hello as.
- ack, pair, leader_report: MAC'd with the receiving train's key, and carry the connection's
  challenge "nonce" and "dseq" (0, 1, 2… per connection, gaps where the link lost a message); the
  train drops one whose MAC is missing or wrong, whose nonce is not its connection's or whose dseq is
  not above the last it took (`TrainClient.dropped`, by reason), so a forged or replayed "pair"
  (leader: null) or "leader_report" cannot release a follower's brake.  A relayed leader_report is
  signed by the centre with the follower's key: the follower trusts the centre, not the leader.
- challenge and error are not signed: they change nothing at the train (a forged challenge only
  makes the hello fail, as dropping the line would).

Refused (with keys): a hello whose train has no key ("unknown train"), a hello or report without
"mac" ("no mac") or with a wrong one ("bad mac"), a hello whose nonce is not the connection's unused
challenge ("stale nonce"), a report before an accepted hello ("no hello") or for another train than
the hello's ("wrong train").  Each gets one "error" line naming what was wrong, is neither stored nor
relayed, and is counted by reason (`CentreStats.refused`, in the summary line); the link stays up, as
for a bad line (closing it would not keep a client out: it could reconnect).

The radio link's injected loss spares the first line each way of a connection (the challenge and the
hello: the connection's set-up, which TCP's own handshake would repeat); latency applies to them.

`python -m hil.links.control_centre --db FILE --port 0 [--keys FILE]` (or `railhil control-centre`)
serves until SIGINT or SIGTERM; it prints `listening on HOST:PORT (database FILE)` (`…, keys FILE: N
trains)` with keys) first, and a summary line at the end.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import hashlib
import hmac
import json
import math
import os
import random
import re
import secrets
import signal
import sqlite3
import sys
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from firmware_py.acd import TrainPosition, pair_on_sections
from hil.errors import RailhilError
from hil.resources import read_toml

MAX_LINE = 65_536                 # bytes per protocol line (asyncio StreamReader limit)
SCHEMA_VERSION = 1                # PRAGMA user_version of a control-centre database
SECTION_MAX = 65_535              # DBC RADIO_LEADER_INFO.RouteSection, 16 bit
LENGTH_MAX_M = 6553.5             # DBC RADIO_LEADER_INFO.TrainLength maximum
REPORT_FIELDS = ("train", "session", "seq", "t", "lat", "lon", "speed", "section", "length", "heading")
KEY_BYTES = 32                    # a train's secret HMAC-SHA256 key: 32 random bytes (the hash's block size
#                                   is 64; RFC 2104 §3 asks for at least the output length, 32)
NONCE_BYTES = 16                  # a connection's challenge: 16 random bytes, 32 hex digits
TRANSPORT_FIELDS = ("nonce", "dseq", "mac")      # what authentication adds to a centre → train message
_HEX_KEY = re.compile(rf"[0-9a-fA-F]{{{2 * KEY_BYTES}}}")
_BARE_TOML_KEY = re.compile(r"[A-Za-z0-9_-]+")


class ControlCentreError(RailhilError, ValueError):
    """A control-centre option, database file, key file or address that cannot be used."""


# --- authentication -----------------------------------------------------------------------------------

def mac_input(msg: Mapping) -> bytes:
    """What a message's MAC covers: every field but "mac", as JSON with the keys sorted, no spaces,
    ASCII only (the module docstring defines it for a writer in another language).  ValueError for a
    NaN or infinite number."""
    return json.dumps({k: v for k, v in msg.items() if k != "mac"}, sort_keys=True, separators=(",", ":"),
                      ensure_ascii=True, allow_nan=False).encode("ascii")


def mac_of(key: bytes, msg: Mapping) -> str:
    """HMAC-SHA256 of `msg` (mac_input) with `key`, as 64 lowercase hex digits."""
    return hmac.new(key, mac_input(msg), hashlib.sha256).hexdigest()


def signed(key: bytes, msg: Mapping) -> dict:
    """`msg` with its "mac"."""
    return {**msg, "mac": mac_of(key, msg)}


def mac_matches(key: bytes, msg: Mapping) -> bool:
    """Whether `msg` carries the right "mac" for `key` (compared in constant time)."""
    mac = msg.get("mac")
    return isinstance(mac, str) and hmac.compare_digest(mac_of(key, msg).encode(), mac.encode())


def _train_name_error(name: object) -> str | None:
    if isinstance(name, str) and 0 < len(name) <= 64:
        return None
    return f"train name {str(name)[:70]!r}: expected a string of 1-64 chars"


def read_keys(path: str | Path, named_by: str = "--keys") -> dict[str, bytes]:
    """Train -> secret key, from a key file: TOML, a `[trains]` table of `TRAIN = "<64 hex digits>"`.
    A missing, unreadable or malformed file, or a key that is not 32 bytes, is one ControlCentreError
    line naming the file (and who named it: `named_by`) and the key."""
    path = Path(path)
    where = f"control-centre key file {path} (from {named_by})"
    data = read_toml(path, ControlCentreError, where,
                     "no such file (railhil control-centre --make-keys FILE TRAIN... writes one)")
    unknown = sorted(set(data) - {"trains"})
    if unknown:
        raise ControlCentreError(f"{where}: unknown entry {unknown[0]!r}; expected a [trains] table of "
                                 'TRAIN = "<64 hex digits>"')
    trains = data.get("trains")
    if not isinstance(trains, dict) or not trains:
        raise ControlCentreError(f"{where}: expected a [trains] table of TRAIN = \"<64 hex digits>\" "
                                 "with at least one train")
    out = {}
    for name, text in trains.items():
        if (problem := _train_name_error(name)) is not None:
            raise ControlCentreError(f"{where}: trains: {problem}")
        if not (isinstance(text, str) and _HEX_KEY.fullmatch(text.strip())):
            shown = f"{len(text.strip())} characters" if isinstance(text, str) else type(text).__name__
            raise ControlCentreError(f"{where}: trains.{name}: expected a key of {KEY_BYTES} bytes as "
                                     f"{2 * KEY_BYTES} hex digits, got {shown}")
        out[name] = bytes.fromhex(text.strip())
    return out


def make_keys(path: str | Path, trains: list[str]) -> dict[str, bytes]:
    """Write a new key file at `path` (mode 0600; an existing file is never overwritten: trains hold its
    keys) with a fresh random key (`secrets`) for each train.  Returns the keys."""
    path = Path(path)
    if not trains:
        raise ControlCentreError(f"--make-keys {path}: name the trains after the file, e.g. "
                                 f"--make-keys {path} U1 U2")
    for name in trains:
        if (problem := _train_name_error(name)) is not None:
            raise ControlCentreError(f"--make-keys {path}: {problem}")
    if len(set(trains)) != len(trains):
        twice = next(t for t in trains if trains.count(t) > 1)
        raise ControlCentreError(f"--make-keys {path}: train {twice!r} named twice")
    keys = {name: secrets.token_bytes(KEY_BYTES) for name in trains}
    lines = ["# railhil control-centre keys: a secret HMAC-SHA256 key per train (32 random bytes, hex).",
             "# Give each train's device its own key only; keep this file private.", "", "[trains]"]
    lines += [f"{name if _BARE_TOML_KEY.fullmatch(name) else json.dumps(name)} = \"{key.hex()}\""
              for name, key in keys.items()]
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        raise ControlCentreError(f"--make-keys {path}: exists; not overwritten (trains may hold its keys): "
                                 "remove it first or name a new file") from None
    except OSError as exc:
        raise ControlCentreError(f"--make-keys {path}: cannot create it ({exc.strerror or exc})") from None
    with os.fdopen(fd, "w", encoding="ascii") as f:
        f.write("\n".join(lines) + "\n")
    return keys


class _Refused(Exception):
    """A hello or report the centre does not take from this connection; `reason` is its counter."""

    def __init__(self, reason: str, text: str) -> None:
        super().__init__(text)
        self.reason = reason


# --- the radio link -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class LinkConfig:
    """Injected radio-link faults, each direction alike: every message is lost with probability `loss`
    [0, 1) or delivered `latency_s` [s] after it was sent.  `seed` seeds the loss draws (Python's
    Mersenne Twister)."""

    latency_s: float = 0.0
    loss: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.latency_s, int | float) and math.isfinite(self.latency_s)
                and 0.0 <= self.latency_s <= 60.0):
            raise ControlCentreError(f"LinkConfig.latency_s: expected 0 to 60 s, got {self.latency_s!r}")
        if not (isinstance(self.loss, int | float) and 0.0 <= self.loss < 1.0):
            raise ControlCentreError(f"LinkConfig.loss: expected a probability in [0, 1), got {self.loss!r}")


@dataclass
class LinkStats:
    """What one direction of the radio link did: messages offered, lost, delivered, and the delay
    applied to the delivered ones [s] (from arrival at the link to hand-over)."""

    offered: int = 0
    lost: int = 0
    delivered: int = 0
    delay_sum_s: float = 0.0
    delay_min_s: float = math.inf
    delay_max_s: float = 0.0

    def record_delay(self, delay_s: float) -> None:
        self.delivered += 1
        self.delay_sum_s += delay_s
        self.delay_min_s = min(self.delay_min_s, delay_s)
        self.delay_max_s = max(self.delay_max_s, delay_s)

    def summary(self) -> str:
        mean = self.delay_sum_s / self.delivered * 1e3 if self.delivered else 0.0
        return (f"{self.offered} offered, {self.lost} lost, {self.delivered} delivered, "
                f"mean delay {mean:.1f} ms")


class _Direction:
    """One direction of the link: draws losses, stamps delivery times, delivers in order."""

    def __init__(self, cfg: LinkConfig, rng: random.Random, stats: LinkStats) -> None:
        self.cfg, self.rng, self.stats = cfg, rng, stats
        self.queue: asyncio.Queue[tuple[float, float, bytes]] = asyncio.Queue()

    def offer(self, line: bytes, lossless: bool = False) -> None:
        """Queue `line`; lost with probability `loss` unless `lossless` (a connection's first line)."""
        self.stats.offered += 1
        if not lossless and self.cfg.loss > 0.0 and self.rng.random() < self.cfg.loss:
            self.stats.lost += 1
            return
        now = asyncio.get_running_loop().time()
        self.queue.put_nowait((now, now + self.cfg.latency_s, line))

    async def deliver(self, handler: Callable[[bytes], object]) -> None:
        loop = asyncio.get_running_loop()
        while True:
            arrived, due, line = await self.queue.get()
            wait = due - loop.time()
            if wait > 0.0:
                await asyncio.sleep(wait)       # the injected latency itself
            self.stats.record_delay(loop.time() - arrived)
            result = handler(line)
            if asyncio.iscoroutine(result):
                await result


# --- the database -------------------------------------------------------------------------------------

def open_database(path: str | Path) -> sqlite3.Connection:
    """The control centre's SQLite database at `path`, created if missing (WAL journal, full sync: a
    committed report survives a crash of the process)."""
    path = Path(path)
    if path.is_dir():
        raise ControlCentreError(f"--db {path}: is a directory; expected an SQLite file")
    if not path.parent.is_dir():
        raise ControlCentreError(f"--db {path}: folder {path.parent} does not exist")
    try:
        db = sqlite3.connect(path, isolation_level=None)
        version = db.execute("PRAGMA user_version").fetchone()[0]
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if version not in (0, SCHEMA_VERSION) or (version == 0 and tables):
            db.close()
            raise ControlCentreError(f"--db {path}: an SQLite database, but not a railhil control-centre "
                                     f"one (schema version {version}, tables {sorted(tables)})")
        db.execute("PRAGMA journal_mode = WAL")
        db.execute("PRAGMA synchronous = FULL")
        db.execute("""CREATE TABLE IF NOT EXISTS reports (
                          train TEXT NOT NULL, session TEXT NOT NULL, seq INTEGER NOT NULL,
                          received_at REAL NOT NULL, t REAL, lat REAL NOT NULL, lon REAL NOT NULL,
                          speed REAL NOT NULL, section INTEGER NOT NULL, length REAL NOT NULL,
                          heading REAL, PRIMARY KEY (train, session, seq))""")
        db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
    except sqlite3.DatabaseError as exc:
        raise ControlCentreError(f"--db {path}: cannot use it as an SQLite database ({exc})") from None
    return db


def stored_reports(path: str | Path) -> list[dict]:
    """Every report in a control-centre database, in the order received (for tests and tools)."""
    db = open_database(path)
    try:
        cur = db.execute(f"SELECT {', '.join(REPORT_FIELDS)}, received_at FROM reports ORDER BY rowid")
        return [dict(zip((*REPORT_FIELDS, "received_at"), row, strict=True)) for row in cur]
    finally:
        db.close()


def _check_report(msg: dict) -> dict:
    """The report's fields, checked; ValueError naming the field and what was expected."""
    def need(ok: bool, name: str, what: str) -> None:
        if not ok:
            raise ValueError(f"report field {name!r}: expected {what}, got {msg.get(name)!r}")

    def real(name: str) -> bool:
        v = msg.get(name)
        return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)

    need(isinstance(msg.get("train"), str) and 0 < len(msg["train"]) <= 64, "train", "a string of 1-64 chars")
    need(isinstance(msg.get("session"), str) and 0 < len(msg["session"]) <= 64, "session",
         "a string of 1-64 chars")
    need(isinstance(msg.get("seq"), int) and not isinstance(msg["seq"], bool) and msg["seq"] >= 0, "seq",
         "an int >= 0")
    need(real("lat") and -90.0 <= msg["lat"] <= 90.0, "lat", "a latitude in [-90, 90] deg")
    need(real("lon") and -180.0 <= msg["lon"] <= 180.0, "lon", "a longitude in [-180, 180] deg")
    need(real("speed") and msg["speed"] >= 0.0, "speed", "a speed >= 0 m/s")
    need(isinstance(msg.get("section"), int) and not isinstance(msg["section"], bool)
         and 0 <= msg["section"] <= SECTION_MAX, "section", f"an int in [0, {SECTION_MAX}]")
    need(real("length") and 0.0 < msg["length"] <= LENGTH_MAX_M, "length",
         f"a length in (0, {LENGTH_MAX_M}] m")
    need(msg.get("heading") is None or (real("heading") and 0.0 <= msg["heading"] < 360.0), "heading",
         "null or a heading in [0, 360) deg")
    need(msg.get("t") is None or real("t"), "t", "null or a time in s")
    return {k: msg.get(k) for k in REPORT_FIELDS}


# --- the server ---------------------------------------------------------------------------------------

@dataclass
class CentreStats:
    """Counters of one control-centre run."""

    reports_stored: int = 0       # new reports committed
    duplicates: int = 0           # reports the database already had (resent by a client)
    relayed: int = 0              # leader reports sent to a follower
    pair_messages: int = 0
    bad_lines: int = 0
    connections: int = 0
    keys: int | None = None       # trains with a key; None: open, nothing authenticated
    refused: dict[str, int] = field(default_factory=dict)   # reason -> hellos and reports refused
    uplink: LinkStats = field(default_factory=LinkStats)
    downlink: LinkStats = field(default_factory=LinkStats)

    def summary(self) -> str:
        if self.keys is None:
            auth = "NOT authenticated (no keys): any client's word taken for any train"
        else:
            auth = f"authenticated (keys of {self.keys} trains), {sum(self.refused.values())} refused"
            if self.refused:
                auth += " (" + ", ".join(f"{n} {why}" for why, n in sorted(self.refused.items())) + ")"
        return (f"{self.reports_stored} reports stored, {self.duplicates} duplicates, "
                f"{self.relayed} relayed, {self.bad_lines} bad lines; {auth}; "
                f"uplink {self.uplink.summary()}; downlink {self.downlink.summary()}")


class _Connection:
    def __init__(self, centre: ControlCentre, reader: asyncio.StreamReader,
                 writer: asyncio.StreamWriter) -> None:
        self.centre, self.reader, self.writer = centre, reader, writer
        self.train: str | None = None
        self.nonce = secrets.token_hex(NONCE_BYTES)    # this connection's challenge
        self.nonce_used = False                         # by an accepted hello
        self.dseq = 0                                   # the next signed message's number
        self.up = _Direction(centre.link, centre.rng, centre.stats.uplink)
        self.down = _Direction(centre.link, centre.rng, centre.stats.downlink)

    def send(self, msg: dict, sign: bool = True, lossless: bool = False) -> None:
        """Queue `msg` for the train; with keys and after a hello, signed with its key (+ nonce, dseq)."""
        keys = self.centre.keys
        if sign and keys is not None and self.train is not None:
            msg = signed(keys[self.train], {**msg, "nonce": self.nonce, "dseq": self.dseq})
            self.dseq += 1
        self.down.offer(json.dumps(msg, separators=(",", ":")).encode() + b"\n", lossless)

    def _write(self, line: bytes) -> None:
        if not self.writer.is_closing():
            self.writer.write(line)

    async def run(self) -> None:
        tasks = [asyncio.create_task(self.up.deliver(self.centre._handle_line_of(self))),
                 asyncio.create_task(self.down.deliver(self._write))]
        self.send({"type": "challenge", "nonce": self.nonce}, sign=False, lossless=True)
        first = True
        try:
            while True:
                try:
                    line = await self.reader.readline()
                except ValueError:          # longer than MAX_LINE
                    self.centre.stats.bad_lines += 1
                    self._write(json.dumps({"type": "error", "error": f"line longer than {MAX_LINE} "
                                                                      "bytes; closing"}).encode() + b"\n")
                    break
                if not line:
                    break
                self.up.offer(line, lossless=first)
                first = False
        except (ConnectionError, OSError):
            pass
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            self.centre._drop(self)
            self.writer.close()
            with contextlib.suppress(ConnectionError, OSError):
                await self.writer.wait_closed()


class ControlCentre:
    """The control-centre service.  `await start(host, port)` → (host, port) actually bound (port 0
    picks a free one); `await stop()`.  Reports of trains not heard from for `forget_after_s` [s] are
    kept in the database but no longer paired.  `keys` (train -> its 32-byte key, read_keys): hellos
    and reports are authenticated and what the centre sends is signed; None: open, as before keys."""

    def __init__(self, db_path: str | Path, link: LinkConfig | None = None,
                 forget_after_s: float = 60.0, keys: Mapping[str, bytes] | None = None) -> None:
        if not (isinstance(forget_after_s, int | float) and forget_after_s > 0):
            raise ControlCentreError(f"--forget-after-s: expected a time > 0 s, got {forget_after_s!r}")
        if keys is not None:
            if not keys:
                raise ControlCentreError("keys: no train's key; give at least one, or None to run open")
            short = sorted(t for t, k in keys.items() if not (isinstance(k, bytes) and len(k) == KEY_BYTES))
            if short:
                raise ControlCentreError(f"keys: {short[0]}'s key is not {KEY_BYTES} bytes")
        self.keys = None if keys is None else dict(keys)
        self.db_path = Path(db_path)
        self.link = link or LinkConfig()
        self.rng = random.Random(self.link.seed)
        self.forget_after_s = float(forget_after_s)
        self.stats = CentreStats(keys=None if self.keys is None else len(self.keys))
        self.db = open_database(self.db_path)
        self.latest: dict[str, dict] = {}       # train -> its latest report (+ received_at)
        cur = self.db.execute(f"SELECT {', '.join(REPORT_FIELDS)}, received_at FROM reports WHERE rowid IN "
                              "(SELECT max(rowid) FROM reports GROUP BY train)")
        for row in cur:
            rep = dict(zip((*REPORT_FIELDS, "received_at"), row, strict=True))
            self.latest[rep["train"]] = rep
        self.pairs: dict[str, tuple[str | None, str | None]] = {}
        self.conns: dict[str, _Connection] = {}
        self._all: dict[_Connection, asyncio.Task] = {}
        self._server: asyncio.Server | None = None
        self._repair()

    async def start(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        try:
            self._server = await asyncio.start_server(self._accept, host, port, limit=MAX_LINE)
        except OSError as exc:
            raise ControlCentreError(f"--host {host} --port {port}: cannot listen there "
                                     f"({exc.strerror or exc})") from None
        addr = self._server.sockets[0].getsockname()
        return addr[0], addr[1]

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
        tasks = list(self._all.values())
        for conn in list(self._all):
            conn.writer.close()
        if tasks:                                 # each connection's task cleans up after itself
            await asyncio.wait(tasks, timeout=5.0)
        if self._server is not None:
            await self._server.wait_closed()
        self.db.close()

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        conn = _Connection(self, reader, writer)
        task = asyncio.current_task()
        assert task is not None
        self._all[conn] = task
        self.stats.connections += 1
        await conn.run()

    def _drop(self, conn: _Connection) -> None:
        self._all.pop(conn, None)
        if conn.train is not None and self.conns.get(conn.train) is conn:
            del self.conns[conn.train]

    def _handle_line_of(self, conn: _Connection) -> Callable[[bytes], None]:
        return lambda line: self._handle(conn, line)

    def _handle(self, conn: _Connection, line: bytes) -> None:
        try:
            msg = json.loads(line)
            if not isinstance(msg, dict):
                raise ValueError("expected a JSON object")
            kind = msg.get("type")
            if kind == "hello":
                train = msg.get("train")
                if not (isinstance(train, str) and 0 < len(train) <= 64):
                    raise ValueError(f"hello field 'train': expected a string of 1-64 chars, got {train!r}")
                if self.keys is not None:
                    self._check_hello(conn, msg)
                self._attach(conn, train)
                self._send_pair(train)
            elif kind == "report":
                if self.keys is not None:
                    self._check_signed_report(conn, msg)
                self._report(conn, _check_report(msg))
            else:
                raise ValueError(f"field 'type': expected 'hello' or 'report', got {kind!r}")
        except _Refused as exc:
            self.stats.refused[exc.reason] = self.stats.refused.get(exc.reason, 0) + 1
            conn.send({"type": "error", "error": str(exc)}, sign=False)
        except ValueError as exc:                  # json.JSONDecodeError is a ValueError
            self.stats.bad_lines += 1
            conn.send({"type": "error", "error": str(exc)}, sign=False)

    def _check_hello(self, conn: _Connection, msg: dict) -> None:
        """_Refused unless the hello is signed with its train's key over this connection's challenge."""
        assert self.keys is not None
        train = msg["train"]
        key = self.keys.get(train)
        if key is None:
            raise _Refused("unknown train", f"hello as {train!r} refused (unknown train): the centre has no "
                                            f"key for {train!r}")
        if "mac" not in msg:
            raise _Refused("no mac", f"hello as {train!r} refused (no mac): this centre authenticates; sign "
                                     "the hello with the train's key")
        if not mac_matches(key, msg):
            raise _Refused("bad mac", f"hello as {train!r} refused (bad mac): 'mac' is not {train!r}'s")
        if conn.nonce_used or msg.get("nonce") != conn.nonce:
            raise _Refused("stale nonce", f"hello as {train!r} refused (stale nonce): 'nonce' is not this "
                                          "connection's unused challenge (a replayed or second hello)")
        conn.nonce_used = True

    def _check_signed_report(self, conn: _Connection, msg: dict) -> None:
        """_Refused unless the report is for the connection's train and signed with its key."""
        assert self.keys is not None
        train = msg.get("train")
        shown = repr(train)[:70]
        if conn.train is None:
            raise _Refused("no hello", f"report of {shown} refused (no hello): no accepted hello on this "
                                       "connection")
        if train != conn.train:
            raise _Refused("wrong train", f"report of {shown} refused (wrong train): this connection said "
                                          f"hello as {conn.train!r}")
        if "mac" not in msg:
            raise _Refused("no mac", f"report of {shown} refused (no mac): this centre authenticates; sign "
                                     "each report with the train's key")
        if not mac_matches(self.keys[conn.train], msg):
            raise _Refused("bad mac", f"report of {shown} refused (bad mac): 'mac' is not {conn.train!r}'s")

    def _attach(self, conn: _Connection, train: str) -> None:
        conn.train = train
        self.conns[train] = conn

    def _report(self, conn: _Connection, rep: dict) -> None:
        if conn.train != rep["train"]:
            self._attach(conn, rep["train"])
        rep["received_at"] = time.time()
        cur = self.db.execute(f"INSERT OR IGNORE INTO reports ({', '.join(REPORT_FIELDS)}, received_at) "
                              f"VALUES ({', '.join('?' * (len(REPORT_FIELDS) + 1))})",
                              [rep[k] for k in REPORT_FIELDS] + [rep["received_at"]])
        new = cur.rowcount == 1                    # autocommit: the row is on disk now
        if not new:
            self.stats.duplicates += 1
            self._ack(conn, rep)
            return
        self.stats.reports_stored += 1
        old = self.latest.get(rep["train"])
        if old is not None and old["session"] == rep["session"] and old["seq"] > rep["seq"]:
            self._ack(conn, rep)                   # an older report resent late: not the latest
            return
        self.latest[rep["train"]] = rep
        told = self._repair()
        follower = self.pairs.get(rep["train"], (None, None))[1]
        self._ack(conn, rep)
        if follower is not None and follower not in told:   # (a train told its new pair got it already)
            self._relay(rep["train"], follower)

    def _ack(self, conn: _Connection, rep: dict) -> None:
        """The acknowledgement, with the train's current pair: a lost "pair" message heals itself."""
        leader, follower = self.pairs.get(rep["train"], (None, None))
        conn.send({"type": "ack", "session": rep["session"], "seq": rep["seq"], "leader": leader,
                   "follower": follower})

    def _repair(self) -> set[str]:
        """Steps 4–5: pair the trains heard from lately; tell those whose pair changed (with their new
        leader's latest report).  Returns the trains told."""
        cutoff = time.time() - self.forget_after_s
        current = [TrainPosition(r["train"], r["lat"], r["lon"], r["section"], r["heading"])
                   for r in self.latest.values() if r["received_at"] >= cutoff]
        new = pair_on_sections(current)
        changed = {t for t in set(new) | set(self.pairs) if new.get(t, (None, None)) !=
                   self.pairs.get(t, (None, None))}
        self.pairs = new
        for train in sorted(changed):
            self._send_pair(train)
        return changed

    def _send_pair(self, train: str) -> None:
        conn = self.conns.get(train)
        if conn is None:
            return
        leader, follower = self.pairs.get(train, (None, None))
        rep = self.latest.get(train)
        conn.send({"type": "pair", "train": train, "section": None if rep is None else rep["section"],
                   "leader": leader, "follower": follower})
        self.stats.pair_messages += 1
        if leader is not None and leader in self.latest:
            self._relay(leader, train)

    def _relay(self, leader: str, follower: str) -> None:
        conn = self.conns.get(follower)
        rep = self.latest.get(leader)
        if conn is None or rep is None:
            return
        msg = {k: rep[k] for k in REPORT_FIELDS}
        conn.send({"type": "leader_report", **msg, "age": max(time.time() - rep["received_at"], 0.0)})
        self.stats.relayed += 1


# --- the train's client -------------------------------------------------------------------------------

class TrainClient:
    """A train's side of the link (its radio Ri): reports with acknowledgement and resending, the pair
    (leader, follower) it was told, and the leader's reports relayed to it.

    `await start()` connects in the background and keeps reconnecting (back-off from 50 ms to 1 s) until
    `await close()`.  `report(...)` numbers a report, queues it and sends it when connected; it stays
    queued until acknowledged and is sent again after a reconnection or `resend_after_s` [s] without
    acknowledgement.  `await wait_for(predicate, timeout)` waits until predicate(self) holds.

    With `key` (the train's 32 bytes, as read_keys gives them) it answers each connection's challenge
    with a signed hello, signs its reports, and takes an ack, pair or leader_report only when signed
    with its key for this connection (nonce) and newer than the last (dseq); it drops any other and
    counts it in `dropped` by reason ("no mac", "bad mac", "stale nonce", "replayed").  Without a key
    it speaks the open protocol: a centre with keys refuses it."""

    def __init__(self, train: str, host: str, port: int, resend_after_s: float = 0.5,
                 key: bytes | None = None) -> None:
        if key is not None and not (isinstance(key, bytes) and len(key) == KEY_BYTES):
            raise ControlCentreError(f"TrainClient {train!r}: key: expected {KEY_BYTES} bytes, got "
                                     f"{len(key) if isinstance(key, bytes) else type(key).__name__}")
        self.train, self.host, self.port = train, host, port
        self.key = key
        self.resend_after_s = resend_after_s
        self.session = uuid.uuid4().hex
        self.next_seq = 0
        self.unacked: OrderedDict[int, tuple[bytes, float]] = OrderedDict()   # seq -> (line, last sent)
        self.acked: set[int] = set()
        self.rtt_s: dict[int, float] = {}        # seq -> first send to acknowledgement [s]
        self._first_sent: dict[int, float] = {}
        self.leader: str | None = None
        self.follower: str | None = None
        self.leader_reports: list[dict] = []
        self.errors: list[str] = []
        self.dropped: dict[str, int] = {}      # reason -> messages from the centre not taken
        self.connects = 0
        self.sent_lines = 0
        self.connected = False
        self.nonce: str | None = None           # this connection's challenge
        self._dseq = -1                         # the last signed message taken on this connection
        self._ready = False                     # hello sent on this connection: reports may follow
        self._writer: asyncio.StreamWriter | None = None
        self._cond: asyncio.Condition | None = None
        self._task: asyncio.Task | None = None
        self._closing = False

    async def start(self) -> None:
        self._cond = asyncio.Condition()
        self._task = asyncio.create_task(self._run())

    async def close(self) -> None:
        self._closing = True
        if self._writer is not None:
            self._writer.close()
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)

    def report(self, lat: float, lon: float, speed: float, section: int, length: float,
               heading: float | None = None, t: float | None = None) -> int:
        """Queue one report (step 3): position [deg] of the locomotive, speed [m/s], route section,
        length [m], heading [deg] or None, train time [s] or None.  Returns its sequence number."""
        seq = self.next_seq
        self.next_seq += 1
        msg = {"type": "report", "train": self.train, "session": self.session, "seq": seq, "t": t,
               "lat": lat, "lon": lon, "speed": speed, "section": section, "length": length,
               "heading": heading}
        if self.key is not None:
            msg = signed(self.key, msg)          # once: a resend is the same line
        self.unacked[seq] = (json.dumps(msg, separators=(",", ":")).encode() + b"\n", -math.inf)
        self._flush()
        return seq

    async def wait_for(self, predicate: Callable[[TrainClient], bool], timeout: float) -> None:
        """Wait until `predicate(self)` holds; TimeoutError after `timeout` [s]."""
        assert self._cond is not None, "start() first"
        async with self._cond:
            await asyncio.wait_for(self._cond.wait_for(lambda: predicate(self)), timeout)

    def _flush(self, force: bool = False) -> None:
        if self._writer is None or self._writer.is_closing() or not self._ready:
            return
        now = time.monotonic()
        for seq, (line, last) in self.unacked.items():
            if force or now - last >= self.resend_after_s:
                self._writer.write(line)
                self.sent_lines += 1
                self._first_sent.setdefault(seq, now)
                self.unacked[seq] = (line, now)

    async def _notify(self) -> None:
        assert self._cond is not None
        async with self._cond:
            self._cond.notify_all()

    async def _run(self) -> None:
        backoff = 0.05
        while not self._closing:
            try:
                reader, writer = await asyncio.open_connection(self.host, self.port, limit=MAX_LINE)
            except OSError:
                await asyncio.sleep(backoff)          # reconnection back-off, not synchronisation
                backoff = min(backoff * 2, 1.0)
                continue
            backoff = 0.05
            self._writer, self.connected = writer, True
            self.connects += 1
            self.nonce, self._dseq, self._ready = None, -1, False
            if self.key is None:                  # open protocol: hello at once; with a key, on the challenge
                self._hello()
            await self._notify()
            resender = asyncio.create_task(self._resend_loop())
            try:
                while line := await reader.readline():
                    self._receive(line)
                    await self._notify()
            except (ConnectionError, OSError, ValueError):
                pass
            finally:
                resender.cancel()
                self._writer, self.connected, self._ready = None, False, False
                writer.close()
                with contextlib.suppress(ConnectionError, OSError):
                    await writer.wait_closed()
                await self._notify()

    async def _resend_loop(self) -> None:
        while True:
            await asyncio.sleep(self.resend_after_s / 2)   # the resend timer
            self._flush()

    def _hello(self) -> None:
        """Say hello on this connection (signed over its challenge with a key), then send what waits."""
        assert self._writer is not None
        msg: dict = {"type": "hello", "train": self.train}
        if self.key is not None:
            msg = signed(self.key, {**msg, "nonce": self.nonce})
        self._writer.write(json.dumps(msg, separators=(",", ":")).encode() + b"\n")
        self._ready = True
        self._flush(force=True)

    def _drop(self, msg: dict) -> str | None:
        """Why a message from the centre is not taken under this train's key, or None to take it."""
        assert self.key is not None
        if "mac" not in msg:
            return "no mac"
        if not mac_matches(self.key, msg):
            return "bad mac"
        if self.nonce is None or msg.get("nonce") != self.nonce:
            return "stale nonce"
        dseq = msg.get("dseq")
        if not isinstance(dseq, int) or isinstance(dseq, bool) or dseq <= self._dseq:
            return "replayed"
        self._dseq = dseq
        return None

    def _receive(self, line: bytes) -> None:
        msg = json.loads(line)
        if not isinstance(msg, dict):
            self.dropped["bad line"] = self.dropped.get("bad line", 0) + 1
            return
        kind = msg.get("type")
        if kind == "challenge":
            if self.nonce is None and isinstance(msg.get("nonce"), str):
                self.nonce = msg["nonce"]
                if self.key is not None and self._writer is not None:
                    self._hello()
            return
        if kind == "error":
            self.errors.append(str(msg.get("error")))
            return
        if self.key is not None and kind in ("ack", "pair", "leader_report"):
            try:
                why = self._drop(msg)
            except ValueError:                    # a NaN or infinite number: not what the centre signs
                why = "bad mac"
            if why is not None:
                self.dropped[why] = self.dropped.get(why, 0) + 1
                return
            msg = {k: v for k, v in msg.items() if k not in TRANSPORT_FIELDS}
        if kind == "ack" and msg.get("session") == self.session:
            seq = msg["seq"]
            if self.unacked.pop(seq, None) is not None:
                self.acked.add(seq)
                self.rtt_s[seq] = time.monotonic() - self._first_sent.get(seq, time.monotonic())
            self.leader, self.follower = msg.get("leader"), msg.get("follower")
        elif kind == "pair":
            self.leader, self.follower = msg.get("leader"), msg.get("follower")
        elif kind == "leader_report":
            self.leader_reports.append(msg)


# --- serving from the command line -------------------------------------------------------------------

def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of `railhil control-centre` and `python -m hil.links.control_centre`."""
    p.add_argument("--db", type=Path, metavar="FILE",
                   help="SQLite database file of the reports (created if missing; reused after a restart); "
                        "required to serve")
    p.add_argument("--keys", type=Path, metavar="FILE",
                   help='the trains\' secret keys, TOML: [trains] U1 = "<64 hex digits>"; hellos and reports '
                        "are authenticated (HMAC-SHA256) and refused without the right MAC. Without it the "
                        "centre takes any client's word for any train (a warning says so)")
    p.add_argument("--make-keys", nargs="+", metavar=("FILE", "TRAIN"),
                   help="write a fresh random key for each TRAIN to the new file FILE (mode 0600; never "
                        "overwritten) and exit; give it to --keys, and each train its own key")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=7007, metavar="N",
                   help="TCP port to listen on; 0 picks a free one (default 7007)")
    p.add_argument("--latency-ms", type=float, default=0.0, metavar="MS",
                   help="injected radio latency per message and direction [ms] (default 0)")
    p.add_argument("--loss", type=float, default=0.0, metavar="P",
                   help="injected radio loss: probability in [0, 1) that a message is lost (default 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the loss draws (default 0)")
    p.add_argument("--forget-after-s", type=float, default=60.0, metavar="S",
                   help="trains not heard from for S seconds are no longer paired (default 60)")


async def _serve(args: argparse.Namespace) -> CentreStats:
    if args.db is None:
        raise ControlCentreError("--db FILE: required to serve (or --make-keys FILE TRAIN... to write a key "
                                 "file)")
    if not 0 <= args.port <= 65535:
        raise ControlCentreError(f"--port {args.port}: expected 0 to 65535 (0 picks a free port)")
    if not (math.isfinite(args.latency_ms) and 0.0 <= args.latency_ms <= 60_000.0):
        raise ControlCentreError(f"--latency-ms {args.latency_ms}: expected 0 to 60000 ms")
    if not 0.0 <= args.loss < 1.0:
        raise ControlCentreError(f"--loss {args.loss}: expected a probability in [0, 1)")
    link = LinkConfig(latency_s=args.latency_ms / 1e3, loss=args.loss, seed=args.seed)
    keys = None if args.keys is None else read_keys(args.keys, "--keys")
    centre = ControlCentre(args.db, link, args.forget_after_s, keys)
    try:
        host, port = await centre.start(args.host, args.port)
    except ControlCentreError:
        centre.db.close()
        raise
    if keys is None:
        print("warning: no --keys: reports are not authenticated; any client can report any train's position",
              file=sys.stderr, flush=True)
        print(f"listening on {host}:{port} (database {args.db})", flush=True)
    else:
        print(f"listening on {host}:{port} (database {args.db}, keys {args.keys}: {len(keys)} trains)",
              flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await stop.wait()
    finally:
        await centre.stop()
    return centre.stats


def serve(args: argparse.Namespace) -> int:
    """Serve until SIGINT/SIGTERM, then print the run's counters; or, with --make-keys, write a key file
    and return.  Exit code 0."""
    if args.make_keys is not None:
        path, trains = Path(args.make_keys[0]), args.make_keys[1:]
        make_keys(path, trains)
        print(f"wrote keys of {len(trains)} trains ({', '.join(trains)}), mode 0600: {path}", flush=True)
        return 0
    stats = asyncio.run(_serve(args))
    print(f"stopped: {stats.summary()}", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m hil.links.control_centre`: errors print one line and exit 2, as `railhil` does."""
    parser = argparse.ArgumentParser(prog="python -m hil.links.control_centre",
                                     description="The control centre of seed 002: trains report, it pairs "
                                                 "follower and leader on a route section and relays.")
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return serve(args)
    except RailhilError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code


if __name__ == "__main__":
    raise SystemExit(main())
