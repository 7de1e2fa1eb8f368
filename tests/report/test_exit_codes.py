"""`railhil run` exits with its verdict: 1 when a gating verdict failed (hil.report.gate: real time held,
each external node PASS, each study's checks), 0 when they all passed or with --exit-zero; the summary's
last line says which.  The gate on made-up kpis.json dicts (pure), then lockstep runs of shipped
scenarios, then two short real-time runs: one whose budget no machine meets, one whose external BECU3
falls silent mid-run."""

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, kill_all, own_bus, railhil, wait_for_output

from hil.report.gate import gates, verdict_line
from hil.report.html import run_verdicts
from hil.runtime.outcome import RunOutcome, realtime_verdict

STOP = "stop_30kmh"            # a shipped scenario that ends fast, no study check
SLIP = "rg_low_adhesion"       # seed 001 Fig. 8: the governor keeps slip ≤ s̄; without it the check fails
NO_BUDGET = ["--set", "realtime.precise_wait=false", "--set", "realtime.deadline.miss_min_us=0",
             "--set", "realtime.deadline.miss_period_pct=0", "--set", "realtime.deadline.budget_pct=0"]


# ------------------------------------------------------------------------------------- the gate, pure
def realtime(late_us: int = 20) -> dict:
    """kpis.json "realtime" of a run with one simulated node (BCU, 1,000 cycles of 10 ms: 1 bench miss
    allowed) whose cycles 10 and 20 were `late_us` late, no probe stall (realtime_verdict)."""
    lateness = np.full(1_000, 20, dtype=np.int64)
    lateness[[10, 20]] = late_us
    cycles = {"BCU": {"period_us": 10_000, "deadline_us": np.arange(1_000) * 10_000, "lateness_us": lateness}}
    probe = {"deadline_us": np.arange(1, 1_001) * 10_000, "lateness_us": np.full(1_000, 60)}
    return realtime_verdict(RunOutcome("realtime", 10_000_000, "standstill", None, {},
                                       realtime={"cycles": cycles, "probes": {"PROBE0": probe}}))


def conduct(timing: str = "PASS", protection: dict | None = None, external: bool = True) -> dict:
    """kpis.json "realtime.conduct" of BECU3 (hil.report.conduct), and of the simulated BCU: FAIL and
    not clean, which gates nothing (the bench's own nodes are judged by real time held)."""
    return {"BECU3": {"external": external, "timing": timing, "protection": protection or {}},
            "BCU": {"external": False, "timing": "FAIL", "protection": {"ERROR": 4}}}


HELD, NOT_HELD = realtime(), realtime(late_us=900)      # 2 misses of > 500 µs: over the budget of 1
WHEEL_SLIP = {"slip_limit_mps": 0.1, "max_slip_every_step_mps": [0.08, 0.1709],
              "slip_within_limit": [True, False]}
ACD = {"min_gap_m": 42.0, "collision": False, "overruns": 0}


NOTHING_TO_GATE = "verdict: PASS (no real-time, external-node, device or study check in this run)"


@pytest.mark.parametrize(("kpis", "failed", "line"), [
    ({"mode": "lockstep"}, [], NOTHING_TO_GATE),
    ({"mode": "lockstep", "stopped": False, "frames_lost": 3, "end_reason": "max_duration",
      "protection_events": {"ERROR": 2}, "bus": {"deadline_misses": 5}}, [],
     NOTHING_TO_GATE),                                                       # informational
    ({"realtime": HELD}, [], "verdict: PASS (real time held)"),
    ({"realtime": NOT_HELD}, [("real time", "NOT HELD (BCU 2 bench misses, allowed 1)")],
     "verdict: FAIL — real time NOT HELD (BCU 2 bench misses, allowed 1)"),
    ({"realtime": {**HELD, "conduct": conduct(protection={"NONEWDATA": 12})}, "anticollision": ACD}, [],
     "verdict: PASS (real time held, 1 external node PASS, 2 study checks PASS)"),
    ({"realtime": {**HELD, "conduct": conduct(timing="FAIL")}}, [("external BECU3", "timing FAIL")],
     "verdict: FAIL — external BECU3 timing FAIL"),
    ({"realtime": {**HELD, "conduct": conduct(timing="SILENT")}}, [("external BECU3", "timing SILENT")],
     "verdict: FAIL — external BECU3 timing SILENT"),
    ({"realtime": {**HELD, "conduct": conduct(protection={"NONEWDATA": 3, "WRONGSEQUENCE": 2})}},
     [("external BECU3", "E2E/SecOC WRONGSEQUENCE 2")],
     "verdict: FAIL — external BECU3 E2E/SecOC WRONGSEQUENCE 2"),
    ({"realtime": {**HELD, "conduct": conduct(timing="FAIL", external=False)}}, [],
     "verdict: PASS (real time held)"),                                      # simulated: not a device
    ({"realtime": {**NOT_HELD, "conduct": conduct(timing="FAIL", protection={"SECOC_MAC_MISMATCH": 1})}},
     [("real time", "NOT HELD (BCU 2 bench misses, allowed 1)"),
      ("external BECU3", "timing FAIL, E2E/SecOC SECOC_MAC_MISMATCH 1")],
     "verdict: FAIL — real time NOT HELD (BCU 2 bench misses, allowed 1); external BECU3 timing FAIL, "
     "E2E/SecOC SECOC_MAC_MISMATCH 1"),
    ({"mode": "lockstep", "wheel_slip": WHEEL_SLIP},
     [("wheel_slip: slip ≤ s̄ at every plant step", "FAIL (0.0800 0.1709 m/s; expected ≤ 0.1 m/s)")],
     "verdict: FAIL — wheel_slip: slip ≤ s̄ at every plant step FAIL (0.0800 0.1709 m/s; expected ≤ 0.1 m/s)"),
    ({"mode": "lockstep", "anticollision": {**ACD, "overruns": 1}},
     [("anticollision: no red signal passed", "FAIL (1; expected = 0)")],
     "verdict: FAIL — anticollision: no red signal passed FAIL (1; expected = 0)"),
    ({"mode": "lockstep", "anticollision": ACD}, [], "verdict: PASS (2 study checks PASS)"),
])
def test_the_gate_names_each_failed_verdict_with_its_figure(kpis, failed, line):
    checks = gates(kpis)
    assert [(g.what, g.figure) for g in checks if not g.passed] == failed
    assert verdict_line(checks) == line


