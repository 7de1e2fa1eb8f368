"""The control centre (hil.links.control_centre), seed 002 steps 3–6: real TCP sockets on 127.0.0.1 (port 0),
a real SQLite file, the server in-process and as its own OS process killed and restarted.  Waits are on
events with timeouts (TrainClient.wait_for), never sleeps."""

import argparse
import asyncio
import json
import re
import signal
import socket
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from hil.cli import control_centre as cli
from hil.links.control_centre import (
    ControlCentre,
    ControlCentreError,
    LinkConfig,
    TrainClient,
    main,
    stored_reports,
)
from plant_sim import geo

ROOT = Path(__file__).resolve().parents[1]
LAT0, LON0, AZ = 56.9496, 24.1052, 63.0
WAIT_S = 20.0                                  # generous: a loaded 2-core machine


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 60.0))


def at(d_m: float) -> tuple[float, float]:
    lat, lon, _ = geo.destination(LAT0, LON0, AZ, d_m)
    return lat, lon


def report(client: TrainClient, d_m: float, speed: float = 10.0, section: int = 7, **kw) -> int:
    lat, lon = at(d_m)
    return client.report(lat, lon, speed, section, 180.0, heading=kw.pop("heading", AZ), **kw)


def all_acked(c: TrainClient) -> bool:
    return not c.unacked and len(c.acked) == c.next_seq


def keys(rows, train):
    return sorted((r["session"], r["seq"]) for r in rows if r["train"] == train)


async def clients(port, *names):
    out = [TrainClient(n, "127.0.0.1", port, resend_after_s=0.3) for n in names]
    for c in out:
        await c.start()
    return out


# --- steps 3–6 ----------------------------------------------------------------------------------------

def test_two_trains_learn_each_other_and_the_follower_gets_the_leaders_reports(tmp_path):
    async def scenario():
        cc = ControlCentre(tmp_path / "cc.sqlite")
        _, port = await cc.start("127.0.0.1", 0)
        u1, u2, u3 = await clients(port, "U1", "U2", "U3")
        try:
            report(u1, 2000.0)                     # U1 ahead, U2 behind, both on section 7
            report(u2, 0.0)
            report(u3, 500.0, section=8)           # alone on section 8
            await u2.wait_for(lambda c: c.leader == "U1", WAIT_S)
            await u1.wait_for(lambda c: c.follower == "U2", WAIT_S)
            assert (u1.leader, u2.follower) == (None, None)
            assert (u3.leader, u3.follower) == (None, None)
            seqs = [report(u1, 2000.0 + 10.0 * k, t=float(k)) for k in range(1, 6)]
            await u2.wait_for(lambda c: any(r["seq"] == seqs[-1] for r in c.leader_reports), WAIT_S)
            got = {r["seq"]: r for r in u2.leader_reports if r["train"] == "U1"}
            assert set(seqs) <= set(got)
            lat, lon = at(2050.0)
            last = got[seqs[-1]]
            assert (last["lat"], last["lon"], last["speed"], last["section"], last["length"], last["t"]) == \
                (lat, lon, 10.0, 7, 180.0, 5.0)
            assert all(r["age"] >= 0.0 for r in u2.leader_reports)
            assert not u1.leader_reports and not u3.leader_reports
            # U2 overtakes on another track of the section: the roles swap
            report(u2, 3000.0)
            await u1.wait_for(lambda c: c.leader == "U2", WAIT_S)
            await u2.wait_for(lambda c: c.follower == "U1" and c.leader is None, WAIT_S)
            for c in (u1, u2, u3):
                await c.wait_for(all_acked, WAIT_S)
        finally:
            for c in (u1, u2, u3):
                await c.close()
            await cc.stop()
        return cc.stats

    stats = run(scenario())
    assert stats.reports_stored == 9 and stats.duplicates == 0 and stats.bad_lines == 0
    assert stats.relayed >= 5
    rows = stored_reports(tmp_path / "cc.sqlite")
    assert [r["train"] for r in rows].count("U1") == 6


