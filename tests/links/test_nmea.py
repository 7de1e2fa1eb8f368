"""hil.links.nmea: NMEA 0183 RMC/GGA and the framed binary fix, written and read back; streaming readers that
count every byte of any input and never raise."""

from __future__ import annotations

import math
import struct
from datetime import UTC, datetime
from functools import reduce

import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.links.nmea import (
    BIN_FIX,
    BIN_TYPE_FIX,
    DEFAULT_UTC0,
    KNOT_MPS,
    REASONS,
    BinaryEncoder,
    BinaryStreamReader,
    NmeaEncoder,
    NmeaStreamReader,
    _crc16,
)
from plant_sim.gps import GpsFix, GpsModel, GpsParams

# Published sentences, with the checksum their source prints
PUBLISHED = {
    # Trimble receiver help, "NMEA-0183 message: RMC" (receiverhelp.trimble.com/oem-gnss)
    "trimble_rmc": b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A",
    # Trimble R7/R8 GPS Receiver User Guide, appendix A "NMEA-0183 Output", GGA example
    "trimble_gga": b"$GPGGA,172814.0,3723.46587704,N,12202.26957864,W,2,6,1.2,18.893,M,-25.669,M,2.0,0031*4F",
    # Cypress Solutions CTM-200 report messages, message type 82 GPRMC, NMEA 0183 v3.0 example
    "cypress_rmc": b"$GPRMC,222414.00,A,4915.3920,N,12259.8072,W,000.2,242.0,211210,,,A*49",
    # Parallax SIM33EAU GPS module user guide (rev C, 2021), "a valid position fix" (course field empty)
    "parallax_rmc": b"$GPRMC,041845.00,A,3846.50323,N,12115.39233,W,0.264,,040814,,,A*67",
    # NOAA PSL PISTON 2019 cruise, raw GPS log (Hemisphere VS100, differential mode D)
    "noaa_rmc": b"$GPRMC,195959.00,A,1813.38282955,N,12606.12767097,E,1.31,262.13,160919,3.0,W,D*21",
    # Deltares Markermeer 2007 GPS log: a GGA without a fix (quality 0)
    "deltares_gga0": b"$GPGGA,132411.60,5231.91297,N,00516.97745,E,0,00,2.3,5.7,M,46.6,M,,*63",
    # u-blox NEO-6M right after power-on (chris.cnie.de/avr/neo-6.html): no time, no fix
    "neo6_rmc_cold": b"$GPRMC,,V,,,,,,,,,,N*53",
    "neo6_gga_cold": b"$GPGGA,,,,,,0,00,99.99,,,,,,*48",
}
# the rest of that NEO-6M power-on output: well-formed, checksummed, not RMC/GGA
NEO6_OTHERS = [b"$GPTXT,01,01,02,u-blox ag - www.u-blox.com*50", b"$GPVTG,,,,,,,,,N*30",
               b"$GPGSA,A,1,,,,,,,,,,,,,99.99,99.99,99.99*30", b"$GPGSV,1,1,00*79", b"$GPGLL,,,,,,V,N*64"]


def xor_checksum(sentence: bytes) -> int:
    """The NMEA checksum computed independently: XOR of every byte between "$" and "*"."""
    return reduce(lambda a, b: a ^ b, sentence[1:sentence.index(b"*")], 0)


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_published_checksums(name):
    s = PUBLISHED[name]
    assert xor_checksum(s) == int(s[-2:], 16)


def read_all(reader, data: bytes):
    fixes = reader.feed(data)
    return fixes


def test_published_rmc_values():
    (f,) = read_all(NmeaStreamReader(), PUBLISHED["trimble_rmc"] + b"\r\n")
    assert f.source == "RMC" and f.talker == "GP" and f.valid
    assert f.utc == datetime(1994, 3, 23, 12, 35, 19, tzinfo=UTC)
    assert f.lat_deg == pytest.approx(48 + 7.038 / 60, abs=1e-9)
    assert f.lon_deg == pytest.approx(11 + 31.0 / 60, abs=1e-9)
    assert f.speed_mps == pytest.approx(22.4 * 1852 / 3600, abs=1e-9)
    assert f.heading_deg == pytest.approx(84.4)


