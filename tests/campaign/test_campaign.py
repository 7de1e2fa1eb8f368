"""Campaigns (issue #10 item 1): sweeps of a scenario run through local processes and a Dask LocalCluster,
resumed after an interruption, with a failing point recorded while the others finish.

Every point is a real lockstep run (1 car, 0.7 s simulated) writing its real run folder; the campaign
subcommand is reached through hil.cli.main."""

from __future__ import annotations

import csv
import json
import shutil

import pytest
from conftest import ROOT, assert_one_line_error, railhil

from hil.campaign.sweep import (
    CampaignError,
    draw,
    expand,
    load_campaign,
    point_key,
    run_campaign,
)
from hil.cli import main as cli_main
from hil.cli.campaign import HELP

BASE = ROOT / "scenarios" / "stop_30kmh.toml"
SHORT = {"max_duration_s": 0.7, "train.cars": 1}      # a point: about 1 s of wall time


@pytest.fixture(autouse=True)
def _registered(monkeypatch):
    """`railhil campaign` until hil/cli/main.py lists it in COMMANDS (then this changes nothing)."""
    monkeypatch.setitem(cli_main.COMMANDS, "campaign", ("hil.cli.campaign", HELP))


def toml_value(v) -> str:
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + " }"
    return json.dumps(v)


