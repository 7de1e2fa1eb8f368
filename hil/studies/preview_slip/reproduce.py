"""`railhil reproduce preview-slip`: seed 000 (Picasso, Caporale, Colaneri) reproduced in lockstep over CAN.

Every point is a paper-mode lockstep run (nodes.py: the reduced model of eqs. (1)-(4) as the PLANT node,
the reference generators in BECU1..n, frames through the codec and the bit-timed bus):

* Table 1 — α = 1.5, v(0) = 30 m/s, Δ2 ∈ {10, 25, 50} m, n = 2: S°, S^Lf, S^Bd, S^Dp next to the paper's;
* the ordering grid — Δ2 ∈ {10, 25, 50} × α ∈ {0.5, 1, 1.5, 2, 3, 5}: S° < S^Dp < S^Bd, Lf worst for Δ2 ≥ 25;
* campaign 2 (Fig. 6) — v(0) = 50, Δ2 = 50, α from 0.5 to 5: A, A%, A%°, N%;
* campaign 3 (Fig. 7) — α = 1.5, Δ2 = 50, β from 0.2 to 1.2, v(0) ∈ {20, 30, 40}.

Runs go to a process pool (`--jobs`), with a tqdm progress bar; the tables print at the end and the
figures are written as PNG (fig5.png, fig6.png, fig7.png) with a results.json.

`--full` runs full mode instead (scenarios/preview_slip_full.toml: the wheelset plant, each BECU's slip
controller): Lf, Bd, Dp, the α each slip loop achieves (`achieved_alpha`), and paper mode at that α.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from firmware_py.preview import RefParams, delta_star, reference
from hil.campaign.jobs import map_jobs
from hil.can.codec import loaded_dbc
from hil.errors import RailhilError
from hil.resources import scenarios_dir
from hil.runtime.lockstep import run_lockstep
from hil.scenario import load_scenario
from hil.scenario.params import kmh, run_params
from hil.studies.preview_slip.kpis import achieved_alpha, tracking_norm
from hil.studies.preview_slip.plots import plot_figures
from hil.studies.preview_slip.scenario import DEFAULT_PROFILE, load_theta_table, profile_path
from plant_sim.reduced_train import Rail, ReducedTrainParams, simulate

BASE_SCENARIO = scenarios_dir() / "preview_slip_dp.toml"

#: seed 000 Table 1 (α = 1.5, v(0) = 30): stopping distances [m] by Δ2
PAPER_TABLE1 = {10: {"ideal": 252.77, "Lf": 259.59, "Bd": 259.79, "Dp": 259.20},
                25: {"ideal": 252.08, "Lf": 264.25, "Bd": 259.72, "Dp": 259.40},
                50: {"ideal": 246.16, "Lf": 270.26, "Bd": 254.43, "Dp": 254.11}}
SPACINGS = (10.0, 25.0, 50.0)
GRID_ALPHAS = (0.5, 1.0, 1.5, 2.0, 3.0, 5.0)
C2_ALPHAS = (0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0)
C3_BETAS = tuple(round(0.2 + 0.1 * k, 1) for k in range(11))
C3_SPEEDS = (20.0, 30.0, 40.0)


class PreviewSlipError(RailhilError):
    """A reproduction that cannot run as asked (bad option value)."""


# ------------------------------------------------------------------------------------ one run
@dataclass(frozen=True)
class Case:
    """One stopping run of the reduced model (n = len(spacing_m) + 1 cars)."""

    method: str                        # Lf | Bd | Dp | ideal
    alpha: float = 1.5                 # [1/s]
    v0: float = 30.0                   # [m/s]
    spacing_m: tuple[float, ...] = (50.0,)
    beta: float = 1.0
    source: str = "oracle"             # oracle | estimate
    profile: str = DEFAULT_PROFILE


def case_sets(c: Case) -> list[str]:
    """`railhil run --set` texts that turn the base scenario into this case."""
    return [f"preview.method={c.method}", f"preview.alpha_per_s={c.alpha}", f"preview.beta={c.beta}",
            f"train.initial_speed_kmh={kmh(c.v0)!r}", f"train.cars={len(c.spacing_m) + 1}",
            f"preview.spacing_m={list(c.spacing_m)!r}", f"preview.sigma_source={c.source}",
            f"preview.rail_profile={json.dumps(c.profile)}"]


def run_case(c: Case, with_truth: bool = False) -> dict:
    """The lockstep run of a case over CAN (no trace file): stopping distance S [m], time [s], and the
    normalised tracking-error norm n_e of §3.2 (with the truth columns when asked)."""

    scenario = load_scenario(BASE_SCENARIO, sets=case_sets(c))
    db, codec = _db_codec()
    out = run_lockstep(scenario, db, codec, writer=None)
    cols = out.truth.columns()
    plant_stop = out.reason == "standstill"
    x = cols["x_m_1"]
    res = {"case": c.__dict__, "S_m": float(x[-1] - x[0]) if plant_stop else float("nan"),
           "time_s": out.end_us / 1e6, "stopped": plant_stop,
           "n_e": tracking_norm(cols, len(c.spacing_m) + 1),
           "wall_s": out.wall_s}
    if with_truth:
        res["t_s"], res["v_mps"] = cols["t_s"].tolist(), cols["v_mps_1"].tolist()
    return res


def _db_codec():
    """The project DBC and its codec, built once per process (hil.can.codec.loaded_dbc)."""
    return loaded_dbc()


# ------------------------------------------------------------------------------------ full mode
FULL_SCENARIO = scenarios_dir() / "preview_slip_full.toml"


def run_full(method: str = "Bd", sets: tuple[str, ...] = ()) -> dict:
    """A full-mode lockstep run (wheelset plant, slip controllers): stopping distance [m], WSP activations
    per car, and the α the slip loops achieve (`achieved_alpha`), from the truth and the BECUs' frames."""
    import can


    scenario = load_scenario(FULL_SCENARIO, sets=[f"preview.method={method}", *sets])
    db, codec = _db_codec()
    refs = can.BufferedReader()
    out = run_lockstep(scenario, db, codec, writer=refs)
    cols = out.truth.columns()
    n = scenario.train.cars
    frames: dict[int, list[tuple[float, float]]] = {k: [] for k in range(1, n + 1)}
    ids = {codec.by_name(f"BECU{k}_SLIP_REF").frame_id: k for k in range(1, n + 1)}
    while (msg := refs.get_message(0.0)) is not None:
        k = ids.get(msg.arbitration_id)
        if k is not None:
            frames[k].append((msg.timestamp, codec[msg.arbitration_id].decode(bytes(msg.data))["SlipRef"]))
    x = cols["x_m_1"]
    wsp = [int(np.sum((cols[f"wsp_valve_{k}"][1:] == 2) & (cols[f"wsp_valve_{k}"][:-1] != 2)))
           for k in range(1, n + 1)]
    alphas = [achieved_alpha(cols, k, np.array(frames[k])) for k in range(1, n + 1)]
    return {"method": method, "S_m": float(x[-1] - x[0]), "stopped": out.reason == "standstill",
            "wsp_activations": wsp, "achieved_alpha": alphas, "wall_s": out.wall_s}


