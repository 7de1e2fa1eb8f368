"""A device over OPC UA (hil.devices.opcua): the device file's checks, the bench's link as server and as
client with asyncua on the other end (a real OPC UA stack, no mock), its security, its errors, and an OPC UA
device's model in lockstep."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from hil.can.codec import loaded_dbc
from hil.errors import DeviceError
from hil.resources import scenarios_dir
from hil.runtime.assembly import build_foundation_node, device_gateway
from hil.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
NAMESPACE = "urn:railhil:test-plc"
PASSWORD = "brake-valve-4"
WAIT_S = 20.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def device_text(port: int, *, role: str = "server", security: str = "None", model: str | None = None,
                extra: str = "", writes: str = "", reads: str = "") -> str:
    """A PLC in the DESK's place: it reads the train's position and speed, writes the brake step."""
    secure = "" if security == "None" else ('trust = ["pki/plc.der"]\npki = "pki-bench"\nuser = "plc"\n'
                                            'password_env = "RAILHIL_TEST_PLC_PASSWORD"\n')
    return f'''description = "a PLC braking the train, over OPC UA"
replaces = "DESK"
transport = "opcua"
{f'model = "{model}"' if model else ""}

[opcua]
role = "{role}"
endpoint = "opc.tcp://127.0.0.1:{port}/railhil"
namespace = "{NAMESPACE}"
security = "{security}"
cycle_ms = 100
stamp = "Train.Stamp"
echo = "Command.Echo"
{secure}{extra}
[reads.Train]
Position = {{ type = "Double", unit = "m" }}
Speed = {{ type = "Double", unit = "km/h" }}
Stamp = {{ type = "UInt32" }}
{reads}
[writes.Command]
BrakeStep = {{ type = "Int16" }}
Emergency = {{ type = "Boolean" }}
Echo = {{ type = "UInt32" }}
{writes}
[receive.Train]
Position = {{ from = "truth.car1.position" }}
Speed = {{ from = "truth.car1.speed" }}

[send.DESK_CMD]
BrakeStep = {{ from = "Command.BrakeStep" }}
EmergencyReq = {{ from = "Command.Emergency" }}
BrakeValve = {{ value = "NONE" }}

[send.DESK_TARGET]
TargetStopValid = {{ value = 0 }}
TargetStopPos = {{ value = 0 }}
'''


def certificate(folder: Path, name: str, use: str = "client") -> tuple[Path, Path]:
    """A self-signed application certificate and key, as a PLC's engineering tool makes one."""
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    folder.mkdir(parents=True, exist_ok=True)
    cert, key = folder / f"{name}.der", folder / f"{name}-key.pem"
    uses = [ExtendedKeyUsageOID.CLIENT_AUTH if use == "client" else ExtendedKeyUsageOID.SERVER_AUTH]
    asyncio.run(setup_self_signed_certificate(key, cert, f"urn:test:{name}", socket.gethostname(), uses,
                                              {"commonName": name}))
    return cert, key


def gateway_of(path: Path):
    scenario = load_scenario(scenarios_dir() / "default.toml")
    db, codec = loaded_dbc(ROOT / "dbc" / "train_brake.dbc")
    return device_gateway(str(path), build_foundation_node("DESK", scenario, db, codec), scenario, db, codec)


def link_of(path: Path):
    from hil.devices.opcua import OpcUaLink

    return OpcUaLink(gateway_of(path).device)


def wait_for_writes(link, n: int) -> list:
    """What the PLC wrote, once it wrote `n` times (the link's pipe, waited on with a timeout)."""
    import select

    got = []
    while len(got) < n:
        ready, _, _ = select.select([link.fileno()], [], [], WAIT_S)
        assert ready, f"the PLC wrote {len(got)} times in {WAIT_S:g} s, expected {n}"
        link.take(lambda t, fid, ext, values, msg: got.append((fid, values)))
    return got


async def plc_session(port: int, writes: int, *, cert=None, key=None, user=None, password=None,
                      mode: str = "SignAndEncrypt") -> list:
    """An OPC UA client standing in for a PLC: `writes` scans, each reading the stamp and writing the brake
    step and its echo; the stamps it read."""
    from asyncua import Client, ua
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

    client = Client(f"opc.tcp://127.0.0.1:{port}/railhil", timeout=5)
    client.application_uri = f"urn:test:{Path(cert).stem}" if cert else "urn:test:plc"
    if cert is not None:
        await client.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key),
                                  mode=getattr(ua.MessageSecurityMode, mode))
    if user is not None:
        client.set_user(user)
        client.set_password(password)
    stamps = []
    async with client:
        idx = await client.get_namespace_index(NAMESPACE)
        objects = client.nodes.objects
        stamp = await objects.get_child([f"{idx}:Train", f"{idx}:Stamp"])
        outs = [await objects.get_child([f"{idx}:Command", f"{idx}:{v}"]) for v in ("BrakeStep", "Emergency",
                                                                                     "Echo")]
        for k in range(writes):
            s = await stamp.read_value()
            stamps.append(s)
            await client.write_values(outs, [ua.Variant(k % 8, ua.VariantType.Int16),
                                             ua.Variant(False, ua.VariantType.Boolean),
                                             ua.Variant(s, ua.VariantType.UInt32)])
    return stamps


