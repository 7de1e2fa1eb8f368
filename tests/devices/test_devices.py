"""A device on its own CAN matrix, mapped onto the bench (hil.devices), in lockstep.

The example device, examples/acme_becu/ (ACME's EBC-7: its own identifiers and cycle times, Motorola signals,
km/h and bar, a multiplexed status frame, AUTOSAR E2E profiles 5 and 11 and plain counters with XOR and sum
checksums), runs as BECU3 of the default scenario with its model behind the gateway: the train stops as far
as with every node simulated, the device and the gateway are judged, and two runs leave the same traces
byte for byte.  Then the map's parts one by one (units, value tables, defaults while stale, routing), and
every bad device file: one line naming the file and the key, exit 2, no run folder.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
from pathlib import Path

import cantools
import pytest
from conftest import ROOT, assert_one_line_error, railhil

from hil.can.codec import Codec, loaded_dbc
from hil.can.dbc import DEFAULT_DBC
from hil.devices.device import ReplacedNode, load_device
from hil.devices.gateway import Gateway
from hil.devices.units import affine
from hil.errors import DeviceError

ACME = ROOT / "examples" / "acme_becu"
DEVICE = ACME / "acme_becu.toml"
BECU3 = ReplacedNode("BECU3", ("PLANT_CAR3_SENSORS", "BCU_DEMAND", "BCU_EMERGENCY"),
                     ("BECU3_PRESS_CMD", "BECU3_STATUS", "BECU3_DIAG", "BECU3_EST"), 10_000, 4_000, 3)


@pytest.fixture(scope="module")
def acme_lockstep(tmp_path_factory):
    """The default scenario with the EBC-7 as BECU3, in lockstep, twice: (first run folder, its kpis, second
    run folder)."""
    folders = []
    for k in range(2):
        out = tmp_path_factory.mktemp(f"acme-{k}") / "run"
        code, _, err = railhil_cli("run", "default", "--device", DEVICE, "--out", out, "-q")
        assert code == 0, err
        folders.append(out)
    return folders[0], json.loads((folders[0] / "kpis.json").read_text()), folders[1]


def railhil_cli(*args) -> tuple[int, str, str]:
    """`railhil ARGS` in a subprocess (its own pint and module caches, as a user runs it)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "hil", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    return done.returncode, done.stdout, done.stderr


# --- the example as BECU3 ------------------------------------------------------------------------------

def test_the_train_stops_as_far_with_the_device_as_becu3(acme_lockstep, default_lockstep):
    _, kpis, _ = acme_lockstep
    ours, all_simulated = kpis["stopping_distance_m"], default_lockstep.kpis["stopping_distance_m"]
    assert ours == pytest.approx(all_simulated, rel=0.01)           # the acceptance: within 1 %
    assert kpis["stopped"] and kpis["end_reason"] == "standstill"


def test_the_device_and_the_gateway_are_judged(acme_lockstep):
    out, kpis, _ = acme_lockstep
    d = kpis["devices"]["BECU3"]
    assert d["verdict"] == "PASS" and d["mode"] == "model" and d["node"] == "EBC7"
    assert {m: v["verdict"] for m, v in d["device"]["messages"].items()} == {
        "EBC7_VALVE_CMD": "PASS", "EBC7_STATUS": "PASS"}
    assert d["device"]["protection_clean"]
    assert {m: v["verdict"] for m, v in d["to_device"].items()} == {"VCU_BRAKE_DEMAND": "PASS",
                                                                     "VCU_WHEEL_DATA": "PASS"}
    assert d["bench"]["timing"] == "PASS" and not d["bench"]["protection"]   # the bench took its frames
    assert set(d["bench"]["messages"]) == {"BECU3_PRESS_CMD", "BECU3_STATUS", "BECU3_DIAG", "BECU3_EST"}
    assert d["protection"] == {"EBC7_VALVE_CMD": "AUTOSAR E2E P11, data id 0xA3 (BOTH)",
                               "EBC7_STATUS": "counter (4 bits) + SUM checksum",
                               "VCU_BRAKE_DEMAND": "AUTOSAR E2E P05, data id 0x1027",
                               "VCU_WHEEL_DATA": "counter (4 bits) + XOR checksum"}
    lat = d["latency"]
    # routed frame for frame: each carries the frame before it, a frame time of the other bus later
    # (lockstep: the target bus's queueing and transmission: 8 bytes at 500 / 250 kbit/s, 0.23 / 0.5 ms)
    assert lat["messages"]["BECU3_PRESS_CMD"]["kind"] == "routed"
    assert 200 <= lat["device_to_bench"]["p50_us"] <= lat["device_to_bench"]["max_us"] < 1_000
    assert 400 <= lat["bench_to_device"]["p50_us"] <= lat["bench_to_device"]["max_us"] < 1_000
    assert lat["messages"]["BECU3_STATUS"]["kind"] == "cyclic"               # 50 ms from 20 ms pages
    assert d["routed"]["bench"] == lat["messages"]["BECU3_PRESS_CMD"]["frames"]
    assert (out / "device-BECU3.blf").is_file()