FULL_METHODS = ("Lf", "Bd", "Dp")


def _run_full_one(args: tuple[str, tuple[str, ...]]) -> dict:
    return run_full(*args)


def reproduce_full(jobs: int, sets: tuple[str, ...] = (), progress: bool = True) -> dict:
    """Full mode: Lf, Bd and Dp on the wheelset plant (FULL_SCENARIO with `sets`), on `jobs` processes, and
    paper mode for the same cars at the α the slip loops achieved (their mean over cars and methods)."""
    scenario = load_scenario(FULL_SCENARIO, sets=list(sets))
    todo = [(m, tuple(sets)) for m in FULL_METHODS]
    runs = map_jobs(_run_full_one, todo, jobs, "preview-slip full-mode runs", progress)
    full = {r["method"]: r for r in runs}
    alphas = [a for r in runs for a in r["achieved_alpha"] if math.isfinite(a)]
    alpha = round(float(np.mean(alphas)), 2) if alphas else scenario.preview.alpha_per_s
    v0, spacing = run_params(scenario).initial_speed_mps, tuple(scenario.preview.spacing_m)
    profile = scenario.preview.rail_profile or DEFAULT_PROFILE
    paper = {m: run_case(Case(m, alpha, v0, spacing, profile=profile))["S_m"]
             for m in ("ideal", *FULL_METHODS)}
    return {"full": full, "alpha_achieved": alpha, "alpha_design": scenario.preview.alpha_per_s,
            "paper_at_alpha": paper, "v0_mps": v0, "spacing_m": list(spacing), "sets": list(sets),
            "dp_shorter_m": full["Bd"]["S_m"] - full["Dp"]["S_m"]}