def test_a_later_verdict_extends_the_list():
    """A device under test on its own CAN matrix adds its own PASS / FAIL to the same list."""
    from hil.report.gate import Gate

    checks = gates({"realtime": HELD}) + [Gate("device check", "device PCU1", False, "FAIL (map: 2 signals)")]
    assert verdict_line(checks) == "verdict: FAIL — device PCU1 FAIL (map: 2 signals)"
    checks[-1] = Gate("device check", "device PCU1", True, "PASS")
    assert verdict_line(checks) == "verdict: PASS (real time held, 1 device check PASS)"


def test_report_html_judges_an_external_node_as_the_exit_code_does():
    kpis = {"realtime": {**HELD, "conduct": conduct(timing="FAIL")}, "stopped": True,
            "end_reason": "standstill"}
    checks = {v.check: v for v in run_verdicts(kpis, {"mode": "realtime", "node_stats": {}})}
    assert checks["external BECU3 on the bus"].passed is False
    assert checks["external BECU3 on the bus"].value == "timing FAIL"
    assert "external BCU on the bus" not in checks


# ------------------------------------------------------------------------------------- lockstep runs
def test_a_lockstep_run_whose_checks_pass_exits_0(capsys, tmp_path):
    code, out, err = railhil(capsys, "run", SLIP, "--lockstep", "--out", tmp_path / "run", "-q")
    assert code == 0, err
    assert out.strip().splitlines()[-1] == "verdict: PASS (1 study check PASS)", out


def test_a_lockstep_run_whose_study_check_fails_exits_1_and_0_with_exit_zero(capsys, tmp_path):
    """Without the reference governor the slip goes over s̄ (seed 001 Fig. 8): the run and its folder are
    as ever, its last line says FAIL and why; --exit-zero exits 0 with the same summary."""
    args = ("run", SLIP, "--lockstep", "--set", "wheel_slip.governor=false", "-q")
    code, out, err = railhil(capsys, *args, "--out", tmp_path / "strict")
    assert code == 1, err
    last = out.strip().splitlines()[-1]
    assert last.startswith("verdict: FAIL — wheel_slip: slip ≤ s̄ at every plant step FAIL ("), out
    assert (tmp_path / "strict" / "report.html").is_file() and err == ""
    code, out, err = railhil(capsys, *args, "--exit-zero", "--out", tmp_path / "explore")
    assert code == 0, err
    assert out.strip().splitlines()[-1] == last


# ------------------------------------------------------------------------------------ real-time runs
def railhil_run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", "run", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.realtime
def test_a_run_that_cannot_hold_real_time_exits_1_not_held(tmp_path):
    """A budget no machine meets: every cycle later than 0 µs is a miss, none allowed, no precise wait.  The
    ECUs of the grouped host are released one after another at their shared deadlines, so the later ones
    are late by the earlier ones' cycles: misses of the bench's own, whatever the machine's stalls."""
    out = tmp_path / "run"
    proc = railhil_run(STOP, "--realtime", "--set", "max_duration_s=2", *NO_BUDGET, "--out", out, "-q")
    assert proc.returncode == 1, proc.stderr
    rt = json.loads((out / "kpis.json").read_text())["realtime"]
    assert not rt["held"] and rt["misses_bench"] > 0, rt["nodes"]
    last = proc.stdout.strip().splitlines()[-1]
    assert last.startswith("verdict: FAIL — real time NOT HELD (") and "bench misses, allowed 0" in last, last


@pytest.mark.realtime
def test_an_external_node_that_falls_silent_mid_run_exits_1(tmp_path):
    """`railhil node BECU3` as the external BECU3 for 1.5 s of a 4 s run: its frames stop, its timing is
    FAIL, the run exits 1 and says so (whatever real time did); the node itself ends with 0."""
    bus = own_bus()
    node = subprocess.Popen([sys.executable, "-m", "hil", "node", "BECU3", STOP, "--duration", "1.5", *bus],
                            cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    try:
        started = wait_for_output(node, "waiting for the first frame of another node")
        run = railhil_run(STOP, "--realtime", "--external", "BECU3", "--set", "max_duration_s=4", *bus,
                          "--out", tmp_path / "run", "-q")
        node_out, node_err = node.communicate(timeout=60)
    finally:
        kill_all(node)
    assert node.returncode == 0, node_err
    assert "node BECU3: started" in started + node_out, started + node_out
    assert run.returncode == 1, run.stderr
    becu3 = json.loads((tmp_path / "run" / "kpis.json").read_text())["realtime"]["conduct"]["BECU3"]
    assert becu3["external"] and becu3["timing"] == "FAIL" and becu3["frames"] > 0, becu3
    last = run.stdout.strip().splitlines()[-1]
    assert last.startswith("verdict: FAIL — ") and "external BECU3 timing FAIL" in last, last
