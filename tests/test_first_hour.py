"""The first hour with railhil (issue 47): the README's tour works as written, and what the docs print is
what the code prints.

* The tour: the commands of README.md's five-minute tour, parsed from its first `sh` block, run one by one
  in a fresh bash (railhil not on the PATH until the tour's `. .venv/bin/activate`) in a folder laid out as
  a checkout after `make run` (`.venv`, `dbc`, `scenarios` linked to this checkout's, `runs/` holding the
  run folder `make run` leaves): on a real-time run of the default scenario (the session's realtime_run,
  marked realtime) and on a lockstep one.  Every command exits 0 with output; the only change to the text
  is /tmp/tour, which becomes a folder of the test's own (parallel tests, other users).
* One time base: a real-time run's trace read from the run's start (`--start 1.0 --end 1.03` finds the
  frames), from its first frame out of its folder, as recorded with --absolute; a window outside the
  trace is one warning line.  The real-time trace is made from the lockstep one (its timestamps moved to
  the epoch, run.json's trace_t0_s set), so these checks need no real-time run.
* `railhil timing` on a run's trace judges the messages the run sends: 0 MISSING without --ignore.
* Comparisons count the KPIs both runs have; the description comes from each run's own scenario.
* `railhil --version`; a mistyped scenario name gets the closest ones.
* The docs' figures are the code's: the lockstep run's printed summary in README.md and docs/, reports.md's
  kpis.json and docs/img/plot.png equal a fresh lockstep run's (`make docs-figures`, docs/hooks/figures.py,
  makes them again).
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import ROOT, assert_one_line_error, railhil, realtime_held

README = ROOT / "README.md"
DBC = ROOT / "dbc" / "train_brake.dbc"
T0 = 1_796_556_887.138472          # a real-time run's start, as run.json's trace_t0_s holds it
PLUMBING = re.compile(r"^(\.|source)\s|^[A-Za-z_][A-Za-z0-9_]*=")   # activate, VAR=...: print nothing


def figures_module():
    """docs/hooks/figures.py, the script of `make docs-figures`."""
    spec = importlib.util.spec_from_file_location("docs_figures", ROOT / "docs" / "hooks" / "figures.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# --- the README's tour, as written ------------------------------------------------------------------------


def tour_commands() -> list[str]:
    """The commands of the README's five-minute tour: the lines of the first ```sh block of that section."""
    text = README.read_text()
    section = text[text.index("## A five-minute tour"):]
    section = section[:section.index("\n## ", 1)]
    block = re.search(r"```sh\n(.*?)```", section, re.S)
    assert block, "the README's tour has no sh block"
    lines = [line.strip() for line in block.group(1).splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def make_run_command() -> list[str]:
    """`make run`'s railhil command line, from the Makefile (its recipe)."""
    recipe = re.search(r"^run: .*\n\t(.*)$", (ROOT / "Makefile").read_text(), re.M)
    assert recipe, "no run target in the Makefile"
    words = recipe.group(1).split()
    assert words[0] == "$(VENV)/bin/railhil", words
    return words[1:]


def checkout_after_make_run(tmp_path: Path) -> Path:
    """A folder laid out as a checkout: .venv, dbc, scenarios (links to this one's), an empty runs/."""
    ws = tmp_path / "checkout"
    ws.mkdir()
    for name in (".venv", "dbc", "scenarios"):
        (ws / name).symlink_to(ROOT / name)
    (ws / "runs").mkdir()
    return ws


def fresh_shell_env() -> dict[str, str]:
    """The environment of a new terminal: no virtualenv active, .venv/bin not on the PATH."""
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
    venv_bin = str(ROOT / ".venv" / "bin")
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if p and Path(p).resolve() != Path(venv_bin).resolve()
                                  and p != str(Path(sys.executable).parent))
    return env