def print_full(s: dict, write=print) -> None:
    write(f"Full mode (wheelset plant, slip controllers; v(0) = {s['v0_mps']:.1f} m/s, Delta = "
          f"{', '.join(f'{d:g}' for d in s['spacing_m'])} m, eq. (9) with alpha = {s['alpha_design']:g} 1/s)")
    write(f"{'method':>6}{'S [m]':>9}{'WSP per car':>14}{'achieved alpha per car [1/s]':>31}"
          f"{'paper mode at alpha = ' + format(s['alpha_achieved'], 'g'):>28}")
    for m in FULL_METHODS:
        r = s["full"][m]
        wsp = " ".join(str(w) for w in r["wsp_activations"])
        al = " ".join(f"{a:.2f}" for a in r["achieved_alpha"])
        write(f"{m:>6}{r['S_m']:>9.2f}{wsp:>14}{al:>31}{s['paper_at_alpha'][m]:>28.2f}")
    write(f"S° (paper mode, mu = mu°) {s['paper_at_alpha']['ideal']:.2f} m; Bd - Dp in full mode "
          f"{s['dp_shorter_m']:+.2f} m ({'Dp shorter' if s['dp_shorter_m'] > 0 else 'Dp NOT shorter'})")


# ------------------------------------------------------------------------------------ direct, no CAN
def direct_law(rail: Rail, p: ReducedTrainParams, method: str, beta: float = 1.0, prediction: str = "remark2",
               pi2_s_per_m: float = 1.0 / 40.0):
    """Σ_i°(x_1, v, v̇) of `method` from the true rail (what the BECUs compute, with exact σ̄° and no CAN)."""
    params = [RefParams(car=i + 1, spacing_m=d, method=method, beta=beta, alpha_per_s=p.alpha_per_s,
                        pi2_s_per_m=pi2_s_per_m, prediction=prediction) for i, d in enumerate(p.spacing_m)]

    def law(x1: float, v: float, a: float) -> list[float]:
        lead = rail.sigma_opt_bar(x1)
        out = []
        for rp in params:
            own = rail.sigma_opt_bar(x1 - rp.spacing_m)
            pre = None
            if rp.method == "Dp" and rp.car > 1:
                pre = rail.sigma_opt_bar(x1 - delta_star(rp.spacing_m, v, rp.alpha_per_s))
            out.append(reference(rp, v, a, own, lead, pre).sigma)
        return out
    return law


def run_direct(c: Case, dt_s: float = 0.002) -> float:
    """Stopping distance [m] of a case by direct integration of eqs. (1)-(4), references exact, no CAN."""
    rail = Rail(load_theta_table(profile_path(c.profile)))
    p = ReducedTrainParams(spacing_m=(0.0, *c.spacing_m), alpha_per_s=c.alpha, ideal=c.method == "ideal")
    return simulate(rail, p, c.v0, direct_law(rail, p, c.method, c.beta), dt_s=dt_s).stopping_m


