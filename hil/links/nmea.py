"""GPS fixes on a serial line: NMEA 0183 RMC + GGA sentences, and a compact framed binary protocol.

**NMEA 0183** (what seed 002's GPS module sends). Sentences are assembled and checksummed by
pynmeagps (semuconsulting, BSD-3, maintained; chosen over pynmea2, whose last release is 1.19.0 of
January 2023): `NMEAMessage(talker, id, GET, payload=fields).serialize()` writes
``$GPRMC,...*hh<CR><LF>``; the fields are formatted here, in the NMEA 2.3 layout of a u-blox NEO-6
(lat/lon ``ddmm.mmmmm`` = 1.85 cm, time ``hhmmss.ss``, speed in knots). The reader checks each
sentence's checksum with `pynmeagps.calc_checksum` and parses it with `NMEAReader.parse`.

**Binary** (seed 002 §X: "an alternative protocol should be established to avoid flooding the
serial link"): one fix per frame, fixed-point little-endian fields (`BIN_FIX` below), a CRC-16
(CRC-16/IBM-3740 a.k.a. CCITT-FALSE: poly 0x1021, init 0xFFFF, by fastcrc) over them, COBS-encoded
(the `cobs` package; S. Cheshire, M. Baker, "Consistent Overhead Byte Stuffing", IEEE/ACM Trans.
Networking 7 (2) 1999) so that 0x00 never occurs inside a frame, and a 0x00 delimiter before and
after it: garbage between two frames ends at the next frame's leading delimiter, so no good frame is
lost to it. 30 bytes per fix against ~150 for RMC + GGA.

**Stream readers** (`NmeaStreamReader`, `BinaryStreamReader`) take bytes as they come from a port —
partial sentences, CR/LF, noise — and return the fixes they complete. They never raise on any input:
every byte fed ends up, exactly once, in `stats` as accepted, idle (line terminators, frame
delimiters), or rejected for one of `REASONS`, or is still `pending` (an incomplete sentence/frame):
``stats.bytes_in == stats.bytes_ok + stats.bytes_idle + sum(stats.rejected_bytes) + pending``.
Results do not depend on how the bytes are split into chunks.

Units: degrees (heading clockwise from true north), m, m/s; times are UTC (`utc0` is the UTC time of
simulation time 0).
"""

from __future__ import annotations

import math
import re
import struct
from abc import ABC, abstractmethod
from collections import Counter
from dataclasses import dataclass, field
from datetime import UTC, date, datetime, timedelta

import fastcrc
from cobs import cobs
from pynmeagps import GET, VALCKSUM, NMEAMessage, NMEAReader, calc_checksum

from plant_sim.gps import GpsFix

KNOT_MPS = 1852.0 / 3600.0     # international knot [m/s] (1 nmi = 1852 m exactly)
COCOM_SPEED_MPS = 1000.0 * KNOT_MPS  # receivers stop reporting above 1000 kn (COCOM limit): above = bad
COCOM_ALT_M = 18_288.0         # and above 60 000 ft = 18 288 m
MIN_ALT_M = -1_000.0           # below any land (Dead Sea shore −430 m) with margin; chosen
# NMEA 0183 caps a sentence at 82 characters incl. "$" and CR LF, but high-precision receivers exceed it
# (Trimble's GGA with 8-decimal minutes is 87): a "$" with no end within this many bytes is a runaway.
MAX_SENTENCE = 200             # bytes; chosen
DEFAULT_UTC0 = datetime(2024, 1, 1, tzinfo=UTC)  # UTC of sim time 0 unless the scenario says; chosen

#: why input was rejected; the same names for NMEA and binary
REASONS = ("garbage", "truncated", "bad_checksum", "unknown_type", "bad_value")
#: garbage       bytes that are not part of any sentence/frame (NMEA: outside "$...\n"; binary: not COBS)
#: truncated     a sentence cut short (a new "$" before its end, no "*hh" checksum, no end within
#:               MAX_SENTENCE bytes, or the stream closed) / a frame shorter than its type's layout
#: bad_checksum  the NMEA checksum or the frame's CRC-16 does not match
#: unknown_type  well-formed and checksummed, but not RMC/GGA (GSV, VTG, ...) / an unknown frame type
#: bad_value     a field that does not parse, or is non-finite or out of range (|lat| > 90, ...)


