"""The bench's end of an OPC UA device (transport = "opcua"): asyncua, in a thread of its own.

A PLC joins the bench as HIL rigs connect PLCs: over OPC UA, its variables mapped onto the bench's frames by
the device file's map (hil.devices.device, its objects a schema: hil.devices.variables).  Two roles:

* **server** — the bench serves the device's objects and variables at `endpoint`; the PLC's client reads
  the [reads] variables and writes the [writes] ones (each write request is seen as it arrives: asyncua's
  PostWrite callback);
* **client** — the bench connects to the PLC's own server, finds each variable (its `node_id`, else the
  browse path Objects/OBJECT/VARIABLE in the device's namespace), checks its data type, writes the [reads]
  variables and polls the [writes] ones every `cycle_ms / 10`.

Security as PLCs expect: Basic256Sha256 with SignAndEncrypt (or Sign), the bench's application
certificate created on first use and kept (`pki`, default ~/.local/share/railhil/pki), the PLC's
certificate trusted by file (`trust`: an exact match, checked for its validity period), optionally a user
name and password; "None" only where the device file asks for it.  A client with an untrusted certificate
or a wrong password is refused and counted.

The OPC UA stack runs on its own event loop in a thread, so that a slow PLC or network never holds up the
gateway's real-time loop (hil.runtime.gateway_host): what the PLC wrote is queued and a byte written to a
pipe the host selects on (`fileno`, `take`), and what the bench writes is handed to the loop (`send`).  A
"frame" here is an object: its frame id is its place in the schema, its payload its variables' values.

Measured, as a PLC engineer reads a PLC's integration: its cycle (the time between its writes), and, with
an `[opcua] stamp` the bench counts up on each update and the `echo` the PLC writes back, the age of what it
read when it wrote (its write's time − the time the bench published the count it echoed) and the round trip
from an update of the bench to the PLC's write that reflects it; as client, also the bench's own OPC UA
calls.  A gap in its writes longer than `silent_after_ms` is a silence (counted, the longest kept).
"""

from __future__ import annotations

import asyncio
import difflib
import logging
import math
import os
import socket
import threading
import time
from collections import deque
from datetime import UTC
from pathlib import Path
from urllib.parse import urlparse

from hil.devices.description import OpcUaSpec
from hil.devices.device import Device
from hil.devices.units import affine
from hil.errors import BusError, DeviceError

APP_URI = "urn:railhil:bench"
START_TIMEOUT_S = 20.0             # server started, or client connected and its variables found
CALL_TIMEOUT_S = 4.0               # one OPC UA request of the bench (client role)
POLL_DIVISOR = 10                  # client role: the PLC's variables are read every cycle_ms / 10


def _ua():
    """asyncua, imported on first use (it takes 0.5 s to import: runs without an OPC UA device skip it)."""
    from asyncua import ua

    return ua


def default_pki() -> Path:
    base = os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share"
    return Path(base) / "railhil" / "pki"