def write_campaign(path, *, fixed=None, grid=None, random=None, n=None, extra="", name="t", seed=1):
    lines = [f'base = "{BASE}"', f'name = "{name}"', f"seed = {seed}", extra, "[set]"]
    swept = {**(grid or {}), **(random or {})}
    base = {k: v for k, v in SHORT.items() if k not in swept}
    lines += [f'"{k}" = {toml_value(v)}' for k, v in {**base, **(fixed or {})}.items()]
    if grid:
        lines += ["[grid]"] + [f'"{k}" = {toml_value(v)}' for k, v in grid.items()]
    if random:
        lines += ["[random]", f"n = {n}"] + [f'"{k}" = {toml_value(v)}' for k, v in random.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def read_rows(out):
    with (out / "results.csv").open() as f:
        return list(csv.DictReader(f))


# --- the file and its points ------------------------------------------------------------------------


def test_points_are_grid_times_draws_with_seeded_per_key_streams(tmp_path):
    f = write_campaign(tmp_path / "c.toml", grid={"train.mass_kg": [30000, 50000]}, n=3,
                       random={"train.initial_speed_kmh": {"uniform": [20, 40]},
                               "seed": {"integers": [1, 9]}})
    points = expand(load_campaign(f))
    assert len(points) == 6
    assert [p.values["train.mass_kg"] for p in points] == [30000] * 3 + [50000] * 3
    # the same draws at each grid value, applied to the scenario itself
    assert [p.values["seed"] for p in points[:3]] == [p.values["seed"] for p in points[3:]]
    for p in points:
        assert p.scenario.train.mass_kg == p.values["train.mass_kg"]
        assert p.scenario.train.initial_speed_kmh == p.values["train.initial_speed_kmh"]
        assert 20 <= p.scenario.train.initial_speed_kmh <= 40 and 1 <= p.scenario.seed <= 9
        assert p.scenario.max_duration_s == 0.7 and p.scenario.train.cars == 1      # [set]
    assert len({p.key for p in points}) == 6
    # raising n keeps the first draws (their cache); another key's stream is not disturbed
    assert draw("uniform", [20, 40], 1, "k", 10)[:3] == draw("uniform", [20, 40], 1, "k", 3)
    assert draw("uniform", [20, 40], 2, "k", 3) != draw("uniform", [20, 40], 1, "k", 3)
    ints = draw("integers", [1, 3], 5, "seed", 200)
    assert set(ints) == {1, 2, 3}                                                   # both ends included
    assert all(x in ("a", "b") for x in draw("choice", ["a", "b"], 0, "c", 20))


def test_cache_key_follows_scenario_and_dbc_content(tmp_path):
    dbc = tmp_path / "copy.dbc"
    shutil.copy(ROOT / "dbc" / "train_brake.dbc", dbc)
    f = write_campaign(tmp_path / "c.toml", fixed={"dbc": str(dbc)})
    (p,) = expand(load_campaign(f))
    assert p.key == point_key(p.scenario)
    assert point_key(p.scenario.model_copy(update={"seed": 99})) != p.key
    dbc.write_text(dbc.read_text() + "\nCM_ \"edited\";\n")          # same path, other bytes: runs again
    assert point_key(p.scenario) != p.key
    assert point_key(p.scenario, version="0.0.0") != point_key(p.scenario)
    assert point_key(p.scenario, code="another source") != point_key(p.scenario)


@pytest.mark.parametrize("body, needles", [
    ('bse = "x.toml"', ["bse", "did you mean 'base'"]),
    ('base = "nowhere.toml"', ["nowhere.toml", "no such scenario file"]),
    (f'base = "{BASE}"\n[grid]\n"train.mas_kg" = [1]', ["train.mas_kg", "did you mean 'train.mass_kg'"]),
    (f'base = "{BASE}"\n[grid]\n"train.mass_kg" = [40000, 5]', ["point 1", "train.mass_kg", "5"]),
    (f'base = "{BASE}"\n[grid]\n"train.mass_kg" = 40000', ["[grid]", "train.mass_kg", "non-empty list"]),
    (f'base = "{BASE}"\n[random]\nn = 3\nseed = {{ uniforn = [1, 2] }}', ["seed", "uniforn", "uniform"]),
    (f'base = "{BASE}"\n[random]\nn = 3\nseed = {{ integers = [9, 1] }}', ["seed", "hi is below lo"]),
    (f'base = "{BASE}"\n[random]\nseed = {{ integers = [1, 9] }}', ["[random] n", "integer ≥ 1"]),
    (f'base = "{BASE}"\n[set]\nseed = 1\n[grid]\nseed = [1, 2]', ["seed", "[set]", "[grid]"]),
    ("base = [", ["not valid TOML"]),
])
def test_bad_campaign_file_is_one_line_exit_2(capsys, tmp_path, body, needles):
    f = tmp_path / "bad.toml"
    f.write_text(body + "\n")
    code, _, err = railhil(capsys, "campaign", f, "-o", tmp_path / "out", "-q")
    assert_one_line_error(code, err, str(f), *needles)
    with pytest.raises(CampaignError):
        expand(load_campaign(f))


def test_bad_options_are_one_line_exit_2(capsys, tmp_path):
    f = write_campaign(tmp_path / "c.toml")
    code, _, err = railhil(capsys, "campaign", f, "--jobs", "0")
    assert_one_line_error(code, err, "--jobs 0", "at least 1")
    code, _, err = railhil(capsys, "campaign", f, "--dask", "tcp://127.0.0.1:9", "--dask-timeout", "1",
                           "-o", tmp_path / "out", "-q")
    assert_one_line_error(code, err, "--dask tcp://127.0.0.1:9", "cannot connect")


# --- running ----------------------------------------------------------------------------------------


def test_twenty_points_on_two_processes_then_rerun_runs_only_unfinished(capsys, tmp_path):
    f = write_campaign(tmp_path / "c.toml", grid={"train.initial_speed_kmh": [20.0, 30.0]}, n=10,
                       random={"seed": {"integers": [1, 10_000]}})
    out = tmp_path / "out"
    code, stdout, err = railhil(capsys, "campaign", f, "--jobs", "2", "-o", out, "-q")
    assert code == 0, err
    rows = read_rows(out)
    assert len(rows) == 20 and {r["status"] for r in rows} == {"ok"}
    assert {r["cached"] for r in rows} == {"False"}
    assert "20 of 20 points finished (20 ok, 0 from cache, 0 failed)" in stdout
    for r in rows:                                    # each row is its point's own run folder
        kpis = json.loads((out / r["run_dir"] / "kpis.json").read_text())
        assert kpis["seed"] == int(r["seed"])
        assert float(r["stopping_distance_m"]) == kpis["stopping_distance_m"]
        assert (out / r["run_dir"] / "trace.blf").stat().st_size > 0
    faster = [float(r["stopping_distance_m"]) for r in rows if r["train.initial_speed_kmh"] == "30.0"]
    slower = [float(r["stopping_distance_m"]) for r in rows if r["train.initial_speed_kmh"] == "20.0"]
    assert min(faster) > max(slower)                  # 0.2 s of braking from 30 km/h: more ground
    assert (out / "plot_train.initial_speed_kmh.png").stat().st_size > 0
    # lose 3 finished points, as if the campaign had been killed before they ended: only they run again
    lost = {rows[i]["run_dir"] for i in (2, 11, 19)}
    for d in lost:
        shutil.rmtree(out / d)
    code, stdout, err = railhil(capsys, "campaign", f, "--jobs", "2", "-o", out, "-q")
    assert code == 0, err
    again = read_rows(out)
    assert {r["run_dir"] for r in again if r["cached"] == "False"} == lost
    assert "(20 ok, 17 from cache, 0 failed)" in stdout
    assert [r["stopping_distance_m"] for r in again] == [r["stopping_distance_m"] for r in rows]  # lockstep


def test_interrupted_campaign_keeps_finished_points_and_resumes(tmp_path):
    f = write_campaign(tmp_path / "c.toml", random={"seed": {"integers": [1, 10_000]}}, n=4)
    spec = load_campaign(f)
    seen = []

    def ctrl_c_after_two(result):
        seen.append(result)
        if len(seen) == 2:
            raise KeyboardInterrupt

    first = run_campaign(spec, tmp_path / "out", None, progress=ctrl_c_after_two)
    assert first.interrupted and len(first.results) == 2 and first.total == 4
    second = run_campaign(spec, tmp_path / "out")
    assert not second.interrupted and [r.cached for r in second.results].count(True) == 2
    assert {r.point.index for r in second.results if r.cached} == {r.point.index for r in first.results}
    assert all(r.status == "ok" for r in second.results)


def test_failing_point_is_recorded_and_the_others_finish_on_a_dask_local_cluster(capsys, tmp_path):
    distributed = pytest.importorskip("distributed")
    # BECU2's timing is set at every point, but with 1 car there is no BECU2: that point fails at run time
    f = write_campaign(tmp_path / "c.toml", fixed={"nodes.BECU2.drift_ppm": 5.0},
                       grid={"train.cars": [1, 2, 3]})
    out = tmp_path / "out"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address="127.0.0.1:0") as cluster:
        address = cluster.scheduler_address
        code, stdout, err = railhil(capsys, "campaign", f, "--dask", address, "-o", out, "-q")
        assert code == 1, err
        assert "1 of 3 points failed" in err.strip().splitlines()[-1]
        rows = read_rows(out)
        assert [r["status"] for r in rows] == ["failed", "ok", "ok"]
        assert "BECU2" in rows[0]["error"] and rows[0]["stopping_distance_m"] == ""
        assert [json.loads((out / r["run_dir"] / "kpis.json").read_text())["frames_sent_by_node"].keys()
                >= {"BECU2"} for r in rows[1:]] == [True, True]
        # rerun: the finished points come from the cache, the failed one is tried again
        code, stdout, _ = railhil(capsys, "campaign", f, "--dask", address, "-o", out, "-q")
    assert code == 1 and "(2 ok, 2 from cache, 1 failed)" in stdout
    assert "point 0 (train.cars=1) failed" in stdout


