"""Across hosts: the plant (with the recorder and the probes) in one network namespace, every ECU in
another (`railhil node DESK,BCU,BECU1,...`), joined by a veth pair, the default scenario on udp_multicast
between them: the same verdicts as the run on one host.  Needs root (CAP_NET_ADMIN) and iproute2: skipped
with the reason where namespaces cannot be made."""

import json
import os
import shutil
import subprocess
import sys

import pytest
from conftest import ATTEMPTS, DEFAULT, ROOT, kill_all, realtime_held
from test_realtime import excused_unless_realtime_held

pytestmark = pytest.mark.realtime

ECUS = ["DESK", "BCU"] + [f"BECU{i}" for i in range(1, 7)]


def ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True)


@pytest.fixture
def two_hosts():
    """(namespace A, namespace B): two network namespaces joined by a veth pair, 10.199.0.1 and .2,
    multicast routed over the link; removed afterwards."""
    if shutil.which("ip") is None:
        pytest.skip("no iproute2 (`ip`) on this machine: cannot make network namespaces")
    tag = f"{os.getpid() % 100000}"
    a, b, va, vb = f"rh-a-{tag}", f"rh-b-{tag}", f"rha{tag}", f"rhb{tag}"
    made = ip("netns", "add", a)
    if made.returncode != 0:
        pytest.skip(f"cannot create a network namespace here (needs root / CAP_NET_ADMIN): "
                    f"{made.stderr.strip()}")
    try:
        ip("netns", "add", b)
        for step in (("link", "add", va, "type", "veth", "peer", "name", vb),
                     ("link", "set", va, "netns", a), ("link", "set", vb, "netns", b),
                     ("-n", a, "addr", "add", "10.199.0.1/24", "dev", va),
                     ("-n", b, "addr", "add", "10.199.0.2/24", "dev", vb),
                     ("-n", a, "link", "set", va, "up"), ("-n", b, "link", "set", vb, "up"),
                     ("-n", a, "link", "set", "lo", "up"), ("-n", b, "link", "set", "lo", "up"),
                     ("-n", a, "route", "add", "224.0.0.0/4", "dev", va),
                     ("-n", b, "route", "add", "224.0.0.0/4", "dev", vb)):
            done = ip(*step)
            assert done.returncode == 0, (step, done.stderr)
        yield a, b
    finally:
        ip("netns", "del", a)
        ip("netns", "del", b)


@pytest.mark.slow         # a whole real-time run of the default scenario beside realtime_run's: over a minute
def test_plant_and_ecus_on_two_hosts_give_the_same_verdicts(tmp_path, two_hosts, realtime_run):
    a, b = two_hosts
    bus = ["-i", "udp_multicast", "-c", "239.255.199.7", "--bus-kwargs", "port=43199"]
    for attempt in range(ATTEMPTS):
        out = tmp_path / f"run{attempt}"
        ecus = subprocess.Popen(["ip", "netns", "exec", b, sys.executable, "-m", "hil", "node",
                                 ",".join(ECUS), str(DEFAULT), *bus, "--until-idle", "3", "--stats",
                                 str(tmp_path / "ecus.json")],
                                cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                start_new_session=True)
        try:
            line = ecus.stdout.readline()
            assert line.startswith("node DESK,BCU,BECU1"), (line, ecus.poll())
            assert "waiting for the first frame" in ecus.stdout.readline()
            external = [arg for name in ECUS for arg in ("--external", name)]
            plant = subprocess.run(["ip", "netns", "exec", a, sys.executable, "-m", "hil", "run",
                                    str(DEFAULT), "--realtime", *external, *bus, "--out", str(out), "-q"],
                                   cwd=ROOT, capture_output=True, text=True, timeout=400)
            ecus_out, ecus_err = ecus.communicate(timeout=60)
        finally:
            kill_all(ecus)
        assert plant.returncode in (0, 1), plant.stderr      # 1: a verdict that failed, judged below
        assert ecus.returncode == 0, ecus_err
        if realtime_held(out):
            break
    kpis = json.loads((out / "kpis.json").read_text())
    reference = json.loads((realtime_run[0] / "kpis.json").read_text())
    rt = kpis["realtime"]
    assert sorted(rt["external"]) == sorted(ECUS) and list(rt["nodes"]) == ["PLANT"]
    assert kpis["stopped"] and kpis["frames_lost"] == 0, kpis
    conduct = rt["conduct"]
    assert all(conduct[n]["protection_clean"] for n in ECUS), {n: conduct[n]["protection"] for n in ECUS}
    stats = json.loads((tmp_path / "ecus.json").read_text())
    assert set(stats) == set(ECUS) and all(s["cycles"] > 200 for s in stats.values()), stats
    with excused_unless_realtime_held(out):
        assert {n: conduct[n]["timing"] for n in ECUS} == {n: "PASS" for n in ECUS}, conduct
        d, d0 = kpis["stopping_distance_m"], reference["stopping_distance_m"]
        assert abs(d - d0) / d0 < 0.02, (d, d0)
    print(f"\ntwo hosts: stopping distance {kpis['stopping_distance_m']:.2f} m (one host "
          f"{reference['stopping_distance_m']:.2f} m); ECU host: "
          + "; ".join(f"{n} p99 {s['lateness_us']['p99']} us" for n, s in stats.items()))