# ------------------------------------------------------------------------------------ the campaigns
def campaign_cases(fast: bool = False) -> dict[str, list[Case]]:
    """The cases of each part of the reproduction (a case may serve several parts; it runs once)."""
    alphas = (0.5, 1.5, 5.0) if fast else GRID_ALPHAS
    c2 = (0.5, 1.5, 3.0, 5.0) if fast else C2_ALPHAS
    betas = (0.4, 0.8, 1.0) if fast else C3_BETAS
    parts: dict[str, list[Case]] = {"table1": [], "grid": [], "c2": [], "c3": [], "n3": [], "estimate": []}
    for d in SPACINGS:
        parts["table1"] += [Case(m, 1.5, 30.0, (d,)) for m in ("ideal", "Lf", "Bd", "Dp")]
        parts["grid"].append(Case("ideal", 1.5, 30.0, (d,)))
        parts["grid"] += [Case(m, a, 30.0, (d,)) for a in alphas for m in ("Lf", "Bd", "Dp")]
    parts["c2"] = [Case("ideal", 1.5, 50.0)] + [Case(m, a, 50.0) for a in c2 for m in ("Bd", "Dp")]
    for v0 in C3_SPEEDS:
        parts["c3"].append(Case("ideal", 1.5, v0))
        parts["c3"] += [Case(m, 1.5, v0, beta=b) for b in betas for m in ("Bd", "Dp")]
    parts["n3"] = [Case(m, 1.5, 30.0, (25.0, 50.0)) for m in ("ideal", "Lf", "Bd", "Dp")]
    parts["estimate"] = [Case(m, 1.5, 30.0, (d,), source="estimate")
                         for d in SPACINGS for m in ("Lf", "Bd", "Dp")]
    return parts


def _run_one(args: tuple[Case, bool]) -> tuple[Case, dict]:
    c, truth = args
    return c, run_case(c, with_truth=truth)


def run_all(parts: dict[str, list[Case]], jobs: int, progress: bool = True) -> dict[Case, dict]:
    """Every distinct case once, on `jobs` processes (1: in this process), with a tqdm bar."""
    todo = list(dict.fromkeys(c for cs in parts.values() for c in cs))
    with_truth = set(parts["table1"])
    # the longest runs first (v(0) = 50, small alpha), so that the pool does not end on one long run
    todo.sort(key=lambda c: (-c.v0, c.alpha))
    return dict(map_jobs(_run_one, [(c, c in with_truth) for c in todo], jobs, "preview-slip runs", progress))


def _s(results: dict[Case, dict], c: Case) -> float:
    return results[c]["S_m"]


