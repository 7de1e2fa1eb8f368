"""Campaigns: one base scenario run at many points of a grid and a seeded random sweep, in parallel.

A campaign file (TOML) names a base scenario and the scenario keys to vary; a key is exactly a
`railhil run --set` key (a dotted path into the scenario, list items by index: ``desk.0.at_s``)::

    base = "../scenarios/stop_30kmh.toml"   # relative to the campaign file
    name = "mass_sweep"                    # default: the file's stem; names the output folder
    description = "..."
    seed = 1                               # the random sweep's seed (default 0)
    plot = ["stopping_distance_m"]         # KPIs of the summary plots (default: DEFAULT_PLOT)
    [set]                                  # fixed overrides of the base, every point
    max_duration_s = 20.0
    [grid]                                 # cartesian product of these lists
    "train.mass_kg" = [30000, 40000, 50000]
    [random]                               # n draws, each key from a distribution, seeded
    n = 10
    "train.initial_speed_kmh" = { uniform = [20, 40] }
    "seed" = { integers = [1, 1000] }

Points: every grid combination (in file order, the last key varying fastest) times every random draw
0..n-1 — the same n draws at every grid combination (common random numbers), so grid cells differ
only by the grid keys.  Neither table: one point, the base.  Distributions (DISTRIBUTIONS):
``uniform = [lo, hi]`` and ``loguniform = [lo, hi]`` (floats), ``integers = [lo, hi]`` (both ends
included), ``normal = [mean, std]``, ``choice = [v1, v2, ...]`` (any TOML values).  Each key has its
own stream, numpy's PCG64 seeded by (seed, CRC-32 of the key): adding a key leaves the others' draws
unchanged, and raising n adds points without changing the first n, so their cached results are kept.

Every point is validated (the keys and values, like `--set`) before anything runs.  A point's cache
key is the SHA-256 of its resolved scenario as canonical JSON (sorted keys, the DBC path replaced by
the SHA-256 of the DBC file's bytes) plus the railhil version: a point whose scenario, DBC or railhil
changed runs again, an unchanged one is read from its cache.  Each point runs in lockstep into the run
folder ``<out>/points/<key[:16]>/``: the trace, truth.csv, kpis.json and run.json as `railhil run`
writes them, but no figures and no report.html unless asked (``plots``, `railhil campaign --plots`:
then plot.png, the studies' figures and report.html as `railhil run`; a point cached without them gets
them drawn from its run folder, not run again).  When a point finishes, the campaign process writes
``point.json`` there (atomically), which is the cache: an interrupted campaign keeps every finished
point, a rerun runs only the others.  A point that raises is recorded with its error, is not cached (a
rerun tries it again) and does not stop the others.

Results: ``results.csv`` (and ``results.parquet`` when pyarrow is installed: the ``parquet`` extra),
one row per point: ``point``, the swept keys, ``status`` (ok / failed), ``cached``, ``error``,
``wall_s`` (the point's wall time [s] in its worker), ``sim_wall_s`` (of which the lockstep simulation
itself, RunOutcome.wall_s; the rest is writing the run folder and its KPIs), ``run_dir`` (relative to
``<out>``), then every KPI of kpis.json, nested ones flattened with dots (``bus.load``), a per-car list
as JSON text plus its largest value (``max_slip_speed_mps.max``); and ``plot_<key>.png`` per numeric
swept key: each plotted KPI against it.

Execution goes through any ``concurrent.futures.Executor``: local processes (`--jobs N`), or a Dask
distributed cluster through ``Client.get_executor()`` (`--dask tcp://host:8786`, the ``dask`` extra).
Workers write the run folders, so on a multi-host cluster ``<out>`` must be on a filesystem the workers
share; the KPIs travel back with the result, so table, plots and cache are complete either way.
"""

from __future__ import annotations

import csv
import difflib
import functools
import hashlib
import json
import math
import os
import sys
import time
import zlib
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass, field
from itertools import product
from pathlib import Path

import numpy as np

import firmware_py
import plant_sim
from hil.errors import ScenarioError
from hil.report.html import write_campaign_report
from hil.report.plots import pyplot
from hil.report.run import has_figures, run_scenario_lockstep, write_figures
from hil.resources import campaigns_dir, read_toml
from hil.runtime.run import check_out_dir, dbc_path_of, prepare_worker
from hil.scenario import Scenario, apply_set, load_scenario, parse_scenario