@dataclass
class LinkStats:
    """Counters of one stream reader (bytes and events). `accepted` counts fixes by source
    ("RMC", "GGA", "BIN"); `rejected` counts events and `rejected_bytes` their bytes, by reason;
    `seq_gaps` counts binary frames missing by their sequence counter (lost on the line)."""

    bytes_in: int = 0
    bytes_ok: int = 0
    bytes_idle: int = 0
    accepted: Counter = field(default_factory=Counter)
    rejected: Counter = field(default_factory=Counter)
    rejected_bytes: Counter = field(default_factory=Counter)
    seq_gaps: int = 0

    def reject(self, reason: str, nbytes: int, events: int = 1) -> None:
        self.rejected[reason] += events
        self.rejected_bytes[reason] += nbytes

    def accounted(self, pending: int) -> bool:
        """Every byte fed is accepted, idle, rejected or pending."""
        return self.bytes_in == self.bytes_ok + self.bytes_idle + sum(self.rejected_bytes.values()) + pending

    def summary(self) -> str:
        """One line: fixes accepted and rejections by reason, e.g. for a report."""
        acc = ", ".join(f"{k} {v}" for k, v in sorted(self.accepted.items())) or "none"
        rej = ", ".join(f"{r} {self.rejected[r]} ({self.rejected_bytes[r]} B)" for r in REASONS
                        if self.rejected[r]) or "none"
        return f"{self.bytes_in} B in; accepted: {acc}; rejected: {rej}"


@dataclass(frozen=True, slots=True)
class ReceivedFix:
    """A fix as read from the line. Fields a sentence does not carry are NaN (floats) or −1 (ints):
    RMC has no sats/HDOP/altitude, GGA no speed/heading; binary frames carry everything. `valid` is
    RMC status A (mode not N) / GGA quality 1–5 / the binary valid flag."""

    source: str             # "RMC", "GGA" or "BIN"
    talker: str             # NMEA talker ("GP", "GN", ...), "" for binary
    utc: datetime | None    # UTC of the fix; None for a GGA before any RMC gave the date
    tod_s: float            # UTC time of day [s]
    valid: bool
    lat_deg: float
    lon_deg: float
    speed_mps: float
    heading_deg: float
    quality: int            # GGA fix quality (RMC/BIN: 1 valid, 0 not)
    n_sats: int
    hdop: float
    alt_m: float
    seq: int = -1           # binary frame sequence number 0–255, −1 for NMEA

    def sim_time_us(self, utc0: datetime = DEFAULT_UTC0) -> int | None:
        """The fix time as sim time [µs] (its UTC minus `utc0`), None if the date is unknown."""
        if self.utc is None:
            return None
        return (self.utc - utc0) // timedelta(microseconds=1)


