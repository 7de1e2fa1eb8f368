"""`railhil reproduce consensus` — seed 003's consensus braking: cases 1-3 with and without the observer,
the cycle sweep and the latency sweep, next to the paper's statements.

Settings, all in lockstep with the real nodes, frames and codec:

- **paper**: the paper's simulation — Table 2's gains unscaled, the BECUs and the sensor frames every
  1 ms (the paper's sampling), 1 ms plant step, on the *ideal* bus (a frame arrives when it is sent).  A
  500 kbit/s bus cannot carry this (the static load is printed): it is the reference for the paper's claims.
- **can**: the scenario as written (scenarios/consensus_case*.toml) — the DBC's cycle (2 ms) on the
  bit-timed bus of the consensus segment (1 Mbit/s), the gains scaled to the cycle (`loop_gain`).
- **can500** (cycle sweep only): the same on a bit-timed 500 kbit/s bus (the DBC's Baudrate).

Cycle sweep: case 1 at cycles 1-10 ms (DBC cycle times of BECUn_CONS and PLANT_CONS_CARn replaced in a
copy of the DBC) in every setting, and case 3 (the hardest: every car skids, then regains its braking force
at once) in the can setting over its first CASE3_SWEEP_S.  Latency sweep: the paper and can settings with
extra delay on every BECUn_CONS frame (`[messages.BECUn_CONS] delay_min_us = delay_max_us`,
hil/runtime/release.py).

Figures per run (like Figs. 3-17 of seed 003, plots.py): speeds, coupler displacements, tracking errors and
the observer's estimate for car 2 against the plant's φ₂/m₂.  The tables' definitions (max |Δl|,
convergence time, tracking RMS, observer convergence) are kpis.py's, the same for a `railhil run`.
"""

from __future__ import annotations

import argparse
import copy
import json
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np

from hil.campaign.jobs import map_jobs
from hil.can.busload import declared_bitrate, static_load
from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.errors import RailhilError, ScenarioError
from hil.resources import scenarios_dir
from hil.runtime.lockstep import run_lockstep
from hil.scenario import MessageTiming, load_scenario
from hil.studies.consensus.kpis import consensus_figures
from hil.studies.consensus.plots import case_series, case_title, plot_case, plot_sweeps

SCENARIOS = scenarios_dir()
CASES = (1, 2, 3)
SETTINGS = ("paper", "can", "can500")
CASE3_SWEEP_S = 5.0            # case 3's cycle sweep runs past the end of skidding at 4.5 s [s]
PAPER = {
    "case1": "convergence < 0.04 s; |Δl| within ±1 cm; observer converges within 20 ms",
    "case2": "≈ 0.03 s to converge after the braking capacity is restored; |Δl| within ±1 cm",
    "case3": "observer compensation keeps the tracking error small; without it the error oscillates",
}


@dataclass(frozen=True)
class Job:
    """One lockstep run of the study."""

    label: str
    case: int
    observer: bool = True
    setting: str = "paper"          # "paper" (1 ms, ideal bus, Table 2 gains) | "can" (the scenario as is)
    #                                 | "can500" (the scenario on a 500 kbit/s bus)
    cycle_ms: int | None = None     # replaces the DBC cycle of the consensus frames (None: paper 1, can DBC)
    delay_ms: float = 0.0           # extra delay of every BECUn_CONS frame [ms]
    horizon_s: float | None = None  # None: the scenario's max_duration_s
    series: bool = True             # keep decimated time series for the figures


def _scenario(job: Job):
    sc = load_scenario(SCENARIOS / f"consensus_case{job.case}.toml")
    cons = sc.consensus.model_copy(update={"observer": job.observer})
    upd: dict = {}
    if job.setting == "paper":           # the paper's simulation: no bus timing, Table 2 gains, 1 ms
        cons = cons.model_copy(update={"loop_gain": None, "plant_step_us": 1000})
        upd["bus"] = sc.bus.model_copy(update={"timing": "ideal", "bitrate": None})
    elif job.setting == "can500":
        upd["bus"] = sc.bus.model_copy(update={"bitrate": 500_000})
    upd["consensus"] = cons
    if job.horizon_s is not None:
        upd["max_duration_s"] = job.horizon_s
    if job.delay_ms:
        d = round(job.delay_ms * 1000)
        upd["messages"] = {f"BECU{i}_CONS": MessageTiming(delay_min_us=d, delay_max_us=d)
                           for i in range(1, sc.train.cars + 1)}
    return sc.model_copy(update=upd)


