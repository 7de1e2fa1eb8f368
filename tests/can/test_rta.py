"""hil.can.rta: the revised CAN response-time analysis of Davis et al. 2007 against hand-worked cases, against
the project's bit-timed bus (hil.can.bustiming) as an oracle, and by its properties; messages from the DBC;
the response estimate from frame timestamps."""

from __future__ import annotations

import heapq
import math
import random
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.can.busload import frame_bits, static_load, with_functions
from hil.can.bustiming import BitTimedBus, Pending
from hil.can.dbc import load_dbc
from hil.can.rta import RtaError, RtaMessage, analyse, measured_response, messages_from_dbc, priority_key
from hil.errors import RailhilError

ROOT = Path(__file__).resolve().parents[2]
TRAIN_DBC = ROOT / "dbc" / "train_brake.dbc"


def msg(name: str, frame_id: int, period_us: int, dlc: int = 8, deadline_us: int | None = None,
        jitter_us: int = 0, extended: bool = False) -> RtaMessage:
    return RtaMessage(name, frame_id, extended, dlc, period_us, deadline_us or period_us, jitter_us)


def simulate(messages: list[RtaMessage], bitrate: int, phases_us: list[int], horizon_us: int,
             jitter_seed: int | None = None) -> dict[str, int]:
    """Worst response [ns] of each message on hil.can.bustiming's bus (worst-case stuffing, one node per
    message), instance k released at phase + k·T (+ U(0, J) queuing delay when jitter_seed is given);
    the response runs from the release, jitter included, to the end of the frame."""
    bus = BitTimedBus(bitrate, len(messages), stuffing="worst")
    rng = random.Random(jitter_seed)
    heap = [(p * 1000, i, p * 1000) for i, p in enumerate(phases_us)]  # (queued, message, release)
    heapq.heapify(heap)
    worst = {m.name: 0 for m in messages}
    now = 0
    while True:
        while heap and heap[0][0] <= now:
            queued, i, release = heapq.heappop(heap)
            m = messages[i]
            data = bytes(min(m.dlc, 8))
            bus.enqueue(Pending(i, m.frame_id, m.extended, data, queued, release, item=release))
            nxt = release + m.period_us * 1000
            if nxt < horizon_us * 1000:
                delay = 0 if jitter_seed is None else rng.randint(0, m.jitter_us * 1000)
                heapq.heappush(heap, (nxt + delay, i, nxt))
        if bus.pending():
            p, _deliver, end = bus.arbitrate(now)
            name = messages[p.node].name
            worst[name] = max(worst[name], end - p.item)
            now = end
        elif heap:
            now = heap[0][0]
        else:
            return worst


def test_paper_example_three_messages_125k():
    """The example with which Davis et al. 2007 (Sect. 3) refute the original analysis, as we recall it
    (we could not retrieve the paper's text to check the figures): 125 kbit/s, three 7-byte 11-bit
    messages of C = (55 + 70) bits x 8 µs = 1 ms; A T = D = 2.5 ms; B and C T = 3.5 ms, D = 3.25 ms.
    By hand, message C (lowest priority, B = 0):
      busy period t: 1 → 3 → 4 → 6 → 7 ms (A 3 x 1 ms + B 2 x 1 + C 2 x 1), Q = ⌈7 / 3.5⌉ = 2;
      q = 0: w = ⌈8µs/2.5⌉ + ⌈8µs/3.5⌉ = 2 ms, R(0) = 2 + 1 = 3 ms (all the original analysis sees);
      q = 1: w = 1 + 1 → 3 → 4 → 5 → 6 → 6 ms, R(1) = 6 - 3.5 + 1 = 3.5 ms > D = 3.25 ms.
    B: t 1 → 3 → 4 → 5 → 5 ms, Q = 2, R(0) = 1 + 1 + 1 = 3 ms, R(1) = 4 - 3.5 + 1 = 1.5 ms: R = 3 ms.
    A: B = 1 ms, R = 2 ms."""
    messages = [msg("A", 1, 2500, 7), msg("B", 2, 3500, 7, 3250), msg("C", 3, 3500, 7, 3250)]
    assert frame_bits(7, False) == 125
    rep = analyse(messages, 125_000)
    got = {r.message.name: r for r in rep.results}
    assert [r.message.name for r in rep.results] == ["A", "B", "C"]
    expected = {  # C, B, t, Q, R [µs], schedulable
        "A": (1000, 1000, 2000, 1, 2000, True),
        "B": (1000, 1000, 5000, 2, 3000, True),
        "C": (1000, 0, 7000, 2, 3500, False),
    }
    for name, (c, b, t, q, r, ok) in expected.items():
        g = got[name]
        assert (g.c_us, g.blocking_us, g.busy_period_us, g.instances, g.response_us, g.schedulable) == \
            (c, b, t, q, r, ok), name
    assert rep.utilisation == pytest.approx(1 / 2.5 + 2 / 3.5)
    assert not rep.ok
    # the bus itself, all three released together: C's second instance really takes 3.5 ms (and A's
    # second one, released at 2.5 ms, waits for C's first until 3 ms)
    sim = simulate(messages, 125_000, [0, 0, 0], 7000)
    assert sim == {"A": 1_500_000, "B": 2_000_000, "C": 3_500_000}