def test_restart_of_the_control_centre_loses_no_report(tmp_path):
    """Reports made before, during and after a restart (same SQLite file, same port) are all stored,
    each once; pairing and relaying resume from the database."""
    db = tmp_path / "cc.sqlite"

    async def scenario():
        cc = ControlCentre(db)
        _, port = await cc.start("127.0.0.1", 0)
        u1, u2 = await clients(port, "U1", "U2")
        try:
            for k in range(20):
                report(u1, 3000.0 + k, t=float(k))
                report(u2, 1000.0 + k, t=float(k))
            await u2.wait_for(lambda c: c.leader == "U1" and len(c.acked) >= 5, WAIT_S)
            for k in range(20, 30):                 # in flight while the centre goes down
                report(u1, 3000.0 + k, t=float(k))
                report(u2, 1000.0 + k, t=float(k))
            await cc.stop()
            await u1.wait_for(lambda c: not c.connected, WAIT_S)
            await u2.wait_for(lambda c: not c.connected, WAIT_S)
            for k in range(30, 40):                 # made while it is down: queued by the trains
                report(u1, 3000.0 + k, t=float(k))
                report(u2, 1000.0 + k, t=float(k))
            before = len(u2.leader_reports)
            cc2 = ControlCentre(db)
            assert set(cc2.latest) == {"U1", "U2"}  # the latest reports came back from the file
            await cc2.start("127.0.0.1", port)
            try:
                for c in (u1, u2):
                    await c.wait_for(all_acked, WAIT_S)
                await u2.wait_for(lambda c: c.leader == "U1" and len(c.leader_reports) > before, WAIT_S)
                report(u1, 3100.0, t=99.0)
                await u2.wait_for(lambda c: c.leader_reports[-1]["t"] == 99.0, WAIT_S)
            finally:
                await cc2.stop()
        finally:
            for c in (u1, u2):
                await c.close()
        return u1, u2, cc2.stats

    u1, u2, stats2 = run(scenario())
    rows = stored_reports(db)
    for c in (u1, u2):
        assert keys(rows, c.train) == [(c.session, k) for k in range(c.next_seq)]    # all, each once
        assert c.connects >= 2
    assert len(rows) == 81
    # the second centre stored at least the 21 reports made while the first was down or after it
    assert stats2.reports_stored >= 21


def test_injected_latency_is_applied_and_counted(tmp_path):
    latency = 0.05

    async def scenario():
        cc = ControlCentre(tmp_path / "cc.sqlite", LinkConfig(latency_s=latency))
        _, port = await cc.start("127.0.0.1", 0)
        (u1,) = await clients(port, "U1")
        try:
            for k in range(10):
                report(u1, float(k))
            await u1.wait_for(all_acked, WAIT_S)
        finally:
            await u1.close()
            await cc.stop()
        return u1, cc.stats

    u1, stats = run(scenario())
    # report up, acknowledgement down: each leg waited at least the latency (lower bounds only)
    assert len(u1.rtt_s) == 10 and min(u1.rtt_s.values()) >= 2 * latency
    for leg in (stats.uplink, stats.downlink):
        assert leg.lost == 0 and leg.delivered >= 10 and leg.delay_min_s >= latency
    assert stats.uplink.delivered == stats.uplink.offered       # hello + 10 reports, none lost


def test_injected_loss_is_applied_counted_and_repaired_by_resending(tmp_path):
    async def scenario():
        cc = ControlCentre(tmp_path / "cc.sqlite", LinkConfig(loss=0.3, seed=7))
        _, port = await cc.start("127.0.0.1", 0)
        u1, u2 = await clients(port, "U1", "U2")
        try:
            for k in range(40):
                report(u1, 2000.0 + k)
                report(u2, float(k))
            for c in (u1, u2):
                await c.wait_for(all_acked, WAIT_S)
            await u2.wait_for(lambda c: c.leader == "U1", WAIT_S)
        finally:
            for c in (u1, u2):
                await c.close()
            await cc.stop()
        return u1, u2, cc.stats

    u1, u2, stats = run(scenario())
    rows = stored_reports(tmp_path / "cc.sqlite")
    assert len(rows) == 80 and stats.reports_stored == 80
    up, down = stats.uplink, stats.downlink
    assert up.lost > 0 and down.lost > 0
    assert up.lost + up.delivered <= up.offered and down.lost + down.delivered <= down.offered
    assert 0.15 < (up.lost + down.lost) / (up.offered + down.offered) < 0.45    # binomial, p = 0.3
    # the trains repaired the losses by resending: more lines than reports, duplicates recognised
    assert u1.sent_lines + u2.sent_lines > 80
    assert up.delivered - 2 >= 80                       # every report got through at least once


# --- the server as its own OS process ----------------------------------------------------------------

async def start_process(db: Path, port: int) -> tuple[asyncio.subprocess.Process, int]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hil.links.control_centre", "--db", str(db), "--port", str(port),
        cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    line = (await asyncio.wait_for(proc.stdout.readline(), WAIT_S)).decode()
    m = re.fullmatch(r"listening on 127\.0\.0\.1:(\d+) \(database .+\)\n", line)
    assert m, line + (await proc.stderr.read()).decode()
    return proc, int(m.group(1))


