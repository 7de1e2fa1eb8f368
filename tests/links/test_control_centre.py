"""The control centre (hil.links.control_centre), seed 002 steps 3–6: real TCP sockets on 127.0.0.1 (port 0),
a real SQLite file, the server in-process and as its own OS process killed and restarted; its
authentication (a MAC per message, a key per train) against forgers on raw sockets and a fake centre.
Waits are on events with timeouts (TrainClient.wait_for), never sleeps."""

import argparse
import asyncio
import json
import re
import secrets
import shutil
import signal
import socket
import sqlite3
import stat
import subprocess
import sys
from pathlib import Path

import pytest

import hil.links.control_centre as centre_module
from hil.cli import control_centre as cli
from hil.cli.main import main as railhil_main
from hil.errors import ScenarioError
from hil.links.control_centre import (
    ControlCentre,
    ControlCentreError,
    LinkConfig,
    TrainClient,
    mac_input,
    mac_matches,
    mac_of,
    main,
    make_keys,
    read_keys,
    signed,
    stored_reports,
)
from hil.scenario import load_scenario
from hil.studies.anticollision.nodes import World
from plant_sim import geo

ROOT = Path(__file__).resolve().parents[2]
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


async def clients(port, *names, keys=None):
    out = [TrainClient(n, "127.0.0.1", port, resend_after_s=0.3, key=None if keys is None else keys.get(n))
           for n in names]
    for c in out:
        await c.start()
    return out


def encoded(msg: dict) -> bytes:
    return json.dumps(msg, separators=(",", ":")).encode() + b"\n"


def a_report(train: str, d_m: float, session: str = "s1", seq: int = 0, section: int = 7) -> dict:
    lat, lon = at(d_m)
    return {"type": "report", "train": train, "session": session, "seq": seq, "t": None, "lat": lat,
            "lon": lon, "speed": 10.0, "section": section, "length": 180.0, "heading": AZ}


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

async def start_process(db: Path, port: int, *more: str) -> tuple[asyncio.subprocess.Process, int]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "hil.links.control_centre", "--db", str(db), "--port", str(port), *more,
        cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    line = (await asyncio.wait_for(proc.stdout.readline(), WAIT_S)).decode()
    m = re.fullmatch(r"listening on 127\.0\.0\.1:(\d+) \(database [^,]+(, keys .+: \d+ trains)?\)\n", line)
    assert m, line + (await proc.stderr.read()).decode()
    assert bool(m.group(2)) == ("--keys" in more), line
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
    # without --keys: open as before, and it says so when it starts and in its summary
    assert "NOT authenticated" in out
    assert err.startswith("warning: no --keys: reports are not authenticated") and err.count("\n") == 1
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
        challenge = json.loads(await asyncio.wait_for(reader.readline(), WAIT_S))
        assert challenge["type"] == "challenge" and "mac" not in challenge
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
    assert "mac" not in answers[4] and stats.refused == {}        # open: nothing signed, nothing refused


def test_cli_subcommand_parses_into_the_same_server_options(tmp_path):
    parser = argparse.ArgumentParser(prog="railhil")
    sub = parser.add_subparsers(dest="command")
    cli.add_subparser(sub)
    args = parser.parse_args(["control-centre", "--db", str(tmp_path / "cc.sqlite"), "--port", "0",
                              "--latency-ms", "20", "--loss", "0.1"])
    assert args.func is cli.run and (args.port, args.latency_ms, args.loss) == (0, 20.0, 0.1)
    help_text = sub.choices["control-centre"].format_help()
    for opt in ("--db", "--port", "--host", "--latency-ms", "--loss", "--seed", "--forget-after-s", "--keys",
                "--make-keys"):
        assert opt in help_text
    args = parser.parse_args(["control-centre", "--make-keys", "k.toml", "U1", "U2"])
    assert args.make_keys == ["k.toml", "U1", "U2"] and args.db is None


def test_link_config_is_checked():
    with pytest.raises(ControlCentreError, match="loss"):
        LinkConfig(loss=1.0)
    with pytest.raises(ControlCentreError, match="latency"):
        LinkConfig(latency_s=float("nan"))


# --- authentication: a MAC per message, a key per train ---------------------------------------------------

@pytest.fixture
def train_keys():
    return {"U1": secrets.token_bytes(32), "U2": secrets.token_bytes(32), "U3": secrets.token_bytes(32)}