def test_hand_computed_jitter_and_29_bit():
    """500 kbit/s (τ = 2 µs): H 11-bit 2 bytes T 1 ms J 100 µs; L 29-bit 8 bytes T 5 ms J 300 µs.
    C_H = (55 + 20) x 2 = 150 µs, C_L = (80 + 80) x 2 = 320 µs.
    H: B = 320; t = 320 + ⌈(t + 100)/1000⌉·150: 150 → 470 → 470; Q = ⌈570/1000⌉ = 1;
       w = 320 → R = 100 + 320 + 150 = 570 µs.
    L: B = 0; t = ⌈(t+100)/1000⌉·150 + ⌈(t+300)/5000⌉·320: 320 → 470 → 470; Q = ⌈770/5000⌉ = 1;
       w = ⌈(w + 100 + 2)/1000⌉·150: 0 → 150 → 150; R = 300 + 150 + 320 = 770 µs."""
    rep = analyse([msg("L", 0x18FF0001, 5000, 8, jitter_us=300, extended=True),
                   msg("H", 0x100, 1000, 2, jitter_us=100)], 500_000)
    h, low = rep.results
    assert h.message.name == "H"
    assert (h.c_us, h.blocking_us, h.busy_period_us, h.instances, h.response_us) == (150, 320, 470, 1, 570)
    assert (low.c_us, low.blocking_us, low.busy_period_us, low.instances, low.response_us) == \
        (320, 0, 470, 1, 770)
    assert rep.ok and rep.utilisation == pytest.approx(150 / 1000 + 320 / 5000)


def test_priority_as_on_the_bus():
    """The 11 base bits first; an 11-bit frame beats a 29-bit one with the same base bits."""
    names = ["std 0x123", "ext 0x0CF00400", "std 0x033", "ext 0x00CC0001", "ext 0x0CC00000"]
    ids = [(0x123, False), (0x0CF00400, True), (0x033, False), (0x00CC0001, True), (0x0CC00000, True)]
    rep = analyse([msg(n, i, 10_000, extended=e) for n, (i, e) in zip(names, ids, strict=True)], 500_000)
    # bases: 0x123, 0x33C, 0x033, 0x033, 0x330
    assert [r.message.name for r in rep.results] == \
        ["std 0x033", "ext 0x00CC0001", "std 0x123", "ext 0x0CC00000", "ext 0x0CF00400"]
    assert priority_key(0x100, False) < priority_key(0x100 << 18, True) < priority_key(0x101, False)


