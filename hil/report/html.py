"""One self-contained HTML page per run folder (report.html) and per campaign folder.

A run's page is built from the files of its folder only — run.json, kpis.json and the PNG plots — so
`railhil report RUN_DIR` rebuilds it at any time and `hil.runtime.run.finish_run` writes it after every run
(cheap: the plots are already drawn; they are embedded as base64 PNG, so the page needs nothing else,
no network, no neighbouring file). It shows:

* the scenario (name, description, seed, the full resolved scenario);
* the verdicts: each check of `run_verdicts` with its value, its criterion and pass / fail;
* every KPI of kpis.json (definitions in hil.report.kpis.compute_kpis);
* timing: per message on the bit-timed lockstep bus, frames, worst and mean response time [µs] and
  deadline misses (response longer than the message's cycle time); per node of a real-time run, cycles,
  late cycles (started after their deadline) and missed cycles;
* faults injected and what the receivers' E2E / SecOC checks and the plausibility checks reported;
* what reproduces the run: railhil and library versions, seed, DBC path and SHA-256, git commit.

A campaign's page (`write_campaign_report`) holds the point counts, the results table (results.csv)
and the summary plots (plot_<key>.png) of the campaign folder.

`run_metadata` gives the reproduction data that finish_run also writes into run.json; the git commit is
read from the repository's .git directory (HEAD, loose refs, packed-refs), so no git program is run.
"""

from __future__ import annotations

import base64
import csv
import hashlib
import html
import json
import platform
import sys
from dataclasses import dataclass
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from hil.errors import RailhilError
from hil.scenario import registry

REPORT_NAME = "report.html"
#: distributions whose versions go into run.json (and the report): what a reproduction needs to match
VERSIONED = ("railhil", "python-can", "cantools", "numpy", "pydantic", "matplotlib")
MAX_FAULT_EVENTS = 200       # fault events listed in a report (run.json keeps them all)
MAX_TABLE_ROWS = 2000        # campaign rows shown in the page (results.csv keeps them all)


class ReportError(RailhilError):
    """A folder that is not a run folder or a campaign folder, or whose files do not read (exit 2)."""


# ------------------------------------------------------------------------------------ reproduction data
def _repo_root(start: Path) -> Path | None:
    for folder in (start, *start.parents):
        if (folder / ".git").exists():
            return folder
    return None


def git_commit(start: Path | None = None) -> str | None:
    """The commit checked out in the git repository holding `start` (default: railhil's own source), as
    40 hex digits; None outside a repository or when .git cannot be read. Reads .git's files only."""
    root = _repo_root((start or Path(__file__)).resolve().parent)
    if root is None:
        return None
    git = root / ".git"
    try:
        if git.is_file():                              # a worktree or submodule: "gitdir: <path>"
            git = (root / git.read_text().split(":", 1)[1].strip()).resolve()
        head = (git / "HEAD").read_text().strip()
        if not head.startswith("ref:"):
            return head or None                        # detached HEAD: the commit itself
        ref = head.split(":", 1)[1].strip()
        common = git / "commondir"
        base = (git / common.read_text().strip()).resolve() if common.exists() else git
        for folder in (git, base):
            loose = folder / ref
            if loose.is_file():
                return loose.read_text().strip() or None
        packed = base / "packed-refs"
        if packed.is_file():
            for line in packed.read_text().splitlines():
                parts = line.split()
                if len(parts) == 2 and parts[1] == ref:
                    return parts[0]
    except (OSError, IndexError, UnicodeDecodeError):
        return None
    return None


@cache
def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist in VERSIONED:
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = "not installed"
    return out


def sha256_of(path: Path) -> str | None:
    """SHA-256 (hex) of a file's bytes; None when it cannot be read."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def run_metadata(dbc_path: Path, seed: int) -> dict:
    """What reproduces a run, for run.json: versions, seed, the DBC and its SHA-256, the git commit of
    railhil's source, the command line that started the process."""
    return {"versions": dict(_versions()), "seed": seed, "dbc_sha256": sha256_of(dbc_path),
            "git_commit": git_commit(), "command": " ".join(sys.argv), "platform": platform.platform()}


# --------------------------------------------------------------------------------------------- verdicts
@dataclass(frozen=True)
class Verdict:
    check: str
    value: str
    criterion: str
    passed: bool | None            # None: informational, no criterion applies to this run