class Raw:
    """A hand-made client on a raw socket, line by line: what a forger, or a device written in C, sends."""

    async def open(self, port: int) -> "Raw":
        self.reader, self.writer = await asyncio.open_connection("127.0.0.1", port)
        challenge = await self.next()
        assert challenge["type"] == "challenge" and re.fullmatch(r"[0-9a-f]{32}", challenge["nonce"])
        self.nonce = challenge["nonce"]
        return self

    async def next(self) -> dict:
        return json.loads(await asyncio.wait_for(self.reader.readline(), WAIT_S))

    async def ask(self, msg: dict | bytes, until: str | None = None) -> dict:
        """Send one line; the answer (an error, or the first message of type `until`)."""
        self.writer.write(msg if isinstance(msg, bytes) else encoded(msg))
        while True:
            answer = await self.next()
            if until is None or answer["type"] in (until, "error"):
                return answer

    def close(self) -> None:
        self.writer.close()


def test_the_documented_mac_example_holds():
    """The module docstring's worked example, for a device writer in another language."""
    rep = {"type": "report", "train": "U1", "session": "s1", "seq": 0, "t": 12.5, "lat": 56.95, "lon": 24.105,
           "speed": 12.5, "section": 7, "length": 180.0, "heading": 63.0}
    assert mac_input({**rep, "mac": "anything"}) == (
        b'{"heading":63.0,"lat":56.95,"length":180.0,"lon":24.105,"section":7,"seq":0,"session":"s1",'
        b'"speed":12.5,"t":12.5,"train":"U1","type":"report"}')
    mac = mac_of(bytes(range(32)), rep)
    assert mac == "5bdb3dbdcabf1093f711da0a1c08615aa9c99a91fee700d332a46e59dcd24d01"
    assert mac in centre_module.__doc__
    assert mac_matches(bytes(range(32)), {**rep, "mac": mac})
    assert not mac_matches(bytes(range(32)), {**rep, "seq": 1, "mac": mac})


def test_signed_trains_are_paired_and_relayed_as_before(tmp_path, train_keys):
    async def scenario():
        cc = ControlCentre(tmp_path / "cc.sqlite", keys=train_keys)
        _, port = await cc.start("127.0.0.1", 0)
        u1, u2 = await clients(port, "U1", "U2", keys=train_keys)
        try:
            report(u1, 2000.0)
            report(u2, 0.0)
            await u2.wait_for(lambda c: c.leader == "U1", WAIT_S)
            await u1.wait_for(lambda c: c.follower == "U2", WAIT_S)
            seqs = [report(u1, 2000.0 + 10.0 * k, t=float(k)) for k in range(1, 4)]
            await u2.wait_for(lambda c: any(r["seq"] == seqs[-1] for r in c.leader_reports), WAIT_S)
            for c in (u1, u2):
                await c.wait_for(all_acked, WAIT_S)
        finally:
            for c in (u1, u2):
                await c.close()
            await cc.stop()
        return u1, u2, cc.stats

    u1, u2, stats = run(scenario())
    assert stats.reports_stored == 5 and stats.relayed >= 3 and stats.refused == {} and stats.bad_lines == 0
    assert u1.dropped == {} and u2.dropped == {} and not u1.errors and not u2.errors
    last = u2.leader_reports[-1]
    assert (last["train"], (last["lat"], last["lon"]), last["t"]) == ("U1", at(2030.0), 3.0)
    assert not {"mac", "nonce", "dseq"} & set(last)                # the transport's fields stay in the client
    assert "authenticated (keys of 3 trains), 0 refused;" in stats.summary()


def test_a_client_without_u1s_key_cannot_put_u1_5_km_ahead_of_its_follower(tmp_path, train_keys):
    """The attack the keys are for: a forged report of the leader far ahead would let the follower's
    ACD release its brake.  Refused, counted, not stored, not relayed."""
    async def scenario():
        cc = ControlCentre(tmp_path / "cc.sqlite", keys=train_keys)
        _, port = await cc.start("127.0.0.1", 0)
        u1, u2 = await clients(port, "U1", "U2", keys=train_keys)
        forgers = [TrainClient("U1", "127.0.0.1", port, resend_after_s=0.3),          # no key
                   TrainClient("U1", "127.0.0.1", port, resend_after_s=0.3,          # a wrong key
                               key=secrets.token_bytes(32))]
        try:
            report(u1, 2000.0)
            report(u2, 0.0)
            await u2.wait_for(lambda c: c.leader == "U1" and c.leader_reports, WAIT_S)
            for f in forgers:
                await f.start()
                report(f, 5000.0, speed=30.0)                    # U1 5 km ahead of U2, running away
                await f.wait_for(lambda c: len(c.errors) >= 2, WAIT_S)     # hello refused, then the report
            seq = report(u1, 2010.0)                             # the true U1, after the forgeries
            await u2.wait_for(lambda c: any(r["seq"] == seq for r in c.leader_reports), WAIT_S)
        finally:
            for c in (u1, u2, *forgers):
                await c.close()
            await cc.stop()
        return u2, forgers, cc.stats

    u2, (no_key, wrong_key), stats = run(scenario())
    true_positions = {at(2000.0), at(2010.0)}
    assert {(r["lat"], r["lon"]) for r in u2.leader_reports} <= true_positions
    assert (u2.leader_reports[-1]["lat"], u2.leader_reports[-1]["lon"]) == at(2010.0)
    assert u2.leader == "U1"
    rows = stored_reports(tmp_path / "cc.sqlite")
    assert {(r["lat"], r["lon"]) for r in rows if r["train"] == "U1"} == true_positions
    assert stats.reports_stored == 3
    assert "(no mac)" in no_key.errors[0] and "(bad mac)" in wrong_key.errors[0]
    assert all("(no hello)" in e for e in no_key.errors[1:] + wrong_key.errors[1:])
    assert stats.refused["no mac"] == 1 and stats.refused["bad mac"] == 1 and stats.refused["no hello"] >= 2
    assert no_key.leader is None and not no_key.leader_reports and not wrong_key.leader_reports