__all__ = ["Campaign", "CampaignError", "CampaignResult", "Point", "PointResult", "check_positive", "draw",
           "draw_point", "executor_for", "expand", "load_campaign", "point_key", "rows", "run_campaign",
           "run_point", "shown", "summary_lines", "write_plots", "write_table"]

TOP_KEYS = ("base", "name", "description", "seed", "plot", "set", "grid", "random")
DISTRIBUTIONS = ("uniform", "integers", "normal", "loguniform", "choice")
DEFAULT_PLOT = ("stopping_distance_m", "time_to_stop_s", "max_slip_speed_mps.max",
                "mean_abs_decel_error_mps2")
POINT_FILE = "point.json"         # a finished point's cached result, in its run folder
FIXED_COLUMNS = ("point", "status", "cached", "error", "wall_s", "sim_wall_s", "run_dir")


class CampaignError(ScenarioError):
    """A campaign file or option that does not load or validate (exit 2)."""


# ------------------------------------------------------------------------------------------ the file
@dataclass(frozen=True)
class Campaign:
    path: Path
    name: str
    description: str
    base: Path
    seed: int
    fixed: dict[str, object]                       # [set]
    grid: dict[str, list]                          # [grid]: key -> values
    random_n: int                                  # [random] n (0: no random sweep)
    random: dict[str, tuple[str, list]]            # [random]: key -> (distribution, its parameters)
    plot: tuple[str, ...]

    @property
    def swept(self) -> list[str]:
        return [*self.grid, *self.random]


def _suggest(word: str, choices: Iterable[str]) -> str:
    choices = list(choices)
    close = difflib.get_close_matches(word, choices, n=1, cutoff=0.5)
    return f"; did you mean '{close[0]}'?" if close else f"; expected one of {', '.join(choices)}"