def test_server_process_killed_and_restarted_loses_no_report(tmp_path):
    db = tmp_path / "cc.sqlite"

    async def scenario():
        proc, port = await start_process(db, 0)
        u1, u2 = await clients(port, "U1", "U2")
        try:
            for k in range(15):
                report(u1, 3000.0 + k)
                report(u2, 1000.0 + k)
            await u2.wait_for(lambda c: c.leader == "U1" and len(c.acked) >= 3, WAIT_S)
            proc.send_signal(signal.SIGKILL)        # a crash, not a clean stop
            assert await asyncio.wait_for(proc.wait(), WAIT_S) == -signal.SIGKILL
            for k in range(15, 25):
                report(u1, 3000.0 + k)
                report(u2, 1000.0 + k)
            proc, port2 = await start_process(db, port)
            assert port2 == port
            for c in (u1, u2):
                await c.wait_for(all_acked, WAIT_S)
            await u2.wait_for(lambda c: c.leader == "U1", WAIT_S)
            proc.send_signal(signal.SIGTERM)        # clean stop: summary line, exit 0
            out, err = await asyncio.wait_for(proc.communicate(), WAIT_S)
            return u1, u2, proc.returncode, out.decode(), err.decode()
        finally:
            for c in (u1, u2):
                await c.close()
            if proc.returncode is None:
                proc.kill()
                await proc.wait()

    u1, u2, code, out, err = run(scenario())
    assert code == 0, err
    assert re.match(r"stopped: \d+ reports stored, \d+ duplicates", out), out
    rows = stored_reports(db)
    for c in (u1, u2):
        assert keys(rows, c.train) == [(c.session, k) for k in range(25)]
        assert c.connects >= 2


# --- bad input: one line, exit 2 ----------------------------------------------------------------------

def _error_of(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err
    return err


def test_bad_options_and_files_give_one_line_and_exit_2(tmp_path, capsys):
    assert "does not exist" in _error_of(capsys, ["--db", str(tmp_path / "no" / "cc.sqlite"), "--port", "0"])
    text = tmp_path / "notes.txt"
    text.write_text("not a database\n" * 200)
    assert "notes.txt" in _error_of(capsys, ["--db", str(text), "--port", "0"])
    other = tmp_path / "other.sqlite"
    with sqlite3.connect(other) as con:
        con.execute("CREATE TABLE t (x)")
    assert "not a railhil control-centre" in _error_of(capsys, ["--db", str(other), "--port", "0"])
    db = str(tmp_path / "cc.sqlite")
    assert "--port 70000" in _error_of(capsys, ["--db", db, "--port", "70000"])
    assert "--loss 1.5" in _error_of(capsys, ["--db", db, "--port", "0", "--loss", "1.5"])
    assert "--latency-ms -1" in _error_of(capsys, ["--db", db, "--port", "0", "--latency-ms", "-1"])
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert f"--port {port}" in _error_of(capsys, ["--db", db, "--port", str(port)])


def test_bad_input_as_a_process_has_no_traceback(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "hil.links.control_centre", "--db",
                           str(tmp_path / "x" / "y"),
                           "--port", "0"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "--db" in proc.stderr


def test_bad_protocol_lines_get_an_error_and_the_link_stays_up(tmp_path):
    async def scenario():
        cc = ControlCentre(tmp_path / "cc.sqlite")
        _, port = await cc.start("127.0.0.1", 0)
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        answers = []
        try:
            for line in (b"not json\n", b"[1, 2]\n", b'{"type": "dance"}\n',
                         b'{"type": "report", "train": "U9", "session": "s", "seq": 0, "lat": 95, '
                         b'"lon": 24, "speed": 1, "section": 7, "length": 100}\n',
                         b'{"type": "hello", "train": "U9"}\n'):
                writer.write(line)
                answers.append(json.loads(await asyncio.wait_for(reader.readline(), WAIT_S)))
        finally:
            writer.close()
            await cc.stop()
        return answers, cc.stats

    answers, stats = run(scenario())
    assert [a["type"] for a in answers] == ["error"] * 4 + ["pair"]
    assert "'lat'" in answers[3]["error"] and "[-90, 90]" in answers[3]["error"]
    assert "'type'" in answers[2]["error"]
    assert stats.bad_lines == 4 and stats.reports_stored == 0


def test_cli_subcommand_parses_into_the_same_server_options(tmp_path):
    parser = argparse.ArgumentParser(prog="railhil")
    sub = parser.add_subparsers(dest="command")
    cli.add_subparser(sub)
    args = parser.parse_args(["control-centre", "--db", str(tmp_path / "cc.sqlite"), "--port", "0",
                              "--latency-ms", "20", "--loss", "0.1"])
    assert args.func is cli.run and (args.port, args.latency_ms, args.loss) == (0, 20.0, 0.1)
    help_text = sub.choices["control-centre"].format_help()
    for opt in ("--db", "--port", "--host", "--latency-ms", "--loss", "--seed", "--forget-after-s"):
        assert opt in help_text


def test_link_config_is_checked():
    with pytest.raises(ControlCentreError, match="loss"):
        LinkConfig(loss=1.0)
    with pytest.raises(ControlCentreError, match="latency"):
        LinkConfig(latency_s=float("nan"))
