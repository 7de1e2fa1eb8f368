"""railhil's pytest plugin: HIL tests written as pytest tests (registered through the `pytest11` entry
point, so installing railhil is enough).

The fixture ``hil_run`` is a callable that runs a scenario and returns a `HilRun`::

    from hil.pytest_plugin import eventually, never, within

    def test_full_service_brake(hil_run):
        run = hil_run("scenarios/default.toml", {"train.initial_speed_kmh": 60})
        assert run.kpis["stopped"]
        within(run.signal("BCU_DEMAND.TargetDecel"), 0.0, 1.2, after=0.6)
        never(run.truth("slip_speed_mps_1") > 3.0, for_longer_than=0.5)
        eventually(run.truth("v_mps_1") < 0.1, before=40.0)

* ``hil_run(scenario, overrides=None, *, mode=None, bus=None)``: `scenario` is a TOML path (absolute,
  relative to the test file, to pytest's rootdir, or to the working directory, tried in that order) or a
  `hil.scenario.Scenario`; `overrides` maps dotted scenario keys to values, exactly like
  `railhil run --set KEY=VALUE` (``{"desk.0.brake_step": 5}``); `mode` is "lockstep" (simulated time,
  deterministic; the default, or the ``--hil-mode`` option) or "realtime" (one OS process per node on a
  python-can bus, `bus` its configuration, e.g. ``{"interface": "socketcan", "channel": "vcan0"}``;
  default udp_multicast on a group of its own). Lockstep runs are cached for the test session: tests
  asking for the same scenario and overrides share one run.
* `HilRun`: ``kpis`` (kpis.json: definitions in hil.report.kpis.compute_kpis), ``out_dir`` (the run folder
  with trace.blf and report.html), ``signal("MESSAGE.Signal")`` (decoded from the trace with the DBC; time
  in simulated seconds from the start of the run), ``truth("v_mps_1")`` (the plant's ground truth
  columns of truth.csv).
* Temporal assertions over a `Signal` (samples held until the next one) and the `Condition` that
  comparing it gives (``sig > 3``, ``abs(sig - other) < 0.1``, combined with ``&``, ``|``, ``~``):
  `within` (the signal stays in [low, high]), `never` (the condition never holds longer than a time),
  `eventually` (the condition holds, for long enough, before a deadline). A failure raises
  `TemporalAssertionError` (an AssertionError) whose message names the first violating time.
* The JUnit XML that pytest writes (``--junitxml``) gets, per test, the properties ``railhil_run`` (the
  run folder), ``railhil_report`` (its report.html) and the headline KPIs (``railhil_stopped``...), as
  pytest's own ``record_property`` would add them (``-o junit_family=xunit1`` for a schema with
  properties).
"""

from __future__ import annotations

import json
import math
import operator
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from hil.errors import BindingError
from hil.runtime.clock import RunClock

__all__ = ["Condition", "HilRun", "Signal", "TemporalAssertionError", "eventually", "never", "run_hil",
           "within"]

MODES = ("lockstep", "realtime")
JUNIT_KPIS = ("stopped", "stopping_distance_m", "time_to_stop_s", "frames_lost")


class TemporalAssertionError(AssertionError):
    """A temporal assertion that does not hold; the message names the first violating time [s]."""


