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
is_extended_id=..., data=..., check=False)`` (tests/can/test_frame_io.py compares the two, and python-can's
bus reads the frames sent here and the other way round).  A datagram that is not a python-can frame (a
stray sender on the group) is counted in `undecodable` and dropped; python-can's bus raises on it.

With `drop_own` (a host's FrameIO), frames leave from a socket of their own and the bus's socket filters
that socket's source port out (Linux classic BPF): the multicast loop still gives them to the plant, the
recorder and every other socket on the group, but not back to their sender, which would only drop them
again (in the default run the ECUs' host took 49,400 datagrams, 31,700 of them its own; 17,700 with the
filter: `railhil run scenarios/default.toml --realtime`, run.json realtime.host_frames).

With `drop_ids` (the frames of the DBC that none of a host's nodes receives), the same filter also drops
the datagrams that carry one of those ids, as a CAN controller's acceptance filter (SocketCAN's
CAN_RAW_FILTER) would: it reads the id where python-can's msgpack layout puts it, and keeps every
datagram laid out otherwise (another sender, another python-can version) for the host to read.  A host
then no longer takes, unpacks and drops the frames it has no use for (in the default run the plant took
31,800 datagrams and used 17,700; a BECU hosted alone takes 7,300 of the bus's 49,400).
"""

from __future__ import annotations

import ctypes
import socket
import struct
import sys
from collections.abc import Callable, Iterable

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

    def __init__(self, bus: can.BusABC, drop_own: bool = False, drop_ids: Iterable[int] = ()) -> None:
        self.bus = bus
        self.ids_dropped = False      # drop_ids are filtered out in the kernel (fast path, Linux)
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
            drop_ids = sorted(set(drop_ids))
            if (self._tx is not None or drop_ids) and sys.platform.startswith("linux"):
                port = self._tx.getsockname()[1] if self._tx is not None else None
                # refused with the ids (e.g. longer than BPF_MAXINSNS): its own frames are dropped at least;
                # no filter at all: they come back and are recognised (hil.runtime.host.Delivery)
                if _attached(sock, _filter_program(port, drop_ids)):
                    self.ids_dropped = bool(drop_ids)
                elif self._tx is not None and not _attached(sock, _filter_program(port, [])):
                    self._tx.close()
                    self._tx, self._out = None, sock

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
    """A socket to send to the bus's group from a port of its own (the multicast loop still hands its frames
    to every other socket on the group: plant, recorder, another process); the caller filters that port
    out of the bus's socket (`_filter_program`).  None where the OS has no socket filter (Linux classic
    BPF, SO_ATTACH_FILTER): the frames then come back and the host recognises them
    (hil.runtime.host.Delivery)."""
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
    except OSError:
        tx.close()
        return None
    return tx


# classic BPF (<linux/filter.h>): the filter runs on the UDP datagram from its UDP header on
_LDW, _LDH, _LDB, _LDLEN = 0x20, 0x28, 0x30, 0x80       # ld/ldh/ldb [k], ld len
_JA, _JEQ, _JGT, _JGE, _RET = 0x05, 0x15, 0x25, 0x35, 0x06
_UDP = 8                                                 # the UDP header's bytes before the payload
_KEEP, _DROP = (_RET, 0, 0, 0xFFFFFFFF), (_RET, 0, 0, 0)
# python-can's msgpack of a Message up to the id's value: a map of 11, "timestamp", a float64 (any
# value), "arbitration_id" (can.interfaces.udp_multicast.utils.pack_message; tests/can/test_frame_io.py)
_LAYOUT = [(0, _LDW, 0x8BA97469), (4, _LDW, 0x6D657374), (8, _LDW, 0x616D70CB),      # 8b a9 "timestamp" cb
           (20, _LDW, 0xAE617262), (24, _LDW, 0x69747261), (28, _LDW, 0x74696F6E),   # ae "arbitration_id"
           (32, _LDH, 0x5F69), (34, _LDB, 0x64)]
_ID_AT = 35                      # the id's msgpack: a positive fixint, or cc/cd/ce and 1/2/4 bytes
_MIN_LEN = _UDP + _ID_AT + 5     # the longest of those ends here; a shorter datagram is kept as it is


def _filter_program(own_port: int | None, drop_ids: list[int]) -> list[tuple[int, int, int, int]]:
    """The socket filter: drop the datagrams sent from `own_port` (None: none) and those whose frame id,
    read where python-can lays it out, is one of `drop_ids`; keep every other datagram whole."""
    prog: list[tuple[int, int, int, int]] = []
    if own_port is not None:
        prog += [(_LDH, 0, 0, 0), (_JEQ, 0, 1, own_port), _DROP]      # the source port
    if not drop_ids:
        return prog + [_KEEP]
    prog += [(_LDLEN, 0, 0, 0), (_JGE, 1, 0, _MIN_LEN), _KEEP]
    for offset, load, value in _LAYOUT:                              # not python-can's layout: keep
        prog += [(load, 0, 0, _UDP + offset), (_JEQ, 1, 0, value), _KEEP]
    # the id into A, then a jump to the comparisons (`ja` takes a 32-bit offset, patched below)
    prog += [(_LDB, 0, 0, _UDP + _ID_AT), (_JGT, 1, 0, 0x7F)]        # a positive fixint is the id itself
    jumps = [len(prog)]
    prog.append((_JA, 0, 0, 0))
    for marker, load in ((0xCC, _LDB), (0xCD, _LDH), (0xCE, _LDW)):   # uint8 / uint16 / uint32
        prog += [(_JEQ, 0, 2, marker), (load, 0, 0, _UDP + _ID_AT + 1)]
        jumps.append(len(prog))
        prog.append((_JA, 0, 0, 0))
    prog.append(_KEEP)                                               # another encoding: keep
    compare = len(prog)
    for at in jumps:
        prog[at] = (_JA, 0, 0, compare - at - 1)
    for frame_id in drop_ids:
        prog += [(_JEQ, 0, 1, frame_id), _DROP]
    return prog + [_KEEP]


def _attached(sock: socket.socket, program: list[tuple[int, int, int, int]]) -> bool:
    """Attach the classic BPF `program` to `sock`; False where the OS refuses it (or it is too long)."""
    insns = ctypes.create_string_buffer(b"".join(struct.pack("HBBI", *i) for i in program))
    fprog = struct.pack("HL", len(program), ctypes.addressof(insns))
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, fprog)
    except OSError:
        return False
    return True


SO_ATTACH_FILTER = getattr(socket, "SO_ATTACH_FILTER", 26)    # Linux <asm-generic/socket.h>