def _utc_parts(fix_t_us: int, utc0: datetime, quantum_us: int) -> tuple[date, int]:
    """(UTC date, time of day in units of `quantum_us`) of sim time `fix_t_us`, rounded to the quantum."""
    epoch_us = (utc0 - datetime(1970, 1, 1, tzinfo=UTC)) // timedelta(microseconds=1) + int(fix_t_us)
    q = (epoch_us + quantum_us // 2) // quantum_us
    per_day = 86_400_000_000 // quantum_us
    days, tod = divmod(q, per_day)
    return date(1970, 1, 1) + timedelta(days=days), tod


def _dmm(value_deg: float, deg_digits: int) -> str:
    """|value| as NMEA (d)ddmm.mmmmm, rounded to 1e-5 minute with integer arithmetic (never "60.00000")."""
    q = round(abs(value_deg) * 6_000_000)   # units of 1e-5 minute
    deg, rest = divmod(q, 6_000_000)
    mins, frac = divmod(rest, 100_000)
    return f"{deg:0{deg_digits}d}{mins:02d}.{frac:05d}"


class NmeaEncoder:
    """GpsFix → bytes of NMEA sentences (RMC then GGA, as a u-blox NEO-6 sends them each epoch)."""

    def __init__(self, utc0: datetime = DEFAULT_UTC0, talker: str = "GP",
                 sentences: tuple[str, ...] = ("RMC", "GGA")) -> None:
        self.utc0, self.talker, self.sentences = utc0, talker, sentences

    def rmc(self, fix: GpsFix) -> bytes:
        day, cs = _utc_parts(fix.t_us, self.utc0, 10_000)
        tod = _hhmmss(cs)
        if fix.valid:
            fields = [tod, "A", _dmm(fix.lat_deg, 2), "N" if fix.lat_deg >= 0 else "S",
                      _dmm(fix.lon_deg, 3), "E" if fix.lon_deg >= 0 else "W",
                      f"{fix.speed_mps / KNOT_MPS:.3f}", f"{fix.heading_deg:.2f}", day.strftime("%d%m%y"),
                      "", "", "A"]
        else:
            fields = [tod, "V", "", "", "", "", "", "", day.strftime("%d%m%y"), "", "", "N"]
        return NMEAMessage(self.talker, "RMC", GET, payload=fields).serialize()

    def gga(self, fix: GpsFix) -> bytes:
        _, cs = _utc_parts(fix.t_us, self.utc0, 10_000)
        if fix.valid:
            fields = [_hhmmss(cs), _dmm(fix.lat_deg, 2), "N" if fix.lat_deg >= 0 else "S",
                      _dmm(fix.lon_deg, 3), "E" if fix.lon_deg >= 0 else "W", "1", f"{fix.n_sats:02d}",
                      f"{fix.hdop:.2f}", f"{fix.alt_m:.1f}", "M", "", "", "", ""]
        else:
            fields = [_hhmmss(cs), "", "", "", "", "0", "00", "99.99", "", "", "", "", "", ""]
        return NMEAMessage(self.talker, "GGA", GET, payload=fields).serialize()

    def encode(self, fix: GpsFix) -> bytes:
        """All configured sentences for one fix, each ending in CR LF."""
        return b"".join(self.rmc(fix) if s == "RMC" else self.gga(fix) for s in self.sentences)


def _hhmmss(cs_of_day: int) -> str:
    s, cs = divmod(cs_of_day, 100)
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h:02d}{m:02d}{s:02d}.{cs:02d}"


_CRLF = re.compile(rb"[\r\n]")
_NOT_CRLF = re.compile(rb"[^\r\n]+")
_ADDRESS = re.compile(r"[A-Z]{2}[A-Z0-9]{3}")   # talker (2) + sentence type (3)
_PRINTABLE = re.compile(r"[\x20-\x7e]*")


class _StreamReader(ABC):
    """What both stream readers share: the buffer, the stats, the garbage-run state."""

    def __init__(self) -> None:
        self.stats = LinkStats()
        self._buf = bytearray()
        self._in_garbage = False   # the last byte consumed outside a sentence/frame was garbage

    @property
    def pending(self) -> int:
        """Bytes held for a sentence/frame not complete yet."""
        return len(self._buf)

    def _garbage(self, chunk: bytes | bytearray, idle: re.Pattern, run: re.Pattern) -> None:
        """Account for bytes outside any sentence/frame: `idle` bytes (terminators, delimiters) are
        idle, every maximal `run` of other bytes one garbage event, even when it spans two feeds."""
        if not chunk:
            return
        runs = 0
        nbytes = 0
        for m in run.finditer(chunk):
            nbytes += m.end() - m.start()
            if not (m.start() == 0 and self._in_garbage):   # a run that started in an earlier feed
                runs += 1
        self.stats.bytes_idle += len(chunk) - nbytes
        if nbytes:
            self.stats.reject("garbage", nbytes, runs)
        self._in_garbage = idle.fullmatch(chunk[-1:]) is None

    def feed(self, data: bytes) -> list[ReceivedFix]:
        """Take the next bytes from the line; return the fixes they complete (possibly none)."""
        self.stats.bytes_in += len(data)
        self._buf += data
        out: list[ReceivedFix] = []
        consumed = self._scan(out)
        del self._buf[:consumed]
        return out

    def close(self) -> None:
        """End of stream: an incomplete sentence/frame still held is truncated."""
        if self._buf:
            self.stats.reject("truncated", len(self._buf))
            self._buf.clear()

    @abstractmethod
    def _scan(self, out: list[ReceivedFix]) -> int:
        """Parse what `_buf` holds into `out`; return how many bytes were consumed."""


