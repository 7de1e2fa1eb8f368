"""hil.links.gpsserial: GPS fixes over pyserial — loop:// (lockstep) and a real pseudo-terminal pair
(real time).
Waits are on the port with a timeout, never sleeps."""

from __future__ import annotations

import os

import pytest

from hil.errors import RailhilError, SerialLinkError
from hil.links.gpsserial import GpsLinkReader, GpsLinkWriter, PtyLink, line_time_us, open_port
from plant_sim.gps import GpsModel, GpsParams

N_FIXES = 40
GARBAGE = [b"\x13\xfe noise", b"$GPRMC,1235", b"*7F\r\n", b"\x00\x00\x05", b"$GPGSV,1,1,00*79\r\n", b"\r\n"]
PER_FIX = {"nmea": 2, "binary": 1}        # NMEA: an RMC and a GGA per fix


def fixes(n: int = N_FIXES):
    params = GpsParams(rate_hz=10.0, outages_s=((1.0, 1.5),))   # fixes 10-14: no fix
    model = GpsModel(params, 11)
    return [model.fix(k * params.period_us, 56.95, 24.1, 22.0, 80.0) for k in range(n)]


def write_with_garbage(writer: GpsLinkWriter, fx) -> int:
    """Each fix followed by one piece of garbage; returns the garbage bytes written."""
    junk = 0
    for k, f in enumerate(fx):
        writer.write_fix(f)
        junk += writer.write_bytes(GARBAGE[k % len(GARBAGE)])
    return junk


def check_received(reader: GpsLinkReader, got, fx, protocol: str) -> None:
    assert len(got) == PER_FIX[protocol] * len(fx)
    times = [g.sim_time_us() for g in got if g.utc is not None]
    assert times == sorted(times)
    assert [g.valid for g in got[::PER_FIX[protocol]]] == [f.valid for f in fx]
    stats = reader.stats
    assert sum(stats.rejected.values()) > 0 and stats.accounted(reader.decoder.pending)
    # nothing good was lost to garbage: every fix arrived; every garbage byte is idle, rejected or pending
    assert sum(stats.accepted.values()) == len(got)


@pytest.mark.parametrize("protocol", ["nmea", "binary"])
def test_loop_url_lockstep(protocol):
    port = open_port("loop://")
    writer, reader = GpsLinkWriter(port, protocol), GpsLinkReader(port, protocol)
    fx = fixes()
    assert any(not f.valid for f in fx)
    got = []
    for f in fx:                      # lockstep: what is written is readable at once
        writer.write_fix(f)
        got += reader.poll()
        writer.write_bytes(b"\x13\xfe$GP\r\n")
    check_received(reader, got, fx, protocol)
    assert writer.bytes_dropped == 0
    port.close()


@pytest.mark.parametrize("protocol", ["nmea", "binary"])
def test_real_pseudo_terminal(protocol):
    with PtyLink() as link:
        assert link.port_name.startswith("/dev/") and link.port.is_open
        writer, reader = GpsLinkWriter(link.device, protocol), GpsLinkReader(link.port, protocol)
        fx = fixes()
        junk = write_with_garbage(writer, fx)
        got = reader.collect(PER_FIX[protocol] * len(fx), timeout_s=20.0)
        check_received(reader, got, fx, protocol)
        assert writer.bytes_dropped == 0 and junk > 0
        # the garbage after the last fix is all that is left over
        assert reader.stats.bytes_in <= writer.bytes_written


def test_collect_returns_at_the_timeout_when_nothing_comes():
    with PtyLink() as link:
        reader = GpsLinkReader(link.port)
        assert reader.collect(1, timeout_s=0.05) == []


def test_overflow_of_the_line_buffer_is_counted_not_raised():
    port = open_port("loop://")       # pyserial's loop handler buffers 4096 bytes, like a UART FIFO
    writer, reader = GpsLinkWriter(port, "nmea"), GpsLinkReader(port, "nmea")
    fx = fixes(100)
    for f in fx:                      # a reader that does not poll: the buffer fills up
        writer.write_fix(f)
    assert writer.bytes_written == port.buffer_size
    assert writer.bytes_dropped == sum(len(writer.encoder.encode(f)) for f in fx) - port.buffer_size
    got = reader.poll()
    reader.close()
    assert 0 < len(got) < 2 * len(fx)
    assert reader.stats.bytes_in == port.buffer_size and reader.stats.accounted(0)
    assert reader.stats.rejected["truncated"] == 1         # the sentence cut by the full buffer


@pytest.mark.parametrize("url, needle", [("/dev/railhil-no-such-tty", "/dev/railhil-no-such-tty"),
                                         ("nosuch://x", "nosuch://x"), (os.devnull, os.devnull)])
def test_a_port_that_cannot_be_opened_is_a_one_line_error(url, needle):
    with pytest.raises(SerialLinkError) as info:
        open_port(url)
    msg = str(info.value)
    assert needle in msg and "expected" in msg and "\n" not in msg
    assert isinstance(info.value, RailhilError) and info.value.exit_code == 2


def test_bad_baud_rate_and_protocol_are_one_line_errors():
    with pytest.raises(SerialLinkError, match="baud rate"):
        open_port("loop://", baudrate=0)
    port = open_port("loop://")
    with pytest.raises(SerialLinkError, match="protocol 'ubx'.*binary, nmea"):
        GpsLinkReader(port, "ubx")


def test_line_time_of_a_fix():
    # 8N1 at 9600 baud: 960 characters per second
    assert line_time_us(960, 9600) == 1_000_000
    assert line_time_us(1, 9600) == 1042            # 1041.67 µs, rounded up