def _sum_stat(meta: dict, key: str) -> int:
    return sum(int(s.get(key) or 0) for s in (meta.get("node_stats") or {}).values())


def run_verdicts(kpis: dict, meta: dict) -> list[Verdict]:
    """The checks every run is judged by, from its kpis.json and run.json:

    * the run ended by itself (standstill or max_duration), not interrupted or failed;
    * the train stopped (every car below the plant's standstill speed) before the run ended;
    * no frame lost: every frame sent is in the trace, still queued at the end, or overwritten;
    * no bus deadline miss (bit-timed lockstep bus: response time above the message's cycle time);
    * no node step error (an exception inside a controller's step, answered with safe values);
    * real time held (hil.runtime.outcome.realtime_verdict: no node's cycle more than 50 ms late, none
      skipped);
    * E2E / SecOC: without injected faults, nothing reported by the receivers; with faults, the
      detections are listed (informational); NONEWDATA (a frame 1.5 of its cycles late) is a verdict of
      its own: none in lockstep, informational in real time;
    * each study's own checks (hil/studies/<name>/kpis.py `verdicts`), e.g. the governor's slip bound."""
    out = [Verdict("run ended by itself", str(kpis.get("end_reason")), "standstill or max_duration",
                   kpis.get("end_reason") in ("standstill", "max_duration")),
           Verdict("train stopped", str(kpis.get("stopped")), "standstill before the run ended",
                   bool(kpis.get("stopped")))]
    if "frames_lost" in kpis:
        out.append(Verdict("frames lost", str(kpis["frames_lost"]), "= 0", kpis["frames_lost"] == 0))
    bus = kpis.get("bus")
    if bus:
        out.append(Verdict("bus deadline misses", str(bus.get("deadline_misses")), "= 0",
                           bus.get("deadline_misses") == 0))
    steps = _sum_stat(meta, "step_errors")
    out.append(Verdict("controller step errors", str(steps), "= 0", steps == 0))
    if meta.get("mode") == "realtime":
        missed, late = _sum_stat(meta, "missed_cycles"), _sum_stat(meta, "late_cycles")
        rt = kpis.get("realtime")
        if rt:                              # hil.runtime.outcome.realtime_verdict
            worst = rt["worst_node"]
            out.append(Verdict("real time held", f"{worst} up to {rt['max_lag_ms'][worst]:g} ms late, "
                               f"{missed} cycles skipped",
                               f"no cycle more than {rt['limit_ms']:g} ms late, none skipped", rt["held"]))
        else:
            out.append(Verdict("real-time cycles missed", str(missed), "= 0", missed == 0))
        out.append(Verdict("real-time cycles late", str(late), "(informational)", None))
    events = kpis.get("protection_events") or {}
    # NONEWDATA is timing, not protection: a receiver's cycle found no frame 1.5 cycles after the last one
    # (hil.runtime.node): on a real-time bus every late frame counts, so there it is informational
    late_frames = events.get("NONEWDATA", 0)
    seen = {k: v for k, v in events.items() if k != "NONEWDATA"}
    detected = ", ".join(f"{k} {v}" for k, v in seen.items()) or "none"
    if kpis.get("faults_injected") is None:
        out.append(Verdict("E2E / SecOC errors reported", detected, "none (no fault injected)", not seen))
        realtime = meta.get("mode") == "realtime"
        out.append(Verdict("frames 1.5 cycles late (E2E NONEWDATA)", str(late_frames),
                           "(real time: informational)" if realtime else "= 0 (no fault injected)",
                           None if realtime else late_frames == 0))
    else:
        if late_frames:
            detected = ", ".join(f"{k} {v}" for k, v in events.items())
        out.append(Verdict("E2E / SecOC errors reported", detected, "(faults injected: informational)", None))
    for study in registry.studies():              # each study's own checks of its KPIs
        hook = getattr(study.part("kpis"), "verdicts", None) if study.name in kpis else None
        if hook is not None:
            out += [Verdict(*v) for v in hook(kpis[study.name])]
    return out


