"""hil.runtime.realtime.GroupDelivery: a grouped host's frames decoded once and handed to its nodes."""

from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.runtime.realtime import ECHO_DEPTH, GroupDelivery


class FakeNode:
    """What GroupDelivery uses of a Node: its receptions, its counters."""

    def __init__(self, name: str, rx_ids: set[int]) -> None:
        self.name, self.rx_ids = name, frozenset(rx_ids)
        self.got: list[tuple[int, dict, int]] = []

        class Stats:
            unknown_frames = bad_frames = 0
        self.stats = Stats()

    def receive_values(self, fid, values, t_us, data=None) -> None:
        self.got.append((fid, dict(values), t_us))


def test_a_frame_is_decoded_once_for_every_node_that_takes_it_and_not_twice_when_echoed():
    db = load_dbc()
    codec = Codec(db)
    demand = codec.by_name("BCU_DEMAND")
    data = demand.encode({"TargetDecel": 0.8})
    bcu, becu1, becu2 = (FakeNode("BCU", set()), FakeNode("BECU1", {demand.frame_id}),
                         FakeNode("BECU2", {demand.frame_id}))
    group = GroupDelivery([bcu, becu1, becu2], codec)
    group.sent(bcu, demand.frame_id, data, 100)              # the BCU's frame, as it is sent
    assert [g[2] for g in becu1.got] == [100] and becu1.got[0][1]["TargetDecel"] == 0.8
    group.receive(demand.frame_id, data, 150)                # the bus returns it (udp_multicast): dropped
    assert len(becu1.got) == len(becu2.got) == 1
    group.receive(demand.frame_id, data, 160)                # the same bytes again, not sent from here
    assert len(becu1.got) == 2                               # a foreign (replayed) frame is delivered


def test_echo_memory_is_bounded_and_foreign_frames_are_counted_as_a_node_would():
    db = load_dbc()
    codec = Codec(db)
    demand = codec.by_name("BCU_DEMAND")
    becu = FakeNode("BECU1", {demand.frame_id})
    group = GroupDelivery([FakeNode("BCU", set()), becu], codec)
    for k in range(ECHO_DEPTH + 3):                          # a bus that does not echo (SocketCAN)
        group.sent(None, demand.frame_id, demand.encode({"TargetDecel": 0.1 * k}), k)
    assert len(group._echo[demand.frame_id]) == ECHO_DEPTH
    group.receive(0x7FF, b"\x00" * 8, 10)                    # no message of the DBC: unknown to every node
    group.receive(demand.frame_id, b"\x01", 11)              # too short for BCU_DEMAND: bad for its receiver
    assert becu.stats.unknown_frames == 1 and becu.stats.bad_frames == 1
