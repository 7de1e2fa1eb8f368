"""`railhil reproduce wheel-slip | decel-feedback | precise-stop`: each runs its study's lockstep runs,
prints our figures next to the paper's and leaves its run folders and results.json; bad options are one
line.  (The preview-slip, anticollision and consensus reproductions have their tests beside their
studies' tests.)"""

from __future__ import annotations

import json

import pytest

from hil.cli.main import main


def test_reproduce_wheel_slip_prints_figs_8_and_9_next_to_the_paper(tmp_path, capsys):
    assert main(["reproduce", "wheel-slip", "--jobs", "2", "--out", str(tmp_path), "-q"]) == 0
    out = capsys.readouterr().out
    assert "Fig. 8" in out and "paper 0.0718" in out and "paper 0.0682" in out and "Fig. 9" in out
    rows = json.loads((tmp_path / "results.json").read_text())
    by = {(r["figure"], r["governor"]): r["wheel_slip"] for r in rows}
    assert by[("fig8", True)]["wsp_activations"] == [0] and by[("fig8", False)]["wsp_activations"][0] > 0
    for fig in ("fig8", "fig9"):
        for gov in ("on", "off"):
            assert (tmp_path / f"{fig}-governor-{gov}" / "wheel_slip.png").is_file()


def test_reproduce_decel_feedback_compares_the_loops(tmp_path, capsys):
    assert main(["reproduce", "decel-feedback", "--out", str(tmp_path), "-q"]) == 0
    out = capsys.readouterr().out
    assert "open loop" in out and "closed loop" in out and "1.32" in out
    results = json.loads((tmp_path / "results.json").read_text())
    rows = {r["closed_loop"]: r["decel_feedback"] for r in results}
    assert rows[True]["within_band_after_engagement"] > rows[False]["within_band_after_engagement"]
    assert (tmp_path / "fig19_20.png").stat().st_size > 10_000


def test_reproduce_precise_stop_one_run(tmp_path, capsys):
    args = ["reproduce", "precise-stop", "--runs", "1", "--distance", "400", "--method", "pi",
            "--out", str(tmp_path), "-q"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "best method pi" in out and "goal <= 0.3 m" in out
    (row,) = json.loads((tmp_path / "results.json").read_text())
    assert row["method"] == "pi" and row["stopped"] and abs(row["stop_error_m"]) < 1.0
    assert (tmp_path / "pi_0" / "precise_stop.png").is_file()


@pytest.mark.parametrize("argv, what", [
    (["wheel-slip", "--jobs", "0"], "--jobs 0"),
    (["decel-feedback", "--jobs", "-1"], "--jobs -1"),
    (["precise-stop", "--runs", "0"], "--runs 0"),
    (["precise-stop", "--distance", "5"], "--distance 5.0"),
])
def test_bad_reproduce_options_are_one_line(argv, what, capsys):
    assert main(["reproduce", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and what in err


def test_reproduce_out_that_is_a_file_is_one_line(tmp_path, capsys):
    f = tmp_path / "a-file"
    f.write_text("x")
    assert main(["reproduce", "wheel-slip", "--out", str(f)]) == 2
    assert "is not a folder" in capsys.readouterr().err