def _database(cycle_ms: int | None):
    """The project DBC, with the consensus loop's frames at `cycle_ms` when given (in a copy)."""
    db = load_dbc()
    if cycle_ms is not None:
        db = copy.deepcopy(db)
        for m in db.messages:
            if m.name.startswith("PLANT_CONS_CAR") or m.name.endswith("_CONS"):
                m.cycle_time = cycle_ms
    return db


class DiagListener(can.Listener):
    """Collects BECU2's consensus diagnostics (PhiHat) from the bus as a python-can listener."""

    def __init__(self, codec, frame_id: int) -> None:
        self.codec, self.frame_id = codec, frame_id
        self.t: list[float] = []
        self.phi_hat: list[float] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == self.frame_id:
            self.t.append(msg.timestamp)
            self.phi_hat.append(self.codec[self.frame_id].decode(msg.data)["PhiHat"])


def run_job(job: Job) -> dict:
    """Run one job in lockstep and reduce it to the study's figures (and decimated series)."""
    sc = _scenario(job)
    cycle = job.cycle_ms if job.cycle_ms is not None else (1 if job.setting == "paper" else None)
    db = _database(cycle)
    codec = Codec(db)
    diag_id = db.get_message_by_name("BECU2_CONS_DIAG").frame_id
    listener = DiagListener(codec, diag_id)
    out = run_lockstep(sc, db, codec, listener)
    cols = out.truth.columns()
    n = sc.train.cars
    t = cols["t_s"]
    fig = consensus_figures(sc, cols, float(max(out.truth.max_abs_dl_m)), np.asarray(listener.t),
                            np.asarray(listener.phi_hat))
    end = float(t[-1]) + 1e-9
    load = out.bus["load"] if out.bus else None
    names = ["CONS_REF"] + [f"{f}" for i in range(1, n + 1)
                            for f in (f"PLANT_CONS_CAR{i}", f"BECU{i}_CONS", f"BECU{i}_CONS_DIAG")]
    ids = [db.get_message_by_name(m).frame_id for m in names]
    bitrate = sc.bus.bitrate or declared_bitrate(db) or 500_000
    static = static_load(db, bitrate_bps=bitrate, frame_ids=ids).total
    res = {
        "label": job.label, "case": job.case, "observer": job.observer, "setting": job.setting,
        "cycle_ms": cycle if cycle is not None else int(db.get_message_by_name("BECU1_CONS").cycle_time),
        "bus": sc.bus.timing, "bitrate": bitrate, "delay_ms": job.delay_ms, "horizon_s": round(end, 3),
        **fig, "bus_load_measured": None if load is None else round(load, 4),
        "bus_load_static": round(static, 4), "wall_s": round(out.wall_s, 2),
        "frames_lost": sum(v.get("deadline_misses", 0) for v in (out.bus or {}).get("messages", {}).values()),
    }
    if job.series:
        res["series"] = case_series(sc, cols, np.asarray(listener.t), np.asarray(listener.phi_hat))
    return res


def _run_all(jobs: list[Job], workers: int, progress: bool) -> list[dict]:
    return map_jobs(run_job, jobs, workers, "consensus runs", progress)


def build_jobs(cycles: list[int], latencies: list[float], sweep_horizon_s: float,
               case_horizon_s: float | None) -> list[Job]:
    jobs = []
    for setting in ("paper", "can"):
        for case in CASES:
            for obs in (True, False):
                jobs.append(Job(f"{setting}/case{case}/{'obs' if obs else 'noobs'}", case, obs, setting,
                                horizon_s=case_horizon_s))
    for setting in SETTINGS:
        for cyc in cycles:
            jobs.append(Job(f"cycle/{setting}/{cyc}ms", 1, True, setting, cycle_ms=cyc,
                            horizon_s=sweep_horizon_s, series=False))
    for cyc in cycles:
        jobs.append(Job(f"cycle/can/case3/{cyc}ms", 3, True, "can", cycle_ms=cyc,
                        horizon_s=max(sweep_horizon_s, CASE3_SWEEP_S), series=False))
    for setting in ("paper", "can"):
        for d in latencies:
            jobs.append(Job(f"latency/{setting}/{d:g}ms", 1, True, setting, delay_ms=d,
                            horizon_s=sweep_horizon_s, series=False))
    return jobs


