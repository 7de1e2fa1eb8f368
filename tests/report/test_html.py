"""The HTML reports (hil.report.html): every run folder gets report.html with verdicts, KPIs (name, value,
unit, meaning; per-car values a column per car), the signals as an interactive plotly figure (plotly.js
inline, nothing fetched), the static plots embedded, timing, faults and what reproduces the run
(run.json); every KPI of every kpis.json has a description (hil.report.kpi_info, the studies' KPI_INFO);
`railhil report` rebuilds the page and `--against` compares two runs; a campaign folder gets its table and
plots; the pages render with their plots in a headless browser."""

from __future__ import annotations

import base64
import hashlib
import html
import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, assert_one_line_error, railhil

from hil.can.dbc import DEFAULT_DBC


class Page(HTMLParser):
    """The tags, embedded images, links, scripts, table rows and cell texts of a page (the parser raises
    nothing: we count).  A cell's text is that of its own table only (a mapping KPI's small table inside
    a cell gives cells of its own too)."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.images: list[bytes] = []
        self.links: list[str] = []
        self.refs: list[str] = []                   # every src= and href= of every tag
        self.scripts: list[tuple[dict, str]] = []   # (attributes, text)
        self.cells: list[str] = []
        self.rows: list[tuple[str, list[str]]] = []  # (class of the <tr>, texts of its cells)
        self._cells: list[list[str]] = []
        self._row: list[tuple[str, list[str]]] = []
        self._script: dict | None = None
        self._text: list[str] = []
        self.raw = text
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.refs += [v or "" for k, v in attrs if k in ("src", "href")]
        if tag == "img" and a.get("src", "").startswith("data:image/png;base64,"):
            self.images.append(base64.b64decode(a["src"].split(",", 1)[1]))
        if tag == "a":
            self.links.append(a.get("href", ""))
        if tag == "script":
            self._script, self._text = a, []
        if tag == "tr":
            self._row.append((a.get("class") or "", []))
        if tag in ("td", "th"):
            self._cells.append([])

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cells:
            text = "".join(self._cells.pop()).strip()
            self.cells.append(text)
            if self._row:
                self._row[-1][1].append(text)
            if self._cells:                         # a cell inside a cell: its text is the outer's too
                self._cells[-1].append(text + " ")
        if tag == "tr" and self._row:
            self.rows.append(self._row.pop())
        if tag == "script" and self._script is not None:
            self.scripts.append((self._script, "".join(self._text)))
            self._script = None

    def handle_data(self, data):
        if self._script is not None:
            self._text.append(data)
        elif self._cells:
            self._cells[-1].append(data)

    def row(self, first: str) -> tuple[str, list[str]]:
        """The (class, cells) of the first row whose first cell starts with `first`."""
        return next(r for r in self.rows if r[1] and r[1][0].startswith(first))

    def figure(self, div_id: str = "signals-plot") -> dict:
        """The plotly figure (data, layout) embedded for the <div id=div_id>."""
        text = next(t for a, t in self.scripts if a.get("id") == f"{div_id}-data")
        assert a_figure_div(div_id) in self.raw
        return json.loads(text)


def a_figure_div(div_id: str) -> str:
    return f"<div id={div_id} class=plot>"


def array(v) -> np.ndarray:
    """A plotly data array: a list, or a typed array {"dtype": "f4", "bdata": base64}."""
    if isinstance(v, dict):
        return np.frombuffer(base64.b64decode(v["bdata"]), dtype=np.dtype(v["dtype"])).astype(float)
    return np.asarray(v, dtype=float)


def page_of(path: Path) -> Page:
    return Page(path.read_text(encoding="utf-8"))


def assert_self_contained(page: Page) -> None:
    """Nothing loaded from elsewhere: every src/href is an embedded data: URI or an anchor in the page,
    no <script src=...>, plotly.js inlined exactly once."""
    assert page.refs and all(r.startswith(("data:", "#")) for r in page.refs), \
        [r for r in page.refs if not r.startswith(("data:", "#"))]
    assert not any("src" in a for a, _ in page.scripts)
    assert sum("* plotly.js v" in t[:200] for _, t in page.scripts) == 1


def verdict_of(page: Page, check: str) -> str:
    i = page.cells.index(check)
    return page.cells[i + 3]                         # check, value, criterion, verdict


def test_every_run_folder_has_a_self_contained_report(default_lockstep):
    out = default_lockstep.out_dir
    report = out / "report.html"
    assert report in default_lockstep.files
    page = page_of(report)
    assert page.images == [(out / "plot.png").read_bytes()]       # the plot itself, embedded
    assert_self_contained(page)
    kpis = default_lockstep.kpis
    assert verdict_of(page, "train stopped") == ("pass" if kpis["stopped"] else "FAIL")
    assert verdict_of(page, "frames lost") == ("pass" if kpis["frames_lost"] == 0 else "FAIL")
    assert str(kpis["stopping_distance_m"]) in page.cells         # the KPI table
    meta = json.loads((out / "run.json").read_text())
    for name in meta["bus_timing"]["messages"]:                 # a timing row per message
        assert name in page.cells
    assert page.cells[page.cells.index("BCU_DEMAND") + 2] == str(meta["bus_timing"]["messages"]
                                                                   ["BCU_DEMAND"]["frames"])


def test_run_json_records_what_reproduces_the_run(default_lockstep):
    meta = json.loads((default_lockstep.out_dir / "run.json").read_text())
    assert meta["dbc_sha256"] == hashlib.sha256(DEFAULT_DBC.read_bytes()).hexdigest()
    assert meta["seed"] == meta["scenario"]["seed"]
    import can
    import cantools

    assert meta["versions"]["python-can"] == can.__version__
    assert meta["versions"]["cantools"] == cantools.__version__
    assert meta["git_commit"] is None or re.fullmatch(r"[0-9a-f]{40}", meta["git_commit"])
    assert meta["wall_s"] > 0


def test_git_commit_is_read_from_the_git_directory(tmp_path):
    from hil.runtime.provenance import git_commit

    sha = "0123456789abcdef0123456789abcdef01234567"
    (tmp_path / "repo" / ".git" / "refs" / "heads").mkdir(parents=True)
    (tmp_path / "repo" / "pkg").mkdir()
    (tmp_path / "repo" / ".git" / "HEAD").write_text("ref: refs/heads/main\n")
    (tmp_path / "repo" / ".git" / "packed-refs").write_text(f"# pack-refs\n{sha} refs/heads/main\n")
    assert git_commit(tmp_path / "repo" / "pkg" / "x.py") == sha           # packed
    other = sha[::-1]
    (tmp_path / "repo" / ".git" / "refs" / "heads" / "main").write_text(other + "\n")
    assert git_commit(tmp_path / "repo" / "pkg" / "x.py") == other         # a loose ref wins
    (tmp_path / "repo" / ".git" / "HEAD").write_text(sha + "\n")
    assert git_commit(tmp_path / "repo" / "pkg" / "x.py") == sha           # detached
    assert git_commit(tmp_path / "x.py") in (None, git_commit(Path("/") / "x.py"))


def test_railhil_report_rebuilds_it_and_a_failed_check_shows(default_lockstep, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(default_lockstep.out_dir, run)
    kpis = json.loads((run / "kpis.json").read_text())
    kpis["frames_lost"] = 3
    (run / "kpis.json").write_text(json.dumps(kpis))
    (run / "report.html").unlink()
    code, out, err = railhil(capsys, "report", run)
    assert code == 0, err
    assert out.strip() == str(run / "report.html")
    page = Page((run / "report.html").read_text())
    assert verdict_of(page, "frames lost") == "FAIL"
    assert "FAIL: frames lost" in (run / "report.html").read_text()


def test_late_frames_are_informational_in_real_time_and_a_stall_fails_the_real_time_check():
    """E2E NONEWDATA (a frame 1.5 of its cycles late) is timing, not a protection error: informational in
    real time (every `make run` has some), a failure in lockstep without faults; a run whose bench missed
    deadlines beyond the budget fails its own check (tests/runtime/test_realtime_verdict.py has the rest)."""
    from hil.report.html import run_verdicts
    from hil.runtime.outcome import RunOutcome, realtime_verdict

    def verdicts(mode, late_us):
        lateness = np.full(1_000, 30)
        lateness[500] = late_us
        cycles = {"BECU1": {"period_us": 10_000, "deadline_us": np.arange(1_000) * 10_000,
                            "lateness_us": lateness}}
        kpis = {"end_reason": "standstill", "stopped": True, "frames_lost": 0,
                "protection_events": {"NONEWDATA": 88}}
        if mode == "realtime":
            kpis["realtime"] = realtime_verdict(RunOutcome(
                "realtime", 10_000_000, "standstill", None, {}, realtime={"cycles": cycles, "probes": {}}))
        return {v.check: v for v in run_verdicts(kpis, {"mode": mode, "node_stats": {}})}

    rt = verdicts("realtime", 400)
    held = "real time held (the bench's deadline misses)"
    assert rt["E2E / SecOC errors reported"].passed is True
    assert rt["frames 1.5 cycles late (E2E NONEWDATA)"].passed is None
    assert rt["frames 1.5 cycles late (E2E NONEWDATA)"].value == "88"
    assert rt[held].passed is True and "0 bench misses" in rt[held].value
    assert verdicts("realtime", 12_000)[held].passed is False
    assert verdicts("lockstep", 0)["frames 1.5 cycles late (E2E NONEWDATA)"].passed is False


def test_report_bad_folders_are_one_line_errors(tmp_path, capsys):
    assert_one_line_error(*railhil(capsys, "report", tmp_path / "nope")[::2], "nope", "no such folder")
    assert_one_line_error(*railhil(capsys, "report", tmp_path)[::2], str(tmp_path), "run.json",
                          "results.csv")
    (tmp_path / "run.json").write_text("{not json")
    (tmp_path / "kpis.json").write_text("{}")
    assert_one_line_error(*railhil(capsys, "report", tmp_path)[::2], "run.json", "cannot read")


def test_campaign_folder_gets_its_report(tmp_path):
    from hil.campaign.sweep import load_campaign, run_campaign, write_plots, write_table

    spec = tmp_path / "c.toml"
    spec.write_text(f'base = "{ROOT / "scenarios" / "stop_30kmh.toml"}"\nname = "tiny"\n'
                    f'[set]\nmax_duration_s = 1.0\n[grid]\n"train.mass_kg" = [30000.0, 40000.0]\n')
    result = run_campaign(load_campaign(spec), tmp_path / "out", plots=True)   # --plots: point reports
    files = write_table(result) + write_plots(result)
    report = tmp_path / "out" / "report.html"
    assert report in files
    page = Page(report.read_text())
    plots = sorted((tmp_path / "out").glob("plot_*.png"))
    assert plots and page.images == [p.read_bytes() for p in plots]
    assert page.links == [f"{r.run_dir.relative_to(tmp_path / 'out')}/report.html" for r in result.results]
    for link in page.links:                                   # each point's own run report exists
        point = (tmp_path / "out" / link).read_text()
        assert "Plotly.newPlot" not in point and len(point) < 1_000_000   # static figures, no plotly.js
        assert f"railhil report {(tmp_path / 'out' / link).parent}" in point    # how to get the zoomable one
    assert page.cells.count("ok") == len(result.results) == 2
    rebuilt = tmp_path / "out" / "again.html"
    report.rename(rebuilt)
    from hil.report.html import write_report

    assert write_report(tmp_path / "out") == report           # from results.csv alone
    assert Page(report.read_text()).cells.count("ok") == 2


# ------------------------------------------------------------------------------------- KPIs described
def entries():
    """(where, key, entry) of every KPI description: the foundation's and each study's KPI_INFO."""
    from hil.report.kpi_info import FOUNDATION
    from hil.scenario.registry import studies

    out = [("hil/report/kpi_info.py", k, e) for k, e in FOUNDATION.items()]
    for study in studies():
        table = getattr(study.part("kpis"), "KPI_INFO", None)
        assert table, f"hil/studies/{study.name}/kpis.py has no KPI_INFO"
        out += [(f"hil/studies/{study.name}/kpis.py", k, e) for k, e in table.items()]
    return out


def test_every_kpi_description_has_a_name_a_unit_and_a_one_line_meaning():
    from hil.report.kpi_info import KpiInfo

    for where, key, entry in entries():
        assert isinstance(entry, tuple) and len(entry) in (3, 4), (where, key, entry)
        info = KpiInfo(*entry)
        assert all(isinstance(x, str) and x.strip() for x in info[:3]), (where, key, entry)
        assert "\n" not in info.meaning and len(info.meaning) < 250, (where, key)
        assert isinstance(info.per_car, bool), (where, key)


def study_scenarios() -> dict[str, Path]:
    """Each study -> the first shipped scenario with its section (scenarios/*.toml, sorted)."""
    from hil.scenario import load_scenario
    from hil.scenario.registry import active

    out: dict[str, Path] = {}
    for path in sorted((ROOT / "scenarios").glob("*.toml")):
        for study in active(load_scenario(path)):
            out.setdefault(study.name, path)
    return out


STUDY_RUN_S = 6.0          # a study's scenario is run this long (enough for every KPI key it writes)


def test_every_kpi_of_a_default_run_has_a_description(default_lockstep):
    """A KPI added to compute_kpis or finish_run without an entry in hil/report/kpi_info.py fails here; the
    real-time and fault KPIs are checked on top of the lockstep run's (below)."""
    from hil.report.kpi_info import undescribed
    from hil.runtime.outcome import RunOutcome, realtime_verdict

    kpis = json.loads((default_lockstep.out_dir / "kpis.json").read_text())
    assert undescribed(kpis) == []
    cycles = {"PLANT": {"period_us": 1_000, "deadline_us": np.arange(10), "lateness_us": np.zeros(10)}}
    kpis["realtime"] = realtime_verdict(RunOutcome("realtime", 10_000, "standstill", None, {},
                                                   realtime={"cycles": cycles, "probes": {}}))
    kpis["realtime"]["conduct"] = {}
    assert undescribed(kpis) == []


def test_every_kpi_of_a_run_with_faults_has_a_description(tmp_path):
    from hil.report.kpi_info import undescribed
    from hil.report.run import run_scenario_lockstep
    from hil.scenario import load_scenario

    scenario = load_scenario("default", overrides={"max_duration_s": 1.5, "faults": [
        {"kind": "deletion", "message": "BCU_DEMAND", "from_s": 1.0, "to_s": 1.05},
        {"kind": "sensor", "sensor": "wheel_speed", "car": 2, "mode": "stuck", "from_s": 0.2, "to_s": 1.5}]})
    kpis = run_scenario_lockstep(scenario, tmp_path / "run").kpis
    assert "faults_injected" in kpis and "plausibility_flags" in kpis
    assert undescribed(kpis) == []


@pytest.mark.parametrize("study", sorted(study_scenarios()))
def test_every_kpi_of_a_study_run_has_a_description(study, tmp_path):
    """Each study's first shipped scenario, run STUDY_RUN_S: every key its kpis() writes is in its
    KPI_INFO (appended to hil/studies/<name>/kpis.py)."""
    from hil.report.kpi_info import undescribed
    from hil.report.run import run_scenario_lockstep
    from hil.scenario import load_scenario

    path = study_scenarios()[study]
    base = load_scenario(path)
    scenario = load_scenario(path, overrides={"max_duration_s": min(base.max_duration_s, STUDY_RUN_S)})
    kpis = run_scenario_lockstep(scenario, tmp_path / "run").kpis
    assert study in kpis
    assert undescribed(kpis) == [], f"describe them in hil/studies/{study}/kpis.py KPI_INFO"
    page = page_of(tmp_path / "run" / "report.html")
    assert any(c.startswith(f"{by_name_title(study)} ({study})") for c in page_headings(page))


def by_name_title(name: str) -> str:
    from hil.scenario.registry import by_name

    return by_name(name).title


def page_headings(page: Page) -> list[str]:
    return re.findall(r"<h3>([^<]*)</h3>", page.raw)


def test_the_kpi_tables_give_name_value_unit_and_meaning(default_lockstep):
    from hil.report.kpi_info import FOUNDATION, KpiInfo

    page = page_of(default_lockstep.out_dir / "report.html")
    kpis = default_lockstep.kpis
    cls, cells = page.row("stopping distance stopping_distance_m")
    info = KpiInfo(*FOUNDATION["stopping_distance_m"])
    assert cells == ["stopping distance stopping_distance_m", str(kpis["stopping_distance_m"]), "m",
                     info.meaning]
    assert page.row("train stopped stopped")[1][1:3] == ["yes", "yes/no"]
    head = next(c for _, c in page.rows if c and c[0] == "per car")      # a column per car
    assert head == ["per car", *(f"car {i}" for i in range(1, 7)), "unit", "meaning"]
    _, slip = page.row("max slip speed max_slip_speed_mps")
    assert slip[1:7] == [f"{v:.6g}" for v in kpis["max_slip_speed_mps"]] and slip[7] == "m/s"
    assert page.row("bitrate bus.bitrate_bps")[1][1:3] == ["500000", "bit/s"]   # the bus: a table of its own
    assert {"Train (from the plant&#x27;s truth)", "Run and frames", "CAN bus"} <= set(page_headings(page))
    by_node = page.row("frames sent by node frames_sent_by_node")[1]   # a mapping: one line of pairs
    nodes = json.loads((default_lockstep.out_dir / "kpis.json").read_text())["frames_sent_by_node"]
    assert by_node[1].replace("\xa0", " ") == ", ".join(f"{k} {v}" for k, v in nodes.items())
    assert not any("undescribed" in c for c, _ in page.rows)


def test_a_kpi_without_a_description_shows_as_such(default_lockstep, tmp_path):
    from hil.report.html import render_run_report
    from hil.report.kpi_info import undescribed

    run = tmp_path / "run"
    shutil.copytree(default_lockstep.out_dir, run)
    kpis = json.loads((run / "kpis.json").read_text())
    kpis["brake_pad_wear_mm"] = 0.3
    kpis["bus"]["error_frames"] = 2
    (run / "kpis.json").write_text(json.dumps(kpis))
    assert undescribed(kpis) == ["brake_pad_wear_mm", "bus.error_frames"]
    page = Page(render_run_report(run))
    cls, cells = page.row("brake_pad_wear_mm")
    assert cls == "undescribed" and cells[1:3] == ["0.3", "?"] and cells[3].startswith("no description")
    assert page.row("error_frames")[0] == "undescribed"
    assert "2 KPIs without a description: brake_pad_wear_mm, bus.error_frames" in page.raw


# ------------------------------------------------------------------------------------------- signals
def test_decimate_keeps_the_peaks_and_short_curves_whole():
    from hil.report.html import decimate

    t = np.arange(10_000) * 0.01
    y = np.sin(t)
    y[4321] = 7.0                                  # a one-sample spike
    y[777] = -5.0
    td, yd = decimate(t, y, 2000)
    assert len(td) <= 2002 and np.all(np.diff(td) > 0)
    assert yd.max() == 7.0 and yd.min() == -5.0 and td[0] == t[0] and td[-1] == t[-1]
    assert np.all(np.isin(td, t))                   # samples, not interpolations
    short = np.arange(500.0)
    assert decimate(short, short, 2000)[0] is short


def test_the_signals_are_embedded_as_an_interactive_figure(default_lockstep):
    from hil.report.html import MAX_POINTS
    from hil.runtime.truth import read_truth_csv

    out = default_lockstep.out_dir
    page = page_of(out / "report.html")
    fig = page.figure()
    cols = read_truth_csv(out / "truth.csv")
    traces = fig["data"]
    assert len(traces) == 3 * 6                               # speed, pressure, slip of every car
    axes = [tr.get("yaxis", "y") for tr in traces]
    assert axes == ["y"] * 6 + ["y2"] * 6 + ["y3"] * 6
    assert [tr["name"] for tr in traces[:6]] == [f"car {i}" for i in range(1, 7)]
    for tr, (key, scale) in ((traces[0], ("v_mps_1", 3.6)), (traces[6], ("p_Pa_1", 1e-3)),
                             (traces[15], ("slip_speed_mps_4", 1.0))):
        x, y = array(tr["x"]), array(tr["y"])
        assert 100 < len(x) <= MAX_POINTS + 2
        truth = cols[key] * scale
        assert np.allclose(y, np.interp(x, cols["t_s"], truth), rtol=1e-4, atol=1e-3 * np.abs(truth).max())
        assert y.max() == pytest.approx(truth.max(), rel=1e-5)   # the peak survives the decimation
    assert fig["layout"]["xaxis3"]["title"]["text"] == "time [s]"
    assert fig["layout"]["xaxis"].get("matches") or fig["layout"]["xaxis2"].get("matches")  # zoom together
    assert fig["layout"].get("dragmode", "zoom") == "zoom"
    assert "Plotly.newPlot('signals-plot'" in page.raw
    assert 2_000_000 < len(page.raw.encode()) < 8_000_000      # plotly.js (4.8 MB) + the data


# ------------------------------------------------------------------------------------------ --against
@pytest.fixture(scope="module")
def seed2_run(tmp_path_factory):
    """The default scenario in lockstep with seed 2, through the command line."""
    out = tmp_path_factory.mktemp("against") / "seed2"
    from hil.cli.main import main

    assert main(["run", "default", "--lockstep", "--seed", "2", "--out", str(out), "-q"]) == 0
    return out


def test_against_compares_two_seeds_of_the_default_scenario(default_lockstep, seed2_run, capsys):
    ref = default_lockstep.out_dir
    code, out, err = railhil(capsys, "report", seed2_run, "--against", ref)
    assert code == 0, err
    page_path = seed2_run / f"report-vs-{ref.name}.html"
    line, path = out.strip().splitlines()                 # the comparison in one line, then the page
    assert path == str(page_path)
    assert line.startswith("Train (from the plant's truth): ") and "differ" in line, line
    page = page_of(page_path)
    assert_self_contained(page)
    assert page.row("seed")[1][1:] == ["2", "1"] and page.row("seed")[0] == "changed"   # runs table
    assert page.row("scenario")[1][1:] == ["default", "default"]
    a = json.loads((seed2_run / "kpis.json").read_text())
    b = default_lockstep.kpis
    cls, cells = page.row("stopping distance stopping_distance_m")
    d = a["stopping_distance_m"] - b["stopping_distance_m"]
    assert cells[1:3] == [str(a["stopping_distance_m"]), str(b["stopping_distance_m"])]
    assert cells[3] == f"{d:+.4g}" and cells[4] == f"{100 * d / abs(b['stopping_distance_m']):+.2f} %"
    assert cls == ("changed" if d else "")
    assert cells[5] == "m"
    assert "KPIs both runs have differ" in page.raw
    cls, same = page.row("frames lost frames_lost")                     # the same value: Δ 0, not marked
    assert same[3] == "0" and cls == ""
    fig = page.figure()
    names = [tr["name"] for tr in fig["data"]]
    assert f"{seed2_run.name} · car 1" in names and f"{ref.name} · car 1" in names
    assert len(fig["data"]) == 2 * 3 * 6
    dashes = {tr["name"]: tr["line"]["dash"] for tr in fig["data"]}
    assert dashes[f"{seed2_run.name} · car 1"] == "solid" and dashes[f"{ref.name} · car 1"] == "dash"
    shown = [tr["name"] for tr in fig["data"] if tr.get("visible", True) is True]
    assert set(shown) == {f"{seed2_run.name} · car 1", f"{ref.name} · car 1"}   # the rest: a legend click


def test_against_writes_where_o_says_and_bad_input_is_a_one_line_error(default_lockstep, seed2_run,
                                                                     tmp_path, capsys):
    ref = default_lockstep.out_dir
    code, out, err = railhil(capsys, "report", seed2_run, "--against", ref, "-o", tmp_path / "cmp.html")
    assert code == 0 and out.strip().splitlines()[-1] == str(tmp_path / "cmp.html")
    assert (tmp_path / "cmp.html").is_file()
    (tmp_path / "empty").mkdir()
    assert_one_line_error(*railhil(capsys, "report", seed2_run, "--against", tmp_path / "nope")[::2],
                          "nope", "no such run folder")
    assert_one_line_error(*railhil(capsys, "report", seed2_run, "--against", tmp_path / "empty")[::2],
                          "empty", "not a run folder", "run.json")
    assert_one_line_error(*railhil(capsys, "report", tmp_path / "empty", "--against", ref)[::2],
                          "empty", "run.json")
    assert_one_line_error(*railhil(capsys, "report", seed2_run, ref, "--against", ref)[::2],
                          "--against", "one run folder")
    assert_one_line_error(*railhil(capsys, "report", seed2_run, "-o", tmp_path / "x.html")[::2],
                          "-o", "--against")
    assert_one_line_error(*railhil(capsys, "report", seed2_run, "--against", ref, "-o",
                                   tmp_path / "no" / "x.html")[::2], "no such directory")


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
#: headless, and nothing of its own on the network (no updates, no sync): the page must need nothing either
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="no headless browser (apt-get install chromium) "
                                                             "to render the report with")


def chromium(*args, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, "--virtual-time-budget=20000", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout)


@needs_chromium
def test_report_renders_with_its_plots_in_a_headless_browser(default_lockstep, tmp_path):
    """plotly.js runs offline from the page (it draws the 18 curves, with its zoom button), and the static
    plot is on the screen: its lines in matplotlib's tab10 colours, car 1's (tab:blue) and car 2's
    (tab:orange)."""
    from matplotlib.image import imread

    page = default_lockstep.out_dir / "report.html"
    dom = chromium("--dump-dom", page.as_uri())
    assert "js-plotly-plot" in dom.stdout, dom.stderr[-2000:]
    assert dom.stdout.count('class="trace scatter') == 18
    assert 'data-title="Zoom"' in dom.stdout and 'data-title="Share chart' not in dom.stdout
    shot = tmp_path / "report.png"
    proc = chromium("--hide-scrollbars", "--window-size=1200,4600", f"--screenshot={shot}", page.as_uri())
    assert shot.exists(), proc.stderr[-2000:]
    img = imread(shot)[..., :3]                   # floats in [0, 1]
    for rgb in ((0x1F, 0x77, 0xB4), (0xFF, 0x7F, 0x0E)):
        close = np.all(np.abs(img - np.asarray(rgb) / 255.0) < 0.08, axis=-1)
        assert close.sum() > 500, (rgb, int(close.sum()))


@needs_chromium
def test_comparison_renders_in_a_headless_browser(default_lockstep, seed2_run, tmp_path):
    from hil.report.html import write_comparison

    page = write_comparison(seed2_run, default_lockstep.out_dir, tmp_path / "cmp.html")
    dom = chromium("--dump-dom", page.as_uri())
    assert "js-plotly-plot" in dom.stdout, dom.stderr[-2000:]
    assert dom.stdout.count('class="trace scatter') == 2 * 3      # car 1 of both runs; the rest hidden


#: appended to a copy of a page: once it is drawn, what a reader sees of it on a screen of that width, as
#: JSON in a <pre id=railhil-layout>: the page's width and height, the elements wider than the page, and
#: where the verdict, the key figures and the KPIs are
LAYOUT_SCRIPT = """<script>window.addEventListener('load', function () { setTimeout(function () {
  var W = document.documentElement.clientWidth, wide = [];
  document.querySelectorAll('body *').forEach(function (e) {
    var r = e.getBoundingClientRect();
    if (r.width > 0 && r.right > W + 1) wide.push(e.tagName + '.' + e.className + ' ' + Math.round(r.right));
  });
  function box(sel) { var e = document.querySelector(sel); if (!e) return null;
    var r = e.getBoundingClientRect(); return [Math.round(r.top + scrollY), Math.round(r.bottom + scrollY)]; }
  var out = document.createElement('pre'); out.id = 'railhil-layout';
  out.textContent = JSON.stringify({width: W, height: document.documentElement.scrollHeight, wide: wide,
    banner: box('.banner'), figures: box('.figures'), kpis: box('#kpis'), kpi_table: box('table.kpis'),
    signals: box('#signals')});
  document.body.appendChild(out); }, 500); });</script>"""
SCREEN = (1280, 800)        # the first screen: what opens without scrolling on a laptop
MAX_PAGE_PX = 5000


def layout(page: Path, tmp_path: Path, width: int = SCREEN[0]) -> dict:
    """The page drawn by headless Chromium in a window `width` px wide (LAYOUT_SCRIPT)."""
    copy = tmp_path / f"layout-{page.name}"
    copy.write_text(page.read_text(encoding="utf-8").replace("</body>", LAYOUT_SCRIPT + "</body>"),
                    encoding="utf-8")
    dom = chromium("--hide-scrollbars", f"--window-size={width},{SCREEN[1]}", "--dump-dom", copy.as_uri(),
                   timeout=240)
    found = re.search(r'<pre id="railhil-layout">(.*?)</pre>', dom.stdout, re.S)
    assert found, dom.stderr[-2000:]
    return json.loads(html.unescape(found.group(1)))


def assert_reads_at_a_glance(got: dict) -> None:
    """No element wider than the page, the verdict and the KPIs on the first screen, the page not too tall."""
    assert got["width"] == SCREEN[0] and not got["wide"], got["wide"][:10]
    assert got["banner"][1] < SCREEN[1] and got["figures"][1] < SCREEN[1], got   # the verdict, key figures
    assert got["kpis"][0] < SCREEN[1] and got["kpi_table"][0] < SCREEN[1], got   # the KPIs begin
    assert got["signals"][0] < got["height"] and got["height"] < MAX_PAGE_PX, got


@needs_chromium
def test_the_run_report_reads_at_a_glance_on_a_1280_px_screen(default_lockstep, tmp_path):
    assert_reads_at_a_glance(layout(default_lockstep.out_dir / "report.html", tmp_path))


@needs_chromium
@pytest.mark.realtime
def test_the_report_of_make_run_reads_at_a_glance_on_a_1280_px_screen(realtime_run, tmp_path):
    """The page of a real-time run: its nodes in one compact table, lateness.png, the details folded; its E2E
    start-up discards labelled apart from the errors the verdict counts (none)."""
    out, _, _ = realtime_run
    got = layout(out / "report.html", tmp_path)
    assert_reads_at_a_glance(got)
    page = page_of(out / "report.html")
    assert "E2E start-up discards" in page.cells and "E2E discarded" not in page.raw
    header = next(c for _, c in page.rows if c and c[0] == "node" and "E2E / SecOC errors" in c)
    errors = header.index("E2E / SecOC errors")
    rows = [c for _, c in page.rows if len(c) == len(header) and c[0].split()[0] in ("BCU", "PLANT", "DESK")]
    if verdict_of(page, "E2E / SecOC errors reported") == "pass":             # none reported: every row 0
        assert rows and all(c[errors] == "0" for c in rows), rows
    kpis = json.loads((out / "kpis.json").read_text())
    assert kpis["bus"]["source"] == "trace" and 0.35 < kpis["bus"]["load"] < 0.45, kpis["bus"]