def _is_number(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _check_distribution(where: str, spec: object) -> tuple[str, list]:
    if not isinstance(spec, dict) or len(spec) != 1:
        raise CampaignError(f"{where}: expected a table with one distribution, e.g. "
                            f"{{ uniform = [20, 40] }}; distributions: {', '.join(DISTRIBUTIONS)}")
    (kind, args), = spec.items()
    if kind not in DISTRIBUTIONS:
        raise CampaignError(f"{where}: '{kind}' is not a distribution{_suggest(kind, DISTRIBUTIONS)}")
    if kind == "choice":
        if not isinstance(args, list) or not args:
            raise CampaignError(f"{where}: choice = {args!r}: expected a non-empty list of values")
        return kind, args
    if not (isinstance(args, list) and len(args) == 2 and all(_is_number(a) for a in args)):
        pair = "mean, std" if kind == "normal" else "lo, hi"
        raise CampaignError(f"{where}: {kind} = {args!r}: expected two numbers [{pair}]")
    a, b = args
    if kind == "integers" and not all(isinstance(x, int) for x in args):
        raise CampaignError(f"{where}: integers = {args!r}: expected two integers [lo, hi]")
    if kind == "normal" and b < 0:
        raise CampaignError(f"{where}: normal = {args!r}: the standard deviation must be ≥ 0")
    if kind != "normal" and b < a:
        raise CampaignError(f"{where}: {kind} = {args!r}: hi is below lo")
    if kind == "loguniform" and a <= 0:
        raise CampaignError(f"{where}: loguniform = {args!r}: expected 0 < lo ≤ hi")
    return kind, args


def load_campaign(path: str | Path) -> Campaign:
    """Read and check a campaign file (module docstring); every error names the file and the key.  A
    name without a folder that is no file here is a shipped campaign (`mass_sweep`: campaigns/)."""
    path = Path(path)
    if not path.exists() and "/" not in str(path):
        shipped = campaigns_dir() / (path.name if path.suffix == ".toml" else f"{path.name}.toml")
        path = shipped if shipped.is_file() else path
    data = read_toml(path, CampaignError, str(path), lambda: (
        "no such campaign file, and no shipped campaign of that name (shipped: "
        f"{', '.join(sorted(p.stem for p in campaigns_dir().glob('*.toml')))})"))
    for key in data:
        if key not in TOP_KEYS:
            raise CampaignError(f"{path}: key '{key}' is not a campaign key{_suggest(key, TOP_KEYS)}")
    if not isinstance(data.get("base"), str):
        raise CampaignError(f"{path}: key 'base' is missing or not a string: expected the base scenario's "
                            f"path, relative to the campaign file")
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
        raise CampaignError(f"{path}: key 'name' = {name!r}: expected a non-empty name without '/'")
    seed = data.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise CampaignError(f"{path}: key 'seed' = {seed!r}: expected an integer ≥ 0")
    plot = data.get("plot", list(DEFAULT_PLOT))
    if not isinstance(plot, list) or not all(isinstance(p, str) for p in plot):
        raise CampaignError(f"{path}: key 'plot' = {plot!r}: expected a list of KPI names")
    tables = {}
    for table in ("set", "grid", "random"):
        value = data.get(table, {})
        if not isinstance(value, dict):
            raise CampaignError(f"{path}: key '{table}' must be a table [{table}] of dotted scenario keys")
        tables[table] = dict(value)
    for key, values in tables["grid"].items():
        if not isinstance(values, list) or not values:
            raise CampaignError(f"{path}: [grid] \"{key}\" = {values!r}: expected a non-empty list of values")
    n = tables["random"].pop("n", None)
    random = {k: _check_distribution(f"{path}: [random] \"{k}\"", v) for k, v in tables["random"].items()}
    if random and (not isinstance(n, int) or isinstance(n, bool) or n < 1):
        raise CampaignError(f"{path}: [random] n = {n!r}: expected the number of draws, an integer ≥ 1")
    if n is not None and not random:
        raise CampaignError(f"{path}: [random] n = {n!r} but no key to draw: add e.g. "
                            f"\"seed\" = {{ integers = [1, 1000] }}")
    seen: dict[str, str] = {}
    for table in ("set", "grid", "random"):
        for key in (random if table == "random" else tables[table]):
            if key in seen:
                raise CampaignError(f"{path}: key \"{key}\" is in both [{seen[key]}] and [{table}]: "
                                    f"give it once")
            seen[key] = table
    return Campaign(path=path, name=name, description=str(data.get("description", "")),
                    base=(path.parent / data["base"]), seed=seed, fixed=tables["set"],
                    grid=tables["grid"], random_n=n or 0, random=random, plot=tuple(plot))


# ---------------------------------------------------------------------------------------- the points
@dataclass(frozen=True)
class Point:
    index: int
    values: dict[str, object]          # swept key -> value
    scenario: Scenario
    key: str                           # cache key: sha256 hex (point_key)


def draw(kind: str, args: list, seed: int, key: str, n: int) -> list:
    """The first n draws of `key`'s stream (module docstring), as plain Python values."""
    rng = np.random.default_rng([seed, zlib.crc32(key.encode())])
    if kind == "uniform":
        return [float(x) for x in rng.uniform(args[0], args[1], n)]
    if kind == "loguniform":
        return [float(x) for x in np.exp(rng.uniform(math.log(args[0]), math.log(args[1]), n))]
    if kind == "normal":
        return [float(x) for x in rng.normal(args[0], args[1], n)]
    if kind == "integers":
        return [int(x) for x in rng.integers(args[0], args[1], n, endpoint=True)]
    return [args[int(i)] for i in rng.integers(0, len(args), n)]          # choice


def _dbc_digest(scenario: Scenario) -> str:
    path = dbc_path_of(scenario)
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as exc:
        raise CampaignError(f"dbc {path}: cannot read: {exc.strerror or exc}") from None


def railhil_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("railhil")
    except PackageNotFoundError:
        return "unknown"


@functools.cache
def code_digest() -> str:
    """SHA-256 (hex) of the Python source that makes a run (firmware_py, plant_sim, hil: every .py file's
    path and bytes), so that a changed controller or plant invalidates a stored result even where the
    package version stayed the same (a working copy between releases)."""

    h = hashlib.sha256()
    for pkg in (firmware_py, plant_sim, sys.modules["hil"]):
        root = Path(pkg.__file__).resolve().parent
        for f in sorted(root.rglob("*.py")):
            h.update(f.relative_to(root.parent).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def point_key(scenario: Scenario, dbc_digest: str | None = None, version: str | None = None,
              code: str | None = None) -> str:
    """SHA-256 (hex) of the scenario as canonical JSON, the DBC path replaced by the DBC's content hash,
    the railhil version and the digest of its source (`code_digest`)."""
    data = scenario.model_dump(mode="json")
    data["dbc"] = dbc_digest or _dbc_digest(scenario)
    data["railhil_version"] = version or railhil_version()
    data["code"] = code or code_digest()
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _set(data: dict, key: str, value: object, where: str) -> None:
    try:
        apply_set(data, key, value, where)
    except ScenarioError as exc:         # apply_set speaks of --set; here the key sits in a table
        raise CampaignError(str(exc).replace(": --set ", ": ", 1)) from None


def _parse(data: dict, source: str) -> Scenario:
    try:
        return parse_scenario(data, source)
    except ScenarioError as exc:
        raise CampaignError(str(exc)) from None


def expand(campaign: Campaign) -> list[Point]:
    """Every point of the campaign, each validated as a scenario (a bad key or value: CampaignError)."""
    try:
        base = load_scenario(campaign.base)
    except ScenarioError as exc:
        raise CampaignError(f"{campaign.path}: base: {exc}") from None
    data0 = base.model_dump(mode="json")
    for key, value in campaign.fixed.items():
        _set(data0, key, value, f"{campaign.path} [set]")
    fixed = _parse(data0, f"{campaign.path} [set] applied to {campaign.base}")
    data0 = fixed.model_dump(mode="json")
    grid = [dict(zip(campaign.grid, combo, strict=True)) for combo in product(*campaign.grid.values())]
    draws = {k: draw(kind, args, campaign.seed, k, campaign.random_n)
             for k, (kind, args) in campaign.random.items()}
    randoms = [{k: draws[k][i] for k in draws} for i in range(campaign.random_n)] or [{}]
    versions: dict[str, str] = {}
    version = railhil_version()
    points = []
    for values in (g | r for g in grid for r in randoms):
        index = len(points)
        data = json.loads(json.dumps(data0))
        for key, value in values.items():
            _set(data, key, value, f"{campaign.path} [{'grid' if key in campaign.grid else 'random'}]")
        shown = ", ".join(f"{k}={v!r}" for k, v in values.items())
        scenario = _parse(data, f"{campaign.path} point {index} ({shown})")
        digest = versions.get(scenario.dbc or "")
        if digest is None:
            digest = versions[scenario.dbc or ""] = _dbc_digest(scenario)
        points.append(Point(index, values, scenario, point_key(scenario, digest, version)))
    return points


# -------------------------------------------------------------------------------------- running them
def run_point(scenario_json: str, run_dir: str, plots: bool = False) -> dict:
    """Run one point in lockstep into `run_dir` (the worker's job; never raises): {"status": "ok",
    "kpis": ..., "wall_s": ..., "sim_wall_s": ...} or {"status": "failed", "error": "Type: message",
    "wall_s": ...}.  `wall_s` is the point's wall time [s] from here (the runtime imported and the
    worker prepared, hil.runtime.run.prepare_worker: the DBC and the compiled plant loaded, once per worker
    process, not per point; those seconds are `startup_s`) to its KPIs; `sim_wall_s` the lockstep
    simulation's part of it (RunOutcome.wall_s).  The run folder keeps the trace, truth.csv, kpis.json and
    run.json; `plots` adds plot.png, the studies' figures and report.html."""

    startup_s = 0.0
    try:
        scenario = Scenario.model_validate_json(scenario_json)
        startup_s = prepare_worker(scenario)
    except Exception:                  # the run below reports it
        scenario = None
    t0 = time.perf_counter()
    try:
        if scenario is None:
            scenario = Scenario.model_validate_json(scenario_json)
        report = run_scenario_lockstep(scenario, Path(run_dir),
                                       interactive_report=False, plots=plots)  # 4.8 MB of plotly.js: no
        if report.outcome.reason == "interrupted":       # a cut-short run is no result to cache
            raise KeyboardInterrupt
        kpis = json.loads(json.dumps(report.kpis, default=str))
        return {"status": "ok", "kpis": kpis, "error": "", "wall_s": time.perf_counter() - t0,
                "sim_wall_s": report.outcome.wall_s, "startup_s": startup_s}
    except Exception as exc:           # one failing point is recorded, the others go on
        text = " ".join(str(exc).split())
        return {"status": "failed", "kpis": {}, "error": f"{type(exc).__name__}: {text}",
                "wall_s": time.perf_counter() - t0}


def draw_point(scenario_json: str, run_dir: str, cached: dict) -> dict:
    """The figures and report.html of a point cached without them (`--plots` now), drawn from its run
    folder: `cached` (its point.json) with "drawn": True; a folder they cannot be drawn from is run
    again with plots (run_point).  Never raises."""

    try:
        write_figures(Path(run_dir))
    except Exception:                  # a damaged folder: the point runs again, with its figures
        return run_point(scenario_json, run_dir, plots=True)
    return {**cached, "drawn": True}


@dataclass
class PointResult:
    point: Point
    status: str                        # "ok" or "failed"
    cached: bool
    error: str
    wall_s: float                      # wall time of the point's run [s] (of the original run if cached)
    run_dir: Path
    kpis: dict = field(default_factory=dict)
    sim_wall_s: float | None = None    # of which the lockstep simulation [s] (None: failed, older cache)
    startup_s: float | None = None     # the worker's one-time preparation before it (prepare_worker) [s]


@dataclass
class CampaignResult:
    campaign: Campaign
    out_dir: Path
    results: list[PointResult]         # in point order; only finished points when interrupted
    total: int                         # points in the campaign
    wall_s: float                      # wall time of this invocation [s]
    interrupted: bool = False

    @property
    def failed(self) -> list[PointResult]:
        return [r for r in self.results if r.status != "ok"]


def _read_cache(run_dir: Path, key: str) -> dict | None:
    try:
        cached = json.loads((run_dir / POINT_FILE).read_text())
    except (OSError, ValueError):
        return None
    return cached if cached.get("key") == key and cached.get("status") == "ok" else None


def _write_cache(run_dir: Path, key: str, point: Point, outcome: dict) -> None:
    run_dir.mkdir(parents=True, exist_ok=True)
    tmp = run_dir / f".{POINT_FILE}.tmp"
    tmp.write_text(json.dumps({"key": key, "values": point.values, **outcome}, indent=2, default=str) + "\n")
    os.replace(tmp, run_dir / POINT_FILE)


@contextmanager
def executor_for(jobs: int = 1, dask: str | None = None,
                 timeout_s: float = 10.0) -> Iterator[Executor | None]:
    """The executor of a campaign: None (run in this process) for jobs == 1, local worker processes for
    jobs > 1, or the Dask cluster whose scheduler is at `dask` (jobs is then ignored).  A scheduler
    that does not answer within `timeout_s` seconds is a CampaignError naming the address."""
    if dask:
        try:
            from distributed import Client
        except ImportError:
            raise CampaignError(f"--dask {dask}: Dask is not installed; install the extra: "
                                f"pip install 'railhil[dask]'") from None
        try:
            client = Client(dask, timeout=timeout_s, set_as_default=False)
        except Exception as exc:       # OSError, TimeoutError, ValueError for a malformed address...
            text = " ".join(str(exc).split())[:160]
            raise CampaignError(f"--dask {dask}: cannot connect to a Dask scheduler "
                                f"(expected an address such as tcp://host:8786): {text}") from None
        try:
            yield client.get_executor(pure=False)
        finally:
            client.close()
    elif jobs > 1:
        pool = ProcessPoolExecutor(max_workers=jobs)
        try:
            yield pool
        finally:
            pool.shutdown(wait=False, cancel_futures=True)
    else:
        yield None


def run_campaign(campaign: Campaign, out_dir: Path, executor: Executor | None = None,
                 points: list[Point] | None = None,
                 progress: Callable[[PointResult], None] | None = None,
                 plots: bool = False) -> CampaignResult:
    """Run every point not already cached in `out_dir`, through `executor` (None: in this process).
    Cached points are reported first (progress too).  `plots`: each point's run folder gets its figures
    and report.html too, and a cached point without them gets them drawn from its folder (draw_point).
    Ctrl-C stops the campaign, keeps every finished point cached and returns the result so far with
    `interrupted` set."""

    t0 = time.perf_counter()
    out_dir = check_out_dir(out_dir)
    points = expand(campaign) if points is None else points
    done: dict[int, PointResult] = {}
    todo: dict[str, list[Point]] = {}               # key -> points with that scenario (duplicates run once)
    undrawn: dict[str, dict] = {}                   # key -> point.json of a cached point to draw (plots)
    for p in points:
        run_dir = out_dir / "points" / p.key[:16]
        cached = _read_cache(run_dir, p.key)
        if cached is not None and plots and not has_figures(run_dir):
            undrawn[p.key] = cached
            todo.setdefault(p.key, []).append(p)
        elif cached is not None:
            done[p.index] = PointResult(p, "ok", True, "", float(cached.get("wall_s", 0.0)), run_dir,
                                        cached.get("kpis", {}), cached.get("sim_wall_s"))
            if progress:
                progress(done[p.index])
        else:
            todo.setdefault(p.key, []).append(p)

    def job(key: str) -> tuple[Callable[..., dict], tuple]:
        args = (todo[key][0].scenario.model_dump_json(), str(out_dir / "points" / key[:16]))
        return (draw_point, (*args, undrawn[key])) if key in undrawn else (run_point, (*args, plots))

    def finish(key: str, outcome: dict) -> None:
        first = todo[key][0]
        run_dir = out_dir / "points" / key[:16]
        drawn = bool(outcome.get("drawn"))           # a cached point, its figures drawn now
        if outcome["status"] == "ok" and not drawn:
            _write_cache(run_dir, key, first, outcome)
        for p in todo[key]:
            done[p.index] = PointResult(p, outcome["status"], drawn, outcome["error"],
                                        float(outcome.get("wall_s", 0.0)), run_dir, outcome["kpis"],
                                        outcome.get("sim_wall_s"), outcome.get("startup_s"))
            if progress:
                progress(done[p.index])

    interrupted = False
    try:
        if executor is None:
            for key in todo:
                fn, args = job(key)
                finish(key, fn(*args))
        else:
            futures: dict[Future, str] = {}
            for key in todo:
                fn, args = job(key)
                futures[executor.submit(fn, *args)] = key
            try:
                for fut in as_completed(futures):
                    try:
                        outcome = fut.result()
                    except Exception as exc:      # the executor failed (a worker died, a lost connection)
                        outcome = {"status": "failed", "kpis": {}, "wall_s": 0.0,
                                   "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}"}
                    finish(futures[fut], outcome)
            finally:
                for fut in futures:
                    fut.cancel()
    except KeyboardInterrupt:
        interrupted = True
    results = [done[p.index] for p in points if p.index in done]
    return CampaignResult(campaign, out_dir, results, len(points), time.perf_counter() - t0, interrupted)


# ------------------------------------------------------------------------------------- table and plots
def _flatten(d: dict, prefix: str = "") -> dict:
    out: dict = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, f"{name}."))
        elif isinstance(v, list | tuple):            # per-car values: as JSON, and their largest
            out[name] = json.dumps(v)
            if v and all(_is_number(x) for x in v):
                out[f"{name}.max"] = max(v)
        else:
            out[name] = v
    return out


