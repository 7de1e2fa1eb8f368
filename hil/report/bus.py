"""The bus figures of a run from its recorded trace: the load its frames put on the bus and the worst response
the trace shows, so that a real-time run has the `bus` KPIs a lockstep run has (there the bit-timed bus
model knows them frame by frame).

Two loads, both over the run (from its start t0 to its end, in the trace's clock):

* ``load``: the bits the frames took on the wire, each frame with its real stuff bits (its id and data
  stuffed, CRC included: hil.can.bustiming.exact_frame_bits), over the run's duration and the bitrate.
  This is what the lockstep bus counts as its busy time, so a lockstep run and its real-time twin give
  the same figure;
* ``load_worst_case``: every frame at its worst-case stuffed length (Davis et al. 2007: hil.can.busload),
  the length the response-time analysis must assume.  `railhil timing`'s average and the DBC's static
  load (every cyclic frame once per cycle at that length, `railhil timing --rta`) count frames that way,
  so they read a few points above ``load`` (45.4 % against 39.4 % on the default run): the same frames,
  counted at their longest.

Worst response (real time): per cyclic message, each frame's place in its cycle against the cycle's grid
plus its transmission time (`grid_responses`: a lower estimate of release to end of frame, the release
jitter of the sender's host included), and the largest of all messages.  A trace cannot tell a frame
more than a cycle late from one of the next cycle, so a real-time run's `bus` has no deadline misses:
its nodes' lateness is judged by the real-time verdict (kpis.json `realtime`).
"""

from __future__ import annotations

import numpy as np
from cantools.database.can import Database

from hil.can.busload import declared_bitrate, frame_bits
from hil.can.bustiming import FrameBits
from hil.trace.decoded import DecodedTrace

ROUND = 5          # digits of the loads in kpis.json, as the lockstep bus's


def run_frames(decoded: DecodedTrace, from_s: float, to_s: float) -> np.ndarray:
    """The rows of the trace's data and remote frames from `from_s` to `to_s` [trace time]."""
    f = decoded.frames
    t = np.asarray(f.t)
    return np.flatnonzero((t >= from_s) & (t <= to_s) & ~np.asarray(f.error, dtype=bool))


def wire_bits(decoded: DecodedTrace, rows: np.ndarray) -> tuple[int, int]:
    """(bits with each frame's real stuffing, bits at worst-case stuffing) of the frames at `rows`;
    CAN FD frames counted as classic frames of at most 8 bytes."""

    f = decoded.frames
    exact = worst = 0
    coders: dict[tuple, FrameBits] = {}
    ids, ext, remote = f.arbitration_id[rows], f.extended[rows], f.remote[rows]
    dlc, length, payload = f.dlc[rows], f.length[rows], f.payload[rows]
    for i in range(len(rows)):
        n = 0 if remote[i] else int(min(length[i], 8))
        d = int(min(dlc[i], 15))
        key = (int(ids[i]), bool(ext[i]), d, n, bool(remote[i]))
        coder = coders.get(key)
        if coder is None:
            coder = coders[key] = FrameBits(key[0], key[1], d, n, key[4])
        exact += coder.bits(payload[i, :n].tobytes())
        worst += frame_bits(0 if remote[i] else min(d, 8), key[1])
    return exact, worst


