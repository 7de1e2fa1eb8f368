"""Fuzzed frames through the node runtime of a whole train: decode + SecOC verify + E2E check.

Every node of the default scenario (plant, desk, BCU, BECUs) is built as `railhil run` builds it and
cycles on its own schedule; each frame a node sends reaches its receivers as sent and as fuzzed copies
-- replayed, bit-flipped, truncated or extended (wrong DLC), or random bytes under a random identifier
(unknown ids included).  Nothing may raise out of `Node.receive`/`Node.cycle`; every bad frame is
counted in NodeStats; no controller step fails; and a fuzzed copy of an authenticated frame is never
accepted (a forgery) -- the 24-bit MAC lets a random frame through with probability 2**-24, so one
acceptance in 10**6 copies is the limit.

`make fuzz` runs the 10**6-frame session (`RAILHIL_FUZZ_FRAMES` for more) and prints its tally.
"""

from __future__ import annotations

import os
import random
import time

import pytest
from conftest import DEFAULT

from hil.can.attributes import secoc_data_id
from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.runtime.assembly import build_node, node_names
from hil.scenario import load_scenario

COPIES = 6        # fuzzed deliveries per frame sent, besides the genuine one


def _mutate(rng: random.Random, frame: bytes, history: list[bytes]) -> tuple[bytes, str]:
    kind = rng.random()
    if kind < 0.25 and history:
        return rng.choice(history), "replay"
    if kind < 0.65:
        data = bytearray(frame)
        for _ in range(rng.randint(1, 3)):
            bit = rng.randrange(len(data) * 8)
            data[bit // 8] ^= 1 << (bit % 8)
        return bytes(data), "bitflip"
    if kind < 0.85:
        if rng.random() < 0.5:
            return frame[:rng.randrange(len(frame))], "short"
        return frame + rng.randbytes(rng.randint(1, 8)), "long"
    return rng.randbytes(rng.randint(0, 8)), "random"


def fuzz_nodes(count: int, seed: int) -> dict[str, int]:
    """Deliver `count` frames (genuine and fuzzed) to the nodes of the default scenario."""
    rng = random.Random(seed)
    scenario = load_scenario(DEFAULT)
    db = load_dbc()
    codec = Codec(db)
    nodes = [build_node(name, scenario, db, codec) for name in node_names(scenario)]
    receivers = {}
    for node in nodes:
        for fid in node.rx_ids:
            receivers.setdefault(fid, []).append(node)
    authenticated = {m.frame_id for m in db.messages if secoc_data_id(m)}
    tally = dict.fromkeys(("frames", "genuine", "replay", "bitflip", "short", "long", "random",
                           "forged_accepted"), 0)
    history: dict[int, list[bytes]] = {}
    due = {node.name: node.offset_us for node in nodes}
    now = 0

    def deliver(fid: int, data: bytes, to) -> bool:
        """Deliver to `to`; True when an authenticated message's value was taken by any receiver."""
        taken = False
        for node in to:
            version = node.rx.version                    # bumps when a frame's values are taken
            node.receive(fid, data, now)
            taken |= node.rx.version != version
        tally["frames"] += 1
        return taken

    while tally["frames"] < count:
        now = min(due.values())
        for node in nodes:
            if due[node.name] != now:
                continue
            due[node.name] += node.period_us
            for fc, data in node.cycle(now):
                fid = fc.frame_id
                to = receivers.get(fid, [])
                deliver(fid, data, to)
                tally["genuine"] += 1
                past = history.setdefault(fid, [])
                for _ in range(COPIES):
                    if rng.random() < 0.1:               # random bytes under a random identifier
                        rid = rng.randrange(0x800)
                        deliver(rid, rng.randbytes(rng.randint(0, 8)), receivers.get(rid, nodes))
                        tally["random"] += 1
                        continue
                    bad, kind = _mutate(rng, data, past)
                    tally[kind] += 1
                    if deliver(fid, bad, to) and fid in authenticated and bad != data:
                        tally["forged_accepted"] += 1
                past.append(data)
                del past[:-16]
    for node in nodes:
        stats = node.stats
        tally["bad_frames"] = tally.get("bad_frames", 0) + stats.bad_frames
        tally["e2e_discarded"] = tally.get("e2e_discarded", 0) + stats.e2e_discarded
        tally["secoc_rejected"] = tally.get("secoc_rejected", 0) + sum((stats.secoc_rejected or {}).values())
        tally["step_errors"] = tally.get("step_errors", 0) + stats.step_errors
        tally["bad_outputs"] = tally.get("bad_outputs", 0) + stats.bad_outputs
    tally["simulated_s"] = now / 1e6
    return tally


def _check(tally: dict[str, int], count: int) -> None:
    assert tally["frames"] >= count
    assert tally["step_errors"] == 0 and tally["bad_outputs"] == 0, tally
    assert tally["bad_frames"] > 0 and tally["secoc_rejected"] > 0 and tally["e2e_discarded"] > 0, tally
    assert tally["forged_accepted"] <= 1, tally


def test_fuzzed_frames_through_the_node_runtime():
    tally = fuzz_nodes(30_000, seed=3)
    _check(tally, 30_000)


@pytest.mark.slow
def test_a_million_fuzzed_frames_through_the_node_runtime():
    count = int(os.environ.get("RAILHIL_FUZZ_FRAMES", 1_000_000))
    start = time.perf_counter()
    tally = fuzz_nodes(count, seed=int(os.environ.get("RAILHIL_FUZZ_SEED", 4)))
    elapsed = time.perf_counter() - start
    print(f"\n{tally['frames']:,} frames through the nodes of the default train (decode + SecOC + E2E) in "
          f"{elapsed:.1f} s ({tally['frames'] / elapsed:,.0f} frames/s), {tally['simulated_s']:.1f} s "
          f"simulated: {tally}")
    _check(tally, count)
