"""The anti-collision device as a device under test (seed 002's Arduino box): `railhil run --realtime
--external ACD` serves the device its GPS line (NMEA on a pseudo-terminal whose path the run prints), its
radio (a control centre on this host, each train's key in the run folder) and takes its brake request
over CAN; a stand-in device — railhil's own ACD alone, `railhil node ACD`, reading that pty through
pyserial and talking to the centre over TCP with its train's key — closes the loop.

In `make test`: a short run, its plumbing (the pty and the centre announced, the device's fixes read, its
reports stored, its frames judged).  In `make test-slow`: the whole scenario — the train stops behind
the leader with no collision — while a client without the leader's key reports the leader 5 km ahead
every second: the centre refuses and counts it, and the follower keeps braking.
"""

from __future__ import annotations

import json
import os
import re
import selectors
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT

from hil.can.codec import loaded_dbc
from hil.links.control_centre import stored_reports
from hil.trace.decoded import DecodedTrace

pytestmark = pytest.mark.realtime


class Lines:
    """The lines a process writes on a pipe, read off the pipe itself as they come (a text file's readline
    would keep the next lines buffered where select() cannot see them)."""

    def __init__(self, pipe) -> None:
        self.fd = pipe.fileno()
        self.sel = selectors.DefaultSelector()
        self.sel.register(self.fd, selectors.EVENT_READ)
        self.buffer = b""
        self.seen: list[str] = []

    def until(self, pattern: str, timeout_s: float = 120.0) -> re.Match:
        """The first line from here on that matches `pattern`, waiting at most `timeout_s` for each read."""
        while True:
            while b"\n" in self.buffer:
                line, self.buffer = self.buffer.split(b"\n", 1)
                self.seen.append(line.decode(errors="replace"))
                if m := re.search(pattern, self.seen[-1]):
                    return m
            chunk = os.read(self.fd, 4096) if self.sel.select(timeout_s) else b""
            if not chunk:
                raise AssertionError(f"no {pattern!r} within {timeout_s:g} s:\n" + "\n".join(self.seen))
            self.buffer += chunk

    def rest(self, fileobj) -> str:
        """What was seen, then the rest of the pipe (once the process ended)."""
        return "\n".join(self.seen) + "\n" + self.buffer.decode(errors="replace") + fileobj.read()


def stop(proc: subprocess.Popen, sig=signal.SIGTERM) -> tuple[str, str]:
    if proc.poll() is None:
        os.killpg(proc.pid, sig)
    try:
        return proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        return proc.communicate()


def own_bus() -> list[str]:
    """python-can's flags of a udp_multicast group of the test's own (parallel runs do not hear each
    other)."""
    rnd = np.random.default_rng()
    group = f"239.255.{rnd.integers(1, 255)}.{rnd.integers(1, 255)}"
    return ["-i", "udp_multicast", "-c", group, "--bus-kwargs", f"port={rnd.integers(20_000, 60_000)}",
            "hop_limit=0"]


