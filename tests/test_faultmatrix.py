"""The threat matrix, generated as tests: every EN 50159 threat x every safety frame of a 6-car stop
from 30 km/h, in lockstep.  Each cell must be detected by every receiver within 3 cycles and leave
the train safe (plant truth).  Every safety frame of this run is authenticated, so a masquerading
rogue frame (correct E2E trailer, release claimed) is rejected by SecOC and releases no brake."""

import json
import subprocess
import sys

import pytest
from conftest import DEFAULT, ROOT

from hil.can.dbc import load_dbc
from hil.safety.injection import MESSAGE_THREATS
from hil.safety.threat_matrix import _pressures, _run, run_cell, safety_messages
from hil.scenario import load_scenario, parse_scenario

SPEED_KMH = 30.0


def matrix_scenario():
    base = load_scenario(DEFAULT)
    return parse_scenario({**base.model_dump(), "name": "matrix", "max_duration_s": 30.0,
                           "train": {**base.train.model_dump(), "initial_speed_kmh": SPEED_KMH}})


SCENARIO = matrix_scenario()
MESSAGES = safety_messages(SCENARIO, load_dbc())


@pytest.fixture(scope="module")
def baseline():
    _, cols, kpis = _run(SCENARIO)
    assert kpis["stopped"]
    return (kpis, *_pressures(cols, SCENARIO.train.cars))


def test_the_matrix_covers_every_safety_frame_of_the_run():
    assert set(MESSAGES) == {"BCU_EMERGENCY", "DESK_CMD", "BCU_DEMAND"} | {
        f"BECU{i}_PRESS_CMD" for i in range(1, 7)}


CELLS = [(m, t) for m in MESSAGES for t in MESSAGE_THREATS]


@pytest.mark.parametrize("message, threat", CELLS)
def test_threat_is_detected_and_the_train_stays_safe(baseline, message, threat):
    cell = run_cell(SCENARIO, message, threat, baseline)
    assert not cell.error, cell.error
    assert cell.injected > 0
    assert cell.detected, cell
    assert not cell.unsafe, cell
    assert not cell.released, cell


def test_faults_matrix_cli_writes_markdown_and_json(tmp_path):
    scenario = tmp_path / "matrix.toml"
    scenario.write_text(f'name = "m"\nseed = 1\n[train]\ninitial_speed_kmh = {SPEED_KMH}\n'
                        '[[desk]]\nat_s = 0.5\nbrake_step = 7\n')
    proc = subprocess.run([sys.executable, "-m", "hil", "faults", "matrix", str(scenario), "--message",
                           "BCU_DEMAND", "--threat", "corruption", "--threat", "masquerade", "-q",
                           "--jobs", "1", "-o", str(tmp_path / "out")],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "| BCU_DEMAND | corruption |" in proc.stdout
    cells = json.loads((tmp_path / "out" / "matrix.json").read_text())["cells"]
    assert [(c["threat"], c["detected"], c["unsafe"]) for c in cells] == [
        ("corruption", True, False), ("masquerade", True, False)]
    bad = subprocess.run([sys.executable, "-m", "hil", "faults", "matrix", str(scenario), "--message",
                          "BCU_DEMAN"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "BCU_DEMAND" in bad.stderr