def test_the_summary_report_and_run_json_show_the_device(acme_lockstep):
    out, kpis, _ = acme_lockstep
    page = (out / "report.html").read_text()
    assert "<h2 id=devices>Devices</h2>" in page and "EBC7_VALVE_CMD" in page and "device BECU3" in page
    meta = json.loads((out / "run.json").read_text())
    assert meta["devices"]["BECU3"]["routes"] and meta["devices"]["BECU3"]["model"]["step_errors"] == 0


def test_two_runs_leave_the_same_traces_byte_for_byte(acme_lockstep):
    first, _, second = acme_lockstep
    for name in ("trace.blf", "device-BECU3.blf"):
        assert hashlib.sha256((first / name).read_bytes()).digest() == \
            hashlib.sha256((second / name).read_bytes()).digest(), name


def test_the_device_trace_decodes_with_its_own_dbc(acme_lockstep, capsys):
    out, _, _ = acme_lockstep
    trace, dbc = out / "device-BECU3.blf", ACME / "acme_becu.dbc"
    code, text, err = railhil(capsys, "trace", "decode", trace, "--dbc", dbc, "--message", "EBC7_STATUS",
                              "--start", "5", "--end", "5.05")
    assert code == 0, err
    assert "StatusPage=BRAKE" in text and "StatusPage=DIAGNOSIS" in text and "km/h" in text


# --- the device on the bench's own bus (bus = "bench") -------------------------------------------------

def on_the_bench(tmp_path: Path) -> Path:
    """A copy of the example (and the control law its model imports) whose device is on the bench's bus."""
    for name in ("acme_becu", "external_becu"):
        shutil.copytree(ROOT / "examples" / name, tmp_path / name,
                        ignore=shutil.ignore_patterns("__pycache__"))
    path = tmp_path / "acme_becu" / "acme_becu.toml"
    text = path.read_text()
    start, end = text.index("[bus]"), text.index("hop_limit = 0\n") + len("hop_limit = 0\n")
    path.write_text(text[:start] + 'bus = "bench"\n' + text[end:])
    return path


def test_a_device_on_the_benchs_bus_arbitrates_with_the_bench(tmp_path, default_lockstep):
    out = tmp_path / "run"
    code, _, err = railhil_cli("run", "default", "--device", on_the_bench(tmp_path), "--out", out, "-q")
    assert code == 0, err
    assert "acme_becu.dbc declares 250 kbit/s; on the bench's bus" in err and "500 kbit/s" in err
    kpis = json.loads((out / "kpis.json").read_text())
    all_simulated = default_lockstep.kpis["stopping_distance_m"]
    assert kpis["stopping_distance_m"] == pytest.approx(all_simulated, rel=0.01)
    d = kpis["devices"]["BECU3"]
    assert d["verdict"] == "PASS" and d["trace"] == "trace.blf" and not (out / "device-BECU3.blf").exists()
    assert kpis["frames_lost"] == 0 and kpis["frames_sent_by_node"]["BECU3.device"] > 2_000
    # one bus: the device's frames in the bench's trace and its bit timing, by their own names
    messages = json.loads((out / "run.json").read_text())["bus_timing"]["messages"]
    assert {"EBC7_VALVE_CMD", "VCU_BRAKE_DEMAND", "BCU_DEMAND"} <= set(messages)
    assert 400 <= d["latency"]["bench_to_device"]["p50_us"] < 5_000          # behind the bench's own frames