def _field_float(val) -> float:
    """A numeric field: NaN when empty (not sent); a field sent as "nan"/"inf" is a bad value."""
    if val == "" or val is None:
        return math.nan
    x = float(val)
    if not math.isfinite(x):
        raise ValueError(f"non-finite field {val!r}")
    return x


class NmeaStreamReader(_StreamReader):
    """Bytes from a serial line → fixes from its RMC and GGA sentences; everything else counted."""

    SOURCES = ("RMC", "GGA")

    def __init__(self, max_sentence: int = MAX_SENTENCE) -> None:
        super().__init__()
        self.max_sentence = max_sentence
        self._last_rmc_utc: datetime | None = None

    def _scan(self, out: list[ReceivedFix]) -> int:
        buf, pos, n = self._buf, 0, len(self._buf)
        while pos < n:
            if buf[pos] != 0x24:                      # outside a sentence: up to the next "$"
                j = buf.find(b"$", pos)
                end = n if j < 0 else j
                self._garbage(bytes(buf[pos:end]), _CRLF, _NOT_CRLF)
                pos = end
                continue
            self._in_garbage = False
            limit = pos + self.max_sentence
            nl = buf.find(b"\n", pos + 1, limit)
            nxt = buf.find(b"$", pos + 1, limit)
            if nl < 0 and nxt < 0:
                if n - pos < self.max_sentence:
                    break                              # wait for the rest of the sentence
                self.stats.reject("truncated", self.max_sentence)   # runaway: no end in sight
                pos = limit
            elif nxt >= 0 and (nl < 0 or nxt < nl):
                self.stats.reject("truncated", nxt - pos)            # cut short by the next "$"
                pos = nxt
            else:
                self._sentence(bytes(buf[pos:nl + 1]), out)
                pos = nl + 1
        return pos

    def _sentence(self, line: bytes, out: list[ReceivedFix]) -> None:
        """One "$...\\n" line: verify, parse, range-check; a fix into `out` or a counted rejection."""
        nbytes = len(line)
        body = line[:-1]
        if body.endswith(b"\r"):
            body = body[:-1]
        text = body.decode("latin-1")
        if len(text) < 4 or text[-3] != "*" or not _is_hex2(text[-2:]):
            self.stats.reject("truncated", nbytes)                  # no "*hh": cut short
            return
        content = text[1:-3]
        if calc_checksum(content) != text[-2:].upper():
            self.stats.reject("bad_checksum", nbytes)
            return
        address = content.split(",", 1)[0]
        if not _PRINTABLE.fullmatch(content) or not _ADDRESS.fullmatch(address):
            self.stats.reject("bad_value", nbytes)                  # checksummed, but not NMEA text
            return
        kind = address[2:]
        if kind not in self.SOURCES:
            self.stats.reject("unknown_type", nbytes)
            return
        fix = self._parse(body, kind, address[:2])
        if fix is None:
            self.stats.reject("bad_value", nbytes)
            return
        self.stats.bytes_ok += nbytes
        self.stats.accepted[kind] += 1
        out.append(fix)

    def _parse(self, body: bytes, kind: str, talker: str) -> ReceivedFix | None:
        try:
            msg = NMEAReader.parse(body + b"\r\n", msgmode=GET, validate=VALCKSUM)
            if msg is None:
                return None
            # a receiver without a fix may not know the time yet (NEO-6 cold start: "$GPRMC,,V,,,,,,,,,,N")
            t = None if msg.time == "" else msg.time
            tod = math.nan if t is None else t.hour * 3600 + t.minute * 60 + t.second + t.microsecond / 1e6
            lat, lon = _signed(msg.lat, msg.NS, "N", "S"), _signed(msg.lon, msg.EW, "E", "W")
            if kind == "RMC":
                valid = msg.status == "A" and getattr(msg, "posMode", "") != "N"
                speed = _field_float(msg.spd) * KNOT_MPS
                heading = _field_float(msg.cog)
                utc = None
                if t is not None and msg.date != "":
                    utc = datetime.combine(msg.date, t).replace(tzinfo=UTC)
                    self._last_rmc_utc = utc
                elif valid:
                    return None                      # a fix must say when it was taken
                quality, n_sats, hdop, alt = int(valid), -1, math.nan, math.nan
            else:
                quality = int(msg.quality) if msg.quality != "" else 0
                valid = 1 <= quality <= 5
                n_sats = int(msg.numSV) if msg.numSV != "" else -1
                hdop, alt = _field_float(msg.HDOP), _field_float(msg.alt)
                speed = heading = math.nan
                utc = None
                if t is None and valid:
                    return None
                if t is not None and self._last_rmc_utc is not None:  # GGA has no date: the last RMC's
                    utc = datetime.combine(self._last_rmc_utc.date(), t).replace(tzinfo=UTC)
                    if utc < self._last_rmc_utc - timedelta(hours=12):
                        utc += timedelta(days=1)
                    elif utc > self._last_rmc_utc + timedelta(hours=12):
                        utc -= timedelta(days=1)
        except Exception:  # noqa: BLE001 - any parse failure of any field is a bad value, never a crash
            return None
        fix = ReceivedFix(kind, talker, utc, tod, valid, lat, lon, speed, heading, quality, n_sats, hdop, alt)
        return fix if _in_range(fix) else None