# --------------------------------------------------------------------------------- the device file
@pytest.mark.parametrize("change, expected", [
    (("[writes.Command]", "[writesx.Command]"), "key 'writesx' is not a device-file key"),
    (('stamp = "Train.Stamp"', 'stamp = "Train.Speed"'),
     "key 'opcua.stamp' = 'Train.Speed': a count needs an integer variable (it is a Double)"),
    (('echo = "Command.Echo"', 'echo = "Command.Echoo"'),
     "key 'opcua.echo' = 'Command.Echoo': not a variable of [writes]"),
    (('echo = "Command.Echo"\n', ''), "'stamp' and 'echo' go together"),
    (('security = "None"', 'security = "SignAndEncrypt"'), "needs 'trust': the PLC's certificate file(s)"),
    (('endpoint = "opc.tcp', 'endpoint = "http'), "expected opc.tcp://HOST:PORT[/PATH]"),
    (('BrakeStep = { type = "Int16" }', 'BrakeStep = { type = "Int12" }'),
     "key 'writes.Command.BrakeStep.type'"),
    (('Position = { type = "Double", unit = "m" }', 'Position = { type = "Double", unit = "m/s" }'),
     "receive.Train.Position"),
    (('replaces = "DESK"', 'replaces = "DESK"\ndbc = "x.dbc"'), "an OPC UA device has no 'dbc' or [bus]"),
    ((('Stamp = { type = "UInt32" }',
       'Stamp = { type = "UInt32" }\nSpeedEst = { type = "Byte", unit = "km/h" }'),
      ('Position = { from = "truth.car1.position" }',
       'Position = { from = "truth.car1.position" }\nSpeedEst = { from = "BCU_STATUS.TrainSpeedEst" }')),
     "the variable Train.SpeedEst (Byte, 0..255 km/h) cannot carry BCU_STATUS.TrainSpeedEst "
     "(0..2359.26 km/h"),
])
def test_a_device_file_that_does_not_fit_is_one_line_naming_the_key(tmp_path, change, expected):
    path = tmp_path / "plc.toml"
    text = device_text(free_port())
    for old, new in (change if isinstance(change[0], tuple) else (change,)):
        text = text.replace(old, new)
    path.write_text(text)
    with pytest.raises(DeviceError) as err:
        gateway_of(path)
    assert expected in str(err.value) and "\n" not in str(err.value), str(err.value)
    assert str(path) in str(err.value)


def test_the_map_reads_an_opcua_device_as_objects_of_variables(tmp_path):
    path = tmp_path / "plc.toml"
    path.write_text(device_text(free_port()))
    gw = gateway_of(path)
    routes = {r.message: r for r in (*gw.device.to_device, *gw.device.to_bench)}
    speed = next(e for e in routes["Train"].entries if e.target == "Speed")
    assert speed.truth == ("v", 0) and speed.a == pytest.approx(3.6)           # m/s -> km/h by pint
    assert routes["Train"].cycle_ms == 10 and routes["Train"].trigger is None  # truth alone: input_cycle_ms
    assert routes["DESK_CMD"].trigger == "Command"                               # routed on each PLC write
    assert "Stamp" not in {e.target for e in routes["Train"].entries}          # the link counts it itself