def test_each_refusal_is_answered_with_its_reason_and_counted(tmp_path, train_keys):
    k1, k2 = train_keys["U1"], train_keys["U2"]

    async def scenario():
        cc = ControlCentre(tmp_path / "cc.sqlite", keys={"U1": k1, "U2": k2})
        _, port = await cc.start("127.0.0.1", 0)
        a, b = await Raw().open(port), await Raw().open(port)
        try:
            unsigned = {"type": "hello", "train": "U2", "nonce": a.nonce}
            hello = signed(k2, unsigned)
            good = signed(k2, a_report("U2", 100.0))
            got = {
                "unknown train": await a.ask(signed(k2, {**unsigned, "train": "U9"})),
                "no mac (hello)": await a.ask(unsigned),
                "bad mac (hello)": await a.ask(signed(k1, unsigned)),               # U1's key
                "no hello": await a.ask(good),
                "pair": await a.ask(hello),
                "stale nonce (second hello)": await a.ask(hello),
                "no mac (report)": await a.ask(a_report("U2", 100.0, seq=1)),
                "bad mac (report altered)": await a.ask({**signed(k2, a_report("U2", 100.0, seq=1)),
                                                         "lat": at(5000.0)[0]}),
                "wrong train": await a.ask(signed(k1, a_report("U1", 5000.0))),    # U1's MAC, U2's link
                "ack": await a.ask(good, until="ack"),
                "bad mac (new session)": await a.ask({**good, "session": "s2"}),   # replay, other session
                "ack (verbatim replay)": await a.ask(good, until="ack"),           # a duplicate, ignored
                "stale nonce (replayed hello)": await b.ask(hello),                # a's hello on b
                "no hello (b)": await b.ask(signed(k2, a_report("U2", 100.0, seq=2))),
            }
        finally:
            a.close()
            b.close()
            await cc.stop()
        return got, cc.stats

    got, stats = run(scenario())
    for what, answer in got.items():
        if what.startswith(("pair", "ack")):
            assert answer["type"] == what.split()[0], (what, answer)
            assert mac_matches(k2, answer) and answer["nonce"] != ""        # signed for U2
        else:
            assert answer["type"] == "error" and "\n" not in answer["error"], (what, answer)
            assert f"refused ({what.split(' (')[0]})" in answer["error"], (what, answer["error"])
    assert "this connection said hello as 'U2'" in got["wrong train"]["error"]
    assert stats.refused == {"unknown train": 1, "no mac": 2, "bad mac": 3, "no hello": 2, "stale nonce": 2,
                             "wrong train": 1}
    assert "11 refused (3 bad mac, 2 no hello, 2 no mac, 2 stale nonce, 1 unknown train, 1 wrong train)" \
        in stats.summary()
    assert stats.reports_stored == 1 and stats.duplicates == 1 and stats.bad_lines == 0
    assert [(r["train"], r["session"], r["seq"]) for r in stored_reports(tmp_path / "cc.sqlite")] == \
        [("U2", "s1", 0)]


