"""Bad input at the command line: one line `error: ...`, exit code 2, no traceback."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def railhil(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "hil", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=120)


def assert_one_line_error(proc, *needles):
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


def test_bad_scenario_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[train]\ncars = 0\n")
    assert_one_line_error(railhil("run", str(bad), "--lockstep", "--out", str(tmp_path / "o")),
                          "train.cars", "0")


def test_dbc_that_does_not_load(tmp_path):
    (tmp_path / "broken.dbc").write_text("BO_ this is not a dbc\n")
    scen = tmp_path / "s.toml"
    scen.write_text('dbc = "broken.dbc"\n')
    for mode in ("--lockstep", "--realtime"):
        assert_one_line_error(railhil("run", str(scen), mode, "--out", str(tmp_path / "o")),
                              "broken.dbc", "not a loadable DBC")
        assert not (tmp_path / "o").exists()            # no empty run folder left behind


def test_unknown_signal_name_in_a_node_binding(tmp_path):
    # a DBC whose car-1 sensor frame has a misspelt signal: the PLANT/BECU1 bindings must say so
    text = (ROOT / "dbc" / "train_brake.dbc").read_text().replace(" SG_ AxleSpeed :", " SG_ AxelSpeed :", 1)
    (tmp_path / "typo.dbc").write_text(text)
    scen = tmp_path / "s.toml"
    scen.write_text('dbc = "typo.dbc"\n[train]\ncars = 2\n')
    for mode in ("--lockstep", "--realtime"):
        assert_one_line_error(railhil("run", str(scen), mode, "--out", str(tmp_path / "o")),
                              "AxleSpeed", "closest: AxelSpeed")
        assert not (tmp_path / "o").exists()            # nor a partial one: the nodes are built first


def test_help_lists_the_run_command():
    proc = railhil("run", "--help")
    assert proc.returncode == 0 and "--realtime" in proc.stdout and "--interface" in proc.stdout