# --------------------------------------------------------------------------------- the bench as server
def test_the_bench_serves_a_plc_with_signandencrypt_and_refuses_the_others(tmp_path, monkeypatch):
    monkeypatch.setenv("RAILHIL_TEST_PLC_PASSWORD", PASSWORD)
    plc_cert, plc_key = certificate(tmp_path / "pki", "plc")
    intruder_cert, intruder_key = certificate(tmp_path / "other", "intruder")
    port = free_port()
    path = tmp_path / "plc.toml"
    path.write_text(device_text(port, security="SignAndEncrypt"))
    link = link_of(path)
    link.start()
    try:
        assert (tmp_path / "pki-bench" / "railhil-bench.der").is_file()   # created on first use, kept
        stamps = []
        plc = threading.Thread(target=lambda: stamps.extend(asyncio.run(plc_session(
            port, 5, cert=plc_cert, key=plc_key, user="plc", password=PASSWORD))))
        plc.start()
        wrote = []
        while len(wrote) < 5:
            link.send(2, False, {"Position": 100.0, "Speed": 72.0})   # the bench's update: the stamp counts
            wrote += wait_for_writes(link, 1)
        plc.join(WAIT_S)
        assert [v["BrakeStep"] for _, v in wrote] == [0.0, 1.0, 2.0, 3.0, 4.0]
        for attempt in (dict(cert=plc_cert, key=plc_key, user="plc", password="wrong"),
                        dict(cert=intruder_cert, key=intruder_key, user="plc", password=PASSWORD),
                        dict(user="plc", password=PASSWORD)):                # security None
            with pytest.raises(Exception):                                   # noqa: B017 - asyncua's own
                asyncio.run(plc_session(port, 1, **attempt))
        record = link.payload()
    finally:
        link.close()
    assert record["security"] == "Basic256Sha256 SignAndEncrypt" and record["writes"] == 5
    assert record["refused"] == {"wrong user name or password": 1, "untrusted certificate": 1}
    assert record["read_age"]["n"] >= 1 and record["read_age"]["max_ms"] < WAIT_S * 1000


# --------------------------------------------------------------------------------- the bench as client
class PlcServer:
    """An asyncua server standing in for a PLC's own (a CODESYS or S7-1500 server exposes its variables):
    Train.Position/Speed/Stamp and Command.BrakeStep/Emergency/Echo in NAMESPACE, in a thread."""

    def __init__(self, port: int, types: dict | None = None, certs: tuple | None = None) -> None:
        self.port, self.types, self.certs = port, types or {}, certs
        self.ready, self.stop_event = threading.Event(), None
        self.thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)

    async def _main(self) -> None:
        from asyncua import Server, ua

        server = Server()
        await server.init()
        server.set_endpoint(f"opc.tcp://127.0.0.1:{self.port}/railhil")
        if self.certs is not None:
            await server.load_certificate(str(self.certs[0]))
            await server.load_private_key(str(self.certs[1]))
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
        else:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        idx = await server.register_namespace(NAMESPACE)
        layout = {"Train": {"Position": "Double", "Speed": "Double", "Stamp": "UInt32"},
                  "Command": {"BrakeStep": "Int16", "Emergency": "Boolean", "Echo": "UInt32"}}
        self.vars = {}
        for obj_name, variables in layout.items():
            obj = await server.nodes.objects.add_object(idx, obj_name)
            for name, type_name in variables.items():
                type_name = self.types.get(name, type_name)
                vtype = getattr(ua.VariantType, type_name)
                initial = False if type_name == "Boolean" else 0.0 if type_name == "Double" else 0
                var = await obj.add_variable(idx, name, ua.Variant(initial, vtype), varianttype=vtype,
                                             datatype=ua.NodeId(getattr(ua.ObjectIds, type_name)))
                await var.set_writable()
                if name == "Speed":                  # the PLC's own engineering unit
                    await var.add_property(0, "EngineeringUnits", ua.EUInformation(
                        DisplayName=ua.LocalizedText("km/h"), UnitId=-1))
                self.vars[name] = var
        self.stop_event = asyncio.Event()
        self.loop = asyncio.get_running_loop()
        async with server:
            self.ready.set()
            scan = 0
            while not self.stop_event.is_set():      # the PLC's scan: echo the stamp, step the brake
                stamp = await self.vars["Stamp"].read_value()
                await self.vars["Echo"].write_value(ua.Variant(stamp, ua.VariantType.UInt32))
                await self.vars["BrakeStep"].write_value(ua.Variant(scan % 8, ua.VariantType.Int16))
                scan += 1
                try:
                    await asyncio.wait_for(self.stop_event.wait(), 0.05)
                except TimeoutError:
                    pass

    def __enter__(self):
        self.thread.start()
        assert self.ready.wait(WAIT_S), "the stand-in PLC server did not start"
        return self

    def __exit__(self, *exc):
        self.loop.call_soon_threadsafe(self.stop_event.set)
        self.thread.join(WAIT_S)


def test_the_bench_as_client_finds_the_plcs_variables_and_measures_its_calls(tmp_path, monkeypatch):
    port = free_port()
    path = tmp_path / "plc.toml"
    path.write_text(device_text(port, role="client"))
    server = PlcServer(port)
    with server:
        link = link_of(path)
        link.start()
        try:
            for _ in range(3):
                link.send(2, False, {"Position": 10.0, "Speed": 36.0})
                wait_for_writes(link, 1)
            record = link.payload()
        finally:
            link.close()
    assert record["role"] == "client" and record["writes"] >= 3
    assert record["calls"]["n"] >= 3 and record["calls"]["p50_ms"] < WAIT_S * 1000