def test_a_device_on_the_benchs_bus_with_an_identifier_of_the_bench_is_one_line(tmp_path, capsys):
    path = on_the_bench(tmp_path)
    dbc = path.with_name("acme_becu.dbc")
    dbc.write_text(dbc.read_text().replace(" 419 ", " 40 "))     # EBC7_VALVE_CMD at BCU_DEMAND's identifier
    code, _, err = railhil(capsys, "run", "default", "--device", path, "--out", tmp_path / "run", "-q")
    assert_one_line_error(code, err, "acme_becu.toml", "key 'bus' = \"bench\"", "EBC7_VALVE_CMD",
                          "0x28 of the bench's BCU_DEMAND")
    assert not (tmp_path / "run").exists()


# --- the map's parts -----------------------------------------------------------------------------------

@pytest.mark.parametrize(("src", "dst", "scale", "x", "y"), [
    ("km/h", "m/s", 1.0, 36.0, 10.0),
    ("Pa", "bar", 1.0, 250_000.0, 2.5),
    ("%", "", 1.0, 50.0, 0.5),
    ("rad/s", "km/h", "0.46 m", 10.0, 16.56),           # r·ω
    ("rpm", "rad/s", 1.0, 60.0, 2 * math.pi),
    ("degC", "K", 1.0, 20.0, 293.15),
    ("Nm", "N.m", 1.0, 3.0, 3.0),                        # a DBC's newton metre
])
def test_units_convert_as_pint_reads_the_dbc_strings(src, dst, scale, x, y):
    a, b = affine(src, dst, scale, where="test")
    assert a * x + b == pytest.approx(y)


@pytest.mark.parametrize(("src", "dst", "scale"), [("km/h", "bar", 1.0), ("rad/s", "km/h", 1.0),
                                                   ("m/s", "", 1.0), ("blorps/s", "m/s", 1.0)])
def test_units_that_do_not_convert_are_one_line(src, dst, scale):
    with pytest.raises(DeviceError) as err:
        affine(src, dst, scale, where="f.toml: key 'receive.A.b'", source="X.y", target="A.b")
    assert "f.toml: key 'receive.A.b'" in str(err.value) and "\n" not in str(err.value)


@pytest.fixture(scope="module")
def gateway():
    db, codec = loaded_dbc(DEFAULT_DBC)
    return Gateway(load_device(DEVICE, db, BECU3), BECU3, db, codec)


def test_the_map_is_compiled_against_both_dbcs(gateway):
    routes = {r.message: r for r in (*gateway.device.to_device, *gateway.device.to_bench)}
    assert routes["VCU_BRAKE_DEMAND"].trigger == "BCU_DEMAND"                   # same cycle: routed
    assert routes["BECU3_STATUS"].trigger is None                             # 50 ms from 20 ms: cyclic
    wheel = {e.target: e for e in routes["VCU_WHEEL_DATA"].entries}
    assert wheel["WheelSpeed"].a == pytest.approx(0.46 * 3.6)                 # rad/s · 0.46 m -> km/h
    assert wheel["CylPressure"].a == pytest.approx(1e-5)                      # Pa -> bar
    valve = {e.target: e for e in routes["BECU3_PRESS_CMD"].entries}
    assert valve["WspValve"].choices == {0.0: 0.0, 1.0: 1.0, 2.0: 2.0}         # INFLATE/LAP/DUMP -> FILL/...
    assert valve["ValveCmd"].a == pytest.approx(0.01)                         # % -> fraction
    demand = {e.target: e for e in routes["VCU_BRAKE_DEMAND"].entries}
    assert demand["CarLoad"].constant == 40.0                                 # "40 t" in the DBC's t
    assert demand["DecelDemand"].stale_us == 30_000                           # 3 of BCU_DEMAND's 10 ms


def _frame(gw_side, message: str, values: dict) -> tuple[int, bytes]:
    fc = gw_side.codec.by_name(message)
    return fc.frame_id, fc.encode(values)