# ----------------------------------------------------------------------------------- signals, conditions
def _hold(t: np.ndarray, v: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Values of the samples (t, v), each held until the next sample, at the times `at` (≥ t[0])."""
    return v[np.searchsorted(t, at, side="right") - 1]


def _align(a: Signal | Condition, b: Signal | Condition) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Both on the union of their sample times from the later of their first samples (sample and hold)."""
    if a.t.size == 0 or b.t.size == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    t = np.union1d(a.t, b.t)
    t = t[t >= max(a.t[0], b.t[0])]
    return t, _hold(a.t, a.values, t), _hold(b.t, b.values, t)


@dataclass(frozen=True, eq=False)
class Signal:
    """A sampled signal: times `t` [s] (increasing) and `values`, each held until the next sample."""

    name: str
    t: np.ndarray
    values: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "values", np.asarray(self.values, dtype=float))
        if t.size > 1 and np.any(np.diff(t) < 0):
            raise ValueError(f"signal {self.name}: sample times must not decrease")

    def __len__(self) -> int:
        return int(self.t.size)

    def __repr__(self) -> str:
        span = f"{self.t[0]:.3f}-{self.t[-1]:.3f} s" if self.t.size else "no samples"
        return f"Signal({self.name}: {self.t.size} samples, {span})"

    def at(self, time_s: float) -> float:
        """The value held at `time_s` [s] (the last sample at or before it)."""
        if not self.t.size or time_s < self.t[0]:
            raise ValueError(f"signal {self.name} has no sample at or before t = {time_s} s")
        return float(_hold(self.t, self.values, np.asarray([time_s]))[0])

    def _binary(self, other: Signal | float, op: Callable, symbol: str) -> tuple[str, np.ndarray, np.ndarray]:
        if isinstance(other, Signal):
            t, a, b = _align(self, other)
            return f"{self.name} {symbol} {other.name}", t, op(a, b)
        return f"{self.name} {symbol} {other:g}", self.t, op(self.values, float(other))

    def _arith(self, other, op, symbol) -> Signal:
        name, t, v = self._binary(other, op, symbol)
        return Signal(f"({name})", t, v)

    def _cmp(self, other, op, symbol) -> Condition:
        name, t, v = self._binary(other, op, symbol)
        return Condition(name, t, v)

    def __add__(self, other):
        return self._arith(other, operator.add, "+")

    def __sub__(self, other):
        return self._arith(other, operator.sub, "-")

    def __mul__(self, other):
        return self._arith(other, operator.mul, "*")

    def __abs__(self) -> Signal:
        return Signal(f"|{self.name}|", self.t, np.abs(self.values))

    def __neg__(self) -> Signal:
        return Signal(f"-{self.name}", self.t, -self.values)

    def __lt__(self, other):
        return self._cmp(other, operator.lt, "<")

    def __le__(self, other):
        return self._cmp(other, operator.le, "<=")

    def __gt__(self, other):
        return self._cmp(other, operator.gt, ">")

    def __ge__(self, other):
        return self._cmp(other, operator.ge, ">=")

    def __eq__(self, other):          # a Condition, like numpy: sig == 2
        return self._cmp(other, operator.eq, "==")

    def __ne__(self, other):
        return self._cmp(other, operator.ne, "!=")

    __hash__ = object.__hash__