def test_the_train_drops_forged_and_replayed_messages_from_the_centre_side(train_keys):
    """A man in the middle, here a fake centre: what it sends unsigned, signed with another key, for
    another connection, or again, is dropped and counted; a forged leader_report 5 km ahead or an old
    "no leader" pair cannot release the follower."""
    key, nonce = train_keys["U2"], "ab" * 16
    lat, lon = at(2000.0)
    true = {"type": "leader_report", "train": "U1", "session": "s", "seq": 0, "t": 1.0, "lat": lat,
            "lon": lon, "speed": 10.0, "section": 7, "length": 180.0, "heading": AZ, "age": 0.0}
    far = {**true, "seq": 1, "lat": at(7000.0)[0], "lon": at(7000.0)[1], "speed": 30.0}

    def ok(msg, dseq):
        return signed(key, {**msg, "nonce": nonce, "dseq": dseq})

    no_leader = {"type": "pair", "train": "U2", "section": 7, "leader": None, "follower": None}
    sent = [far,                                                        # no mac
            signed(train_keys["U3"], {**far, "nonce": nonce, "dseq": 0}),   # bad mac: U3's key
            signed(key, {**far, "nonce": "cd" * 16, "dseq": 0}),        # stale nonce: another connection's
            ok(no_leader, 0),                                           # taken (the pair at hello)
            ok(true, 1),                                                # taken
            ok(true, 1),                                                # replayed verbatim
            ok(no_leader, 0),                                           # replayed: an old "no leader"
            {"type": "ack", "session": "?", "seq": 0, "leader": None, "follower": None},   # no mac
            ok({**no_leader, "leader": "U1"}, 2)]                       # taken
    hellos = []

    async def scenario():
        done = asyncio.Event()

        async def fake_centre(reader, writer):
            writer.write(encoded({"type": "challenge", "nonce": nonce}))
            hellos.append(json.loads(await reader.readline()))
            for msg in sent:
                writer.write(encoded(msg))
            await done.wait()
            writer.close()

        server = await asyncio.start_server(fake_centre, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        (u2,) = await clients(port, "U2", keys=train_keys)
        try:
            report(u2, 0.0)
            await u2.wait_for(lambda c: c.leader == "U1", WAIT_S)
        finally:
            done.set()
            await u2.close()
            server.close()
            await server.wait_closed()
        return u2

    u2 = run(scenario())
    assert u2.dropped == {"no mac": 2, "bad mac": 1, "stale nonce": 1, "replayed": 2}
    assert u2.leader_reports == [true]
    assert u2.unacked and not u2.acked                      # the forged ack did not stop the resending
    hello = hellos[0]                                       # signed over the fake centre's challenge
    assert (hello["type"], hello["train"], hello["nonce"]) == ("hello", "U2", nonce)
    assert mac_matches(key, hello)


def test_the_scenario_keys_sign_the_real_time_radio_of_both_trains(tmp_path):
    """[acd] control_centre_keys, beside the scenario file: the World's TcpCentre signs U1's and U2's
    reports for a centre run with --keys (its own process), and takes its signed pair and relays."""
    keys = make_keys(tmp_path / "keys.toml", ["U1", "U2"])
    scen = tmp_path / "acd.toml"
    shutil.copy(ROOT / "scenarios" / "acd_anticollision.toml", scen)

    async def scenario():
        proc, port = await start_process(tmp_path / "cc.sqlite", 0, "--keys", str(tmp_path / "keys.toml"))
        try:
            spec = load_scenario(scen, sets=[f'acd.control_centre="127.0.0.1:{port}"',
                                             'acd.control_centre_keys="keys.toml"']).acd
            assert spec.control_centre_keys == str(tmp_path / "keys.toml")
            world = World(spec, seed=2)
            try:
                world.step(0, 100.0, 20.0)                  # opens the link; both trains report
                clients_ = world.tcp.clients
                assert {t: c.key for t, c in clients_.items()} == keys
                await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(
                    clients_["U2"].wait_for(lambda c: c.leader == "U1" and c.leader_reports, WAIT_S),
                    world.tcp.loop))
                world.step(100_000, 102.0, 20.0)
                assert world.leader.leader_id == 1 and world.leader.report["train"] == "U1"
                assert all(not c.dropped for c in clients_.values())
            finally:
                if world.tcp is not None:
                    world.tcp.close()
            proc.send_signal(signal.SIGTERM)
            out, err = await asyncio.wait_for(proc.communicate(), WAIT_S)
            return out.decode(), err.decode()
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()

    out, err = run(scenario())
    assert "authenticated (keys of 2 trains), 0 refused;" in out and "warning" not in err