class LinkMeter:
    """What an OPC UA device did, measured on the bench's clock [s]: its writes, and with a stamp and echo
    (module docstring) the age of what it read and the round trip; the bench's own calls (client role),
    refusals, values that were not numbers.  Shared by the real-time link and the lockstep model
    (hil.runtime.lockstep), so that both report the same figures."""

    def __init__(self, spec: OpcUaSpec, objects: dict) -> None:
        self.spec = spec
        self.stamp = _split(spec.stamp, objects)
        self.echo = _split(spec.echo, objects)
        self.writes: list[float] = []                 # the PLC's writes [s]
        self.read_age_us: list[int] = []
        self.round_trip_us: list[int] = []
        self.calls_us: list[int] = []                 # client role: the bench's requests
        self.bench_writes = 0
        self.refused: dict[str, int] = {}             # reason -> count
        self.bad_values = 0                           # written values not finite or not numbers
        self.count = 0                                # the bench's stamp
        self.published: deque = deque(maxlen=4096)    # (count, s)
        self.answered = 0                             # the highest count echoed so far

    def refuse(self, reason: str) -> None:
        self.refused[reason] = self.refused.get(reason, 0) + 1

    def bench_wrote(self, fid: int, values: dict, t: float) -> None:
        """The bench writes an object: counted; its stamp (if it holds it) counted up into `values`."""
        self.bench_writes += 1
        if self.stamp is not None and self.stamp[0] == fid:
            self.count += 1
            values[self.stamp[1]] = self.count
            self.published.append((self.count, t))

    def plc_wrote(self, fid: int, values: dict, t: float) -> dict[str, float]:
        """The PLC wrote an object at `t`: measured; its values as numbers (NaN for what is not one)."""
        clean = {}
        for name, v in values.items():
            if isinstance(v, bool):
                v = float(v)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                self.bad_values += 1
                v = math.nan
            clean[name] = float(v)
        if self.echo is not None and self.echo[0] == fid:
            k = clean.get(self.echo[1], math.nan)
            if k == k and k > self.answered:
                self._echoed(int(k), t)
        self.writes.append(t)
        return clean

    def _echoed(self, k: int, t: float) -> None:
        for count, t_pub in self.published:
            if count == k:
                self.read_age_us.append(round((t - t_pub) * 1e6))
            if self.answered < count <= k:
                self.round_trip_us.append(round((t - t_pub) * 1e6))
        self.answered = k

    def record(self, security: str, t0: float | None = None, end: float | None = None) -> dict:
        """The figures for the run's records (kpis.json `opcua`): role, endpoint, security, the PLC's cycle,
        read age, round trip, the bench's calls, silences, refusals; writes before `t0` left out, a gap
        from the last write to `end` counted as a silence when long enough."""
        import numpy as np

        writes = np.asarray(self.writes, dtype=np.float64)
        if t0 is not None:
            writes = writes[writes >= t0]
        gaps = np.diff(writes) * 1e6 if writes.size > 1 else np.zeros(0)
        silent_us = (self.spec.silent_after_ms or 3 * self.spec.cycle_ms) * 1000
        last_gap = (end - writes[-1]) * 1e6 if end is not None and writes.size else None
        silences = int((gaps > silent_us).sum()) + int(last_gap is not None and last_gap > silent_us)
        longest_us = max(float(gaps.max()) if gaps.size else 0.0, last_gap or 0.0)
        return {"transport": "opcua", "role": self.spec.role, "endpoint": self.spec.endpoint,
                "security": security, "user": self.spec.user,
                "cycle_ms_declared": self.spec.cycle_ms, "writes": int(writes.size),
                "cycle": _figures(gaps), "read_age": _figures(self.read_age_us),
                "round_trip": _figures(self.round_trip_us),
                "calls": _figures(self.calls_us), "bench_writes": self.bench_writes,
                "echo": self.spec.echo, "silences": silences, "longest_gap_ms": round(longest_us / 1000, 1),
                "silent_after_ms": silent_us / 1000, "refused": dict(self.refused),
                "bad_values": self.bad_values}


def _split(text: str | None, objects: dict) -> tuple[int, str] | None:
    """"OBJECT.Variable" -> (the object's frame id, the variable)."""
    if text is None:
        return None
    obj, _, var = text.partition(".")
    return next(m.frame_id for m in objects.values() if m.name == obj), var


def _figures(us) -> dict:
    import numpy as np

    a = np.asarray(us, dtype=np.float64)
    if not a.size:
        return {"n": 0, "p50_ms": None, "p99_ms": None, "max_ms": None}
    return {"n": int(a.size), "p50_ms": round(float(np.percentile(a, 50)) / 1000, 2),
            "p99_ms": round(float(np.percentile(a, 99)) / 1000, 2), "max_ms": round(float(a.max()) / 1000, 2)}


def _load_certificate(path: Path, where: str):
    from cryptography import x509

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DeviceError(f"{where}: {path}: {exc.strerror or exc}") from None
    for load in (x509.load_der_x509_certificate, x509.load_pem_x509_certificate):
        try:
            return load(data)
        except ValueError:
            continue
    raise DeviceError(f"{where}: {path} is not a certificate (expected an X.509 certificate, DER or PEM)")