def rows(result: CampaignResult) -> tuple[list[str], list[dict]]:
    """(columns, rows) of the results table (module docstring)."""
    swept = result.campaign.swept
    table, kpi_cols = [], {}
    for r in result.results:
        kpis = _flatten(r.kpis)
        kpi_cols.update(dict.fromkeys(kpis))
        table.append({"point": r.point.index, **r.point.values, "status": r.status, "cached": r.cached,
                      "error": r.error, "wall_s": round(r.wall_s, 3),
                      "sim_wall_s": None if r.sim_wall_s is None else round(r.sim_wall_s, 3),
                      "run_dir": str(r.run_dir.relative_to(result.out_dir)), **kpis})
    columns = ["point", *swept, *FIXED_COLUMNS[1:], *(k for k in kpi_cols if k not in swept)]
    return columns, table


def write_table(result: CampaignResult) -> list[Path]:
    """results.csv, and results.parquet when pyarrow is installed; returns the files written."""
    columns, table = rows(result)
    csv_path = result.out_dir / "results.csv"
    with csv_path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="")
        writer.writeheader()
        writer.writerows(table)
    files = [csv_path]
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return files
    arrays = {}
    for col in columns:
        values = [row.get(col) for row in table]
        try:
            arrays[col] = pa.array(values)
        except (pa.ArrowInvalid, pa.ArrowTypeError):     # mixed types in one column: kept as text
            arrays[col] = pa.array([None if v is None else str(v) for v in values], pa.string())
    parquet = result.out_dir / "results.parquet"
    pq.write_table(pa.table(arrays), parquet)
    return files + [parquet]