# ----------------------------------------------------------------------------------------- HTML pieces
CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;margin:1.5em auto;max-width:1150px;
color:#1d1d1f;padding:0 1em}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.88em;margin:.4em 0}
th,td{border:1px solid #ddd;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#f4f4f6}td.num{text-align:right;font-variant-numeric:tabular-nums}
.pass{background:#dff5e1;color:#165c1e;font-weight:600}.fail{background:#fde2e1;color:#8a1c14;font-weight:600}
.info{color:#666}.banner{padding:.5em .8em;border-radius:4px;margin:.6em 0;font-weight:600}
img{max-width:100%;border:1px solid #eee}pre{background:#f7f7f9;padding:.6em;overflow:auto;font-size:.8em}
.scroll{max-height:32em;overflow:auto}
"""


def _e(x: object) -> str:
    return html.escape(str(x), quote=True)


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        return " ".join(_fmt(x) for x in v)
    if isinstance(v, dict):
        return ", ".join(f"{k} {_fmt(x)}" for k, x in v.items()) or "—"
    return "—" if v is None else str(v)


def _table(header: list[str], rows: list[list[object]], numeric: set[int] | frozenset = frozenset()) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td{' class=num' if i in numeric else ''}>{_e(_fmt(c))}</td>"
                                    for i, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _verdict_cell(passed: bool | None) -> str:
    if passed is None:
        return "<td class=info>info</td>"
    return "<td class=pass>pass</td>" if passed else "<td class=fail>FAIL</td>"


def _images(paths: list[Path]) -> str:
    parts = []
    for p in paths:
        data = base64.b64encode(p.read_bytes()).decode("ascii")
        parts.append(f"<figure><img alt=\"{_e(p.name)}\" src=\"data:image/png;base64,{data}\">"
                     f"<figcaption class=info>{_e(p.name)}</figcaption></figure>")
    return "".join(parts) or "<p class=info>no plot in this folder</p>"


def _page(title: str, body: str) -> str:
    return (f"<!DOCTYPE html>\n<html lang=en><head><meta charset=utf-8>"
            f"<meta name=viewport content=\"width=device-width, initial-scale=1\">"
            f"<title>{_e(title)}</title><style>{CSS}</style></head><body>\n{body}\n</body></html>\n")


def _read_json(path: Path, what: str) -> dict:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise ReportError(f"{path.parent}: not a run folder: no {path.name} ({what})") from None
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise ReportError(f"{path}: cannot read {what}: {' '.join(str(exc).split())[:160]}") from None


# --------------------------------------------------------------------------------------------- run page
def _us(value) -> str:
    """A time in µs for a table cell: whole µs, or a dash when there is none (a message never sent)."""
    return "—" if value is None else f"{float(value):.0f}"


def _timing_section(meta: dict) -> str:
    parts = []
    bus = meta.get("bus_timing")
    if bus:
        load = bus.get("load")
        parts.append(f"<p>bit-timed bus at {_e(bus.get('bitrate_bps'))} bit/s, stuffing "
                     f"{_e(bus.get('stuffing'))}, load {'—' if load is None else f'{100 * load:.1f} %'}; "
                     f"response = end of frame − start of its release window; deadline = the message's "
                     f"cycle time</p>")
        rows = sorted((bus.get("messages") or {}).items(), key=lambda kv: kv[1].get("frame_id", 0))
        body = "".join(
            f"<tr><td>{_e(name)}</td><td class=num>0x{int(m.get('frame_id', 0)):03X}</td>"
            f"<td class=num>{_e(m.get('frames'))}</td>"
            f"<td class=num>{_us(m.get('response_max_us'))}</td>"
            f"<td class=num>{_us(m.get('response_mean_us'))}</td>"
            f"<td class=num>{_us(m.get('queued_max_us'))}</td>"
            f"<td class=num>{_e(m.get('overwritten'))}</td><td class=num>{_e(m.get('deadline_misses'))}</td>"
            f"{_verdict_cell(m.get('deadline_misses') == 0)}</tr>" for name, m in rows)
        parts.append("<div class=scroll><table><thead><tr><th>message</th><th>id</th><th>frames</th>"
                     "<th>worst response [µs]</th><th>mean response [µs]</th><th>worst queued [µs]</th>"
                     "<th>overwritten</th><th>deadline misses</th><th>verdict</th></tr></thead><tbody>"
                     f"{body}</tbody></table></div>")
    stats = meta.get("node_stats") or {}
    if stats:
        realtime = meta.get("mode") == "realtime"
        header = ["node", "cycles", "frames sent", "frames received", "step errors", "E2E discarded",
                  "SecOC rejected"] + (["late cycles", "missed cycles"] if realtime else [])
        rows = [[n, s.get("cycles"), s.get("frames_sent"), s.get("frames_received"), s.get("step_errors"),
                 s.get("e2e_discarded"), s.get("secoc_rejected")]
                + ([s.get("late_cycles"), s.get("missed_cycles")] if realtime else [])
                for n, s in stats.items()]
        parts.append(_table(header, rows, set(range(1, len(header)))))
    return "".join(parts) or "<p class=info>no timing data in run.json</p>"


def _faults_section(kpis: dict, meta: dict) -> str:
    rows = [["faults injected", kpis.get("faults_injected", "none")],
            ["E2E / SecOC reported by receivers", kpis.get("protection_events") or "nothing"],
            ["frames added (+) / removed (−) by faults", kpis.get("frames_faulted", 0)]]
    for flag, cars in sorted((kpis.get("plausibility_flags") or {}).items()):
        rows.append([f"first flagged: {flag} [s]", cars])
    out = _table(["", ""], rows)
    events = (meta.get("faults") or {}).get("events") or []
    if events:
        shown = events[:MAX_FAULT_EVENTS]
        more = (f" (first {MAX_FAULT_EVENTS} of {len(events)}; all in run.json)"
                if len(events) > len(shown) else "")
        out += (f"<details><summary>fault events{_e(more)}</summary><pre>"
                + _e("\n".join(json.dumps(e, default=str) for e in shown)) + "</pre></details>")
    return out


def _kpi_rows(kpis: dict, prefix: str = "") -> list[list[object]]:
    rows = []
    for k, v in sorted(kpis.items()):
        if isinstance(v, dict) and v and all(not isinstance(x, dict) for x in v.values()) and len(v) > 12:
            rows.append([prefix + k, v])
        elif isinstance(v, dict) and v:
            rows += _kpi_rows(v, f"{prefix}{k}.")
        else:
            rows.append([prefix + k, v])
    return rows


def render_run_report(run_dir: Path) -> str:
    """The HTML page of a run folder (module docstring), from its run.json, kpis.json and PNG plots."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ReportError(f"{run_dir}: no such run folder")
    meta = _read_json(run_dir / "run.json", "the run's metadata")
    kpis = _read_json(run_dir / "kpis.json", "the run's KPIs")
    scenario = meta.get("scenario") or {}
    verdicts = run_verdicts(kpis, meta)
    failed = [v for v in verdicts if v.passed is False]
    name = scenario.get("name", run_dir.name)
    title = f"railhil run {name} ({meta.get('mode', '?')}, seed {scenario.get('seed')})"
    banner = ("<div class='banner fail'>FAIL: " + _e(", ".join(v.check for v in failed)) + "</div>"
              if failed else "<div class='banner pass'>PASS: every check holds</div>")
    vrows = "".join(f"<tr><td>{_e(v.check)}</td><td>{_e(v.value)}</td><td>{_e(v.criterion)}</td>"
                    f"{_verdict_cell(v.passed)}</tr>" for v in verdicts)
    versions = meta.get("versions") or {"python": meta.get("python"), "python-can": meta.get("python_can")}
    repro = [["seed", scenario.get("seed")], ["mode", meta.get("mode")], ["DBC", meta.get("dbc")],
             ["DBC SHA-256", meta.get("dbc_sha256")], ["git commit", meta.get("git_commit")],
             ["command", meta.get("command")], ["platform", meta.get("platform")],
             ["wall time [s]", meta.get("wall_s")], ["simulated [s]", kpis.get("simulated_s")]]
    repro += [[f"version: {k}", v] for k, v in versions.items()]
    plots = sorted(run_dir.glob("*.png"))
    body = (f"<h1>{_e(title)}</h1><p>{_e(scenario.get('description', ''))}</p>{banner}"
            f"<p class=info>folder {_e(run_dir.resolve())}; ended by {_e(kpis.get('end_reason'))} after "
            f"{_e(_fmt(kpis.get('simulated_s')))} s simulated</p>"
            f"<h2>Verdicts</h2><table><thead><tr><th>check</th><th>value</th><th>criterion</th>"
            f"<th>verdict</th></tr></thead><tbody>{vrows}</tbody></table>"
            f"<h2>Plots</h2>{_images(plots)}"
            f"<h2>KPIs</h2>{_table(['KPI', 'value'], _kpi_rows(kpis))}"
            f"<h2>Timing</h2>{_timing_section(meta)}"
            f"<h2>Faults</h2>{_faults_section(kpis, meta)}"
            f"<h2>Reproduce</h2>{_table(['', ''], repro)}"
            f"<h2>Scenario</h2><details><summary>the resolved scenario (JSON)</summary><pre>"
            f"{_e(json.dumps(scenario, indent=2))}</pre></details>")
    return _page(title, body)


def write_run_report(run_dir: Path) -> Path:
    """Write <run_dir>/report.html; returns its path."""
    page = render_run_report(run_dir)
    out = Path(run_dir) / REPORT_NAME
    out.write_text(page, encoding="utf-8")
    return out


# ---------------------------------------------------------------------------------------- campaign page
def _read_results_csv(path: Path) -> tuple[list[str], list[dict]]:
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            return list(reader.fieldnames or []), list(reader)
    except FileNotFoundError:
        raise ReportError(f"{path.parent}: not a campaign folder: no results.csv") from None
    except (OSError, csv.Error, UnicodeDecodeError) as exc:
        raise ReportError(f"{path}: cannot read the campaign results: {exc}") from None


def render_campaign_report(out_dir: Path, table: tuple[list[str], list[dict]] | None = None,
                           name: str | None = None, description: str = "") -> str:
    """The HTML page of a campaign folder: counts, the results table (`table` = (columns, rows), else
    read from results.csv) with each point's status and a link to its run report, the summary plots."""
    out_dir = Path(out_dir)
    columns, rows = table if table is not None else _read_results_csv(out_dir / "results.csv")
    name = name or out_dir.name
    status = [str(r.get("status", "")) for r in rows]
    n_ok = status.count("ok")
    n_failed = len(rows) - n_ok
    cached = sum(str(r.get("cached")) in ("True", "true", "1") for r in rows)
    banner = (f"<div class='banner {'fail' if n_failed else 'pass'}'>{len(rows)} points: {n_ok} ok, "
              f"{n_failed} failed, {cached} from cache</div>")
    shown = rows[:MAX_TABLE_ROWS]
    head = "".join(f"<th>{_e(c)}</th>" for c in columns)
    body = []
    for r in shown:
        cells = []
        for c in columns:
            v = r.get(c, "")
            if c == "status":
                cells.append(_verdict_cell(None if v == "" else v == "ok").replace(">pass<", ">ok<")
                             .replace(">FAIL<", f">{_e(v)}<"))
            elif c == "run_dir" and v:
                link = f"{v}/{REPORT_NAME}"
                cells.append(f"<td><a href=\"{_e(link)}\">{_e(v)}</a></td>")
            else:
                cells.append(f"<td>{_e(_fmt(v))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    more = (f"<p class=info>first {MAX_TABLE_ROWS} of {len(rows)} rows; all in results.csv</p>"
            if len(rows) > len(shown) else "")
    title = f"railhil campaign {name}"
    page = (f"<h1>{_e(title)}</h1><p>{_e(description)}</p>{banner}"
            f"<p class=info>folder {_e(out_dir.resolve())}</p>"
            f"<h2>Plots</h2>{_images(sorted(out_dir.glob('plot_*.png')))}"
            f"<h2>Results</h2>{more}<div class=scroll><table><thead><tr>{head}</tr></thead><tbody>"
            f"{''.join(body)}</tbody></table></div>")
    return _page(title, page)


def write_campaign_report(out_dir: Path, table: tuple[list[str], list[dict]] | None = None,
                          name: str | None = None, description: str = "") -> Path:
    """Write <out_dir>/report.html (`render_campaign_report`); returns its path."""
    page = render_campaign_report(out_dir, table, name, description)
    out = Path(out_dir) / REPORT_NAME
    out.write_text(page, encoding="utf-8")
    return out


def write_report(folder: Path) -> Path:
    """report.html of a run folder (it has run.json) or a campaign folder (it has results.csv)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ReportError(f"{folder}: no such folder (expected a run folder or a campaign folder)")
    if (folder / "run.json").exists():
        return write_run_report(folder)
    if (folder / "results.csv").exists():
        return write_campaign_report(folder)
    raise ReportError(f"{folder}: neither a run folder (no run.json) nor a campaign folder (no results.csv)")