# ----------------------------------------------------------------------------------------------- figures


# ------------------------------------------------------------------------------------------------- table
def _f(x, nd=3) -> str:
    return "-" if x is None else (f"{x:.{nd}f}" if isinstance(x, float) else str(x))


def case_table(rows: list[dict]) -> list[str]:
    out = [f"{'run':<20} {'cyc':>4} {'max|Δl| mm':>10} {'±1cm':>5} {'conv s':>13} {'conv rec s':>13} "
           f"{'RMS v_e m/s':>11} {'obs ms':>7} {'load':>6}  paper   (conv: to 1 / 0.1 km/h)"]
    for r in rows:
        load = r["bus_load_measured"] if r["bus_load_measured"] is not None else r["bus_load_static"]
        out.append(f"{r['label']:<20} {r['cycle_ms']:>4} {r['max_abs_dl_mm']:>10.2f} "
                   f"{'yes' if r['holds_1cm'] else 'NO':>5} "
                   f"{_f(r['converged_s']) + ' / ' + _f(r['converged_fine_s']):>13} "
                   f"{_f(r['converged_after_recovery_s']) + ' / ':>8}"
                   f"{_f(r['converged_after_recovery_fine_s']):<5} "
                   f"{_f(r['tracking_rms_mps'], 4):>11} "
                   f"{_f(r['observer_converged_ms'], 1):>7} {100 * load:>5.0f}%  "
                   f"{PAPER['case' + str(r['case'])]}")
    return out


def sweep_table(rows: list[dict], key: str, unit: str) -> list[str]:
    out = [f"{key + ' ' + unit:<14} {'setting':<7} {'case':>4} {'max|Δl| mm':>10} {'±1cm':>5} {'conv s':>7} "
           f"{'|v_e| end':>9} {'load':>6}"]
    for r in rows:
        load = r["bus_load_measured"] if r["bus_load_measured"] is not None else r["bus_load_static"]
        out.append(f"{r[key]:<14g} {r['setting']:<7} {r['case']:>4} {r['max_abs_dl_mm']:>10.2f} "
                   f"{'yes' if r['holds_1cm'] else 'NO':>5} {_f(r['converged_s']):>7} "
                   f"{r['final_abs_ve_max_mps']:>9.4f} {100 * load:>5.0f}%")
    return out


def slowest_holding(rows: list[dict]) -> int | None:
    """The slowest cycle of a sweep at which ±1 cm holds and the cars converge, every cycle from the fastest
    holding one up to it holding too (cycles faster than that may fail: a saturated bus)."""
    best = None
    for r in sorted(rows, key=lambda r: r["cycle_ms"]):
        if not (r["holds_1cm"] and r["converged_s"] is not None):
            if best is not None:
                break
            continue
        best = r["cycle_ms"]
    return best


def first_breaking(rows: list[dict]) -> float | None:
    for r in sorted(rows, key=lambda r: r["delay_ms"]):
        if not r["holds_1cm"]:
            return r["delay_ms"]
    return None