def write_plots(result: CampaignResult) -> list[Path]:
    """plot_<key>.png per numeric swept key: each of the campaign's plot KPIs (those the runs have)
    against that key, one dot per finished point, and the mean per value for a grid key; then the
    campaign's report.html (hil.report.html: the results table and these plots, one self-contained page)."""

    files = _summary_plots(result)
    return files + [write_campaign_report(result.out_dir, rows(result), result.campaign.name,
                                          result.campaign.description)]


def _summary_plots(result: CampaignResult) -> list[Path]:
    ok = [r for r in result.results if r.status == "ok"]
    metrics = [m for m in result.campaign.plot if any(_is_number(_flatten(r.kpis).get(m)) for r in ok)]
    if not ok or not metrics:
        return []

    plt = pyplot()
    files = []
    for key in result.campaign.swept:
        xs = [r.point.values[key] for r in ok]
        if not all(_is_number(x) for x in xs):
            continue
        height_in = 2.2 * len(metrics) + 0.6
        fig, axes = plt.subplots(len(metrics), 1, figsize=(6.4, height_in), sharex=True, squeeze=False)
        # fixed margins [in] for the tick labels, the y labels and the title: tight_layout drew the whole
        # figure once more to measure them, 40 % of the campaign's closing plot (~0.1-0.2 s on 2 cores)
        fig.subplots_adjust(left=1.0 / 6.4, right=1.0 - 0.15 / 6.4, top=1.0 - 0.45 / height_in,
                            bottom=0.55 / height_in, hspace=0.12)
        for ax, metric in zip(axes[:, 0], metrics, strict=True):
            pairs = [(x, _flatten(r.kpis).get(metric)) for x, r in zip(xs, ok, strict=True)]
            pairs = [(x, y) for x, y in pairs if _is_number(y)]
            ax.plot([x for x, _ in pairs], [y for _, y in pairs], "o", alpha=0.6, ms=4)
            if key in result.campaign.grid and pairs:
                levels = sorted({x for x, _ in pairs})
                means = [float(np.mean([y for x, y in pairs if x == lv])) for lv in levels]
                ax.plot(levels, means, "-", lw=1.5, label="mean")
                ax.legend(loc="best", fontsize="small")
            ax.set_ylabel(metric, fontsize="small")
            ax.grid(True, alpha=0.3)
        axes[-1, 0].set_xlabel(key)
        fig.suptitle(f"campaign {result.campaign.name}: {len(ok)} points")
        path = result.out_dir / f"plot_{key.replace('/', '_')}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        files.append(path)
    return files