@dataclass(frozen=True, eq=False)
class Condition:
    """A truth value over time: at `t` [s], `values` (bool), each held until the next sample."""

    name: str
    t: np.ndarray
    values: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "t", np.asarray(self.t, dtype=float))
        object.__setattr__(self, "values", np.asarray(self.values, dtype=bool))

    def __repr__(self) -> str:
        return f"Condition({self.name}: {self.t.size} samples)"

    def __and__(self, other: Condition) -> Condition:
        t, a, b = _align(self, other)
        return Condition(f"({self.name}) and ({other.name})", t, a.astype(bool) & b.astype(bool))

    def __or__(self, other: Condition) -> Condition:
        t, a, b = _align(self, other)
        return Condition(f"({self.name}) or ({other.name})", t, a.astype(bool) | b.astype(bool))

    def __invert__(self) -> Condition:
        return Condition(f"not ({self.name})", self.t, ~self.values)

    def intervals(self) -> list[tuple[float, float, bool]]:
        """(start, end, closed) of every stretch where the condition holds: from its first true sample to
        the next false one (closed = True), or to the last sample (closed = False: the data ended)."""
        v = self.values.astype(np.int8)
        edges = np.diff(np.concatenate([[0], v, [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        out = []
        for a, b in zip(starts, ends, strict=True):
            closed = b < self.t.size
            out.append((float(self.t[a]), float(self.t[b] if closed else self.t[-1]), bool(closed)))
        return out


def _window(x: Signal | Condition, after: float | None,
            before: float | None) -> tuple[Signal | Condition, str]:
    lo = -math.inf if after is None else after
    hi = math.inf if before is None else before
    if hi < lo:
        raise ValueError(f"before = {before} s is earlier than after = {after} s")
    keep = (x.t >= lo) & (x.t <= hi)
    text = (("" if after is None else f" after {after:g} s")
            + ("" if before is None else f" before {before:g} s"))
    return type(x)(x.name, x.t[keep], x.values[keep]), text


def _clip(cond: Condition, after: float | None, before: float | None) -> tuple[Condition, str]:
    """The condition within [after, before], with the values held at `after` and at `before` as samples
    (a stretch that began before `after` counts from `after`, one that goes on past `before` up to it)."""
    c, text = _window(cond, after, before)
    if after is not None and cond.t.size and cond.t[0] < after and (not c.t.size or c.t[0] > after):
        held = bool(_hold(cond.t, cond.values, np.asarray([after]))[0])
        c = Condition(c.name, np.concatenate([[after], c.t]), np.concatenate([[held], c.values]))
    if before is not None and c.t.size and cond.t[-1] > before and c.t[-1] < before:
        held = bool(_hold(cond.t, cond.values, np.asarray([before]))[0])
        c = Condition(c.name, np.concatenate([c.t, [before]]), np.concatenate([c.values, [held]]))
    return c, text


def within(signal: Signal, low: float, high: float, after: float | None = None,
           before: float | None = None) -> None:
    """Every sample of `signal` at after ≤ t ≤ before [s] (default: all) lies in [low, high]; else a
    TemporalAssertionError naming the first sample outside, its time and value. A window without any
    sample fails too (nothing was checked)."""
    __tracebackhide__ = True          # pytest shows the test's line, not this one
    s, text = _window(signal, after, before)
    if not s.t.size:
        raise TemporalAssertionError(f"within: {signal.name} has no sample{text or ''} to check "
                                     f"(its samples span {_span(signal)})")
    bad = np.flatnonzero((s.values < low) | (s.values > high) | np.isnan(s.values))
    if bad.size:
        i = int(bad[0])
        worst = int(bad[np.argmax(np.maximum(low - s.values[bad], s.values[bad] - high))])
        raise TemporalAssertionError(
            f"within: {signal.name} = {s.values[i]:.6g} outside [{low:g}, {high:g}] at t = {s.t[i]:.4f} s "
            f"(first violation{text}; {bad.size} of {s.t.size} samples outside, the farthest "
            f"{s.values[worst]:.6g} at t = {s.t[worst]:.4f} s)")


def _span(x: Signal | Condition) -> str:
    return f"{x.t[0]:.4f}-{x.t[-1]:.4f} s" if x.t.size else "nothing: no samples"


def never(condition: Condition, for_longer_than: float = 0.0, after: float | None = None,
          before: float | None = None) -> None:
    """`condition` never holds for longer than `for_longer_than` [s] at a stretch (0: never holds at
    all) within [after, before]. A failure names the first violating time: the start of the first
    stretch that holds too long plus `for_longer_than`."""
    __tracebackhide__ = True          # pytest shows the test's line, not this one
    if for_longer_than < 0:
        raise ValueError(f"for_longer_than = {for_longer_than}: expected ≥ 0 s")
    c, text = _clip(condition, after, before)
    if not c.t.size:
        raise TemporalAssertionError(f"never: {condition.name} has no sample{text} to check "
                                     f"(its samples span {_span(condition)})")
    for start, end, closed in c.intervals():
        duration = end - start
        if (for_longer_than == 0.0) or duration > for_longer_than:
            until = f"until t = {end:.4f} s" if closed else f"until the end of the data at t = {end:.4f} s"
            if for_longer_than == 0.0:
                raise TemporalAssertionError(f"never: {condition.name} holds at t = {start:.4f} s (first "
                                             f"violation{text}; it holds {until})")
            raise TemporalAssertionError(
                f"never: {condition.name} held for longer than {for_longer_than:g} s: first violation at "
                f"t = {start + for_longer_than:.4f} s (it holds from t = {start:.4f} s {until}, "
                f"{duration:.4f} s{text})")


def eventually(condition: Condition, before: float | None = None, after: float | None = None,
               for_at_least: float = 0.0) -> float:
    """`condition` holds, for at least `for_at_least` [s] at a stretch, somewhere in [after, before];
    returns the time [s] it began to hold. A failure names the violating time: the deadline `before`
    (or the end of the data), and the longest stretch it did hold."""
    __tracebackhide__ = True          # pytest shows the test's line, not this one
    if for_at_least < 0:
        raise ValueError(f"for_at_least = {for_at_least}: expected ≥ 0 s")
    c, text = _clip(condition, after, before)
    if not c.t.size:
        raise TemporalAssertionError(f"eventually: {condition.name} has no sample{text} to check "
                                     f"(its samples span {_span(condition)})")
    stretches = c.intervals()
    for start, end, _ in stretches:
        if end - start >= for_at_least:
            return start
    deadline = before if before is not None and before <= float(c.t[-1]) else float(c.t[-1])
    where = "the deadline" if deadline == before else "the end of the data"
    longest = max(stretches, key=lambda s: s[1] - s[0], default=None)
    seen = (f"; it held longest from t = {longest[0]:.4f} s for {longest[1] - longest[0]:.4f} s"
            if longest else "; it never held")
    need = f" for {for_at_least:g} s" if for_at_least > 0 else ""
    raise TemporalAssertionError(f"eventually: {condition.name} did not hold{need}{text}: violated at "
                                 f"t = {deadline:.4f} s ({where}){seen}")


# ------------------------------------------------------------------------------------------ running
@dataclass
class HilRun:
    """One finished run: its run folder, KPIs, and its decoded signals and ground truth on demand."""

    out_dir: Path
    mode: str
    kpis: dict
    scenario: object                        # hil.scenario.Scenario
    _signals: dict[str, Signal] = field(default_factory=dict, repr=False)
    _truth: dict[str, np.ndarray] | None = field(default=None, repr=False)

    @property
    def report_html(self) -> Path:
        return self.out_dir / "report.html"

    @property
    def trace(self) -> Path:
        """The run's trace file (trace.blf, or the [trace] format's)."""
        return self.out_dir / f"trace.{self.scenario.trace.format}"

    def signals(self, *names: str) -> dict[str, Signal]:
        """Several "MESSAGE.Signal" names decoded in one pass over the trace (time: simulated s)."""
        # lazy: pytest loads this plugin in every session; the run machinery would add 460 ms there
        from hil.can.codec import Codec
        from hil.can.dbc import load_dbc
        from hil.report.kpis import read_signals
        from hil.runtime.run import dbc_path_of

        todo = [n for n in names if n not in self._signals]
        if todo:
            db = load_dbc(dbc_path_of(self.scenario))
            wanted = {}
            for name in todo:
                message, _, sig = name.partition(".")
                try:
                    msg = db.get_message_by_name(message)
                except KeyError:
                    raise BindingError(f"{name}: the DBC has no message {message!r} (expected "
                                       f"MESSAGE.Signal, e.g. BCU_DEMAND.TargetDecel)") from None
                if sig not in {s.name for s in msg.signals}:
                    raise BindingError(f"{name}: message {message} has no signal {sig!r}; it has "
                                       f"{', '.join(s.name for s in msg.signals)}")
                wanted[name] = (message, sig)
            meta = json.loads((self.out_dir / "run.json").read_text())
            decoded = read_signals(self.trace, db, Codec(db), wanted, RunClock.of_run(meta))
            for name, (t, v) in decoded.items():
                self._signals[name] = Signal(name, t, v)
        return {n: self._signals[n] for n in names}

    def signal(self, name: str) -> Signal:
        """One signal of the trace, "MESSAGE.Signal", decoded with the DBC (time: simulated s)."""
        return self.signals(name)[name]

    def truth(self, column: str) -> Signal:
        """A column of the plant's ground truth (truth.csv), e.g. v_mps_1, x_m_1, p_Pa_3, slip_speed_mps_2."""
        if self._truth is None:
            # lazy: pytest loads this plugin in every session; the run machinery would add 460 ms there
            from hil.runtime.truth import read_truth_csv

            self._truth = read_truth_csv(self.out_dir / "truth.csv")
        if column not in self._truth:
            import difflib

            close = difflib.get_close_matches(column, list(self._truth), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise KeyError(f"truth.csv of {self.out_dir} has no column {column!r}{hint}")
        return Signal(f"truth.{column}", self._truth["t_s"], self._truth[column])


def resolve_scenario(scenario, overrides: dict | None = None, search: tuple[Path, ...] = ()):
    """A Scenario from a path (tried as given, then under each folder of `search`) or a Scenario, with
    dotted-key overrides applied like `railhil run --set` (each key and value checked)."""
    # lazy: pytest loads this plugin in every session; the run machinery would add 460 ms there
    from hil.scenario import Scenario, apply_set, load_scenario, parse_scenario

    if isinstance(scenario, Scenario):
        base, source = scenario, scenario.name
    else:
        path = Path(scenario)
        if not path.is_absolute() and not path.exists():
            path = next((d / path for d in search if (d / path).exists()), path)
        base, source = load_scenario(path), str(path)
    if not overrides:
        return base
    data = base.model_dump(mode="json")
    for key, value in overrides.items():
        apply_set(data, key, value, source)
    return parse_scenario(data, f"{source} with overrides {overrides}")


def run_hil(scenario, out_dir: Path, overrides: dict | None = None, mode: str = "lockstep",
            bus: dict | None = None, search: tuple[Path, ...] = ()) -> HilRun:
    """Run a scenario (a path or a Scenario, with `overrides`) into `out_dir` in lockstep or real time."""
    if mode not in MODES:
        raise ValueError(f"mode = {mode!r}: expected one of {', '.join(MODES)}")
    sc = resolve_scenario(scenario, overrides, search)
    if mode == "lockstep":
        # lazy: pytest loads this plugin in every session; the run machinery would add 460 ms there
        from hil.report.run import run_scenario_lockstep

        report = run_scenario_lockstep(sc, Path(out_dir))
    else:
        # lazy: pytest loads this plugin in every session; the run machinery would add 460 ms there
        from hil.report.run import run_scenario_realtime

        report = run_scenario_realtime(sc, Path(out_dir), dict(bus or {}))
    return HilRun(Path(out_dir), mode, report.kpis, sc)


# -------------------------------------------------------------------------------------- pytest hooks
def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("railhil", "railhil HIL tests")
    group.addoption("--hil-mode", choices=MODES, default="lockstep",
                    help="how the hil_run fixture runs scenarios when a test does not say: lockstep "
                         "(simulated time, deterministic; default) or realtime (one OS process per node "
                         "on a python-can bus)")
    group.addoption("--hil-out", metavar="DIR", default=None,
                    help="keep the run folders of hil_run under DIR (default: pytest's temporary folder)")


class _Runs:
    """The session's runs: lockstep ones cached by (scenario, overrides)."""

    def __init__(self, config: pytest.Config, base: Path) -> None:
        self.config = config
        self.base = base
        self.cache: dict[str, HilRun] = {}
        self.count = 0

    def run(self, scenario, overrides, mode, bus, search) -> HilRun:
        # lazy: pytest loads this plugin in every session; the run machinery would add 460 ms there
        from hil.scenario import Scenario

        key = None
        if mode == "lockstep":
            sc = resolve_scenario(scenario, overrides, search)
            key = sc.model_dump_json() if isinstance(sc, Scenario) else None
            if key in self.cache:
                return self.cache[key]
            scenario, overrides = sc, None
        self.count += 1
        name = scenario.name if isinstance(scenario, Scenario) else Path(scenario).stem
        out = self.base / f"{self.count:03d}-{name}-{mode}"
        run = run_hil(scenario, out, overrides, mode, bus, search)
        if key is not None:
            self.cache[key] = run
        return run


@pytest.fixture(scope="session")
def _railhil_runs(pytestconfig: pytest.Config, tmp_path_factory: pytest.TempPathFactory) -> _Runs:
    out = pytestconfig.getoption("--hil-out")
    base = Path(out) if out else tmp_path_factory.mktemp("railhil-runs")
    base.mkdir(parents=True, exist_ok=True)
    return _Runs(pytestconfig, base)


@pytest.fixture
def hil_run(_railhil_runs: _Runs, request: pytest.FixtureRequest) -> Callable[..., HilRun]:
    """A callable `hil_run(scenario, overrides=None, *, mode=None, bus=None) -> HilRun` (module docstring):
    runs the scenario with dotted-key overrides in lockstep (default, or --hil-mode) or in real time,
    and returns its KPIs, decoded signals and ground truth; the run folder and the headline KPIs go
    into the JUnit XML as properties."""
    search = (request.path.parent, request.config.rootpath)

    def record_property(name: str, value: object) -> None:      # what pytest's record_property does
        request.node.user_properties.append((name, value))

    def run(scenario, overrides: dict | None = None, *, mode: str | None = None,
            bus: dict | None = None) -> HilRun:
        result = _railhil_runs.run(scenario, overrides, mode or request.config.getoption("--hil-mode"),
                                   bus, search)
        record_property("railhil_run", str(result.out_dir))
        record_property("railhil_report", str(result.report_html))
        for k in JUNIT_KPIS:
            if k in result.kpis:
                record_property(f"railhil_{k}", result.kpis[k])
        return result

    return run