def _is_hex2(s: str) -> bool:
    return len(s) == 2 and all(c in "0123456789abcdefABCDEF" for c in s)


def _signed(value, hemi: str, pos: str, neg: str) -> float:
    """pynmeagps's lat/lon (signed already when the hemisphere is given) as float, NaN when empty."""
    if value == "" or value is None:
        return math.nan
    v = float(value)
    if hemi not in (pos, neg):
        raise ValueError(f"hemisphere {hemi!r}")
    return -abs(v) if hemi == neg else abs(v)


def _in_range(f: ReceivedFix) -> bool:
    """Physically possible values; NaN stands for 'not sent' and is allowed only where it may be."""
    def ok(x: float, lo: float, hi: float, may_be_absent: bool = True) -> bool:
        return (may_be_absent and math.isnan(x)) or (math.isfinite(x) and lo <= x <= hi)

    if f.valid and (math.isnan(f.lat_deg) or math.isnan(f.lon_deg)):
        return False
    return (ok(f.tod_s, 0.0, 86_401.0) and ok(f.lat_deg, -90.0, 90.0) and ok(f.lon_deg, -180.0, 180.0)
            and ok(f.speed_mps, 0.0, COCOM_SPEED_MPS) and ok(f.heading_deg, 0.0, 360.0)
            and ok(f.hdop, 0.0, 99.99) and ok(f.alt_m, MIN_ALT_M, COCOM_ALT_M) and -1 <= f.n_sats <= 99)


# --- binary ------------------------------------------------------------------------------------------

BIN_TYPE_FIX = 0x01
#: type u8 · seq u8 · flags u8 (bit 0 valid) · days since 1970-01-01 u16 · ms of day u32 ·
#: lat, lon i32 [1e-7 deg] · speed u16 [cm/s] · heading u16 [0.01 deg] · sats u8 · HDOP u16 [0.01] ·
#: altitude i16 [dm]
BIN_FIX = struct.Struct("<BBBHIiiHHBHh")
_CRC = struct.Struct("<H")
BIN_FRAME_MAX = 64          # bytes between delimiters that can still be a frame; chosen (2× a fix frame)
_crc16 = fastcrc.crc16.ibm_3740   # CRC-16/IBM-3740 (CCITT-FALSE): poly 0x1021, init 0xFFFF; check 0x29B1
_ZERO = re.compile(rb"\x00")
_NOT_ZERO = re.compile(rb"[^\x00]+")


def _sat(x: float, lo: int, hi: int) -> int:
    return min(max(round(x), lo), hi)