class OpcUaLink:
    """The bench's end of an OPC UA device (module docstring): `start()`, then `fileno`/`take`/`send` from
    the gateway's host, `close()`, `payload()`."""

    def __init__(self, device: Device, start_timeout_s: float = START_TIMEOUT_S) -> None:
        self.device = device
        self.spec: OpcUaSpec = device.spec.opcua
        self.where = str(device.path)
        self.start_timeout_s = start_timeout_s
        db = device.db
        self.objects = {m.frame_id: m for m in db.messages}
        self.written = {m.frame_id for m in db.messages if device.node in m.senders}   # by the PLC
        self.meter = LinkMeter(self.spec, self.objects)
        self.password = None
        if self.spec.password_env is not None:
            self.password = os.environ.get(self.spec.password_env)
            if self.password is None:
                raise DeviceError(f"{self.where}: key 'opcua.password_env' = {self.spec.password_env!r}: "
                                  "that environment variable is not set (it holds the OPC UA user's "
                                  "password)")
        self.trusted = [_load_certificate((device.path.parent / t), f"{self.where}: key 'opcua.trust'")
                        for t in self.spec.trust]
        if self.spec.certificate is not None:
            _load_certificate(device.path.parent / self.spec.certificate,
                              f"{self.where}: key 'opcua.certificate'")
        self._in: deque = deque()             # (epoch s, frame id, values): what the PLC wrote
        self._r, self._w = os.pipe()
        os.set_blocking(self._r, False)
        os.set_blocking(self._w, False)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._error: BaseException | None = None
        self._nodes: dict[int, dict[str, object]] = {}        # frame id -> variable name -> asyncua Node
        self._types: dict[tuple[int, str], object] = {}       # (frame id, variable) -> ua.VariantType
        self._last_values: dict[int, dict[str, float]] = {}
        self.connected_clients = 0
        self.security_note = ("none (the device file asks for no security)" if self.spec.security == "None"
                              else f"Basic256Sha256 {self.spec.security}")

    # ---------------------------------------------------------------- the gateway host's side (its thread)
    def fileno(self) -> int:
        return self._r

    def take(self, on_frame) -> int:
        """What the PLC wrote since the last call: on_frame(epoch s, object's frame id, False, values, None)
        for each write of an object; the number taken."""
        try:
            while os.read(self._r, 4096):
                pass
        except BlockingIOError:
            pass
        n = 0
        while self._in:
            t, fid, values = self._in.popleft()
            on_frame(t, fid, False, values, None)
            n += 1
        return n

    def send(self, frame_id: int, _extended: bool, values: dict) -> None:
        """The bench writes an object's variables (a to_device route's values): handed to the OPC UA loop."""
        if self._loop is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(self._write_soon, frame_id, dict(values), time.time())

    # ------------------------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """The server started, or the PLC's server connected and its variables found and checked; a
        DeviceError or BusError (one line) if not, within start_timeout_s."""
        self._thread = threading.Thread(target=self._run, name="railhil-opcua", daemon=True)
        self._thread.start()
        if not self._ready.wait(self.start_timeout_s):
            self.close()
            what = "server did not start" if self.spec.role == "server" else "connection did not open"
            raise BusError(f"{self.where}: key 'opcua.endpoint' = {self.spec.endpoint!r}: the OPC UA {what} "
                           f"within {self.start_timeout_s:g} s")
        if self._error is not None:
            self.close()
            raise self._error

    def close(self) -> None:
        if self._loop is not None and self._stop is not None and not self._loop.is_closed():
            try:
                self._loop.call_soon_threadsafe(self._stop.set)
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        for fd in (self._r, self._w):
            try:
                os.close(fd)
            except OSError:
                pass
        self._r = self._w = -1

    def _run(self) -> None:
        for name in ("asyncua", "asyncio"):    # the bench reports what matters in one line, not the stack's
            logging.getLogger(name).setLevel(logging.CRITICAL)
        try:
            asyncio.run(self._main())
        except BaseException as exc:   # noqa: BLE001 - reported to the starting thread in one line
            if self._error is None:
                self._error = exc if isinstance(exc, (DeviceError, BusError)) else DeviceError(
                    f"{self.where}: OPC UA: {type(exc).__name__}: {exc}")
        finally:
            self._ready.set()

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        if self.spec.role == "server":
            await self._serve()
        else:
            await self._connect()

    # ------------------------------------------------------------------------------- certificates
    async def _own_certificate(self) -> tuple[Path, Path]:
        """The bench's certificate and key: the device file's, else created on first use and kept."""
        base = self.device.path.parent
        if self.spec.certificate is not None:
            return base / self.spec.certificate, base / self.spec.private_key
        from asyncua.crypto.cert_gen import setup_self_signed_certificate
        from cryptography.x509.oid import ExtendedKeyUsageOID

        pki = Path(self.spec.pki).expanduser() if self.spec.pki else default_pki()
        if not pki.is_absolute():
            pki = base / pki
        try:
            pki.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DeviceError(f"{self.where}: key 'opcua.pki': cannot create {pki}: {exc.strerror}") from None
        cert, key = pki / "railhil-bench.der", pki / "railhil-bench-key.pem"
        uses = [ExtendedKeyUsageOID.CLIENT_AUTH, ExtendedKeyUsageOID.SERVER_AUTH]
        await setup_self_signed_certificate(key, cert, APP_URI, socket.gethostname(), uses,
                                            {"commonName": "railhil bench", "organizationName": "railhil"})
        return cert, key

    def _is_trusted(self, cert) -> bool:
        from cryptography.hazmat.primitives.serialization import Encoding

        der = cert.public_bytes(Encoding.DER)
        return any(t.public_bytes(Encoding.DER) == der for t in self.trusted)

    async def _validate_peer(self, cert, app_description) -> None:
        """A peer's certificate: one of the trusted files, within its validity period; else refused."""
        from datetime import datetime

        from asyncua.common.utils import ServiceError

        ua = _ua()
        if not self._is_trusted(cert):
            self.meter.refuse("untrusted certificate")
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)
        now = datetime.now(UTC)
        if not cert.not_valid_before_utc <= now <= cert.not_valid_after_utc:
            self.meter.refuse("certificate out of its validity period")
            raise ServiceError(ua.StatusCodes.BadCertificateTimeInvalid)

    # ------------------------------------------------------------------------------------ server role
    async def _serve(self) -> None:
        from asyncua import Server
        from asyncua.common.callback import CallbackType

        ua = _ua()
        link = self

        class Users:                        # the device file's user, or anyone (no user configured)
            def get_user(self, iserver, username=None, password=None, certificate=None):
                from asyncua.crypto.permission_rules import User, UserRole

                if link.spec.user is None:
                    return User(role=UserRole.User)
                if username == link.spec.user and password == link.password:
                    return User(role=UserRole.User, name=username)
                link.meter.refuse("wrong user name or password")
                return None

        server = Server(user_manager=Users())
        await server.init()
        server.set_endpoint(self.spec.endpoint)
        server.set_server_name("railhil bench")
        await server.set_application_uri(APP_URI)
        if self.spec.security == "None":
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        else:
            cert, key = await self._own_certificate()
            await server.load_certificate(str(cert))
            await server.load_private_key(str(key))
            policy = getattr(ua.SecurityPolicyType, f"Basic256Sha256_{self.spec.security}")
            server.set_security_policy([policy])
            server.set_certificate_validator(self._validate_peer)
        server.set_identity_tokens([ua.UserNameIdentityToken] if self.spec.user is not None
                                   else [ua.AnonymousIdentityToken])
        idx = await server.register_namespace(self.spec.namespace)
        objects = server.nodes.objects
        by_id: dict[ua.NodeId, tuple[int, str]] = {}
        for fid, msg in self.objects.items():
            obj = await objects.add_object(ua.NodeId(msg.name, idx), ua.QualifiedName(msg.name, idx))
            self._nodes[fid] = {}
            for sig in msg.signals:
                vs = self._variable_spec(msg.name, sig.name)
                vtype = getattr(ua.VariantType, vs.type)
                node_id = (ua.NodeId.from_string(vs.node_id) if vs.node_id else
                           ua.NodeId(f"{msg.name}.{sig.name}", idx))
                var = await obj.add_variable(node_id, ua.QualifiedName(sig.name, idx),
                                             ua.Variant(self._initial(vs.type), vtype), varianttype=vtype,
                                             datatype=ua.NodeId(getattr(ua.ObjectIds, vs.type)))
                if sig.unit:
                    await var.add_property(0, "EngineeringUnits", ua.EUInformation(
                        NamespaceUri="http://www.opcfoundation.org/UA/units/un/cefact", UnitId=-1,
                        DisplayName=ua.LocalizedText(sig.unit), Description=ua.LocalizedText(sig.unit)))
                if fid in self.written:
                    await var.set_writable()
                self._nodes[fid][sig.name] = var
                self._types[(fid, sig.name)] = vtype
                by_id[var.nodeid] = (fid, sig.name)
        self._server, self._by_id = server, by_id

        async def post_write(event, _dispatcher) -> None:
            t = time.time()
            touched: dict[int, None] = {}
            written = zip(event.request_params.NodesToWrite, event.response_params or [], strict=False)
            for wv, status in written:
                where = by_id.get(wv.NodeId)
                if where is not None and where[0] in self.written and status.is_good():
                    touched[where[0]] = None
            for fid in touched:
                values = {}
                for name, var in self._nodes[fid].items():
                    values[name] = server.read_attribute_value(var.nodeid).Value.Value
                self._plc_wrote(t, fid, values)

        server.subscribe_server_callback(CallbackType.PostWrite, post_write)
        try:
            await server.start()
        except OSError as exc:
            raise BusError(f"{self.where}: key 'opcua.endpoint' = {self.spec.endpoint!r}: cannot serve "
                           f"OPC UA there: {exc.strerror or exc}") from None
        self._ready.set()
        try:
            await self._stop.wait()
        finally:
            await server.stop()

    def _variable_spec(self, obj: str, var: str):
        spec = self.device.spec
        return (spec.writes.get(obj) or spec.reads[obj])[var]

    @staticmethod
    def _initial(type_name: str):
        return False if type_name == "Boolean" else 0.0 if type_name in ("Float", "Double") else 0

    # ------------------------------------------------------------------------------------ client role
    async def _connect(self) -> None:
        from asyncua import Client
        from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

        ua = _ua()
        client = Client(self.spec.endpoint, timeout=CALL_TIMEOUT_S)
        client.application_uri = APP_URI
        client.name = "railhil bench"
        if self.spec.security != "None":
            cert, key = await self._own_certificate()
            trust = self.device.path.parent / self.spec.trust[0]
            await client.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key),
                                      server_certificate=str(trust),
                                      mode=getattr(ua.MessageSecurityMode, self.spec.security))
            client.certificate_validator = self._validate_peer
        if self.spec.user is not None:
            client.set_user(self.spec.user)
            client.set_password(self.password)
        try:
            await client.connect()
        except (TimeoutError, OSError) as exc:
            reason = (exc.strerror if isinstance(exc, OSError) and exc.strerror else
                      f"no answer within {CALL_TIMEOUT_S:g} s" if isinstance(exc, asyncio.TimeoutError)
                      else str(exc) or type(exc).__name__)
            raise BusError(f"{self.where}: key 'opcua.endpoint' = {self.spec.endpoint!r}: cannot reach the "
                           f"PLC's OPC UA server: {reason}") from None
        except ua.UaError as exc:
            raise DeviceError(f"{self.where}: key 'opcua.endpoint' = {self.spec.endpoint!r}: the PLC's "
                              f"server refused the bench ({self.security_note}"
                              f"{', user ' + self.spec.user if self.spec.user else ''}): {exc}") from None
        try:
            await self._find_variables(client)
            self._client = client
            self._ready.set()
            await self._poll(client)
        finally:
            try:
                await client.disconnect()
            except Exception:   # noqa: BLE001 - a PLC gone at the end: nothing left to tell it
                pass

    async def _find_variables(self, client) -> None:
        """Each variable of the device file on the PLC's server, its data type checked."""
        ua = _ua()
        try:
            idx = await client.get_namespace_index(self.spec.namespace)
        except ValueError:
            names = await client.get_namespace_array()
            raise DeviceError(f"{self.where}: key 'opcua.namespace' = {self.spec.namespace!r}: the PLC's "
                              f"server has no such namespace; it has {', '.join(names)}") from None
        objects = client.nodes.objects
        for fid, msg in self.objects.items():
            self._nodes[fid] = {}
            for sig in msg.signals:
                vs = self._variable_spec(msg.name, sig.name)
                key = f"{'writes' if fid in self.written else 'reads'}.{msg.name}.{sig.name}"
                try:
                    if vs.node_id:
                        node = client.get_node(vs.node_id)
                        await node.read_browse_name()
                    else:
                        node = await objects.get_child([f"{idx}:{msg.name}", f"{idx}:{sig.name}"])
                except ua.UaStatusCodeError:
                    shown = vs.node_id or f"Objects/{msg.name}/{sig.name} in {self.spec.namespace}"
                    names = await self._browse_names(objects)
                    close = difflib.get_close_matches(f"{msg.name}/{sig.name}", names, n=3, cutoff=0.4)
                    raise DeviceError(f"{self.where}: key '{key}': the PLC's server has no variable {shown}; "
                                      f"closest browse names: {', '.join(close) or '(none)'}") from None
                dtype = await node.read_data_type()
                want = ua.NodeId(getattr(ua.ObjectIds, vs.type))
                if dtype != want:
                    got = (ua.ObjectIdNames.get(dtype.Identifier, str(dtype)) if dtype.NamespaceIndex == 0
                           else str(dtype))
                    raise DeviceError(f"{self.where}: key '{key}': the variable's data type on the PLC is "
                                      f"{got}, the device file says {vs.type}")
                await self._check_unit(node, vs.unit, key)
                self._nodes[fid][sig.name] = node
                self._types[(fid, sig.name)] = getattr(ua.VariantType, vs.type)

    async def _check_unit(self, node, unit: str | None, key: str) -> None:
        """The variable's EngineeringUnits (where the PLC's server gives them) against the file's unit: the
        same unit, or a DeviceError naming both (a PLC in km/h mapped as m/s would be off by 3.6)."""
        from asyncua.ua import UaStatusCodeError


        try:
            eu = await (await node.get_child("0:EngineeringUnits")).read_value()
        except UaStatusCodeError:
            return                                # the server names no unit: the file's stands
        text = (getattr(getattr(eu, "DisplayName", None), "Text", None) or "").strip()
        if not text or text == (unit or ""):
            return
        where = f"{self.where}: key '{key}'"
        try:
            a, b = affine(text, unit, where=where)
            same = math.isclose(a, 1.0, rel_tol=1e-9) and abs(b) < 1e-9
        except DeviceError:
            same = False
        if not same:
            raise DeviceError(f"{where}: the PLC's server gives the variable the unit {text!r}, the device "
                              f"file says {unit or 'none'}; give it unit = {text!r}")

    @staticmethod
    async def _browse_names(objects) -> list[str]:
        """OBJECT/VARIABLE of every variable two levels under Objects (the server's own folder left out)."""
        out = []
        for obj in await objects.get_children():
            name = (await obj.read_browse_name()).Name
            if name == "Server":
                continue
            for child in await obj.get_children():
                out.append(f"{name}/{(await child.read_browse_name()).Name}")
        return out

    async def _poll(self, client) -> None:
        """Read the PLC's variables every cycle_ms / POLL_DIVISOR; a change is its write."""
        period = self.spec.cycle_ms / 1000 / POLL_DIVISOR
        loop = asyncio.get_running_loop()
        due = loop.time()
        while not self._stop.is_set():
            for fid in self.written:
                nodes = self._nodes[fid]
                t_call = time.perf_counter()
                try:
                    values = await client.read_values(list(nodes.values()))
                except Exception:   # noqa: BLE001 - a PLC that does not answer is silent, counted
                    self.meter.refuse("read failed")
                    continue
                self.meter.calls_us.append(int((time.perf_counter() - t_call) * 1e6))
                got = dict(zip(nodes, values, strict=True))
                if got != self._last_values.get(fid):
                    self._last_values[fid] = got
                    self._plc_wrote(time.time(), fid, got)
            due += period
            try:
                await asyncio.wait_for(self._stop.wait(), max(0.0, due - loop.time()))
            except TimeoutError:
                pass

    # ------------------------------------------------------------------------------------ both roles
    def _plc_wrote(self, t: float, fid: int, values: dict) -> None:
        self._in.append((t, fid, self.meter.plc_wrote(fid, values, t)))
        try:
            os.write(self._w, b"w")
        except OSError:                          # the pipe is full: the host is behind, the queue holds it
            pass

    def _write_soon(self, fid: int, values: dict, t: float) -> None:
        self.meter.bench_wrote(fid, values, t)
        asyncio.ensure_future(self._write(fid, values))

    async def _write(self, fid: int, values: dict) -> None:
        ua = _ua()
        nodes = self._nodes.get(fid, {})
        pairs = []
        for name, node in nodes.items():
            if name not in values or not math.isfinite(values[name]):
                continue
            vtype = self._types[(fid, name)]
            v = values[name]
            v = (bool(v) if vtype == ua.VariantType.Boolean else float(v) if vtype in
                 (ua.VariantType.Float, ua.VariantType.Double) else int(round(v)))
            pairs.append((node, ua.DataValue(ua.Variant(v, vtype))))
        if self.spec.role == "server":
            for node, dv in pairs:
                await self._server.write_attribute_value(node.nodeid, dv)
            return
        t_call = time.perf_counter()
        try:
            await self._client.write_values([n for n, _ in pairs], [dv for _, dv in pairs])
        except Exception:   # noqa: BLE001 - counted: the PLC did not take the bench's values
            self.meter.refuse("write failed")
            return
        self.meter.calls_us.append(int((time.perf_counter() - t_call) * 1e6))

    # ------------------------------------------------------------------------------------ the record
    def payload(self, t0_epoch: float | None = None, end_epoch: float | None = None) -> dict:
        """The link's figures for the run's records (LinkMeter.record), its host beside them."""
        return {**self.meter.record(self.security_note, t0_epoch, end_epoch),
                "host": urlparse(self.spec.endpoint).hostname}