def _ms_list(kind: type, noun: str, lo: float, hi: float, what: str):
    """An argparse type: comma-separated `noun` (parsed by `kind`) [ms], each in lo..hi."""
    def parse(text: str) -> list:
        try:
            vals = [kind(x) for x in text.split(",") if x.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated {noun} (ms), got {text!r}") from None
        if not vals or any(not lo <= v <= hi for v in vals):
            raise argparse.ArgumentTypeError(f"{what} must be {lo:g}..{hi:g} ms, got {text!r}")
        return vals
    return parse


_ints = _ms_list(int, "integers", 1, 100, "cycles")
_floats = _ms_list(float, "numbers", 0, 1000, "latencies")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--jobs", type=int, default=2,
                   help="worker processes for the runs (default 2; 1 = in this process)")
    p.add_argument("--out", type=Path, default=Path("runs") / "consensus",
                   help="folder for the figures (PNG) and results.json (default runs/consensus)")
    p.add_argument("--cycles", type=_ints, default=[1, 2, 3, 4, 5, 6, 8, 10],
                   help="consensus cycles of the sweep [ms], comma-separated (default 1,2,3,4,5,6,8,10)")
    p.add_argument("--latencies", type=_floats, default=[0, 0.5, 1, 2, 3, 5, 10, 20, 50],
                   help="extra latency on every BECUn_CONS frame [ms], comma-separated "
                        "(default 0,0.5,1,2,3,5,10,20,50)")
    p.add_argument("--sweep-horizon", type=float, default=2.0,
                   help="simulated time of each sweep run [s] (default 2: t0 transient and convergence)")
    p.add_argument("--horizon", type=float, default=None,
                   help="simulated time of each case run [s] (default: the scenario's max_duration_s, 10 s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    if args.jobs < 1:
        raise ScenarioError(f"--jobs {args.jobs}: expected 1 or more worker processes")
    for name in ("horizon", "sweep_horizon"):
        val = getattr(args, name)
        if val is not None and not 0.05 <= val <= 60:
            raise ScenarioError(f"--{name.replace('_', '-')} {val}: expected 0.05..60 s")
    out: Path = args.out
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RailhilError(f"--out {out}: cannot create the folder: {exc}") from None
    jobs = build_jobs(args.cycles, args.latencies, args.sweep_horizon, args.horizon)
    results = _run_all(jobs, args.jobs, not args.no_progress)
    by_label = {r["label"]: r for r in results}
    files = []
    for r in results:
        if "series" in r:
            files.append(plot_case(r["series"], case_title(r), out / f"{r['label'].replace('/', '_')}.png"))
    cycle_rows = [r for r in results if r["label"].startswith("cycle/")]
    lat_rows = [r for r in results if r["label"].startswith("latency/")]
    files.append(plot_sweeps(cycle_rows, lat_rows, out / "sweeps.png"))
    lines = ["seed 003 consensus braking — cases (paper = 1 ms ideal bus, Table 2 gains; "
             "can = the scenarios: "
             "the DBC cycle on the bit-timed consensus bus, loop_gain)"]
    lines += case_table([by_label[j.label] for j in jobs if j.label.count("/") == 2 and "case" in j.label])
    for setting in ("paper", "can"):
        on = by_label.get(f"{setting}/case3/obs")
        off = by_label.get(f"{setting}/case3/noobs")
        if on and off and on["tracking_rms_mps"] and off["tracking_rms_mps"]:
            red = 1 - on["tracking_rms_mps"] / off["tracking_rms_mps"]
            lines.append(f"case 3 ({setting}): tracking RMS from {on['rms_from_s']} s with observer "
                         f"{on['tracking_rms_mps']:.4f} m/s, without {off['tracking_rms_mps']:.4f} m/s: "
                         f"reduction {100 * red:.0f} %")
    lines += ["", "cycle sweep"] + sweep_table(sorted(cycle_rows, key=lambda r: (r["setting"], r["case"],
                                                                               r["cycle_ms"])),
                                                 "cycle_ms", "")
    for setting, case in ((s_, c_) for s_ in SETTINGS for c_ in CASES):
        rows = [r for r in cycle_rows if r["setting"] == setting and r["case"] == case]
        if rows:
            lines.append(f"slowest cycle holding ±1 cm and converging ({setting}, case {case}, "
                         f"{rows[0]['bus']} bus {rows[0]['bitrate'] // 1000} kbit/s): "
                         f"{_f(slowest_holding(rows))} ms")
    lines += ["", "latency sweep (case 1)"] + sweep_table(sorted(lat_rows, key=lambda r: (r["setting"],
                                                                                       r["delay_ms"])),
                                                         "delay_ms", "")
    for setting in ("paper", "can"):
        rows = [r for r in lat_rows if r["setting"] == setting]
        if rows:
            lines.append(f"±1 cm first breaks at an injected latency of {_f(first_breaking(rows))} ms "
                         f"({setting}, cycle {rows[0]['cycle_ms']} ms)")
    summary = [{k: v for k, v in r.items() if k != "series"} for r in results]
    (out / "results.json").write_text(json.dumps(summary, indent=1))
    files.append(out / "results.json")
    print("\n".join(lines))
    print("files: " + ", ".join(str(f) for f in files))
    return 0