def test_overload_is_unbounded_and_ends():
    """U >= 1 over hep(m): R = inf, not schedulable; the messages above still get their bounds."""
    ms = [msg(f"M{i}", 0x100 + i, 1000) for i in range(4)]  # 4 x 270 µs per ms at 500 kbit/s: U = 1.08
    rep = analyse(ms, 500_000)
    assert rep.utilisation == pytest.approx(1.08)
    # M2: B = 270, w = 270 + 2 x 270 = 810, R = 1080 µs > D = 1 ms: bounded but late
    assert [r.schedulable for r in rep.results] == [True, True, False, False]
    assert rep.results[2].response_us == 1080 and rep.results[2].instances == 2
    assert math.isinf(rep.results[-1].response_us) and math.isinf(rep.results[-1].busy_period_us)
    assert rep.results[-1].instances == 0 and rep.results[-1].unbounded
    # exactly 100 %: still unbounded (the busy period never closes)
    exact = analyse([msg("A", 1, 540), msg("B", 2, 540)], 500_000)
    assert exact.utilisation == 1.0 and exact.results[1].unbounded and exact.results[0].schedulable


def test_deadline_beyond_period_queues_instances():
    """D > T: several instances in the busy period, R > T is allowed up to D."""
    ms = [msg("A", 1, 500), msg("B", 2, 1150), msg("C", 3, 1200, deadline_us=2400)]
    rep = analyse(ms, 500_000)  # U = 270/500 + 270/1150 + 270/1200 = 0.99978
    c = rep.results[2]
    assert c.instances == 45 and c.busy_period_us == 54_000
    assert c.response_us == 1290 and c.schedulable  # > T, <= D
    sim = simulate(ms, 500_000, [0, 0, 0], 120_000)
    assert 1_200_000 < sim["C"] <= c.response_us * 1000


@pytest.mark.parametrize("bad", [
    dict(period_us=0), dict(deadline_us=-1), dict(jitter_us=-5), dict(dlc=16), dict(period_us=10.5),
    dict(frame_id=0x800),
])
def test_bad_messages(bad):
    fields = dict(name="X", frame_id=0x10, extended=False, dlc=8, period_us=1000, deadline_us=1000)
    fields.update(bad)
    with pytest.raises(RtaError) as err:
        analyse([RtaMessage(**fields)], 500_000)
    assert "X" in str(err.value) and isinstance(err.value, RailhilError)


def test_duplicate_id_and_bad_bitrate():
    with pytest.raises(RtaError, match="same identifier"):
        analyse([msg("A", 0x10, 1000), msg("B", 0x10, 2000)], 500_000)
    analyse([msg("A", 0x10, 1000), msg("B", 0x10, 2000, extended=True)], 500_000)  # 11 vs 29 bit: fine
    with pytest.raises(RtaError, match="bitrate"):
        analyse([msg("A", 0x10, 1000)], 0)


# --- properties --------------------------------------------------------------------------------------

message_sets = st.lists(
    st.tuples(st.integers(0, 0x7FF), st.integers(0, 8),
              st.sampled_from([1000, 2000, 2500, 5000, 10_000, 20_000]), st.integers(0, 400)),
    min_size=1, max_size=8, unique_by=lambda m: m[0],
)


def build(spec, jitter_scale: float = 1.0) -> list[RtaMessage]:
    return [msg(f"M{i:03x}", i, t, dlc, jitter_us=round(j * jitter_scale)) for i, dlc, t, j in spec]


@settings(max_examples=60, deadline=None)
@given(message_sets, st.integers(0, 7), st.integers(1, 500))
def test_monotone_in_jitter(spec, which, extra):
    base = analyse(build(spec), 250_000)
    more = build(spec)
    k = which % len(more)
    m = more[k]
    more[k] = RtaMessage(m.name, m.frame_id, m.extended, m.dlc, m.period_us, m.deadline_us,
                         m.jitter_us + extra)
    after = analyse(more, 250_000)
    for r0, r1 in zip(base.results, after.results, strict=True):
        assert r1.response_us >= r0.response_us, r0.message.name


