"""hil.can.frame_io: python-can's udp_multicast wire format, sent and taken without a Message per frame.

Real python-can buses on a multicast group of their own (TTL 0: the frames stay on this host); each wait
for a frame is a select on the socket with a timeout, never a sleep.
"""

from __future__ import annotations

import os
import random
import select
import socket

import can
import pytest
from can.interfaces.udp_multicast.utils import pack_message

from hil.can.frame_io import FrameIO, pack_data_frame

WAIT_S = 5.0


@pytest.fixture
def pair():
    """Two python-can udp_multicast buses on one group of this test's own."""
    group = f"239.255.{random.randrange(1, 255)}.{random.randrange(1, 255)}"
    port = 40_000 + (os.getpid() % 20_000)
    a = can.Bus(interface="udp_multicast", channel=group, port=port, hop_limit=0)
    b = can.Bus(interface="udp_multicast", channel=group, port=port, hop_limit=0)
    yield a, b
    a.shutdown()
    b.shutdown()


def take_until(io: FrameIO, n: int) -> list[tuple]:
    """At least `n` frames from `io`, waiting for the socket with a timeout."""
    got: list[tuple] = []
    while len(got) < n:
        ready, _, _ = select.select([io.bus.fileno()], [], [], WAIT_S)
        assert ready, f"only {len(got)} of {n} frames within {WAIT_S} s"
        io.take(lambda *frame: got.append(frame))
    return got


def sent_and_read_back(io: FrameIO, bus: can.BusABC, frames: list[tuple]) -> list[tuple]:
    """`frames` (id, extended, data) sent through `io`, as python-can's `bus` reads them back."""
    for arbitration_id, extended, data in frames:
        io.send(arbitration_id, extended, data)
    received = []
    while len(received) < len(frames):
        msg = bus.recv(WAIT_S)
        assert msg is not None, f"python-can's bus got {len(received)} of {len(frames)} frames"
        received.append((msg.arbitration_id, msg.is_extended_id, bytes(msg.data)))
    return received


@pytest.mark.parametrize("extended", [False, True])
def test_a_data_frame_is_packed_as_python_can_packs_its_message(extended):
    for length in range(9):
        data = bytes(random.randrange(256) for _ in range(length))
        arbitration_id = random.randrange(1 << (29 if extended else 11))
        message = can.Message(arbitration_id=arbitration_id, is_extended_id=extended, data=data, check=False)
        assert pack_data_frame(arbitration_id, extended, data) == pack_message(message)


def test_frames_go_both_ways_between_frame_io_and_python_cans_own_bus(pair):
    a, b = pair
    io = FrameIO(b)
    assert io.fast
    sent = [(0x100 + k, k % 2 == 1, bytes(range(k % 9))) for k in range(20)]
    for arbitration_id, extended, data in sent:
        a.send(can.Message(arbitration_id=arbitration_id, is_extended_id=extended, data=data))
    got = take_until(io, len(sent))
    assert [(f[1], f[2], f[3]) for f in got] == sent
    assert all(f[4] is None for f in got)                 # plain data frames: no Message built
    stamps = [f[0] for f in got]
    assert stamps == sorted(stamps) and abs(stamps[-1] - __import__("time").time()) < 60

    # the other way: FrameIO sends, python-can's bus reads the same frames
    assert sent_and_read_back(io, a, sent) == sent


def test_remote_error_and_fd_frames_come_as_python_cans_messages(pair):
    a, b = pair
    io = FrameIO(b)
    a.send(can.Message(arbitration_id=0x7FF, is_remote_frame=True, dlc=2))
    a.send(can.Message(arbitration_id=0x10, is_error_frame=True))
    a.send(can.Message(arbitration_id=0x11, is_extended_id=False, data=b"\x01"))
    got = take_until(io, 3)
    assert got[0][4] is not None and got[0][4].is_remote_frame and got[0][1] == 0x7FF
    assert got[1][4] is not None and got[1][4].is_error_frame
    assert got[2][1:] == (0x11, False, b"\x01", None)


def test_a_datagram_that_is_no_python_can_frame_is_counted_and_dropped(pair):
    a, b = pair
    io = FrameIO(b)
    stray = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stray.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
    stray.sendto(b"\xc1not msgpack", b._multicast._send_destination)
    stray.close()
    a.send(can.Message(arbitration_id=0x22, is_extended_id=False, data=b"\x02\x03"))
    got = take_until(io, 1)
    assert io.undecodable == 1
    assert [f[1:4] for f in got] == [(0x22, False, b"\x02\x03")]