def summarise(parts: dict[str, list[Case]], results: dict[Case, dict]) -> dict:
    """Tables and acceptance figures from the runs (plain data: results.json)."""
    out: dict = {"table1": {}, "grid": [], "c2": [], "c3": [], "n3": {}, "estimate": {}}
    for d in SPACINGS:
        out["table1"][int(d)] = {m: _s(results, Case(m, 1.5, 30.0, (d,)))
                                 for m in ("ideal", "Lf", "Bd", "Dp")}
    alphas = sorted({c.alpha for c in parts["grid"] if c.method != "ideal"})
    for d in SPACINGS:
        so = _s(results, Case("ideal", 1.5, 30.0, (d,)))
        for a in alphas:
            lf, bd, dp = (_s(results, Case(m, a, 30.0, (d,))) for m in ("Lf", "Bd", "Dp"))
            out["grid"].append({"spacing_m": d, "alpha": a, "ideal": so, "Lf": lf, "Bd": bd, "Dp": dp,
                                "A_pct_ideal": 100 * (bd - dp) / (bd - so),
                                "order_ok": bool(so < dp < bd), "lf_worst": bool(lf > max(bd, dp))})
    so = _s(results, Case("ideal", 1.5, 50.0))
    for a in sorted({c.alpha for c in parts["c2"] if c.method != "ideal"}):
        bd_r, dp_r = results[Case("Bd", a, 50.0)], results[Case("Dp", a, 50.0)]
        bd, dp = bd_r["S_m"], dp_r["S_m"]
        out["c2"].append({"alpha": a, "ideal": so, "Bd": bd, "Dp": dp, "A_m": bd - dp,
                          "A_pct": 100 * (bd - dp) / bd,
                          "A_pct_ideal": 100 * (bd - dp) / (bd - so),
                          "N_pct": 100 * (bd_r["n_e"] - dp_r["n_e"]) / bd_r["n_e"]})
    for v0 in C3_SPEEDS:
        so = _s(results, Case("ideal", 1.5, v0))
        for b in sorted({c.beta for c in parts["c3"]}):
            bd, dp = _s(results, Case("Bd", 1.5, v0, beta=b)), _s(results, Case("Dp", 1.5, v0, beta=b))
            out["c3"].append({"v0": v0, "beta": b, "ideal": so, "Bd": bd, "Dp": dp,
                              "A_pct": 100 * (bd - dp) / bd})
    out["n3"] = {m: _s(results, Case(m, 1.5, 30.0, (25.0, 50.0))) for m in ("ideal", "Lf", "Bd", "Dp")}
    for d in SPACINGS:
        est = {m: _s(results, Case(m, 1.5, 30.0, (d,), source="estimate")) for m in ("Lf", "Bd", "Dp")}
        ora = out["table1"][int(d)]
        est["advantage_m"] = est["Bd"] - est["Dp"]
        est["oracle_advantage_m"] = ora["Bd"] - ora["Dp"]
        est["advantage_kept_pct"] = 100 * est["advantage_m"] / est["oracle_advantage_m"]
        out["estimate"][int(d)] = est
    return out


def print_tables(s: dict, write=print) -> None:
    write("Table 1 (alpha = 1.5 1/s, v(0) = 30 m/s, n = 2): stopping distance [m], ours (paper)")
    write(f"{'':6}" + "".join(f"{'Delta2 = ' + str(d) + ' m':>24}" for d in (10, 25, 50)))
    for m, label in (("ideal", "S°"), ("Lf", "S^Lf"), ("Bd", "S^Bd"), ("Dp", "S^Dp")):
        write(f"{label:6}" + "".join(f"{s['table1'][d][m]:>13.2f} ({PAPER_TABLE1[d][m]:>7.2f})"
                                     for d in (10, 25, 50)))
    write("")
    write("Ordering grid (v(0) = 30): S° < S^Dp < S^Bd and, for Delta2 >= 25, S^Lf largest")
    write(f"{'Delta2':>7}{'alpha':>7}{'S°':>9}{'S^Lf':>9}{'S^Bd':>9}{'S^Dp':>9}{'A%°':>7}  ok")
    for r in s["grid"]:
        ok = r["order_ok"] and (r["spacing_m"] < 25 or r["lf_worst"])
        write(f"{r['spacing_m']:>7.0f}{r['alpha']:>7.2f}{r['ideal']:>9.2f}{r['Lf']:>9.2f}{r['Bd']:>9.2f}"
              f"{r['Dp']:>9.2f}{r['A_pct_ideal']:>7.1f}  {'yes' if ok else 'NO'}")
    write("")
    write("Campaign 2 (v(0) = 50 m/s, Delta2 = 50 m; paper Fig. 6: A%° rises with alpha, up to ~15 %; "
          "N% ~ 20 %)")
    write(f"{'alpha':>6}{'S°':>9}{'S^Bd':>9}{'S^Dp':>9}{'A [m]':>8}{'A%':>7}{'A%°':>7}{'N%':>7}")
    for r in s["c2"]:
        write(f"{r['alpha']:>6.2f}{r['ideal']:>9.2f}{r['Bd']:>9.2f}{r['Dp']:>9.2f}{r['A_m']:>8.3f}"
              f"{r['A_pct']:>7.3f}{r['A_pct_ideal']:>7.1f}{r['N_pct']:>7.1f}")
    write("")
    write("Campaign 3 (alpha = 1.5, Delta2 = 50 m; paper Fig. 7: S least at beta = 1, A% largest at some "
          "beta < 1)")
    write(f"{'v(0)':>5}{'beta':>6}{'S^Bd':>9}{'S^Dp':>9}{'A%':>8}")
    for r in s["c3"]:
        write(f"{r['v0']:>5.0f}{r['beta']:>6.1f}{r['Bd']:>9.2f}{r['Dp']:>9.2f}{r['A_pct']:>8.3f}")
    write("")
    n3 = s["n3"]
    write(f"n = 3 (Delta = 25, 50 m, alpha = 1.5, v(0) = 30): S° {n3['ideal']:.2f}  S^Lf {n3['Lf']:.2f}  "
          f"S^Bd {n3['Bd']:.2f}  S^Dp {n3['Dp']:.2f} m")
    write("")
    write("Estimated sigma° (no oracle: each BECU's estimator, cars exchange estimates; alpha = 1.5, "
          "v(0) = 30)")
    write(f"{'Delta2':>7}{'S^Lf':>9}{'S^Bd':>9}{'S^Dp':>9}{'Bd-Dp':>8}{'oracle Bd-Dp':>14}{'kept':>7}")
    for d, e in s["estimate"].items():
        write(f"{d:>7}{e['Lf']:>9.2f}{e['Bd']:>9.2f}{e['Dp']:>9.2f}{e['advantage_m']:>8.2f}"
              f"{e['oracle_advantage_m']:>14.2f}{e['advantage_kept_pct']:>6.0f}%")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--jobs", type=int, default=2, help="worker processes for the runs (default 2; 1 = in "
                                                        "this process)")
    p.add_argument("--out", type=Path, default=Path("runs") / "preview-slip",
                   help="folder for fig5.png, fig6.png, fig7.png and results.json (default "
                        "runs/preview-slip)")
    p.add_argument("--fast", action="store_true",
                   help="a subset of each campaign (3 alphas in the grid, 4 in campaign 2, 3 betas): "
                        "a smoke run")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--full", action="store_true",
                   help="full mode instead of the paper's campaigns: Lf, Bd and Dp on the wheelset plant "
                        "with the slip controllers (scenarios/preview_slip_full.toml), the alpha they "
                        "achieve, and paper mode at that alpha; writes results_full.json")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="with --full: override a key of scenarios/preview_slip_full.toml (repeatable), e.g. "
                        "preview.brake_inverse=direction")