@settings(max_examples=60, deadline=None)
@given(message_sets, st.integers(0, 0x7FF), st.integers(0, 8), st.sampled_from([1000, 5000, 10_000]))
def test_adding_a_message_never_helps(spec, new_id, dlc, period):
    ms = build(spec)
    if any(m.frame_id == new_id for m in ms):
        return
    base = analyse(ms, 250_000).by_name()
    after = analyse([*ms, msg("NEW", new_id, period, dlc)], 250_000).by_name()
    for name, r in base.items():
        assert after[name].response_us >= r.response_us, name


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 10), st.integers(0, 8), st.sampled_from([2000, 5000, 10_000]), st.integers(0, 300))
def test_lower_priority_is_never_faster(n, dlc, period, jitter):
    """Messages alike but for their id: the worst case grows with lower priority."""
    rep = analyse([msg(f"M{i}", 0x100 + i, period, dlc, jitter_us=jitter) for i in range(n)], 125_000)
    responses = [r.response_us for r in rep.results]
    assert responses == sorted(responses)


@settings(max_examples=60, deadline=None)
@given(message_sets)
def test_bound_is_at_least_jitter_blocking_and_transmission(spec):
    for r in analyse(build(spec), 500_000).results:
        assert r.response_us >= r.message.jitter_us + r.blocking_us + r.c_us
        assert r.schedulable == (r.response_us <= r.message.deadline_us)


@settings(max_examples=40, deadline=None)
@given(message_sets, st.randoms(use_true_random=False), st.booleans())
def test_the_bus_never_exceeds_the_bound(spec, rnd, synchronous):
    """hil.can.bustiming's arbitration, random phases (or all at once), random queuing jitter in [0, J]:
    no response ever exceeds the bound."""
    ms = build(spec)
    rep = analyse(ms, 250_000)
    if not all(math.isfinite(r.response_us) for r in rep.results):
        return
    phases = [0 if synchronous else rnd.randrange(m.period_us) for m in ms]
    sim = simulate(ms, 250_000, phases, 60_000, jitter_seed=rnd.randrange(1 << 30))
    bound = {r.message.name: r.response_us for r in rep.results}
    for name, worst_ns in sim.items():
        assert worst_ns <= bound[name] * 1000, name


def test_critical_instant_reaches_the_bound():
    """Blocked by the longest lower-priority frame, then released together with everything above: the
    highest-priority message takes exactly B + C, as the bound says (up to the one bit of the +τ term)."""
    ms = [msg("HI", 0x10, 10_000, 1), msg("MID", 0x20, 10_000, 4), msg("LOW", 0x30, 10_000, 8)]
    rep = analyse(ms, 500_000).by_name()
    sim = simulate(ms, 500_000, [1, 1, 0], 10_000)  # LOW starts at 0, the others come 1 µs later
    assert sim["HI"] == pytest.approx((rep["HI"].response_us - 1) * 1000, abs=1)
    assert sim["MID"] <= rep["MID"].response_us * 1000


# --- from the DBC ------------------------------------------------------------------------------------


def test_train_dbc_all_schedulable():
    """The base train's frames (8 cars; the optional functions' frames left out:
    hil.can.busload.with_functions,
    what `railhil timing --rta` analyses by default)."""
    db = with_functions(load_dbc(TRAIN_DBC), [])
    ms = messages_from_dbc(db)
    cyclic = [m for m in db.messages if m.cycle_time]
    assert [m.name for m in ms] == [m.name for m in cyclic]
    assert all(m.deadline_us == m.period_us == m_db.cycle_time * 1000 and m.jitter_us == 0
               for m, m_db in zip(ms, cyclic, strict=True))
    assert ms[0].sender == cyclic[0].senders[0]
    rep = analyse(ms, 500_000)
    assert rep.ok
    assert rep.utilisation == pytest.approx(static_load(db).total, rel=1e-12)  # ≈ 59 %
    assert 0.5 < rep.utilisation < 0.6
    worst = rep.results[-1]
    assert worst.response_us == max(r.response_us for r in rep.results)