def test_a_routed_frame_goes_out_at_once_translated(gateway):
    """A usable BCU_DEMAND makes VCU_BRAKE_DEMAND go at once, in the device's units, its own E2E profile 5;
    a BCU_DEMAND that fails the bench's checks makes nothing."""
    db = gateway.bench._db
    sender = Codec(db).by_name("BCU_DEMAND")
    from hil.runtime.node import Binding, Node

    bcu = Node("BCU", type("C", (), {"step": lambda self, now, rx: {"TargetDecel": 1.25, "Mode": 1}})(),
               Binding.build(db, "BCU", (), ("TargetDecel", "Mode"), (), ("BCU_DEMAND",)),
               gateway.bench.codec, db, 10_000)
    bcu.use_keys({})
    gateway.bench.use_keys({})
    gateway.take()
    for k in range(3):                                   # the first is INITIAL (profile 1), not used
        (fc, data), = [f for f in bcu.cycle(k * 10_000) if f[0].name == "BCU_DEMAND"]
        gateway.bench.receive(sender.frame_id, data, k * 10_000 + 300)
    routed = gateway.take()
    assert [(side, fc.name) for side, fc, _ in routed] == [("device", "VCU_BRAKE_DEMAND")] * 2
    ddb = cantools.database.load_file(str(ACME / "acme_becu.dbc"))
    values = ddb.decode_message("VCU_BRAKE_DEMAND", routed[-1][2], decode_choices=True)
    assert values["DecelDemand"] == pytest.approx(1.25) and values["BrakeMode"] == "SERVICE"
    assert values["CarLoad"] == 40.0
    from hil.can import e2e

    config = gateway.device.protections["VCU_BRAKE_DEMAND"]
    assert e2e.check(config, e2e.CheckState(), routed[0][2])[1] is e2e.Status.OK
    bad = bytearray(data)
    bad[5] ^= 0x01
    gateway.bench.receive(sender.frame_id, bytes(bad), 40_300)
    assert gateway.take() == []                           # dropped by the bench's checks: nothing routed


def test_a_stale_source_sends_the_default_or_the_last_value(gateway):
    route = next(r for r in gateway.device.to_bench if r.message == "BECU3_STATUS")
    out: dict[str, float] = {}
    gateway.to_bench.fill(route, out, 10_000_000)        # nothing received from the device yet
    assert out["BECU3_STATUS.InputMissing"] == 1.0        # its default
    assert out["BECU3_STATUS.SpeedEst"] == 0.0            # no default: its start value
    assert out["BECU3_STATUS.GovernorActive"] == 0.0      # a constant
    assert gateway.to_bench.stats.stale["BECU3_STATUS.InputMissing"] >= 1


def test_a_node_pages_a_multiplexed_message_it_does_not_set_the_multiplexer_of():
    from hil.runtime.node import Binding, Node

    db = cantools.database.load_file(str(ACME / "acme_becu.dbc"))
    outs = ("EBC7_STATUS.SpeedEstimate", "EBC7_STATUS.AccelBias")
    node = Node("EBC7", type("C", (), {"step": lambda self, now, rx: {outs[0]: 36.0, outs[1]: 0.5}})(),
                Binding.build(db, "EBC7", (), outs, (), ("EBC7_STATUS",)), Codec(db), db, 20_000)
    pages = [db.decode_message("EBC7_STATUS", node.cycle(k * 20_000)[0][1]) for k in range(3)]
    assert [p["StatusPage"] for p in pages] == ["BRAKE", "DIAGNOSIS", "BRAKE"]
    assert pages[0]["SpeedEstimate"] == 36.0 and pages[1]["AccelBias"] == 0.5


# --- bad device files: one line naming the file and the key, exit 2, no run folder -----------------------

def _bad(tmp_path: Path, edit) -> Path:
    """A copy of the example's device file (and its DBC, model) with `edit(text) -> text` applied."""
    folder = tmp_path / "device"
    shutil.copytree(ACME, folder, ignore=shutil.ignore_patterns("__pycache__"))
    path = folder / "acme_becu.toml"
    path.write_text(edit(path.read_text()))
    return path


