"""Frames to and from a python-can bus at a real-time host's rate.

A real-time host sends and receives every frame of the bus through python-can (hil.runtime.host, the
recorder).  On `udp_multicast`, python-can's per-frame path costs a `select` and a `can.Message` for every
frame taken (the socket is polled until empty at each deadline) and a `can.Message` packed into a dict
for every frame sent.  `FrameIO` keeps python-can's bus, its socket and its wire format, and for
python-can's `UdpMulticastBus` takes the frames off that socket without blocking, one `recvmsg` each and
no `select`, and sends python-can's own msgpack layout of a classic data frame without building the
Message (bench/bench_frame_io.py, side by side on the 2-core VM: a frame taken in 8.5 µs against 15.8,
sent in 7.3 µs against 11.2).  A remote, error or FD frame, or one whose fields are not a plain data
frame's, is handed over as python-can's `can.Message` (`unpack_message`, as the bus would have built
it).  Every other interface (SocketCAN, PCAN, Vector, ...) goes through python-can's `recv` and `send`
unchanged.

What goes on the wire is byte for byte what python-can sends for ``can.Message(arbitration_id=...,
is_extended_id=..., data=..., check=False)`` (tests/test_frame_io.py compares the two, and python-can's
bus reads the frames sent here and the other way round).  A datagram that is not a python-can frame (a
stray sender on the group) is counted in `undecodable` and dropped; python-can's bus raises on it.

With `drop_own` (a host's FrameIO), frames leave from a socket of their own and the bus's socket filters
that socket's source port out (Linux classic BPF): the multicast loop still gives them to the plant, the
recorder and every other socket on the group, but not back to their sender, which would only drop them
again (in the default run the ECUs' host took 49,400 datagrams, 31,700 of them its own; 17,700 with the
filter: `railhil run scenarios/default.toml --realtime`, run.json realtime.host_frames).
"""

from __future__ import annotations

import ctypes
import socket
import struct
import sys
from collections.abc import Callable

import can

try:                                  # python-can's udp_multicast needs msgpack; without it, no fast path
    import msgpack
    from can.interfaces.udp_multicast import UdpMulticastBus
    from can.interfaces.udp_multicast.utils import unpack_message
except ImportError:                   # pragma: no cover - msgpack comes with railhil's python-can extra
    msgpack = UdpMulticastBus = unpack_message = None


def pack_data_frame(arbitration_id: int, is_extended_id: bool, data: bytes) -> bytes:
    """What python-can's udp_multicast sends for ``can.Message(arbitration_id=arbitration_id,
    is_extended_id=is_extended_id, data=data, check=False)``: its pack_message's keys in its order, the
    Message's values."""
    return _pack({"timestamp": 0.0, "arbitration_id": arbitration_id, "is_extended_id": is_extended_id,
                  "is_remote_frame": False, "is_error_frame": False, "channel": None, "dlc": len(data),
                  "data": data, "is_fd": False, "bitrate_switch": False, "error_state_indicator": False})


_pack = msgpack.Packer(use_bin_type=True).pack if msgpack is not None else None


