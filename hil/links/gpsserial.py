"""The own-train GPS serial line, through pyserial: the receiver writes fixes, the ACD reads them.

Two kinds of line, the same writer and reader on both:

- **lockstep**: pyserial's ``loop://`` — one in-process port whose writes are read back from it, with
  the 4096-byte buffer of pyserial's loop handler standing in for the UART FIFO; everything is
  synchronous, so a fix written is readable at once and a run is deterministic.
- **real time**: a real pseudo-terminal pair (`PtyLink`): ``os.openpty()``; the slave — a tty device
  like /dev/ttyUSB0 — is opened by the reader with ``serial.Serial(os.ttyname(slave))``, as the ACD
  would open its GPS port; the master is the GPS module's side, written with non-blocking `os.write`.

Reads never block unless asked to wait, and then they wait on the port itself (pyserial's read with a
timeout: select() on a tty, the queue on loop://), never by sleeping. Bytes that do not fit in the line
buffer are dropped and counted (the "data overflow in the exchange process" of seed 002 §IX): a reader
that polls too rarely loses data, which then shows up as truncated sentences on its side.

A UART sends 10 bits per character (8N1: start, 8 data, stop): at the NEO-6's default 9600 baud one
NMEA fix (RMC + GGA, ~142 bytes) occupies the line 148 ms, one binary fix (31 bytes) 32 ms —
`line_time_us` computes it, for a lockstep wiring that wants the line's latency.
"""

from __future__ import annotations

import os
import time
import tty
from datetime import datetime

import serial

from hil.errors import SerialLinkError
from hil.links.nmea import DEFAULT_UTC0, PROTOCOLS, LinkStats, ReceivedFix
from plant_sim.gps import GpsFix

BITS_PER_CHAR_8N1 = 10     # start bit + 8 data bits + stop bit
DEFAULT_BAUDRATE = 9600    # u-blox NEO-6 data sheet: default UART baud rate