def run(args: argparse.Namespace) -> int:
    if args.jobs < 1:
        raise PreviewSlipError(f"--jobs {args.jobs}: expected a number of worker processes >= 1")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise PreviewSlipError(f"--out {out}: exists and is not a folder; expected a folder for the figures")
    if args.sets and not args.full:
        raise PreviewSlipError(f"--set {args.sets[0]}: only with --full (the paper campaigns set their own "
                               f"keys)")
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if args.full:
        s = reproduce_full(args.jobs, tuple(args.sets), progress=not args.quiet)
        print_full(s)
        js = out / "results_full.json"
        js.write_text(json.dumps(s, indent=1, default=float) + "\n")
        print(f"\n{len(FULL_METHODS)} full-mode lockstep runs over CAN in {time.perf_counter() - t0:.1f} s")
        print(f"files: {js}")
        return 0
    parts = campaign_cases(args.fast)
    results = run_all(parts, args.jobs, progress=not args.quiet)
    s = summarise(parts, results)
    print_tables(s)
    table1 = {(m, d): results[Case(m, 1.5, 30.0, (d,))]
              for d in SPACINGS for m in ("ideal", "Lf", "Bd", "Dp")}
    files = plot_figures(s, table1, out)
    js = out / "results.json"
    js.write_text(json.dumps({"summary": s, "runs": [r for r in results.values()]}, indent=1, default=float)
                  + "\n")
    files.append(js)
    print(f"\n{len(results)} lockstep runs over CAN in {time.perf_counter() - t0:.1f} s "
          f"({args.jobs} job{'s' if args.jobs > 1 else ''})")
    print("files: " + ", ".join(str(f) for f in files))
    return 0