class BinaryEncoder:
    """GpsFix → one framed binary fix: 0x00 · COBS(payload · CRC-16) · 0x00 (30 bytes)."""

    def __init__(self, utc0: datetime = DEFAULT_UTC0) -> None:
        self.utc0 = utc0
        self.seq = 0

    def encode(self, fix: GpsFix) -> bytes:
        day, ms = _utc_parts(fix.t_us, self.utc0, 1000)
        days = (day - date(1970, 1, 1)).days
        if fix.valid:
            fields = (round(fix.lat_deg * 1e7), round(fix.lon_deg * 1e7), _sat(fix.speed_mps * 100, 0, 65535),
                      round(fix.heading_deg * 100) % 36000, _sat(fix.n_sats, 0, 255),
                      _sat(fix.hdop * 100, 0, 65535), _sat(fix.alt_m * 10, -32768, 32767))
        else:
            fields = (0, 0, 0, 0, 0, 9999, 0)
        payload = BIN_FIX.pack(BIN_TYPE_FIX, self.seq, int(fix.valid), days, ms, *fields)
        self.seq = (self.seq + 1) & 0xFF
        return b"\x00" + cobs.encode(payload + _CRC.pack(_crc16(payload))) + b"\x00"


class BinaryStreamReader(_StreamReader):
    """Bytes from a serial line → fixes from binary frames; everything else counted (same REASONS)."""

    def __init__(self) -> None:
        super().__init__()
        self._last_seq: int | None = None

    def _scan(self, out: list[ReceivedFix]) -> int:
        buf, pos, n = self._buf, 0, len(self._buf)
        while pos < n:
            end = buf.find(b"\x00", pos, pos + BIN_FRAME_MAX + 1)
            if end < 0:
                if n - pos <= BIN_FRAME_MAX:
                    break                                   # wait for the delimiter
                # too long to be a frame
                self._garbage(bytes(buf[pos:pos + BIN_FRAME_MAX]), _ZERO, _NOT_ZERO)
                pos += BIN_FRAME_MAX
                continue
            self.stats.bytes_idle += 1                      # the delimiter
            if end > pos:
                self._frame(bytes(buf[pos:end]), out)
            self._in_garbage = False
            pos = end + 1
        return pos

    def _frame(self, frame: bytes, out: list[ReceivedFix]) -> None:
        nbytes = len(frame)
        try:
            data = cobs.decode(frame)
        except cobs.DecodeError:
            self.stats.reject("garbage", nbytes)
            return
        if len(data) < 3:
            self.stats.reject("truncated", nbytes)
            return
        body, (crc,) = data[:-2], _CRC.unpack(data[-2:])
        if _crc16(body) != crc:
            self.stats.reject("bad_checksum", nbytes)
            return
        if body[0] != BIN_TYPE_FIX:
            self.stats.reject("unknown_type", nbytes)
            return
        if len(body) != BIN_FIX.size:
            self.stats.reject("truncated", nbytes)
            return
        fix = _bin_fix(body)
        if fix is None:
            self.stats.reject("bad_value", nbytes)
            return
        if self._last_seq is not None:
            self.stats.seq_gaps += (fix.seq - self._last_seq - 1) & 0xFF
        self._last_seq = fix.seq
        self.stats.bytes_ok += nbytes
        self.stats.accepted["BIN"] += 1
        out.append(fix)


def _bin_fix(body: bytes) -> ReceivedFix | None:
    _, seq, flags, days, ms, lat, lon, spd, hdg, sats, hdop, alt = BIN_FIX.unpack(body)
    if flags & ~1 or ms >= 86_401_000 or hdg >= 36000:
        return None
    valid = bool(flags & 1)
    utc = datetime(1970, 1, 1, tzinfo=UTC) + timedelta(days=days, milliseconds=ms)
    nan = math.nan
    fix = ReceivedFix("BIN", "", utc, ms / 1000.0, valid,
                      lat * 1e-7 if valid else nan, lon * 1e-7 if valid else nan,
                      spd / 100.0 if valid else nan, hdg / 100.0 if valid else nan,
                      int(valid), sats, hdop / 100.0, alt / 10.0 if valid else nan, seq)
    return fix if _in_range(fix) else None


#: protocol name → (encoder class, stream reader class)
PROTOCOLS = {"nmea": (NmeaEncoder, NmeaStreamReader), "binary": (BinaryEncoder, BinaryStreamReader)}
