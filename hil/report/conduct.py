"""How each node of a real-time run behaved on the bus, judged from the trace and the receivers' checks, the
same way for a simulated node and an external one (a device under test: `railhil run --external NAME`).

Per node: each cyclic message it sends (the DBC's senders) judged against its GenMsgCycleTime on the
trace (hil.trace.timing.judge: mean period within ±TOLERANCE, no frame missed, not stopped), and what
the receivers' E2E and SecOC checks reported about its frames (every status but OK, by status: REPEATED,
WRONGSEQUENCE, ERROR, NONEWDATA, SECOC_MAC_MISMATCH, ...).  A node's timing is PASS when each of its
cyclic messages is; its protection is clean when nothing but NONEWDATA was reported (a frame 1.5 of its
cycles late: timing, counted apart).  The first and last frame times say when it was heard.
"""

from __future__ import annotations

import numpy as np

from hil.runtime.clock import LOCKSTEP_CLOCK, RunClock
from hil.trace.decoded import DecodedTrace
from hil.trace.timing import KIND_DATA, KIND_ERROR, KIND_REMOTE, FrameArrays, analyse

TOLERANCE = 0.10               # a message's mean period within ±10 % of its cycle time (`railhil timing`'s)


def frame_arrays_of(decoded: DecodedTrace, from_s: float = -np.inf, to_s: float = np.inf) -> FrameArrays:
    """The trace's frames from `from_s` to `to_s` [trace time] as hil.trace.timing's columns."""
    f = decoded.frames
    t = np.asarray(f.t)
    k = (t >= from_s) & (t <= to_s)
    kind = np.where(f.error, KIND_ERROR, np.where(f.remote, KIND_REMOTE, KIND_DATA)).astype(np.int8)
    return FrameArrays(t=np.asarray(f.t, dtype=np.float64)[k], arbitration_id=np.asarray(f.arbitration_id)[k],
                       extended=np.asarray(f.extended, dtype=bool)[k], dlc=np.asarray(f.dlc)[k], kind=kind[k],
                       fd=np.zeros(int(k.sum()), dtype=bool))


def frames_sent_by(decoded: DecodedTrace, db, node: str) -> int:
    """The data frames in the trace of the messages the DBC names `node` the sender of."""
    ids = [m.frame_id for m in db.messages if node in m.senders]
    f = decoded.frames
    return int(np.count_nonzero(np.isin(f.arbitration_id, ids) & ~f.remote & ~f.error))


def node_conduct(decoded: DecodedTrace, db, nodes: list[str], node_stats: dict[str, dict],
                 external: list[str], clock: RunClock = LOCKSTEP_CLOCK,
                 end_s: float = np.inf, sent_by: dict[str, list[str]] | None = None) -> dict[str, dict]:
    """{node: {"external", "frames", "first_s", "last_s", "timing", "messages": {name: {...}},
    "protection": {status: count}}} for every node in `nodes`, judged on the frames of the run: from its
    start (the run's `clock`: t0) to its end `end_s` [trace time] (an external device may send before the
    run began and after it ended, while the recorder still listens).  `sent_by`
    (hil.runtime.run.messages_sent): the messages each node sends in this run; a node's messages are those,
    not every message the DBC gives it (the frames of cars the train does not have, of studies the run has
    not), where it is known."""
    arrays = frame_arrays_of(decoded, clock.t0_s, end_s)
    report = analyse(arrays, db, TOLERANCE)
    by_message = {m.name: m for m in report.messages}
    reported: dict[str, dict[str, int]] = {}         # message -> status -> count, from every receiver
    for stats in node_stats.values():
        for _, message, status in stats.get("e2e_events") or ():
            if status not in ("INITIAL", "OK"):
                counts = reported.setdefault(message, {})
                counts[status] = counts.get(status, 0) + 1
    out: dict[str, dict] = {}
    for node in nodes:
        sent = [m for m in db.messages if node in m.senders]
        if sent_by and node in sent_by:
            names = set(sent_by[node])
            sent = [m for m in db.messages if m.name in names]
        messages = {}
        protection: dict[str, int] = {}
        for m in sent:
            for status, n in (reported.get(m.name) or {}).items():
                protection[status] = protection.get(status, 0) + n
            judged = by_message.get(m.name)
            if judged is None:                      # an event frame: no cycle time to judge
                continue
            s = judged.stats
            messages[m.name] = {"cycle_ms": judged.cycle_ms, "verdict": judged.verdict,
                                "reason": judged.reason,
                                "frames": 0 if s is None else s.count,
                                "mean_ms": None if s is None or s.mean_ms is None else round(s.mean_ms, 3),
                                "max_ms": None if s is None or s.max_ms is None else round(s.max_ms, 3),
                                "missed": judged.missed}
        ids = [m.frame_id for m in sent]
        k = np.flatnonzero(np.isin(arrays.arbitration_id, ids) & (arrays.kind == KIND_DATA))
        # messages the run does not send by design (another study's frames, cars beyond the train) are
        # MISSING for every node alike: a node is judged on the messages it did send
        present = [v for v in messages.values() if v["verdict"] != "MISSING"]
        out[node] = {
            "external": node in external,
            "frames": int(k.size),
            "first_s": round(float(clock.simulated_s(arrays.t[k[0]])), 4) if k.size else None,
            "last_s": round(float(clock.simulated_s(arrays.t[k[-1]])), 4) if k.size else None,
            "timing": ("PASS" if present and all(v["verdict"] == "PASS" for v in present) else
                       "FAIL" if present else "SILENT"),
            "messages": messages,
            "protection": dict(sorted(protection.items())),
            "protection_clean": not (set(protection) - {"NONEWDATA"}),
        }
    return out


def silence_reported(decoded: DecodedTrace, db, node: str, last_s: float | None,
                     clock: RunClock = LOCKSTEP_CLOCK) -> float | None:
    """When the BCU first reported car n silent (BCU_STATUS CarsSilent bit n−1) after BECUn's last frame at
    `last_s` [s, simulated]; None: not a BECU, never silent, or never reported."""
    if last_s is None or not (node.startswith("BECU") and node[4:].isdigit()):
        return None
    table = decoded.table("BCU_STATUS")
    bits = table.columns.get("CarsSilent")
    if bits is None:
        return None
    t = clock.simulated_s(table.t)
    k = np.flatnonzero((t > last_s) & (bits.astype(np.int64) >> (int(node[4:]) - 1) & 1 == 1))
    return round(float(t[k[0]]), 4) if k.size else None