@pytest.mark.parametrize("change, expected", [
    (('Position = { type = "Double", unit = "m" }',
      'Position = { type = "Double", unit = "m", node_id = "ns=2;s=Train.Posn" }'),
     "the PLC's server has no variable ns=2;s=Train.Posn; closest browse names: Train/Position"),
    (('Speed = { type = "Double", unit = "km/h" }', 'Speed = { type = "Float", unit = "km/h" }'),
     "key 'reads.Train.Speed': the variable's data type on the PLC is Double, the device file says Float"),
    (('namespace = "urn:railhil:test-plc"', 'namespace = "urn:acme:plc"'),
     "key 'opcua.namespace' = 'urn:acme:plc': the PLC's server has no such namespace"),
    (('Speed = { type = "Double", unit = "km/h" }', 'Speed = { type = "Double", unit = "m/s" }'),
     "key 'reads.Train.Speed': the PLC's server gives the variable the unit 'km/h', the device file "
     "says m/s"),
])
def test_a_plc_server_that_does_not_have_the_variables_is_one_line(tmp_path, change, expected):
    port = free_port()
    path = tmp_path / "plc.toml"
    path.write_text(device_text(port, role="client").replace(*change))
    with PlcServer(port):
        link = link_of(path)
        with pytest.raises(DeviceError) as err:
            link.start()
    assert expected in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_an_endpoint_that_cannot_be_reached_is_exit_3_and_a_bad_certificate_exit_2(tmp_path, monkeypatch):
    path = tmp_path / "plc.toml"
    path.write_text(device_text(free_port(), role="client"))     # nothing listens there
    proc = subprocess.run([sys.executable, "-m", "hil", "run", "default", "--realtime", "--device", str(path),
                           "--out", str(tmp_path / "run")], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 3, proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith("error: ") and "cannot reach the PLC's OPC UA server" in line, line
    (tmp_path / "pki").mkdir()
    (tmp_path / "pki" / "plc.der").write_text("not a certificate\n")
    path.write_text(device_text(free_port(), role="client", security="SignAndEncrypt"))
    monkeypatch.setenv("RAILHIL_TEST_PLC_PASSWORD", PASSWORD)
    proc = subprocess.run([sys.executable, "-m", "hil", "run", "default", "--realtime", "--device", str(path),
                           "--out", str(tmp_path / "run2")], cwd=ROOT, capture_output=True, text=True,
                          timeout=120, env={**os.environ})
    assert proc.returncode == 2, proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    assert "key 'opcua.trust'" in line, line
    assert "is not a certificate (expected an X.509 certificate, DER or PEM)" in line, line


# --------------------------------------------------------------------------------- lockstep: its model
MODEL = '''class BrakeAfterFive:
    """Brake step 7 from 5 s on; the echo of the bench's stamp."""

    def step(self, now_us, rx):
        stamp = rx["Stamp"]
        return {"BrakeStep": 7 if now_us >= 5_000_000 else 0, "Emergency": 0,
                "Echo": stamp if stamp == stamp else 0}
'''


def test_an_opcua_devices_model_runs_in_lockstep_and_its_traces_repeat(tmp_path):
    (tmp_path / "brake_after_five.py").write_text(MODEL)
    path = tmp_path / "plc.toml"
    path.write_text(device_text(free_port(), model="brake_after_five:BrakeAfterFive"))
    runs = []
    for k in range(2):
        out = tmp_path / f"run{k}"
        proc = subprocess.run([sys.executable, "-m", "hil", "run", "default", "--device", str(path), "--out",
                               str(out), "--set", "max_duration_s=12", "-q"], cwd=ROOT, capture_output=True,
                              text=True, timeout=300)
        assert proc.returncode in (0, 1), proc.stderr
        runs.append(out)
    d = json.loads((runs[0] / "kpis.json").read_text())["devices"]["DESK"]
    assert d["transport"] == "opcua" and d["mode"] == "model" and d["plc"]["timing"] == "PASS", d["plc"]
    assert d["opcua"]["cycle"]["p50_ms"] == pytest.approx(100.0)
    assert d["opcua"]["read_age"]["n"] > 50 and d["bench"]["timing"] == "PASS"
    assert (runs[0] / "trace.blf").read_bytes() == (runs[1] / "trace.blf").read_bytes()
    assert not list(runs[0].glob("device-*"))                  # no device bus: no device trace
