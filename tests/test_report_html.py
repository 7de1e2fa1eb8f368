"""The HTML reports (hil.report.html): every run folder gets report.html with verdicts, KPIs, the plot
embedded, timing, faults and what reproduces the run (run.json); `railhil report` rebuilds it; a
campaign folder gets its table and plots; the page renders with its plots in a headless browser."""

from __future__ import annotations

import base64
import hashlib
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
    """The tags, embedded images and cell texts of a page (the parser raises nothing: we count)."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.images: list[bytes] = []
        self.links: list[str] = []
        self.cells: list[str] = []
        self.open: list[str] = []
        self._cell: list[str] | None = None
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img" and a.get("src", "").startswith("data:image/png;base64,"):
            self.images.append(base64.b64decode(a["src"].split(",", 1)[1]))
        if tag == "a":
            self.links.append(a.get("href", ""))
        if tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.cells.append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def verdict_of(page: Page, check: str) -> str:
    i = page.cells.index(check)
    return page.cells[i + 3]                         # check, value, criterion, verdict


def test_every_run_folder_has_a_self_contained_report(default_lockstep):
    out = default_lockstep.out_dir
    report = out / "report.html"
    assert report in default_lockstep.files
    text = report.read_text()
    page = Page(text)
    assert page.images == [(out / "plot.png").read_bytes()]       # the plot itself, embedded
    refs = re.findall(r"""\b(?:src|href)\s*=\s*["']?([^"' >]*)""", text)
    assert refs and all(r.startswith("data:") for r in refs)      # nothing loaded from elsewhere
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
    from hil.report.html import git_commit

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
    real time (every `make run` has some), a failure in lockstep without faults; a run that did not hold
    real time fails its own check."""
    from hil.report.html import run_verdicts
    from hil.runtime.outcome import realtime_verdict

    def verdicts(mode, lag_us, missed=0):
        stats = {"PLANT": {"max_lag_us": lag_us, "missed_cycles": 0},
                 "BECU1": {"max_lag_us": 1_000, "missed_cycles": missed}}
        kpis = {"end_reason": "standstill", "stopped": True, "frames_lost": 0,
                "protection_events": {"NONEWDATA": 88}}
        if mode == "realtime":
            kpis["realtime"] = realtime_verdict(stats)
        return {v.check: v for v in run_verdicts(kpis, {"mode": mode, "node_stats": stats})}

    rt = verdicts("realtime", 42_900)
    assert rt["E2E / SecOC errors reported"].passed is True
    assert rt["frames 1.5 cycles late (E2E NONEWDATA)"].passed is None
    assert rt["frames 1.5 cycles late (E2E NONEWDATA)"].value == "88"
    assert rt["real time held"].passed is True and "PLANT up to 42.9 ms" in rt["real time held"].value
    assert verdicts("realtime", 120_000)["real time held"].passed is False
    assert verdicts("realtime", 1_000, missed=3)["real time held"].passed is False
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
    result = run_campaign(load_campaign(spec), tmp_path / "out")
    files = write_table(result) + write_plots(result)
    report = tmp_path / "out" / "report.html"
    assert report in files
    page = Page(report.read_text())
    plots = sorted((tmp_path / "out").glob("plot_*.png"))
    assert plots and page.images == [p.read_bytes() for p in plots]
    assert page.links == [f"{r.run_dir.relative_to(tmp_path / 'out')}/report.html" for r in result.results]
    for link in page.links:                                   # each point's own run report exists
        assert (tmp_path / "out" / link).is_file()
    assert page.cells.count("ok") == len(result.results) == 2
    rebuilt = tmp_path / "out" / "again.html"
    report.rename(rebuilt)
    from hil.report.html import write_report

    assert write_report(tmp_path / "out") == report           # from results.csv alone
    assert Page(report.read_text()).cells.count("ok") == 2


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


@pytest.mark.skipif(CHROMIUM is None, reason="no headless browser (apt-get install chromium) to render the "
                                             "report with")
def test_report_renders_with_its_plot_in_a_headless_browser(default_lockstep, tmp_path):
    from matplotlib.image import imread

    shot = tmp_path / "report.png"
    proc = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                           "--window-size=1200,2000", f"--screenshot={shot}",
                           (default_lockstep.out_dir / "report.html").as_uri()],
                          capture_output=True, text=True, timeout=120)
    assert shot.exists(), proc.stderr[-2000:]
    img = imread(shot)[..., :3]                   # floats in [0, 1]
    # the plot's lines are drawn in matplotlib's tab10 colours: count the screen pixels of car 1's
    # (tab:blue) and car 2's (tab:orange); a page without the plot has none of them
    for rgb in ((0x1F, 0x77, 0xB4), (0xFF, 0x7F, 0x0E)):
        close = np.all(np.abs(img - np.asarray(rgb) / 255.0) < 0.08, axis=-1)
        assert close.sum() > 500, (rgb, int(close.sum()))