def run_with_external_acd(out: Path, *sets: str, during=None):
    """`railhil run acd_anticollision --realtime --external ACD` with the stand-in device started on what
    the run announces; `during(address, keys)` runs beside it.  (run's exit code, stdout, stderr, the
    stand-in's stdout)."""
    bus = own_bus()
    run = subprocess.Popen([sys.executable, "-m", "hil", "run", "acd_anticollision", "--realtime",
                            "--external", "ACD", *[a for s in sets for a in ("--set", s)], "--out", str(out),
                            "-q", *bus],
                           cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           start_new_session=True)
    device = None
    err = Lines(run.stderr)
    try:
        centre = err.until(r"control centre on (\S+) .* key in (\S+):")
        pty = err.until(r"GPS line: .* on (\S+) \(")
        err.until(r"external ACD: not simulated")
        address, keys = centre.group(1), centre.group(2)
        device = subprocess.Popen(
            [sys.executable, "-m", "hil", "node", "ACD", "acd_anticollision", *bus[:4],
             "--set", "acd.radio_link=tcp", "--set", f"acd.control_centre={address}",
             "--set", f"acd.control_centre_keys={keys}", "--set", f"acd.gps.port={pty.group(1)}",
             "--set", "realtime.scheduling=normal",      # the device, not the bench: no real-time priority
             *[a for s in sets for a in ("--set", s)], "--until-idle", "3", *bus[4:]],
            cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
        if during is not None:
            during(address, keys)
        out_text = run.stdout.read()                    # the run's summary, once it ended
        run.wait(timeout=300)
        err_text = err.rest(run.stderr)
        device_out, device_err = device.communicate(timeout=60)
    finally:
        for proc in (run, device):
            if proc is not None and proc.poll() is None:
                stop(proc)
    assert device.returncode == 0, device_err + err_text
    return run.returncode, out_text, err_text, device_out


def test_the_run_serves_an_external_acd_its_gps_line_and_its_radio(tmp_path):
    out = tmp_path / "run"
    code, text, err, device = run_with_external_acd(out, "max_duration_s=15")
    assert code in (0, 1), err                            # 1: real time not held on this machine
    meta = json.loads((out / "run.json").read_text())
    kpis = json.loads((out / "kpis.json").read_text())
    acd = kpis["realtime"]["conduct"]["ACD"]
    assert acd["external"] and acd["timing"] == "PASS" and acd["protection_clean"], acd
    line = meta["node_stats"]["PLANT"]["gps_line"]         # what the plant wrote onto the device's line
    assert line["fixes_written"] >= 5 and line["bytes_dropped"] == 0, line
    trains = {r["train"] for r in stored_reports(out / "centre.sqlite")}
    assert trains == {"U1", "U2"}                          # the bench reported the leader, the device itself
    assert "authenticated (keys of 2 trains), 0 refused" in meta["realtime"]["control_centre"]["summary"]
    assert "receivers' checks: nothing reported" in device, device


def forge(address: str, stop_event: threading.Event, answers: list[str]) -> None:
    """Every second until `stop_event`: a client without U1's key says hello as U1 and reports U1 5 km
    ahead of the follower; what the centre answers is kept."""
    host, port = address.rsplit(":", 1)
    seq = 0
    while not stop_event.wait(1.0):
        try:
            with socket.create_connection((host, int(port)), timeout=5) as sock:
                f = sock.makefile("rw", encoding="utf-8", newline="\n")
                f.readline()                                    # the challenge
                for msg in ({"type": "hello", "train": "U1"},
                            {"type": "report", "train": "U1", "session": "forged", "seq": seq, "t": None,
                             "lat": 57.2, "lon": 24.4, "speed": 0.0, "section": 7, "length": 150.0,
                             "heading": None}):
                    f.write(json.dumps(msg) + "\n")
                    f.flush()
                    answers.append(f.readline().strip())
                seq += 1
        except OSError:
            continue                                            # the centre not there (yet, any more)


@pytest.mark.slow
def test_the_follower_stops_behind_the_leader_and_a_forged_report_does_not_release_it(tmp_path):
    out = tmp_path / "run"
    answers: list[str] = []
    stop_forging = threading.Event()
    forger: list[threading.Thread] = []

    def during(address: str, keys: str) -> None:
        forger.append(threading.Thread(target=forge, args=(address, stop_forging, answers), daemon=True))
        forger[0].start()

    try:
        code, text, err, _ = run_with_external_acd(out, during=during)
    finally:
        stop_forging.set()
        for t in forger:
            t.join(timeout=10)
    assert code in (0, 1), err
    kpis = json.loads((out / "kpis.json").read_text())
    k = kpis["anticollision"]
    assert not k["collision"] and k["min_gap_m"] > 0 and k["applications"] >= 1, k
    assert kpis["realtime"]["conduct"]["ACD"]["timing"] == "PASS"
    summary = json.loads((out / "run.json").read_text())["realtime"]["control_centre"]["summary"]
    refused = int(re.search(r"(\d+) refused", summary).group(1))
    assert refused >= 20 and answers and all('"error"' in a for a in answers), (summary, answers[:4])
    # the follower kept braking: once it applied, its request stayed on until the train stood
    db, codec = loaded_dbc(ROOT / "dbc" / "train_brake.dbc")
    table = DecodedTrace.read(out / "trace.blf", db, codec).table("ACD_BRAKE_REQ")
    t = table.t - json.loads((out / "run.json").read_text())["trace_t0_s"]
    truth = np.genfromtxt(out / "truth.csv", delimiter=",", names=True)
    req = table.columns["Request"]
    first = int(np.flatnonzero(req > 0)[0])
    stood = truth["t_s"][np.flatnonzero((truth["t_s"] > t[first]) & (truth["v_mps_1"] < 0.01))[0]]
    assert (req[first:][t[first:] <= stood] > 0).all(), "the ACD released before the train stood"


# --- a box on its own CAN matrix in the ACD's place (--device ACD=FILE) ------------------------------------

BOX_DBC = '''VERSION ""
NS_ :
BS_:
BU_: BOX
BO_ 768 BOX_BRAKE: 8 BOX
 SG_ Request : 0|2@1+ (1,0) [0|2] "" Vector__XXX
 SG_ Decel : 8|16@1+ (0.001,0) [0|10] "m/s^2" Vector__XXX
 SG_ Distance : 24|24@1+ (0.01,0) [0|167772] "m" Vector__XXX
BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 100;
BA_ "GenMsgCycleTime" BO_ 768 100;
VAL_ 768 Request 0 "OFF" 1 "BRK" 2 "EMG" ;
'''

BOX_FILE = '''replaces = "ACD"
dbc = "box.dbc"
node = "BOX"
bus = {bus}

[send.ACD_BRAKE_REQ]
Request = {{ from = "BOX_BRAKE.Request", choices = {{ OFF = "NONE", BRK = "SERVICE", EMG = "EMERGENCY" }} }}
RequestedDecel = {{ from = "BOX_BRAKE.Decel" }}

[send.ACD_STATUS]
DistanceToObstacle = {{ from = "BOX_BRAKE.Distance" }}
'''


def box(port: str, bus: dict, stop_event: threading.Event, sentences: list[bytes]) -> None:
    """The box: reads the GPS line the run serves (pyserial) and sends BOX_BRAKE every 100 ms on its own
    bus (no brake request, a distance of 1 km), until `stop_event`."""
    import can
    import cantools
    import serial

    msg = cantools.database.load_string(BOX_DBC, "dbc").get_message_by_name("BOX_BRAKE")
    data = msg.encode({"Request": "OFF", "Decel": 0.0, "Distance": 1000.0})
    pending = b""
    with serial.Serial(port, timeout=0) as line, can.Bus(**bus) as can_bus:
        while not stop_event.wait(0.1):
            can_bus.send(can.Message(arbitration_id=msg.frame_id, data=data, is_extended_id=False))
            try:
                pending += line.read(4096)
            except serial.SerialException:          # the run ended and closed its end of the line
                break
            *done, pending = pending.split(b"\n")
            sentences.extend(s.strip() for s in done)


def test_a_device_in_the_acds_place_gets_the_gps_line_and_the_centre(tmp_path):
    rnd = np.random.default_rng()
    bus = {"interface": "udp_multicast", "channel": f"239.255.{rnd.integers(1, 255)}.{rnd.integers(1, 255)}",
           "port": int(rnd.integers(20_000, 60_000)), "hop_limit": 0}
    (tmp_path / "box.dbc").write_text(BOX_DBC)
    inline = "{ " + ", ".join(f"{k} = {json.dumps(v)}" for k, v in bus.items()) + " }"
    (tmp_path / "box.toml").write_text(BOX_FILE.format(bus=inline))
    out = tmp_path / "run"
    run = subprocess.Popen([sys.executable, "-m", "hil", "run", "acd_anticollision", "--realtime",
                            "--device", str(tmp_path / "box.toml"), "--set", "max_duration_s=6", "--out",
                            str(out), "-q", *own_bus()],
                           cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           start_new_session=True)
    sentences: list[bytes] = []
    done = threading.Event()
    device = None
    err = Lines(run.stderr)
    try:
        err.until(r"control centre on (\S+) .* key in (\S+):")
        pty = err.until(r"GPS line: .* on (\S+) \(").group(1)
        device = threading.Thread(target=box, args=(pty, bus, done, sentences), daemon=True)
        device.start()
        text = run.stdout.read()
        run.wait(timeout=300)
        err_text = err.rest(run.stderr)
    finally:
        done.set()
        if device is not None:
            device.join(timeout=10)
        if run.poll() is None:
            stop(run)
    assert run.returncode in (0, 1), err_text + text       # 1: real time not held on this machine
    assert "device BOX (box.dbc) in ACD's place" in err_text
    line = json.loads((out / "run.json").read_text())["node_stats"]["PLANT"]["gps_line"]
    assert line["fixes_written"] >= 5 and line["bytes_dropped"] == 0, line
    assert sum(s.startswith(b"$GPRMC") or s.startswith(b"$GNRMC") for s in sentences) >= 3, sentences[:4]
    d = json.loads((out / "kpis.json").read_text())["devices"]["ACD"]
    assert d["device"]["timing"] == "PASS" and d["bench"]["timing"] == "PASS", d