def test_a_scenario_key_file_without_a_trains_key_is_one_line_at_load(tmp_path):
    make_keys(tmp_path / "keys.toml", ["U2", "U7"])
    scen = tmp_path / "acd.toml"
    shutil.copy(ROOT / "scenarios" / "acd_anticollision.toml", scen)
    sets = ['acd.control_centre="127.0.0.1:7007"']
    with pytest.raises(ScenarioError) as info:
        load_scenario(scen, sets=[*sets, 'acd.control_centre_keys="keys.toml"'])
    text = str(info.value)
    assert "\n" not in text and str(tmp_path / "keys.toml") in text and "no key for train U1" in text
    with pytest.raises(ScenarioError, match="no such file"):
        load_scenario(scen, sets=[*sets, 'acd.control_centre_keys="nokeys.toml"'])
    # lockstep (no control centre) does not read the file
    assert load_scenario(scen, sets=['acd.control_centre_keys="nokeys.toml"']).acd.control_centre is None


def test_a_centre_process_with_keys_says_so_and_counts_its_refusals(tmp_path):
    keys = make_keys(tmp_path / "keys.toml", ["U1", "U2"])

    async def scenario():
        proc, port = await start_process(tmp_path / "cc.sqlite", 0, "--keys", str(tmp_path / "keys.toml"))
        u1, impostor = (TrainClient("U1", "127.0.0.1", port, key=keys["U1"]),
                        TrainClient("U2", "127.0.0.1", port, resend_after_s=60.0))
        try:
            for c in (u1, impostor):
                await c.start()
            report(u1, 2000.0)
            report(impostor, 0.0)
            await u1.wait_for(all_acked, WAIT_S)
            await impostor.wait_for(lambda c: len(c.errors) >= 2, WAIT_S)
            proc.send_signal(signal.SIGTERM)
            out, err = await asyncio.wait_for(proc.communicate(), WAIT_S)
            return proc.returncode, out.decode(), err.decode()
        finally:
            for c in (u1, impostor):
                await c.close()
            if proc.returncode is None:
                proc.kill()
                await proc.wait()

    code, out, err = run(scenario())
    assert code == 0 and err == "", err
    assert re.search(r"stopped: 1 reports stored, .*; authenticated \(keys of 2 trains\), 2 refused "
                     r"\(1 no hello, 1 no mac\);", out), out


# --- key files: --make-keys and --keys ---------------------------------------------------------------------

def test_make_keys_writes_a_private_file_once(tmp_path, capsys):
    path = tmp_path / "keys.toml"
    assert main(["--make-keys", str(path), "U1", "U2"]) == 0
    assert str(path) in capsys.readouterr().out
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    keys = read_keys(path)
    assert set(keys) == {"U1", "U2"} and all(len(k) == 32 for k in keys.values()) and keys["U1"] != keys["U2"]
    assert "exists" in _error_of(capsys, ["--make-keys", str(path), "U3"])      # never overwritten
    assert read_keys(path) == keys
    assert "name the trains" in _error_of(capsys, ["--make-keys", str(tmp_path / "k2.toml")])
    assert "'U1' named twice" in _error_of(capsys, ["--make-keys", str(tmp_path / "k3.toml"), "U1", "U1"])
    assert not (tmp_path / "k2.toml").exists() and not (tmp_path / "k3.toml").exists()
    # railhil control-centre: the same, through the one entry point; an odd name is quoted in the TOML
    assert railhil_main(["control-centre", "--make-keys", str(tmp_path / "k4.toml"), "train 9"]) == 0
    assert set(read_keys(tmp_path / "k4.toml")) == {"train 9"}


def test_bad_key_files_give_one_line_naming_the_file_and_the_key(tmp_path, capsys):
    db = str(tmp_path / "cc.sqlite")
    secret = "ab" * 20
    for name, text, needle in (
            ("missing.toml", None, "no such file"),
            ("short.toml", f'[trains]\nU1 = "{secret}"\n', "trains.U1: expected a key of 32 bytes as 64 hex "
                                                           "digits, got 40 characters"),
            ("number.toml", "[trains]\nU1 = 5\n", "trains.U1"),
            ("broken.toml", "[trains\n", "not valid TOML"),
            ("other.toml", 'key = "00"\n', "unknown entry 'key'"),
            ("empty.toml", "[trains]\n", "at least one train")):
        path = tmp_path / name
        if text is not None:
            path.write_text(text)
        err = _error_of(capsys, ["--db", db, "--port", "0", "--keys", str(path)])
        assert f"control-centre key file {path} (from --keys)" in err and needle in err, err
        assert secret not in err                                    # a key is never printed
    assert "--db FILE: required" in _error_of(capsys, ["--port", "0"])
    with pytest.raises(ControlCentreError, match="32 bytes"):
        TrainClient("U1", "127.0.0.1", 1, key=b"short")
    with pytest.raises(ControlCentreError, match="U1's key"):
        ControlCentre(tmp_path / "cc.sqlite", keys={"U1": b"short"})
