"""A device on its own CAN matrix, judged on its own terms (hil.devices), in either mode.

From the run's two traces — the bench's and the device's own bus (device-NODE.<format>) — and what the
gateway counted:

* **the device**: each cyclic message it sends judged against its own DBC's cycle time, and what the
  gateway's checks of its frames reported (hil.report.conduct, as for a node of the bench);
* **the gateway on the bench**: the frames it sends in the replaced node's place, judged on the bench's
  trace against the bench's DBC, as any node's; and its frames to the device, against the device's DBC
  (`to_device`: informational, the bench's own timing);
* **the gateway's latency**, per direction, as a bus analyser with both buses in view measures it: for
  each frame of a message the gateway routes (sends on a frame it translates), the time from the last
  frame of the trigger message on the other bus to it (each bus's trace timestamp: end of frame in
  lockstep, the recorder's reception in real time); for a message sent at its own cycle, the age of its
  first source's frame when it went out;
* what the translation substituted: values sent while a source was stale, source values outside a
  value-table mapping.

The device is PASS when its frames' timing is PASS, its frames' protection clean (nothing but OK, and
NONEWDATA: a frame late) and the gateway's bench frames' timing PASS.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.can.codec import loaded_dbc
from hil.report.conduct import node_conduct, silence_reported
from hil.report.kpis import read_run_trace
from hil.runtime.clock import LOCKSTEP_CLOCK, RunClock
from hil.trace.decoded import DecodedTrace


def _times(decoded: DecodedTrace, name: str) -> np.ndarray:
    """The trace times [s] of the data frames of message `name`, in order."""
    msg = decoded.db.get_message_by_name(name)
    f = decoded.frames
    k = ((np.asarray(f.arbitration_id) == msg.frame_id)
         & (np.asarray(f.extended) == bool(msg.is_extended_frame))
         & ~np.asarray(f.remote) & ~np.asarray(f.error))
    return np.sort(np.asarray(f.t, dtype=np.float64)[k])


def _figures(us: np.ndarray) -> dict:
    if not us.size:
        return {"frames": 0, "p50_us": None, "p99_us": None, "max_us": None}
    return {"frames": int(us.size), "p50_us": round(float(np.percentile(us, 50)), 1),
            "p99_us": round(float(np.percentile(us, 99)), 1), "max_us": round(float(us.max()), 1)}


def gateway_latency(routes: list[dict], bench: DecodedTrace, device: DecodedTrace,
                    clock: RunClock = LOCKSTEP_CLOCK) -> dict:
    """{"device_to_bench": figures, "bench_to_device": figures, "messages": {message: figures + kind}} of
    the routed messages (their latency) and, per message, the cyclic ones (their source's age)."""
    sides = {"bench": bench, "device": device}
    pooled: dict[str, list[np.ndarray]] = {"device_to_bench": [], "bench_to_device": []}
    messages = {}
    for r in routes:
        source_name = r["trigger"] or r.get("source")
        if source_name is None:
            continue
        src = sides["device" if r["to"] == "bench" else "bench"]
        dst = sides[r["to"]]
        s, d = _times(src, source_name), _times(dst, r["message"])
        d = d[d >= clock.t0_s]
        k = np.searchsorted(s, d, side="right") - 1
        ok = k >= 0
        us = (d[ok] - s[k[ok]]) * 1e6 * clock.speed
        messages[r["message"]] = {"to": r["to"], "from": source_name,
                                  "kind": "routed" if r["trigger"] else "cyclic", **_figures(us)}
        if r["trigger"]:
            pooled["device_to_bench" if r["to"] == "bench" else "bench_to_device"].append(us)
    out = {way: _figures(np.concatenate(parts) if parts else np.zeros(0)) for way, parts in pooled.items()}
    out["messages"] = messages
    return out


#: an OPC UA device's cycle is PASS when the 99th percentile of the time between its writes is at most this
#: many of its declared cycles (a PLC's scan varies with its load; a missed scan doubles it)
PLC_CYCLE_BOUND = 1.5


def _gateway_on_bench(record: dict, bench: DecodedTrace, db, node_stats: dict, clock: RunClock,
                      end_s: float) -> dict:
    """The gateway's frames on the bench in the replaced node's place, judged as that node's."""
    replaced = record["replaces"]
    on_bench = node_conduct(bench, db, [replaced], {n: s for n, s in node_stats.items() if n != replaced},
                            [replaced], clock, end_s)[replaced]
    on_bench["reported_silent_s"] = silence_reported(bench, db, replaced, on_bench["last_s"], clock)
    targets = {r["message"] for r in record["routes"]}
    on_bench["messages"] = {m: v for m, v in on_bench["messages"].items() if m in targets}
    return on_bench


def plc_timing(link: dict) -> tuple[str, str]:
    """(PASS | FAIL, why) of an OPC UA device's writes: it wrote, never fell silent, and the p99 of its
    cycle is within PLC_CYCLE_BOUND of the declared one."""
    bound = PLC_CYCLE_BOUND * link["cycle_ms_declared"]
    why = []
    if not link["writes"]:
        why.append("it never wrote")
    if link["silences"]:
        why.append(f"silent {link['silences']}× (longest gap {link['longest_gap_ms']:g} ms, silent after "
                   f"{link['silent_after_ms']:g} ms)")
    p99 = link["cycle"]["p99_ms"]
    if p99 is not None and p99 > bound:
        why.append(f"cycle p99 {p99:g} ms > {bound:g} ms")
    return ("FAIL" if why else "PASS"), "; ".join(why) or f"cycle p99 ≤ {bound:g} ms, never silent"


def opcua_device_kpis(record: dict, bench: DecodedTrace, db, node_stats: dict,
                      clock: RunClock = LOCKSTEP_CLOCK, end_s: float = np.inf) -> dict:
    """kpis.json's entry of a device on OPC UA (hil.devices.opcua): what the link measured — the PLC's
    cycle, the age of what it read when it wrote, the round trip from the bench's update to the PLC's write
    that reflects it, the bench's own calls (client role), refusals — and the gateway's frames on the
    bench.  PASS: its writes' timing PASS (plc_timing) and the gateway's bench frames' timing PASS."""
    link = record["opcua"]
    on_bench = _gateway_on_bench(record, bench, db, node_stats, clock, end_s)
    timing, why = plc_timing(link)
    gw = record["gateway"]
    return {
        "file": record["file"], "transport": "opcua", "node": record["node"], "replaces": record["replaces"],
        "mode": record["mode"],
        "verdict": "PASS" if timing == "PASS" and on_bench["timing"] == "PASS" else "FAIL",
        "opcua": link, "plc": {"timing": timing, "why": why,
                               "cycle_bound_ms": PLC_CYCLE_BOUND * link["cycle_ms_declared"]},
        "bench": on_bench, "routed": gw["routed"],
        "substituted": {"to_device": gw["to_device"], "to_bench": gw["to_bench"]},
        **({"processing": record["processing"]} if record.get("processing") else {}),
    }


def device_kpis(record: dict, bench: DecodedTrace, db, node_stats: dict, device_trace: Path,
                clock: RunClock = LOCKSTEP_CLOCK, end_s: float = np.inf) -> dict:
    """kpis.json's entry of one device (module docstring), from its record in RunOutcome.devices; judged on
    the frames from the run's start (the `clock`'s t0) to its end `end_s` [trace time]."""
    if record.get("opcua") is not None:
        return opcua_device_kpis(record, bench, db, node_stats, clock, end_s)
    ddb, dcodec = loaded_dbc(record["dbc"])

    dtrace = read_run_trace(device_trace, ddb, dcodec)
    gw = record["gateway"]
    own = node_conduct(dtrace, ddb, [record["node"]], {"gateway": gw["device_side"]}, [record["node"]],
                       clock, end_s)[record["node"]]
    replaced = record["replaces"]
    on_bench = _gateway_on_bench(record, bench, db, node_stats, clock, end_s)
    # the gateway's frames to the device, against the device's DBC (informational: the bench's timing)
    senders = sorted({s for m in record["receives"] for s in ddb.get_message_by_name(m).senders})
    judged = node_conduct(dtrace, ddb, senders, {}, [], clock, end_s)
    to_device = {m: v for s in senders for m, v in judged[s]["messages"].items() if m in record["receives"]}
    latency = gateway_latency(record["routes"], bench, dtrace, clock)
    passed = (own["timing"] == "PASS" and own["protection_clean"] and on_bench["timing"] == "PASS")
    return {
        "file": record["file"], "dbc": record["dbc"], "node": record["node"], "replaces": replaced,
        "mode": record["mode"], "trace": device_trace.name,
        "verdict": "PASS" if passed else "FAIL",
        "device": own, "bench": on_bench, "latency": latency, "to_device": to_device,
        "protection": record["protection"],
        "routed": gw["routed"],
        "substituted": {"to_device": gw["to_device"], "to_bench": gw["to_bench"]},
        **({"bus": record["bus"]} if record.get("bus") else {}),
        # real time: what the gateway measured itself, from a frame's reception to its translation's send
        **({"processing": record["processing"]} if record.get("processing") else {}),
    }