def test_another_interface_goes_through_python_cans_own_recv_and_send():
    channel = f"frame-io-{os.getpid()}"
    with can.Bus(interface="virtual", channel=channel) as a, \
            can.Bus(interface="virtual", channel=channel) as b:
        io = FrameIO(b)
        assert not io.fast
        a.send(can.Message(arbitration_id=0x33, is_extended_id=False, data=b"\x04"))
        io.send(0x34, True, b"\x05\x06")
        msg = a.recv(WAIT_S)
        assert (msg.arbitration_id, msg.is_extended_id, bytes(msg.data)) == (0x34, True, b"\x05\x06")
        got = []
        assert io.take(lambda *frame: got.append(frame)) == 1
        assert got[0][1:4] == (0x33, False, b"\x04") and got[0][4] is not None


def test_a_host_does_not_take_back_its_own_frames_and_every_other_socket_gets_them(pair):
    """drop_own: the frames leave from a socket of their own, and the bus's socket filters that socket's
    port out: python-can's bus beside it gets every frame, byte for byte, the sender none of its own."""
    a, b = pair
    io = FrameIO(b, drop_own=True)
    if not io.own_dropped:
        pytest.skip("no socket filter (SO_ATTACH_FILTER) on this OS: the host recognises its echoes instead")
    try:
        sent = [(0x200 + k, k % 2 == 0, bytes(range(k % 9))) for k in range(12)]
        assert sent_and_read_back(io, a, sent) == sent
        a.send(can.Message(arbitration_id=0x55, is_extended_id=False, data=b"\x07"))
        got = take_until(io, 1)          # the own frames were sent first: had they come back, they came first
        assert [f[1:4] for f in got] == [(0x55, False, b"\x07")]
        assert io.take(lambda *frame: got.append(frame)) == 0
    finally:
        io.close()


def test_a_host_takes_only_the_frames_it_does_not_drop_and_every_other_socket_gets_them_all(pair):
    """drop_ids: the socket filter drops the datagrams with those ids, read where python-can's msgpack puts
    them (a positive fixint, uint8, uint16, uint32); python-can's bus beside it still gets every frame, and
    a datagram laid out otherwise (no python-can frame) still comes, counted as before."""
    watcher, b = pair
    io = FrameIO(b, drop_ids={0x7F, 0xC8, 0x123, 0x18FF_0001})
    if not io.ids_dropped:
        pytest.skip("no socket filter (SO_ATTACH_FILTER) on this OS: a host drops those frames itself")
    group, port = b._multicast._send_destination[:2]
    sender = can.Bus(interface="udp_multicast", channel=group, port=port, hop_limit=0)
    try:
        ids = [0x05, 0x7F, 0x80, 0xC8, 0x123, 0x7FF, 0x1_0000, 0x18FF_0001, 0x22]
        sent = [(fid, fid > 0x7FF, bytes([k, fid & 0xFF])) for k, fid in enumerate(ids)]
        for fid, extended, data in sent:
            sender.send(can.Message(arbitration_id=fid, is_extended_id=extended, data=data))
        seen = [watcher.recv(WAIT_S) for _ in sent]
        assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in seen if m is not None] == sent
        got = take_until(io, 5)
        assert [f[1:4] for f in got] == [f for f in sent if f[0] in (0x05, 0x80, 0x7FF, 0x1_0000, 0x22)]
        stray = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        stray.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
        stray.sendto(b"\xc1not msgpack", b._multicast._send_destination)         # short: kept as it is
        stray.sendto(b"\xc1" + bytes(63), b._multicast._send_destination)       # long, not the layout: kept
        stray.close()
        sender.send(can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x01"))
        sender.send(can.Message(arbitration_id=0x33, is_extended_id=False, data=b"\x02"))
        assert [f[1:4] for f in take_until(io, 1)] == [(0x33, False, b"\x02")]
        assert io.undecodable == 2
    finally:
        io.close()
        sender.shutdown()


def test_a_filter_too_long_for_the_kernel_still_drops_the_hosts_own_frames(pair):
    """More ids than a classic BPF program can compare (4,096 instructions): the ids are not filtered (the
    host drops those frames itself), its own frames still are."""
    a, b = pair
    io = FrameIO(b, drop_own=True, drop_ids=range(0x100, 0x100 + 3_000))
    if not io.own_dropped:
        pytest.skip("no socket filter (SO_ATTACH_FILTER) on this OS")
    try:
        assert not io.ids_dropped
        io.send(0x101, False, b"\x01")
        a.send(can.Message(arbitration_id=0x102, is_extended_id=False, data=b"\x02"))
        got = take_until(io, 1)
        assert [f[1:4] for f in got] == [(0x102, False, b"\x02")]
    finally:
        io.close()