def grid_responses(t_s: np.ndarray, period_us: float, c_us: float) -> np.ndarray | None:
    """Estimated responses [µs] of the frames of one cyclic message of a real-time trace, from their
    timestamps alone: each frame's place in its cycle, against the cycle's grid.

    hil.can.rta.measured_response numbers the cycles from the gaps, so a host stall that delays a frame
    and bunches the next can shift the numbering by one for the rest of the trace (its fit then tilts by
    a period over the run).  Here the cycle is taken modulo: the period T is the trace's span over the
    whole number of nominal cycles in it; each frame's phase t/T mod 1 is taken against the message's
    typical phase (their circular mean), wrapped to ±half a cycle, a slow drift of the clocks removed by a
    line fitted through the phases; the earliest of the frames on time (within a tenth of a cycle of the
    usual phase) is taken as not queued, as in measured_response, and no frame comes before its release,
    so a response is ((phase − earliest phase) mod 1)·T + C.  A frame more than a cycle late cannot be told
    from a missed one: the estimate is a lower one, as the trace allows.  None with fewer than 3 frames."""
    t = np.sort(np.asarray(t_s, dtype=np.float64))
    if len(t) < 3 or not period_us > 0:
        return None
    nominal = period_us * 1e-6
    t = t - t[0]
    cycles = round(float(t[-1]) / nominal)
    period = float(t[-1]) / cycles if cycles else nominal      # the sender's period, in the trace's clock
    angle = 2 * np.pi * (t / period)
    phi = np.angle(np.mean(np.exp(1j * angle))) / (2 * np.pi)        # the typical phase, in cycles
    r = (t / period - phi + 0.5) % 1.0 - 0.5                          # each frame's offset, in cycles
    core = np.abs(r - np.median(r)) < 0.1                             # the frames on time: the clocks' drift
    if core.sum() >= 3:
        slope, intercept = np.polyfit(t[core], r[core], 1)
        r = (r - (intercept + slope * t) + 0.5) % 1.0 - 0.5
        core = np.abs(r - np.median(r)) < 0.1
    earliest = float(r[core].min()) if core.any() else float(r.min())
    return ((r - earliest) % 1.0) * period * 1e6 + c_us       # no frame comes before its release


def worst_response(decoded: DecodedTrace, db: Database, rows: np.ndarray, bitrate_bps: int
                   ) -> tuple[str | None, float]:
    """(message, its largest estimated response [µs]) of the cyclic messages of `db` in the frames at `rows`
    (`grid_responses`)."""
    f = decoded.frames
    t = np.asarray(f.t)[rows]
    ids, ext, data = f.arbitration_id[rows], f.extended[rows], ~np.asarray(f.remote)[rows]
    worst_name, worst_us = None, 0.0
    for m in db.messages:
        if not m.cycle_time or m.cycle_time <= 0:
            continue
        mine = t[data & (ids == m.frame_id) & (ext == bool(m.is_extended_frame))]
        c_us = frame_bits(min(m.length, 8), bool(m.is_extended_frame)) / bitrate_bps * 1e6
        got = grid_responses(mine, m.cycle_time * 1e3, c_us)
        if got is not None and got.max() > worst_us:
            worst_name, worst_us = m.name, float(got.max())
    return worst_name, worst_us


def worst_case_load(decoded: DecodedTrace, from_s: float, to_s: float, bitrate_bps: int) -> float | None:
    """The frames of the run at their worst-case stuffed length, over the run's duration and the bitrate."""
    if not to_s > from_s:
        return None
    f = decoded.frames
    rows = run_frames(decoded, from_s, to_s)
    table = np.array([[frame_bits(d, ext) for d in range(16)] for ext in (False, True)], dtype=np.int64)
    dlc = np.where(f.remote[rows], 0, np.minimum(f.dlc[rows], 8))
    bits = int(table[f.extended[rows].astype(np.int64), dlc].sum())
    return round(bits / (to_s - from_s) / bitrate_bps, ROUND)


def trace_bus_kpis(decoded: DecodedTrace, db: Database, from_s: float, to_s: float,
                   bitrate_bps: int | None = None) -> dict | None:
    """kpis.json's `bus` of a run without a bus model (real time), from its trace: bitrate, load (real
    stuffing), load_worst_case, worst response and its message, and `source`: "trace".
    None when the bitrate is unknown (no Baudrate in the DBC and none in the scenario) or the run is
    empty."""
    bitrate = bitrate_bps or declared_bitrate(db)
    if not bitrate or not to_s > from_s:
        return None
    rows = run_frames(decoded, from_s, to_s)
    exact, worst = wire_bits(decoded, rows)
    name, response_us = worst_response(decoded, db, rows, bitrate)
    duration = to_s - from_s
    return {"bitrate_bps": int(bitrate), "load": round(exact / duration / bitrate, ROUND),
            "load_worst_case": round(worst / duration / bitrate, ROUND),
            "worst_response_us": round(response_us, 1), "worst_response_message": name, "source": "trace"}