def line_time_us(nbytes: int, baudrate: int = DEFAULT_BAUDRATE,
                 bits_per_char: int = BITS_PER_CHAR_8N1) -> int:
    """Time [µs, rounded up] a UART at `baudrate` [bit/s] needs to send `nbytes` characters."""
    return -(-nbytes * bits_per_char * 1_000_000 // baudrate)


def _protocol(protocol: str):
    try:
        return PROTOCOLS[protocol]
    except KeyError:
        raise SerialLinkError(f"GPS link protocol {protocol!r}: expected one of "
                              + ", ".join(sorted(PROTOCOLS))) from None


def open_port(url: str, baudrate: int = DEFAULT_BAUDRATE) -> serial.SerialBase:
    """A pyserial port for `url` (a device path such as /dev/ttyUSB0, or a pyserial URL such as
    loop://), 8N1 at `baudrate` [bit/s], non-blocking reads (timeout 0)."""
    if not isinstance(baudrate, int) or isinstance(baudrate, bool) or baudrate <= 0:
        raise SerialLinkError(f"serial port {url!r}: baud rate must be a positive int, got {baudrate!r}")
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=0)
    except (serial.SerialException, ValueError, OSError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise SerialLinkError(f"serial port {url!r} cannot be opened: {msg}; expected a device path such "
                              "as /dev/ttyUSB0 or a pyserial URL such as loop://") from None


class PtyDevice:
    """The device end (master) of a pseudo-terminal: what the GPS module writes into. Non-blocking:
    `write` returns how many bytes the kernel took (the rest did not fit in the tty buffer)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        os.set_blocking(fd, False)

    def write(self, data: bytes) -> int:
        try:
            return os.write(self.fd, data)
        except BlockingIOError:
            return 0

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


class PtyLink:
    """A real serial line in one process: `device` (the GPS module's end) and `port` (a pyserial port
    on the tty device `port_name`, the ACD's end). Use as a context manager, or call `close()`."""

    def __init__(self, baudrate: int = DEFAULT_BAUDRATE) -> None:
        try:
            master, slave = os.openpty()
        except OSError as exc:
            raise SerialLinkError(f"cannot create a pseudo-terminal pair: {exc.strerror or exc}") from None
        try:
            tty.setraw(slave)            # no echo, no CR/LF translation — before a byte is written
            self.port_name = os.ttyname(slave)
            self.port = open_port(self.port_name, baudrate)
        except BaseException:
            os.close(master)
            os.close(slave)
            raise
        os.close(slave)                  # pyserial holds its own descriptor of the slave
        self.device = PtyDevice(master)

    def close(self) -> None:
        self.port.close()
        self.device.close()

    def __enter__(self) -> PtyLink:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ServedPty:
    """A pseudo-terminal whose other end a program outside railhil opens (an external ACD reading its GPS
    line): `device` is the GPS module's end (non-blocking writes), `port_name` the tty device to open.  The
    slave is set raw (no echo, no CR/LF translation) and held open unread, so that the line exists from
    the start and stays up while its reader reopens it.  Use as a context manager, or call `close()`."""

    def __init__(self) -> None:
        try:
            master, slave = os.openpty()
        except OSError as exc:
            raise SerialLinkError(f"cannot create a pseudo-terminal pair: {exc.strerror or exc}") from None
        try:
            tty.setraw(slave)
            self.port_name = os.ttyname(slave)
        except BaseException:
            os.close(master)
            os.close(slave)
            raise
        self._slave = slave
        self.device = PtyDevice(master)

    def close(self) -> None:
        self.device.close()
        if self._slave is not None:
            os.close(self._slave)
            self._slave = None

    def __enter__(self) -> ServedPty:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class GpsLinkWriter:
    """Writes GPS fixes onto a line as `protocol` ("nmea" or "binary"); `sink` is a pyserial port or a
    `PtyDevice`. Counts bytes written and bytes dropped because the line buffer was full."""

    def __init__(self, sink, protocol: str = "nmea", utc0: datetime = DEFAULT_UTC0) -> None:
        self.sink = sink
        self.protocol = protocol
        self.encoder = _protocol(protocol)[0](utc0=utc0)
        self.fixes_written = 0
        self.bytes_written = 0
        self.bytes_dropped = 0

    def _room(self) -> int | None:
        """Free bytes in a pyserial loop:// buffer (None: the sink reports by a short write)."""
        size = getattr(self.sink, "buffer_size", None)
        if size is None:
            return None
        return max(size - self.sink.out_waiting, 0)

    def write_bytes(self, data: bytes) -> int:
        """Put raw bytes on the line (what fits; the rest is dropped and counted); returns bytes sent."""
        room = self._room()
        part = data if room is None or room >= len(data) else data[:room]
        try:
            sent = self.sink.write(part) if part else 0
        except (serial.SerialException, OSError) as exc:
            name = getattr(self.sink, "port", self.sink)
            raise SerialLinkError(f"GPS line {name!r}: write failed: {exc}") from None
        sent = len(part) if sent is None else sent
        self.bytes_written += sent
        self.bytes_dropped += len(data) - sent
        return sent

    def write_fix(self, fix: GpsFix) -> int:
        """Encode and write one fix; returns the bytes sent."""
        self.fixes_written += 1
        return self.write_bytes(self.encoder.encode(fix))


class GpsLinkReader:
    """Reads a pyserial port and decodes it as `protocol`; garbage is counted in `stats`, never raised."""

    def __init__(self, port: serial.SerialBase, protocol: str = "nmea") -> None:
        self.port = port
        self.protocol = protocol
        self.decoder = _protocol(protocol)[1]()

    @property
    def stats(self) -> LinkStats:
        return self.decoder.stats

    def _read(self, size: int) -> bytes:
        try:
            return self.port.read(size)
        except (serial.SerialException, OSError) as exc:
            raise SerialLinkError(f"GPS port {self.port.port!r}: read failed: {exc}") from None

    def poll(self) -> list[ReceivedFix]:
        """Everything waiting on the port now, decoded; never blocks."""
        try:
            waiting = self.port.in_waiting
        except (serial.SerialException, OSError) as exc:
            raise SerialLinkError(f"GPS port {self.port.port!r}: read failed: {exc}") from None
        return self.decoder.feed(self._read(waiting)) if waiting else []

    def collect(self, n_fixes: int, timeout_s: float) -> list[ReceivedFix]:
        """Fixes as they arrive until `n_fixes` are in or `timeout_s` [s] has passed (monotonic clock).
        Waits on the port (a pyserial read of one byte with the remaining time as its timeout)."""
        out = self.poll()
        deadline = time.monotonic() + timeout_s
        while len(out) < n_fixes:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                break
            self.port.timeout = remaining
            try:
                first = self._read(1)
            finally:
                self.port.timeout = 0
            if first:
                out += self.decoder.feed(first)
            out += self.poll()
        return out

    def close(self) -> None:
        """End of stream: what is still pending in the decoder is counted as truncated."""
        self.decoder.close()