def test_parquet_table_matches_csv_when_pyarrow_is_installed(capsys, tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    f = write_campaign(tmp_path / "c.toml", grid={"seed": [1, 2]})
    code, _, err = railhil(capsys, "campaign", f, "-o", tmp_path / "out", "-q")
    assert code == 0, err
    table = pq.read_table(tmp_path / "out" / "results.parquet").to_pylist()
    assert [t["stopping_distance_m"] for t in table] == [float(r["stopping_distance_m"])
                                                       for r in read_rows(tmp_path / "out")]


def test_points_leave_no_figures_unless_plots_then_cached_points_get_theirs_without_running(capsys, tmp_path):
    """A point's run folder: trace, truth.csv, kpis.json, run.json (and point.json); `--plots` adds its
    figures and report.html, drawn from the folder for points already cached (issue #18)."""
    f = write_campaign(tmp_path / "c.toml", grid={"seed": [1, 2]})
    out = tmp_path / "out"
    code, stdout, err = railhil(capsys, "campaign", f, "-o", out, "-q")
    assert code == 0, err
    rows = read_rows(out)
    for r in rows:
        assert sorted(p.name for p in (out / r["run_dir"]).iterdir()) == [
            "kpis.json", "point.json", "run.json", "trace.blf", "truth.csv"]
        assert 0 < float(r["sim_wall_s"]) <= float(r["wall_s"])
        assert f'href="{r["run_dir"]}/"' in (out / "report.html").read_text()   # no point report: its folder
    assert "2 points ran:" in stdout and "of it the lockstep simulation" in stdout
    kpis = {r["run_dir"]: (out / r["run_dir"] / "kpis.json").read_text() for r in rows}
    code, stdout, err = railhil(capsys, "campaign", f, "-o", out, "-q", "--plots")
    assert code == 0, err
    assert "(2 ok, 2 from cache, 0 failed)" in stdout                 # drawn, not run again
    for r in read_rows(out):
        folder = out / r["run_dir"]
        assert (folder / "plot.png").stat().st_size > 0 and (folder / "report.html").stat().st_size > 0
        assert (folder / "kpis.json").read_text() == kpis[r["run_dir"]]
        assert r["cached"] == "True" and float(r["sim_wall_s"]) > 0   # the original run's figures
        assert f'href="{r["run_dir"]}/report.html"' in (out / "report.html").read_text()
    shutil.rmtree(out / rows[0]["run_dir"])                           # lost: runs again, with its figures
    code, stdout, err = railhil(capsys, "campaign", f, "-o", out, "-q", "--plots")
    assert code == 0 and "(2 ok, 1 from cache, 0 failed)" in stdout, err
    assert (out / rows[0]["run_dir"] / "report.html").is_file()


def test_plots_option_has_help(capsys):
    with pytest.raises(SystemExit):
        railhil(capsys, "campaign", "--help")
    assert "--plots" in capsys.readouterr().out
