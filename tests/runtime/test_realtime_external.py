"""A device under test in the loop: BECU3 is not simulated (`--external BECU3`); its frames come from
examples/external_becu/becu.py, a BECU written with python-can and cantools only, on the same
udp_multicast bus.  The train stops as it does with every node simulated, BECU3's frames pass their
timing verdicts, and when the program is killed the BCU reports car 3 silent and car 3's actuator goes
fail-safe.  The command-line errors of --external and `railhil node` are in tests/cli/test_external_cli.py."""

import json
import os
import selectors
import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest
from conftest import ATTEMPTS, DEFAULT, ROOT, kill_all, own_bus, realtime_held
from test_realtime import excused_unless_realtime_held, wait_for_frames, wait_for_start

pytestmark = pytest.mark.realtime

EXAMPLE = ROOT / "examples" / "external_becu" / "becu.py"
HOLD_S = 0.5      # [plant] failsafe_hold_s of the kill test: the actuators hold, then fill, within its 4 s


def realtime_prefix() -> list[str]:
    """chrt -f 50 where the OS allows it: the device under test gets the real-time priority railhil's own
    nodes get (a real ECU has a CPU of its own; on a shared 2-core machine it must not queue behind them)."""
    chrt = shutil.which("chrt")
    if chrt and subprocess.run([chrt, "-f", "50", "true"], capture_output=True).returncode == 0:
        return [chrt, "-f", "50"]
    return []


def start_external_becu(bus: list[str], car: int = 3) -> subprocess.Popen:
    """The example program on `bus`, once it said it is on the bus."""
    proc = subprocess.Popen([*realtime_prefix(), sys.executable, str(EXAMPLE), "--car", str(car), *bus],
                            cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    assert sel.select(timeout=60), "the external BECU did not start within 60 s"
    line = proc.stdout.readline()
    assert line.startswith(f"external BECU{car}: on udp_multicast"), (line, proc.poll())
    return proc


def run_with_external(tmp_path, bus: list[str], *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "hil", "run", str(DEFAULT), "--realtime", "--external",
                             "BECU3", *bus, "--out", str(tmp_path), "-q", *extra], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)


@pytest.mark.slow         # a whole real-time run of the default scenario beside realtime_run's: over a minute
def test_an_external_becu_written_without_railhil_brakes_car_3(tmp_path, realtime_run):
    """The default scenario with that program as BECU3: the train stops within 2 % of the all-simulated
    real-time run, BECU3's frames get PASS timing verdicts and the receivers take them (no E2E or SecOC
    error), and the summary names BECU3 as external."""
    for attempt in range(ATTEMPTS):
        out = tmp_path / f"run{attempt}"
        bus = own_bus()
        becu = start_external_becu(bus)
        try:
            run = run_with_external(out, bus)
            stdout, stderr = run.communicate(timeout=400)
        finally:
            becu.send_signal(signal.SIGTERM)
            becu_out, _ = becu.communicate(timeout=30)
            kill_all(becu)
        assert run.returncode in (0, 1), stderr       # 1: a verdict that failed, judged below
        if realtime_held(out):
            break
    kpis = json.loads((out / "kpis.json").read_text())
    conduct = kpis["realtime"]["conduct"]["BECU3"]
    assert kpis["realtime"]["external"] == ["BECU3"] and conduct["external"]
    assert "external BECU3" in stdout and "BECU3" not in kpis["realtime"]["nodes"]     # not simulated here
    assert kpis["stopped"], kpis
    assert conduct["frames"] > 1000 and conduct["protection_clean"], conduct
    assert kpis["frames_lost"] == 0
    reference = json.loads((realtime_run[0] / "kpis.json").read_text())["stopping_distance_m"]
    with excused_unless_realtime_held(out):
        assert conduct["timing"] == "PASS", conduct["messages"]
        assert abs(kpis["stopping_distance_m"] - reference) / reference < 0.02, (kpis["stopping_distance_m"],
                                                                              reference)
    print(f"\nstopping distance with the external BECU3 {kpis['stopping_distance_m']:.2f} m, all simulated "
          f"{reference:.2f} m; BECU3: {becu_out.strip().splitlines()[-1]}")


def test_a_killed_external_becu_is_reported_silent_and_its_car_brakes_fail_safe(tmp_path):
    """kill -9 of the external BECU3 1.6 s into the run (braking established): the BCU reports car 3
    silent within 3 of BECU3_STATUS's 50 ms cycles (and its own 100 ms status cycle), and the plant's
    actuator of car 3 acts on its own (fail-safe, with `[plant] failsafe_hold_s` = 0.5 s here): it holds
    the cylinder, then applies the brake (the cylinder fills towards the reservoir)."""
    for attempt in range(ATTEMPTS):
        out = tmp_path / f"run{attempt}"
        bus = own_bus()
        becu = start_external_becu(bus)
        try:
            run = run_with_external(out, bus, "--set", "max_duration_s=4.0",
                                    "--set", f"plant.failsafe_hold_s={HOLD_S}")
            _, line = wait_for_start(run)
            assert wait_for_frames(line, 500, until_s=0.3 + 1.6) >= 500
            os.kill(becu.pid, signal.SIGKILL)
            _, stderr = run.communicate(timeout=300)
        finally:
            kill_all(becu)
            kill_all(run)
        assert run.returncode == 1, stderr            # BECU3 fell silent: its timing FAIL gates
        if realtime_held(out):
            break
    kpis = json.loads((out / "kpis.json").read_text())
    becu3 = kpis["realtime"]["conduct"]["BECU3"]
    last, reported = becu3["last_s"], becu3["reported_silent_s"]
    assert reported is not None and reported > last, becu3
    print(f"\nexternal BECU3's last frame at {last:.3f} s; the BCU reported car 3 silent at {reported:.3f} s "
          f"(+{1e3 * (reported - last):.0f} ms)")
    with excused_unless_realtime_held(out):
        assert reported - last <= 3 * 0.050 + 0.100 + 0.05, becu3       # 3 status cycles, then the BCU's
        assert becu3["timing"] == "FAIL" and any("stopped" in m["reason"] for m in becu3["messages"].values())
    cols = np.genfromtxt(out / "truth.csv", delimiter=",", names=True)
    t, p3 = cols["t_s"], cols["p_Pa_3"]
    before = np.median(p3[(t > last - 0.3) & (t < last)])
    held = p3[(t > last + 0.15) & (t < last + HOLD_S - 0.05)]     # stale after 30 ms, filled after the hold
    assert held.size and np.ptp(held) < 1e3, held[::5]                                # held ...
    after = p3[t > last + HOLD_S + 0.5]
    assert after.size and np.median(after) > np.median(held) + 40e3, (before, after[::10])   # then filled
