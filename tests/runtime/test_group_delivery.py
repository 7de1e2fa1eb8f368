"""hil.runtime.host.Delivery: a host's frames taken once from the bus and handed to its nodes (Node.receive);
the plant's kept for its steps."""

from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.runtime.host import ECHO_DEPTH, Delivery


class FakeNode:
    """What Delivery uses of a Node: its receptions (the frames as they came, decoded here for the tests),
    its counters."""

    def __init__(self, name: str, rx_ids: set[int], codec: Codec) -> None:
        self.name, self.rx_ids, self.codec = name, frozenset(rx_ids), codec
        self.got: list[tuple[int, dict, int]] = []
        self.frames: list[bytes] = []

        class Stats:
            unknown_frames = bad_frames = 0
        self.stats = Stats()

    def receive(self, fid, data, t_us) -> None:
        self.frames.append(data)
        fc = self.codec[fid]
        self.got.append((fid, fc.decode(data) if len(data) >= fc.length else {}, t_us))


def test_a_frame_reaches_every_node_that_takes_it_and_not_twice_when_echoed():
    db = load_dbc()
    codec = Codec(db)
    demand = codec.by_name("BCU_DEMAND")
    data = demand.encode({"TargetDecel": 0.8})
    bcu, becu1, becu2 = (FakeNode("BCU", set(), codec), FakeNode("BECU1", {demand.frame_id}, codec),
                         FakeNode("BECU2", {demand.frame_id}, codec))
    group = Delivery([bcu, becu1, becu2], codec)
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
    becu = FakeNode("BECU1", {demand.frame_id}, codec)
    group = Delivery([FakeNode("BCU", set(), codec), becu], codec)
    for k in range(ECHO_DEPTH + 3):                          # a bus that does not echo (SocketCAN)
        group.sent(None, demand.frame_id, demand.encode({"TargetDecel": 0.1 * k}), k)
    assert len(group._echo[demand.frame_id]) == ECHO_DEPTH
    group.receive(0x7FF, b"\x00" * 8, 10)                    # no message of the DBC: unknown to every node
    group.receive(demand.frame_id, b"\x01", 11)              # too short for BCU_DEMAND: to its receiver,
    assert becu.stats.unknown_frames == 1 and becu.frames[-1] == b"\x01"   # which counts it (Node.receive)


def test_the_plant_woken_on_its_frames_gets_each_command_before_the_step_its_reception_time_falls_in():
    """A batched node (the plant, [realtime] plant_wake = "frames") is handed its frames later, in time
    order, each before the first step at or after its reception time, on the plant's own clock (the bus's
    minus its slip)."""
    db = load_dbc()
    codec = Codec(db)
    cmd = codec.by_name("BECU1_PRESS_CMD")
    plant = FakeNode("PLANT", {cmd.frame_id}, codec)
    group = Delivery([FakeNode("BECU1", set(), codec), plant], codec, batched=frozenset({"PLANT"}))
    for t_us in (3_200, 4_000, 13_300):
        group.receive(cmd.frame_id, cmd.encode({"ValveCmd": 0.5}), t_us)
    assert plant.got == []                                   # kept until the plant computes its steps
    group.replay(plant, 3_000)
    assert plant.got == []                                   # step 3 ms: nothing received before it
    group.replay(plant, 4_000)
    assert [g[2] for g in plant.got] == [3_200, 4_000]       # step 4 ms: both, oldest first
    group.replay(plant, 12_000, offset_us=1_000)              # a plant 1 ms behind the bus: 13.3 ms is 12.3
    assert len(plant.got) == 2
    group.replay(plant, 13_000, offset_us=1_000)
    assert [g[2] for g in plant.got] == [3_200, 4_000, 12_300]



def test_a_host_whose_bus_drops_its_own_frames_keeps_no_echo_memory():
    """echoes=False (the host's FrameIO drops its own frames at the socket): nothing to recognise, so a
    frame from another sender with the bytes of one sent here is delivered, not taken for an echo."""
    codec = Codec(load_dbc())
    demand = codec.by_name("BCU_DEMAND")
    data = demand.encode({"TargetDecel": 0.8})
    bcu, becu1 = FakeNode("BCU", set(), codec), FakeNode("BECU1", {demand.frame_id}, codec)
    group = Delivery([bcu, becu1], codec, echoes=False)
    group.sent(bcu, demand.frame_id, data, 100)
    assert not group._echo and [g[2] for g in becu1.got] == [100]
    group.receive(demand.frame_id, data, 150)
    assert [g[2] for g in becu1.got] == [100, 150] and group.received == 1


def test_a_batched_node_takes_every_frame_it_received_at_its_release_in_order():
    db = load_dbc()
    codec = Codec(db)
    demand = codec.by_name("BCU_DEMAND")
    becu = FakeNode("BECU1", {demand.frame_id}, codec)
    group = Delivery([FakeNode("BCU", set(), codec), becu], codec, batched=frozenset({"BECU1"}))
    for t_us, decel in ((100, 0.5), (200, 0.8)):
        group.receive(demand.frame_id, demand.encode({"TargetDecel": decel}), t_us)
    assert becu.got == []                                    # nothing until its cycle is released
    group.replay_all(becu)
    assert [(g[2], g[1]["TargetDecel"]) for g in becu.got] == [(100, 0.5), (200, 0.8)]
    group.replay_all(becu)
    assert len(becu.got) == 2                                # each frame once