BAD = [
    ("a map to a signal in neither DBC",
     lambda t: t.replace('"BCU_DEMAND.TargetDecel"', '"BCU_DEMAND.TargetDecl"'),
     ["key 'receive.VCU_BRAKE_DEMAND.DecelDemand'", "BCU_DEMAND.TargetDecl",
      "closest: BCU_DEMAND.TargetDecel"]),
    ("a device signal without a source",
     lambda t: t.replace('LongAccel = { from = "PLANT_CAR3_SENSORS.AccelLong" }\n', ""),
     ["key 'receive.VCU_WHEEL_DATA'", "no source for LongAccel"]),
    ("a bench signal without a source", lambda t: t.replace("GovernorActive = { value = 0 }", ""),
     ["key 'send.BECU3_STATUS'", "no source for GovernorActive"]),
    ("a unit conversion between incompatible units",
     lambda t: t.replace('CylPressure = { from = "PLANT_CAR3_SENSORS.CylPressure" }',
                         'CylPressure = { from = "PLANT_CAR3_SENSORS.AxleSpeed" }'),
     ["key 'receive.VCU_WHEEL_DATA.CylPressure'", "cannot convert PLANT_CAR3_SENSORS.AxleSpeed [rad/s]",
      "[bar]"]),
    ("a value-table name that does not exist", lambda t: t.replace('LAP = "HOLD"', 'LAP = "HOLT"'),
     ["key 'send.BECU3_PRESS_CMD.WspValve'", "'HOLT' is not a value of BECU3_PRESS_CMD.WspValve", "HOLD"]),
    ("a node the scenario does not have", lambda t: t.replace('replaces = "BECU3"', 'replaces = "BECU9"'),
     ["key 'replaces' = 'BECU9'", "no node 'BECU9'"]),
    ("a device DBC cantools rejects", None, ["key 'dbc' = 'acme_becu.dbc'", "not a loadable DBC file"]),
    ("an unknown key", lambda t: t.replace("[protection.VCU_WHEEL_DATA]", "[protections.VCU_WHEEL_DATA]"),
     ["key 'protections' is not a device-file key", "did you mean 'protection'?"]),
    ("a profile without its data id", lambda t: t.replace("data_id = 0x1027\n", ""),
     ["key 'protection.VCU_BRAKE_DEMAND'", "profile P05 needs data_id"]),
    ("a message the device does not receive",
     lambda t: t.replace("[receive.VCU_WHEEL_DATA]", "[receive.VCU_WHEEL]"), ["key 'receive.VCU_WHEEL'"]),
]


@pytest.mark.parametrize(("what", "edit", "needles"), BAD, ids=[b[0] for b in BAD])
@pytest.mark.parametrize("mode", ["--lockstep", "--realtime"])
def test_a_bad_device_file_is_one_line(tmp_path, capsys, what, edit, needles, mode):
    if edit is None:
        path = _bad(tmp_path, lambda t: t)
        (path.parent / "acme_becu.dbc").write_text('BO_ 12 BROKEN: 8 X\n SG_ S : 0|99@1+ (1,0) [0|1] "" Y\n')
    else:
        path = _bad(tmp_path, edit)
    out = tmp_path / "run"
    given = str(path) if what == "a node the scenario does not have" else f"BECU3={path}"
    code, _, err = railhil(capsys, "run", "default", mode, "--device", given, "--out", out, "-q")
    assert_one_line_error(code, err, "acme_becu.toml", *needles)
    assert not out.exists()


def test_two_devices_for_one_node_are_one_line(tmp_path, capsys):
    out = tmp_path / "run"
    code, _, err = railhil(capsys, "run", "default", "--device", DEVICE, "--device", f"BECU3={DEVICE}",
                           "--out", out)
    assert_one_line_error(code, err, "--device", "two devices for node BECU3")
    assert not out.exists()


def test_a_device_file_for_another_node_is_one_line(tmp_path, capsys):
    code, _, err = railhil(capsys, "run", "default", "--device", f"BECU4={DEVICE}", "--out", tmp_path / "run")
    assert_one_line_error(code, err, "--device BECU4=", "replaces BECU3, not BECU4")


def test_lockstep_needs_the_model(tmp_path, capsys):
    path = _bad(tmp_path, lambda t: t.replace('model = "ebc7_control:Ebc7Control"', ""))
    code, _, err = railhil(capsys, "run", "default", "--device", path, "--out", tmp_path / "run")
    assert_one_line_error(code, err, str(path), "a lockstep run needs the device's model", "--realtime")