def test_published_gga_values_and_west_is_negative():
    (f,) = read_all(NmeaStreamReader(), PUBLISHED["trimble_gga"] + b"\r\n")
    assert f.source == "GGA" and f.valid and f.quality == 2 and f.n_sats == 6
    assert f.lat_deg == pytest.approx(37 + 23.46587704 / 60, abs=1e-9)
    assert f.lon_deg == pytest.approx(-(122 + 2.26957864 / 60), abs=1e-9)
    assert (f.hdop, f.alt_m) == (pytest.approx(1.2), pytest.approx(18.893))
    assert f.tod_s == pytest.approx(17 * 3600 + 28 * 60 + 14.0)
    assert f.utc is None                           # no RMC has given the date yet


def test_published_stream_of_a_neo6_at_power_on():
    reader = NmeaStreamReader()
    stream = b"".join(s + b"\r\n" for s in [*NEO6_OTHERS[:1], PUBLISHED["neo6_rmc_cold"], *NEO6_OTHERS[1:2],
                                            PUBLISHED["neo6_gga_cold"], *NEO6_OTHERS[2:]])
    fixes = reader.feed(stream)
    assert [(f.source, f.valid) for f in fixes] == [("RMC", False), ("GGA", False)]
    assert math.isnan(fixes[0].tod_s) and fixes[0].utc is None and fixes[1].hdop == 99.99
    assert reader.stats.rejected == {"unknown_type": len(NEO6_OTHERS)}
    assert reader.stats.accounted(reader.pending) and reader.pending == 0


@pytest.mark.parametrize("name, valid", [("cypress_rmc", True), ("parallax_rmc", True), ("noaa_rmc", True),
                                         ("deltares_gga0", False)])
def test_published_sentences_are_accepted(name, valid):
    (f,) = read_all(NmeaStreamReader(), PUBLISHED[name] + b"\r\n")
    assert f.valid is valid


def test_a_missing_course_is_nan_not_a_rejection():
    (f,) = read_all(NmeaStreamReader(), PUBLISHED["parallax_rmc"] + b"\r\n")
    assert f.valid and math.isnan(f.heading_deg) and f.speed_mps == pytest.approx(0.264 * KNOT_MPS)


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_one_flipped_character_is_a_bad_checksum(name):
    s = bytearray(PUBLISHED[name])
    s[8] ^= 0x01
    reader = NmeaStreamReader()
    assert reader.feed(bytes(s) + b"\r\n") == []
    assert reader.stats.rejected == {"bad_checksum": 1}


def nmea(body: str) -> bytes:
    """A sentence with a correct checksum around `body` (to test what comes after the checksum)."""
    return b"$%s*%02X\r\n" % (body.encode(), reduce(lambda a, b: a ^ b, body.encode(), 0))


@pytest.mark.parametrize("body", [
    "GPRMC,123519,A,9107.038,N,01131.000,E,022.4,084.4,230394,,,A",     # |lat| > 90
    "GPRMC,123519,A,4807.038,N,18131.000,E,022.4,084.4,230394,,,A",     # |lon| > 180
    "GPRMC,123519,A,4807.038,N,01131.000,E,nan,084.4,230394,,,A",        # non-finite speed
    "GPRMC,123519,A,4807.038,N,01131.000,E,1200.0,084.4,230394,,,A",     # faster than the COCOM limit
    "GPRMC,123519,A,4807.038,N,01131.000,E,022.4,361.0,230394,,,A",      # course > 360
    "GPRMC,123519,A,4807.038,X,01131.000,E,022.4,084.4,230394,,,A",      # hemisphere X
    "GPRMC,123519,A,,,,,022.4,084.4,230394,,,A",                         # a valid fix without position
    "GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,,,,A",            # a valid fix without date
    "GPRMC,126519,A,4807.038,N,01131.000,E,022.4,084.4,230394,,,A",      # minute 65
    "GPGGA,123519,4807.038,N,01131.000,E,x,08,0.9,545.4,M,46.9,M,,",     # quality x
    "GPGGA,123519,4807.038,N,01131.000,E,1,08,inf,545.4,M,46.9,M,,",     # HDOP inf
    "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,99999.0,M,46.9,M,,",   # above the COCOM altitude
    "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,\x01",  # not printable
    "gpgga,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",     # not an NMEA address
])
def test_checksummed_but_impossible_values_are_bad_values(body):
    reader = NmeaStreamReader()
    assert reader.feed(nmea(body)) == []
    assert reader.stats.rejected == {"bad_value": 1}