def shown(values: dict) -> str:
    """Swept values for a person: `key=value, ...`, floats to 6 significant digits."""
    return ", ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v!r}" for k, v in values.items())


def summary_lines(result: CampaignResult) -> list[str]:
    """A short table: points run, cached, failed, and min / mean / max of each plot KPI."""
    n_ok = sum(r.status == "ok" for r in result.results)
    n_cached = sum(r.cached for r in result.results)
    lines = [f"campaign {result.campaign.name}: {len(result.results)} of {result.total} points finished "
             f"({n_ok} ok, {n_cached} from cache, {len(result.failed)} failed) in {result.wall_s:.1f} s"]
    ran = [r for r in result.results if r.status == "ok" and not r.cached and r.sim_wall_s is not None]
    if ran:
        wall = sum(r.wall_s for r in ran)
        sim = sum(r.sim_wall_s for r in ran)
        lines.append(f"  {len(ran)} points ran: {wall / len(ran):.2f} s wall each, {sim / len(ran):.2f} s "
                     f"of it the lockstep simulation ({100 * sim / max(wall, 1e-9):.0f} %)")
    ok = [_flatten(r.kpis) for r in result.results if r.status == "ok"]
    stats = []
    for metric in result.campaign.plot:
        ys = [k[metric] for k in ok if _is_number(k.get(metric))]
        if ys:
            stats.append(f"  {metric:<32} {min(ys):>10.3f} {float(np.mean(ys)):>10.3f} {max(ys):>10.3f}"
                         f"   ({len(ys)} points)")
    if stats:
        lines += [f"  {'KPI':<32} {'min':>10} {'mean':>10} {'max':>10}", *stats]
    for r in result.failed:
        lines.append(f"  point {r.point.index} ({shown(r.point.values)}) failed: {r.error[:200]}")
    return lines


def check_positive(option: str, value: int) -> int:
    """`value` of a count option (--jobs N); below 1 is a CampaignError naming the option."""
    if value < 1:
        raise CampaignError(f"{option} {value}: expected at least 1")
    return value