def run_tour(ws: Path, tour: Path) -> list[tuple[str, int, str]]:
    """Each command of the tour, pasted line by line into one bash in `ws`: (line, exit code, output)."""
    commands = [line.replace("/tmp/tour", str(tour)) for line in tour_commands()]
    script = ["set +e"]
    for k, line in enumerate(commands):
        script.append(f"{line} > .out{k} 2>&1; echo $? > .rc{k}" if not PLUMBING.match(line)
                      else f"{line}; echo $? > .rc{k}; : > .out{k}")
    proc = subprocess.run(["bash", "-c", "\n".join(script)], cwd=ws, env=fresh_shell_env(),
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    return [(line, int((ws / f".rc{k}").read_text()), (ws / f".out{k}").read_text())
            for k, line in enumerate(commands)]


def check_tour(results: list[tuple[str, int, str]], realtime: bool, held: bool = True) -> dict[str, str]:
    """Every command exited 0 with output (plumbing lines: exit 0); the output by command word."""
    outputs = {}
    for line, code, out in results:
        where = f"{line!r} exited {code}:\n{out[-3000:]}"
        if not held and line.startswith("railhil timing $RUN"):    # a stalled machine may fail a cycle time
            assert code in (0, 1), where
        else:
            assert code == 0, where
        if not PLUMBING.match(line):
            assert out.strip(), f"{line!r} printed nothing"
        outputs[line] = out
    decode = next(o for line, o in outputs.items() if "trace decode" in line)
    rows = [r.split() for r in decode.splitlines() if "BCU_DEMAND" in r and not r.startswith("3 frames")]
    assert len(rows) == 3 and all(1.0 <= float(r[0]) <= 1.03 for r in rows), decode
    assert "3 frames decoded" in decode
    timing = next(o for line, o in outputs.items() if line.startswith("railhil timing $RUN"))
    assert re.search(r"35 cyclic messages: \d+ PASS, \d+ FAIL, 0 MISSING", timing), timing
    assert re.search(r"left out \d+ cyclic messages of the DBC that its nodes do not send \(\d+ of cars 7–8",
                     timing), timing
    report = next(o for line, o in outputs.items() if line.startswith("railhil report"))
    assert "Train (from the plant's truth):" in report and report.strip().endswith(".html"), report
    return outputs


def test_the_tour_is_the_readmes_and_its_commands_are_reached_from_a_fresh_shell():
    commands = tour_commands()
    assert commands[0] == ". .venv/bin/activate"                  # how `railhil` is reached, first
    assert commands[1].startswith("RUN=") and "runs/default-" in commands[1]
    assert all(c.startswith("railhil ") for c in commands[2:])
    assert make_run_command()[:2] == ["run", "scenarios/default.toml"]


def test_the_readme_tour_on_a_lockstep_run_folder(tmp_path):
    ws = checkout_after_make_run(tmp_path)
    folder = f"runs/default-lockstep-{time.strftime('%Y%m%d-%H%M%S')}"
    proc = subprocess.run([sys.executable, "-m", "hil", "run", "scenarios/default.toml", "--lockstep",
                           "--out", folder, "-q"], cwd=ws, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    outputs = check_tour(run_tour(ws, tmp_path / "tour"), realtime=False)
    report = next(o for line, o in outputs.items() if line.startswith("railhil report"))
    assert "Train (from the plant's truth): the same (10 KPIs)" in report and "differ" not in report, report
    rta = next(o for line, o in outputs.items() if "--rta" in line)
    assert "35 of 35 schedulable; measured response within the bound for 35 of 35" in rta


@pytest.mark.realtime
def test_the_readme_tour_after_make_run(tmp_path, realtime_run):
    """The tour as written on the folder `make run` leaves: the session's real-time run of the default
    scenario (realtime_run: `make run`'s scenario and mode, run once for every real-time test) in runs/."""
    assert make_run_command()[:3] == ["run", "scenarios/default.toml", "--realtime"]
    src, stdout, _ = realtime_run
    ws = checkout_after_make_run(tmp_path)
    out = ws / "runs" / f"default-realtime-{time.strftime('%Y%m%d-%H%M%S')}"
    shutil.copytree(src, out)
    held = realtime_held(out)
    kpis = json.loads((out / "kpis.json").read_text())
    if kpis["mode"] == "realtime":                        # real time has the bus figures lockstep has
        assert kpis["bus"]["source"] == "trace" and abs(kpis["bus"]["load"] - 0.3937) < 0.01, kpis["bus"]
        assert "bus (500 kbit/s)       load 39." in stdout and "estimated from the trace" in stdout
    outputs = check_tour(run_tour(ws, tmp_path / "tour"), realtime=True, held=held)
    report = next(o for line, o in outputs.items() if line.startswith("railhil report"))
    train = re.search(r"Train \(from the plant's truth\): ([^;]*)", report).group(1)
    if held and train != "the same (10 KPIs)":             # a late cycle may move a figure a little
        assert float(re.search(r"by at most ([0-9.]+) %", train).group(1)) < 2.0, report


# --- one time base --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def epoch_twin(default_lockstep, tmp_path_factory) -> Path:
    """The default lockstep run folder with its trace's first 3 s stamped as a real-time run's (epoch
    seconds from T0) and run.json's trace_t0_s = T0: a real-time run folder's time base, made in a second."""
    src = default_lockstep.out_dir
    out = tmp_path_factory.mktemp("epoch") / "run"
    out.mkdir()
    meta = json.loads((src / "run.json").read_text())
    meta["trace_t0_s"] = T0
    (out / "run.json").write_text(json.dumps(meta))
    with can.LogReader(str(src / "trace.blf")) as reader, can.Logger(str(out / "trace.blf")) as writer:
        for msg in reader:
            if msg.timestamp > 3.0:
                break
            msg.timestamp += T0
            writer.on_message_received(msg)
    return out


def decode_rows(out: str) -> list[tuple[float, str]]:
    return [(float(r.split()[0]), r.split()[1]) for r in out.splitlines()[1:] if r.strip()]


def test_start_and_end_are_seconds_from_the_runs_start_in_every_trace_command(capsys, epoch_twin,
                                                                              default_lockstep, tmp_path):
    args = ["--dbc", DBC, "--message", "BCU_DEMAND", "--start", "1.0", "--end", "1.03"]
    code, twin, err = railhil(capsys, "trace", "decode", epoch_twin / "trace.blf", *args)
    assert code == 0, err
    code, lock, _ = railhil(capsys, "trace", "decode", default_lockstep.out_dir / "trace.blf", *args)
    got, want = decode_rows(twin), decode_rows(lock)
    assert len(got) == len(want) == 3                     # the same three frames, at the same times
    assert all(abs(a[0] - b[0]) < 2e-6 and a[1] == b[1] for a, b in zip(got, want, strict=True))
    assert "3 frames decoded" in err and "times from the run's start: t0 = 1796556887.138472" in err
    # --absolute: the timestamps as recorded
    code, out, err = railhil(capsys, "trace", "decode", epoch_twin / "trace.blf", "--dbc", DBC, "--message",
                             "BCU_DEMAND", "--start", str(T0 + 1.0), "--end", str(T0 + 1.03), "--absolute")
    assert [round(t - T0, 5) for t, _ in decode_rows(out)] == [round(t, 5) for t, _ in want]
    # stats, export, plot and timing read the same window
    code, out, err = railhil(capsys, "trace", "stats", epoch_twin / "trace.blf", "--start", "1.0", "--end",
                             "2.0", "--format", "jsonl")
    assert code == 0 and all(1.0 <= float(json.loads(r)["first_s"]) <= 2.0 for r in out.splitlines()), out
    csv_out = tmp_path / "demand.csv"
    code, _, err = railhil(capsys, "trace", "export", epoch_twin / "trace.blf", *args[:4], "--start", "1.0",
                           "--end", "1.03", "-o", csv_out)
    assert code == 0, err
    times = {float(line.split(",")[0]) for line in csv_out.read_text().splitlines()[1:]}
    assert len(times) == 3 and all(1.0 <= t <= 1.03 for t in times)
    code, out, err = railhil(capsys, "trace", "plot", epoch_twin / "trace.blf", "--dbc", DBC, "TargetDecel",
                             "--start", "1.0", "--end", "2.0", "-o", tmp_path / "p.png")
    assert code == 0 and re.search(r"1\.\d+ to 1\.\d+ s", out), out + err
    code, out, err = railhil(capsys, "timing", epoch_twin / "trace.blf", "--dbc", DBC, "--start", "1.0",
                             "--end", "2.0")
    assert "frames between 1 and 2 s" in out and "0 MISSING" in out, out
    # diff: each trace on its own time base, so the lockstep run and its epoch twin pair up in time
    code, out, err = railhil(capsys, "trace", "diff", default_lockstep.out_dir / "trace.blf",
                             epoch_twin / "trace.blf", "--dbc", DBC, "--end", "2.9",
                             "--time-tolerance", "2e-6")
    assert code == 0 and "equal within tolerance" in out, out


def test_a_trace_of_no_run_is_read_from_its_first_frame(capsys, epoch_twin, tmp_path):
    alone = tmp_path / "alone.blf"
    shutil.copyfile(epoch_twin / "trace.blf", alone)            # out of its folder: no run.json beside it
    first = next(iter(can.LogReader(str(alone)))).timestamp
    code, out, err = railhil(capsys, "trace", "decode", alone, "--dbc", DBC, "--message", "BCU_DEMAND",
                             "--end", "0.05")
    assert code == 0, err
    rows = decode_rows(out)
    assert rows and rows[0][0] < 0.05 and f"t0 = {first:.6f}" in err


def test_a_window_outside_the_trace_is_one_warning_line(capsys, epoch_twin):
    code, out, err = railhil(capsys, "trace", "decode", epoch_twin / "trace.blf", "--dbc", DBC, "--start",
                             str(T0 + 1), "--end", str(T0 + 1.03))
    assert code == 0
    warnings = [line for line in err.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 1 and "add --absolute" in warnings[0] and "the trace runs from 0." in warnings[0]
    assert_one_line_error(*railhil(capsys, "trace", "decode", epoch_twin / "trace.blf", "--dbc", DBC,
                                   "--start", "2", "--end", "1")[::2], "--end 1.0 is before --start 2.0")


# --- timing knows the run -------------------------------------------------------------------------------


def test_timing_of_a_runs_trace_judges_what_the_run_sends(capsys, default_lockstep, tmp_path):
    trace = default_lockstep.out_dir / "trace.blf"
    code, out, err = railhil(capsys, "timing", trace, "--dbc", DBC)
    assert code == 0, out + err
    assert "35 cyclic messages: 35 PASS, 0 FAIL, 0 MISSING" in out
    line = next(x for x in out.splitlines() if x.startswith("run "))
    assert re.search(r"left out \d+ cyclic messages .*\(\d+ of cars 7–8, beyond its 6-car train", line), line
    assert "--all-messages" in line
    code, out, _ = railhil(capsys, "timing", trace, "--dbc", DBC, "--all-messages")
    assert code == 1 and "10 MISSING" in out                     # the base frames of cars 7 and 8
    alone = tmp_path / "alone.blf"                               # a trace of no run: the DBC's base frames
    shutil.copyfile(trace, alone)
    code, out, _ = railhil(capsys, "timing", alone, "--dbc", DBC)
    assert code == 1 and "10 MISSING" in out
    code, out, _ = railhil(capsys, "timing", alone, "--dbc", DBC, "--run", default_lockstep.out_dir,
                           "--format", "json")
    doc = json.loads(out)
    assert code == 0 and doc["summary"]["MISSING"] == 0 and "BECU7_PRESS_CMD" in doc["run"]["left_out"]
    assert_one_line_error(*railhil(capsys, "timing", alone, "--dbc", DBC, "--run", tmp_path)[::2],
                          "--run", "not a run folder")


# --- comparisons ----------------------------------------------------------------------------------------


def test_a_comparison_counts_the_kpis_both_runs_have_and_describes_each_from_its_scenario(default_lockstep,
                                                                                         tmp_path):
    from hil.report.html import comparison_summary, render_comparison

    twin = tmp_path / "twin"
    shutil.copytree(default_lockstep.out_dir, twin)
    kpis = json.loads((twin / "kpis.json").read_text())
    kpis["realtime"] = {"held": True, "misses_bench": 0, "nodes": {"BCU": {"p99_us": 20}}}   # one run only
    kpis["frames_sent"] += 30
    (twin / "kpis.json").write_text(json.dumps(kpis))
    meta = json.loads((twin / "run.json").read_text())
    meta["scenario"]["train"]["initial_speed_kmh"] = 120.0
    (twin / "run.json").write_text(json.dumps(meta))
    line = comparison_summary(twin, default_lockstep.out_dir)
    assert line.startswith("Train (from the plant's truth): the same (10 KPIs); Run and frames: 1 of "), line
    assert "KPIs of one run only, not compared" in line
    page = render_comparison(twin, default_lockstep.out_dir)
    assert "6-car train at 120 km/h" in page and "6-car train at 90 km/h" in page
    assert "realtime.held (run only)" in page


# --- the command line -------------------------------------------------------------------------------------


def test_version_names_railhil_python_can_cantools_and_python(capsys):
    from importlib.metadata import version

    from hil import build

    with pytest.raises(SystemExit) as done:
        railhil(capsys, "--version")
    out = capsys.readouterr().out.strip()
    assert done.value.code == 0
    assert out == (f"railhil {version('railhil')} (python-can {version('python-can')}, cantools "
                   f"{version('cantools')}, Python {sys.version.split()[0]}); {build.state().line()}")


def test_a_mistyped_scenario_gets_the_closest_names(capsys, tmp_path):
    assert_one_line_error(*railhil(capsys, "run", "defualt")[::2], "defualt", "did you mean default?")
    assert_one_line_error(*railhil(capsys, "init", tmp_path / "b", "--scenario", "stop_30kph")[::2],
                          "did you mean stop_30kmh?")
    code, _, err = railhil(capsys, "run", "xyzzy")
    assert code == 2 and "shipped: acd_anticollision" in err and "did you mean" not in err


# --- the docs' figures are the code's ---------------------------------------------------------------------


def test_the_printed_lockstep_figures_are_a_lockstep_runs(default_lockstep):
    figures = figures_module()
    lines = [line.replace(str(default_lockstep.out_dir), figures.TOUR) for line in default_lockstep.summary()]
    shown = [(doc.name, block) for doc in figures.DOCS for block in figures.printed(doc.read_text(),
                                                                                      figures.LOCKSTEP_COMMAND)]
    assert {name for name, _ in shown} >= {"README.md", "getting-started.md", "reports.md"}
    for name, block in shown:
        why = f"{name} prints another lockstep run; `make docs-figures` writes this one:\n" + "\n".join(lines)
        assert figures.same_but_the_wall(block, lines), why


def test_the_kpis_json_of_the_reports_page_is_a_lockstep_runs(default_lockstep):
    figures = figures_module()
    text = figures.KPIS_DOC.read_text()
    a, b = figures.marked(text, figures.KPIS_MARK)
    shown = json.loads(re.search(r"```json\n(.*)```", text[a:b], re.S).group(1))
    assert shown == default_lockstep.kpis, "docs/reports.md's kpis.json is not the run's: make docs-figures"
    assert json.loads(figures.kpis_text(default_lockstep.kpis)) == default_lockstep.kpis


def test_the_docs_plot_is_a_lockstep_runs(default_lockstep):
    from matplotlib.image import imread

    shown, drawn = imread(ROOT / "docs" / "img" / "plot.png"), imread(default_lockstep.out_dir / "plot.png")
    assert shown.shape == drawn.shape and float(np.abs(shown - drawn).mean()) < 1e-3, \
        "docs/img/plot.png is not what the code draws: make docs-figures"