CANOE_DBC = """VERSION ""

NS_ :

BS_:

BU_: ECU1 ECU2

BO_ 256 FAST: 8 ECU1
 SG_ a : 0|8@1+ (1,0) [0|255] "" ECU2

BO_ 512 SLOW: 4 ECU2
 SG_ b : 0|8@1+ (1,0) [0|255] "" ECU1

BO_ 768 EVENT: 1 ECU2
 SG_ d : 0|8@1+ (1,0) [0|255] "" ECU1

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_ BU_ "CANoeJitterMin" INT 0 100;
BA_DEF_ BU_ "CANoeJitterMax" INT 0 100;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_DEF_DEF_ "CANoeJitterMin" 0;
BA_DEF_DEF_ "CANoeJitterMax" 0;
BA_ "CANoeJitterMin" BU_ ECU1 2;
BA_ "CANoeJitterMax" BU_ ECU1 7;
BA_ "GenMsgCycleTime" BO_ 256 10;
BA_ "GenMsgCycleTime" BO_ 512 100;
"""


def test_jitter_from_canoe_node_attributes_and_overrides(tmp_path):
    path = tmp_path / "canoe.dbc"
    path.write_text(CANOE_DBC)
    db = load_dbc(path)
    ms = {m.name: m for m in messages_from_dbc(db)}
    assert set(ms) == {"FAST", "SLOW"}  # EVENT has no cycle time
    assert ms["FAST"].jitter_us == 500  # (7 - 2) % of 10 ms
    assert ms["FAST"].sender == "ECU1"
    assert ms["SLOW"].jitter_us == 0  # ECU2 has only the defaults, no BA_ of its own
    assert messages_from_dbc(db, {"FAST": 123})[0].jitter_us == 123
    with pytest.raises(RtaError, match="FASTT.*closest: FAST"):
        messages_from_dbc(db, {"FASTT": 1})
    with pytest.raises(RtaError, match="EVENT has no GenMsgCycleTime"):
        messages_from_dbc(db, {"EVENT": 1})


# --- measured response -----------------------------------------------------------------------------------


def test_measured_response_exact_delays():
    """Frames at k·T + d_k with a palindromic d (so the least-squares slope is exactly T): R_k = d_k -
    min d + C; a dropped frame is counted as missed and changes nothing else."""
    period, c = 10_000, 270.0
    d = np.array([0, 120, 40, 300, 40, 120, 0], dtype=float)  # µs
    d = np.concatenate([d, d[::-1]])
    t = 1000.0 + (np.arange(len(d)) * period + d) * 1e-6
    mr = measured_response(t, period, c)
    assert mr.frames == len(d) and mr.cycles == len(d) and mr.missed == 0
    assert mr.responses_us == pytest.approx(d - d.min() + c, abs=1e-3)
    assert mr.max_us == pytest.approx(300 + c, abs=1e-3)
    assert mr.period_us == pytest.approx(period, abs=1e-6) and mr.drift_ppm == pytest.approx(0, abs=1e-3)
    shuffled = np.random.default_rng(3).permutation(t)  # any order
    assert measured_response(shuffled, period, c).max_us == pytest.approx(mr.max_us, abs=1e-6)
    gone = np.delete(t, [4, 5])
    m2 = measured_response(gone, period, c)
    assert m2.missed == 2 and m2.cycles == len(d) and m2.frames == len(d) - 2
    assert m2.max_us == pytest.approx(300 + c, abs=40)  # the fit moves a little without two frames


def test_measured_response_drift_and_late_frame():
    period = 10_000
    k = np.arange(2000)
    t = k * period * (1 + 100e-6) * 1e-6  # the sender's clock 100 ppm slow: 2000 periods drift 2 ms
    t[1000] += 7e-3  # one frame 7 ms late: more than half a period
    t[-1000:] += 0.0  # (so the palindrome-free fit is dominated by the grid)
    mr = measured_response(t, period, 100.0)
    assert mr.drift_ppm == pytest.approx(100, abs=0.5)
    assert mr.missed == 0 and mr.cycles == 2000
    assert mr.max_us == pytest.approx(7000 + 100, abs=10)
    assert mr.p50_us == pytest.approx(100, abs=10)


def test_measured_response_needs_two_cycles():
    assert measured_response(np.array([1.0]), 10_000, 270) is None
    assert measured_response(np.array([1.0, 1.0001]), 10_000, 270) is None  # both in one cycle
    assert measured_response(np.array([1.0, 1.01]), 10_000, 270).max_us == pytest.approx(270)