@pytest.mark.parametrize("data, reason, events", [
    (b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4\r\n", "truncated", 1),      # cut: no "*hh"
    (b"$GPRMC,123519,A,4807.0$GPRMC,1", "truncated", 1),                         # cut by a new "$"
    (b"$GP" + b"7" * 300, "truncated", 1),                                       # runaway + garbage
    (b"\x00\xff random \x13 bytes\r\nmore\r\n", "garbage", 2),
    (nmea("GPGSV,1,1,00").rstrip(), "unknown_type", 0),                          # no CR LF yet: pending
])
def test_rejections_by_reason(data, reason, events):
    reader = NmeaStreamReader()
    assert reader.feed(data) == []
    assert reader.stats.rejected[reason] == events
    assert reader.stats.accounted(reader.pending)


def test_lower_case_checksum_and_bare_lf_are_accepted():
    s = PUBLISHED["cypress_rmc"]
    assert len(NmeaStreamReader().feed(s[:-2] + s[-2:].lower() + b"\n")) == 1


def test_gga_takes_the_date_of_the_last_rmc_across_midnight():
    reader = NmeaStreamReader()
    reader.feed(nmea("GPRMC,235959.50,A,4807.038,N,01131.000,E,022.4,084.4,311224,,,A"))
    (gga,) = reader.feed(nmea("GPGGA,000000.50,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"))
    assert gga.utc == datetime(2025, 1, 1, 0, 0, 0, 500000, tzinfo=UTC)


# --- round trips -------------------------------------------------------------------------------------


def model_fixes(n: int, seed: int = 1, **kw) -> list[GpsFix]:
    params = GpsParams(rate_hz=10.0, **kw)
    model = GpsModel(params, seed)
    # a train at 56.95 N 24.1 E (Riga) over a day boundary, east-north-east at 25 m/s
    t0 = 86_399_000_000 - 5 * params.period_us
    return [model.fix(t0 + k * params.period_us, 56.95, 24.1, 25.0, 70.0, alt_m=12.3) for k in range(n)]


def test_nmea_round_trip():
    fixes = model_fixes(200, dropout_rate_per_h=600.0)
    assert any(not f.valid for f in fixes)
    enc, reader = NmeaEncoder(), NmeaStreamReader()
    got = reader.feed(b"".join(enc.encode(f) for f in fixes))
    assert [g.source for g in got] == ["RMC", "GGA"] * len(fixes)
    for f, rmc, gga in zip(fixes, got[::2], got[1::2], strict=True):
        assert rmc.sim_time_us() == f.t_us and gga.sim_time_us() == f.t_us     # 10 ms grid, exact here
        assert rmc.valid is f.valid and gga.valid is f.valid
        if not f.valid:
            assert math.isnan(rmc.lat_deg) and gga.quality == 0
            continue
        for g in (rmc, gga):   # ddmm.mmmmm: half a 1e-5 minute
            assert g.lat_deg == pytest.approx(f.lat_deg, abs=0.5e-5 / 60 + 1e-10)
            assert g.lon_deg == pytest.approx(f.lon_deg, abs=0.5e-5 / 60 + 1e-10)
        assert rmc.speed_mps == pytest.approx(f.speed_mps, abs=0.0005 * KNOT_MPS + 1e-12)
        assert rmc.heading_deg == pytest.approx(f.heading_deg, abs=0.005 + 1e-9)
        assert (gga.n_sats, gga.hdop, gga.alt_m) == (f.n_sats, f.hdop, pytest.approx(12.3))
    assert reader.stats.bytes_ok == reader.stats.bytes_in and not reader.stats.rejected


def test_binary_round_trip_and_size():
    fixes = model_fixes(200, dropout_rate_per_h=600.0)
    enc, reader = BinaryEncoder(), BinaryStreamReader()
    frames = [enc.encode(f) for f in fixes]
    assert {len(b) for b in frames} == {1 + 1 + BIN_FIX.size + 2 + 1}   # delimiters, COBS code, CRC
    got = reader.feed(b"".join(frames))
    assert [g.seq for g in got] == [k & 0xFF for k in range(len(fixes))]
    for f, g in zip(fixes, got, strict=True):
        assert g.valid is f.valid and g.sim_time_us() == f.t_us
        if f.valid:
            assert g.lat_deg == pytest.approx(f.lat_deg, abs=0.5e-7 + 1e-12)
            assert g.lon_deg == pytest.approx(f.lon_deg, abs=0.5e-7 + 1e-12)
            assert g.speed_mps == pytest.approx(f.speed_mps, abs=0.005 + 1e-12)
            assert g.heading_deg == pytest.approx(f.heading_deg, abs=0.005 + 1e-9)
            assert (g.n_sats, g.hdop, g.alt_m) == (f.n_sats, pytest.approx(f.hdop), pytest.approx(12.3))
    assert reader.stats.seq_gaps == 0 and not reader.stats.rejected


def test_binary_is_at_least_four_times_smaller_than_nmea():
    (f,) = model_fixes(1)
    assert len(NmeaEncoder().encode(f)) >= 4 * len(BinaryEncoder().encode(f))


def test_coordinates_just_below_a_whole_degree_never_print_60_minutes():
    fix = GpsFix(0, True, 48.9999999999, -11.99999999999, 0.0, 1.0, 0.0, 8, 1.0, False)
    text = NmeaEncoder().encode(fix)
    assert b"4900.00000,N" in text and b"01200.00000,W" in text


def test_crc16_is_ccitt_false():
    assert _crc16(b"123456789") == 0x29B1     # check value of CRC-16/IBM-3740 (RevEng CRC catalogue)


def _frame(payload: bytes, crc: int | None = None) -> bytes:
    crc = _crc16(payload) if crc is None else crc
    return b"\x00" + cobs.encode(payload + struct.pack("<H", crc)) + b"\x00"


def _payload(**over) -> bytes:
    fields = dict(type=BIN_TYPE_FIX, seq=0, flags=1, days=19723, ms=1000, lat=569500000, lon=241000000,
                  spd=2500, hdg=7000, sats=8, hdop=100, alt=123)
    fields.update(over)
    return BIN_FIX.pack(*fields.values())


@pytest.mark.parametrize("frame, reason", [
    (_frame(_payload(), crc=0x1234), "bad_checksum"),
    (_frame(_payload(type=0x7E)), "unknown_type"),
    (_frame(_payload()[:-3]), "truncated"),
    (_frame(_payload(lat=950_000_000)), "bad_value"),
    (_frame(_payload(flags=0x80)), "bad_value"),
    (_frame(_payload(hdg=36000)), "bad_value"),
    (b"\x00\x05\x01\x00", "garbage"),                       # not COBS: length code past the end
    (b"\x00" + b"\xaa" * 200 + b"\x00", "garbage"),         # longer than any frame
])
def test_binary_rejections_by_reason(frame, reason):
    reader = BinaryStreamReader()
    assert reader.feed(frame) == []
    assert set(reader.stats.rejected) == {reason}
    assert reader.stats.accounted(reader.pending) and reader.pending == 0


def test_binary_sequence_gaps_count_lost_frames():
    enc, reader = BinaryEncoder(), BinaryStreamReader()
    frames = [enc.encode(f) for f in model_fixes(10)]
    reader.feed(b"".join(frames[:3] + frames[6:]))
    assert reader.stats.accepted["BIN"] == 7 and reader.stats.seq_gaps == 3


# --- any input ---------------------------------------------------------------------------------------

READERS = [NmeaStreamReader, BinaryStreamReader]
chunks = st.lists(st.binary(max_size=120), max_size=12)
# bytes that look like the protocols: "$", "*", digits, CR LF, zeros, COBS codes
lookalike = st.lists(st.sampled_from([b"$", b"*", b",", b"\r\n", b"\n", b"\x00", b"GPRMC", b"GPGGA", b"4F",
                                      b"\x01", b"\x1e", b"123519.00"]) | st.binary(max_size=8), max_size=40)


def _stats_tuple(r):
    s = r.stats
    return (s.bytes_in, s.bytes_ok, s.bytes_idle, dict(s.accepted), dict(s.rejected), dict(s.rejected_bytes),
            s.seq_gaps)


@pytest.mark.parametrize("reader_cls", READERS)
@settings(max_examples=150, deadline=None)
@given(parts=chunks | lookalike.map(lambda xs: [b"".join(xs)]))
def test_any_bytes_never_raise_and_every_byte_is_accounted_for(reader_cls, parts):
    reader = reader_cls()
    for part in parts:
        reader.feed(part)
        assert reader.stats.accounted(reader.pending)
        assert set(reader.stats.rejected) <= set(REASONS)
    reader.close()
    assert reader.pending == 0 and reader.stats.accounted(0)


@pytest.mark.parametrize("reader_cls", READERS)
@settings(max_examples=150, deadline=None)
@given(data=st.binary(max_size=400) | lookalike.map(b"".join), cuts=st.lists(st.integers(0, 400), max_size=8))
def test_results_do_not_depend_on_how_the_bytes_are_chunked(reader_cls, data, cuts):
    whole, pieces = reader_cls(), reader_cls()
    got_whole = whole.feed(data)
    got_pieces = []
    bounds = sorted({0, len(data), *(c for c in cuts if c < len(data))})
    for a, b in zip(bounds, bounds[1:], strict=False):
        got_pieces += pieces.feed(data[a:b])
    assert got_pieces == got_whole
    assert _stats_tuple(pieces) == _stats_tuple(whole) and pieces.pending == whole.pending


GOOD = model_fixes(12, dropout_rate_per_h=0.0)


@pytest.mark.parametrize("enc_cls, reader_cls", [(NmeaEncoder, NmeaStreamReader),
                                                 (BinaryEncoder, BinaryStreamReader)])
@settings(max_examples=150, deadline=None)
@given(garbage=st.lists(st.binary(max_size=300) | lookalike.map(b"".join), min_size=len(GOOD) + 1,
                        max_size=len(GOOD) + 1),
       split=st.integers(1, 64))
def test_garbage_between_good_sentences_loses_none_of_them(enc_cls, reader_cls, garbage, split):
    enc, clean, noisy = enc_cls(), reader_cls(), reader_cls()
    encoded = [enc.encode(f) for f in GOOD]
    expected = clean.feed(b"".join(encoded))
    stream = b"".join(g + e for g, e in zip(garbage, encoded + [b""], strict=True))
    got = []
    for k in range(0, len(stream), split):
        got += noisy.feed(stream[k:k + split])
    it = iter(got)                  # every good fix, in order (garbage could only ever add one)
    assert all(any(g == e for g in it) for e in expected)
    assert noisy.stats.accounted(noisy.pending)


def test_sim_time_of_a_fix():
    (f,) = model_fixes(1)
    (g,) = BinaryStreamReader().feed(BinaryEncoder().encode(f))
    assert g.sim_time_us(DEFAULT_UTC0) == f.t_us