class FrameIO:
    """Send and take the frames of one python-can bus; `fast` says whether the udp_multicast path is used."""

    def __init__(self, bus: can.BusABC, drop_own: bool = False) -> None:
        self.bus = bus
        self.undecodable = 0          # datagrams on the group that are not python-can frames (fast path)
        self._tx: socket.socket | None = None     # drop_own's socket to send from (fast path)
        multicast = getattr(bus, "_multicast", None)
        sock = getattr(multicast, "_socket", None)
        self.fast = (UdpMulticastBus is not None and isinstance(bus, UdpMulticastBus)
                     and isinstance(sock, socket.socket)
                     and getattr(multicast, "timestamp_nanosecond", False)
                     and hasattr(multicast, "_send_destination")
                     and sock.gettimeout() in (None, 0.0))   # blocking or not, never a timeout: no waits
        if self.fast:
            self._sock = sock
            self._dest = multicast._send_destination
            self._bufsize = multicast.max_buffer
            self._ancsize = multicast.received_ancillary_buffer_size
            self._stamp = struct.Struct(multicast.received_timestamp_struct).unpack
            self._fd = bus.protocol is can.CanProtocol.CAN_FD
            self._unpackb = msgpack.unpackb
            self._tx = _own_sender(sock) if drop_own else None
            self._out = self._tx or sock

    def send(self, arbitration_id: int, is_extended_id: bool, data: bytes) -> None:
        """One classic data frame on the bus (python-can's errors as the bus raises them)."""
        if not self.fast:
            self.bus.send(can.Message(arbitration_id=arbitration_id, is_extended_id=is_extended_id, data=data,
                                      check=False))
            return
        packed = pack_data_frame(arbitration_id, is_extended_id, data)
        try:
            sent = self._out.sendto(packed, self._dest)
        except OSError as error:
            raise can.CanOperationError("failed to send via socket") from error
        if sent < len(packed):
            raise can.CanOperationError("failed to send via socket: datagram cut")

    def take(self, on_frame: Callable[[float, int, bool, bytes, can.Message | None], None]) -> int:
        """Every frame the bus holds now, oldest first, each to `on_frame(timestamp, arbitration_id,
        is_extended_id, data, message)` (message None for a plain classic data frame taken by the fast
        path, else python-can's Message); the number taken."""
        if not self.fast:
            recv, n = self.bus.recv, 0
            while (msg := recv(0.0)) is not None:
                on_frame(msg.timestamp, msg.arbitration_id, msg.is_extended_id, bytes(msg.data), msg)
                n += 1
            return n
        recvmsg, bufsize, ancsize = self._sock.recvmsg, self._bufsize, self._ancsize
        flags, unpackb, stamp = socket.MSG_DONTWAIT, self._unpackb, self._stamp
        n = 0
        while True:
            try:
                raw, ancillary, _, _ = recvmsg(bufsize, ancsize, flags)
            except BlockingIOError:
                return n
            except InterruptedError:
                continue
            except OSError as exc:
                raise can.CanOperationError(f"Failed to receive from IP/UDP socket: {exc}") from exc
            try:
                fields = unpackb(raw, raw=False)
                seconds, nanoseconds = stamp(ancillary[0][2])
                timestamp = seconds + nanoseconds * 1e-9
                data, arbitration_id = fields["data"], fields["arbitration_id"]
                extended = fields["is_extended_id"]
                msg = None
                if not (type(data) is bytes and fields.get("dlc") == len(data) <= 8
                        and type(arbitration_id) is int and type(extended) is bool
                        and fields.get("is_remote_frame") is False and fields.get("is_error_frame") is False
                        and fields.get("is_fd") is False):
                    msg = unpack_message(raw, replace={"timestamp": timestamp}, check=True)
                    if msg.is_fd and not self._fd:     # as python-can's bus: FD frames only on an FD bus
                        continue
                    data, arbitration_id, extended = bytes(msg.data), msg.arbitration_id, msg.is_extended_id
            except Exception:       # not a python-can frame (python-can's bus raises CanOperationError)
                self.undecodable += 1
                continue
            on_frame(timestamp, arbitration_id, extended, data, msg)
            n += 1

    @property
    def own_dropped(self) -> bool:
        """This FrameIO's own frames do not come back to it (drop_own, in effect)."""
        return self._tx is not None

    def close(self) -> None:
        """Close the socket of its own that `drop_own` sends from (the bus stays open: its owner's)."""
        if self._tx is not None:
            self._out = self._sock
            self._tx.close()
            self._tx = None


def _own_sender(bus_sock: socket.socket) -> socket.socket | None:
    """A socket to send to the bus's group from a port of its own, and on the bus's socket a filter that
    drops the datagrams from that port: the multicast loop still hands this host's frames to every other
    socket on the group (plant, recorder, another process), but not back to the one that sent them.  None
    (and nothing changed) where the OS has no socket filter (Linux classic BPF, SO_ATTACH_FILTER) or
    refuses it: the frames then come back and the host recognises them (hil.runtime.host.Delivery)."""
    if not sys.platform.startswith("linux"):
        return None
    family = bus_sock.family
    tx = socket.socket(family, socket.SOCK_DGRAM)
    try:
        if family == socket.AF_INET6:
            hops = bus_sock.getsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS)
            tx.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, hops)
            tx.bind(("::", 0))
        else:
            ttl = bus_sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL)
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, ttl)
            tx.bind(("", 0))
        port = tx.getsockname()[1]
        # classic BPF, run on the UDP datagram (the filter sees it from its UDP header on): load the
        # source port (2 bytes at offset 0); equal to ours: keep 0 bytes (drop), else keep it whole
        program = [(0x28, 0, 0, 0),               # ldh [0]
                   (0x15, 0, 1, port),            # jeq #port, next, skip one
                   (0x06, 0, 0, 0),               # ret #0
                   (0x06, 0, 0, 0xFFFFFFFF)]      # ret #-1
        insns = ctypes.create_string_buffer(b"".join(struct.pack("HBBI", *i) for i in program))
        fprog = struct.pack("HL", len(program), ctypes.addressof(insns))
        bus_sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, fprog)
    except OSError:
        tx.close()
        return None
    return tx


SO_ATTACH_FILTER = getattr(socket, "SO_ATTACH_FILTER", 26)    # Linux <asm-generic/socket.h>
