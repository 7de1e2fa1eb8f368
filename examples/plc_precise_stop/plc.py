"""A PLC stand-in running seed 002's stopping program (stopping_program.py) over OPC UA, with asyncua only.

    export RAILHIL_PLC_PASSWORD=brake-valve-4
    python examples/plc_precise_stop/plc.py &            # a client of the bench's server (the default)
    railhil run precise_stop --realtime --set precise_stop.method=plc \\
        --device examples/plc_precise_stop/plc_precise_stop.toml

    python examples/plc_precise_stop/plc.py --serve &    # or its own server, the bench its client
    railhil run precise_stop --realtime --set precise_stop.method=plc \\
        --device examples/plc_precise_stop/plc_serves.toml

Every 100 ms (absolute deadlines, as a PLC's cyclic interrupt) it reads Train.Position, Speed, Target and
the bench's Stamp, runs one scan of the program and writes Brake.Valve, Brake.Target and Brake.Echo (the
stamp it read).  Security as a PLC's: Basic256Sha256 SignAndEncrypt with its own application certificate
(pki/plc.der, created on first run: the device file trusts it), the user "plc" and the password in
RAILHIL_PLC_PASSWORD.  As a client it trusts the bench's certificate on first contact (the endpoint's);
as a server it accepts a client with any certificate that logs in with the user and password.  It
reconnects while the bench is not there (the bench opens its server once to check it before the run).
Ctrl-C, SIGTERM or --duration end it with one line: scans, late scans, writes, reconnects.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
import socket
import sys
import time
from pathlib import Path

from asyncua import Client, Server, ua
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from cryptography.x509.oid import ExtendedKeyUsageOID
from stopping_program import StoppingProgram

HERE = Path(__file__).resolve().parent
NAMESPACE = "urn:railhil:plc-precise-stop"
APP_URI = "urn:railhil:example:plc"
USER = "plc"
PASSWORD_ENV = "RAILHIL_PLC_PASSWORD"
INPUTS = {"Position": ua.VariantType.Double, "Speed": ua.VariantType.Double,
          "Target": ua.VariantType.Double, "Stamp": ua.VariantType.UInt32}
OUTPUTS = {"Valve": ua.VariantType.Int16, "Target": ua.VariantType.Double, "Echo": ua.VariantType.UInt32}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="plc.py", description="seed 002's stopping program on a PLC stand-in, "
                                "over OPC UA (asyncua)")
    p.add_argument("--serve", action="store_true",
                   help="run its own OPC UA server (the bench is its client); default: a client of the "
                        "bench's server")
    p.add_argument("--endpoint", help="the bench's server (default opc.tcp://127.0.0.1:48400/railhil) or, "
                   "with --serve, its own (default opc.tcp://127.0.0.1:48410/plc)")
    p.add_argument("--method", choices=("adaptive_diff", "adaptive"), default="adaptive_diff",
                   help="with the differentiation unit (Fig. 3, default) or without (Fig. 2)")
    p.add_argument("--security", choices=("SignAndEncrypt", "None"), default="SignAndEncrypt")
    p.add_argument("--pki", type=Path, default=HERE / "pki", help="its certificate's folder (default: pki/ "
                   "beside this file)")
    p.add_argument("--duration", type=float,
                   help="stop this many seconds after the bench's first update (its Stamp) was read")
    return p


class Plc:
    """The scan loop on absolute deadlines; `read()` and `write()` are the OPC UA side (client or server)."""

    def __init__(self, program: StoppingProgram, duration_s: float | None = None) -> None:
        self.program, self.duration_s = program, duration_s
        self.scans = self.late = self.writes = self.reconnects = 0
        self.end: float | None = None       # --duration: from the first scan with the bench's data

    @property
    def done(self) -> bool:
        return self.end is not None and time.monotonic() >= self.end

    async def cycle(self, read, write, stop: asyncio.Event) -> None:
        period = self.program.p.scan_us / 1e6
        t0 = time.monotonic()
        deadline = t0
        while not stop.is_set() and not self.done:
            now = time.monotonic()
            if now < deadline:
                await asyncio.sleep(deadline - now)
                continue
            self.late += now - deadline > period / 2
            position, speed, target, stamp = await read()
            if self.end is None and self.duration_s and stamp:     # the bench's first update
                self.end = time.monotonic() + self.duration_s
            now_us = round((deadline - t0) * 1e6)
            valve = self.program.scan(now_us, position, speed, target)
            await write({"Valve": valve, "Target": target, "Echo": stamp})
            self.scans += 1
            self.writes += 1
            deadline += period
            if time.monotonic() > deadline + period:               # far behind: the next slot
                deadline = time.monotonic()


async def certificate(pki: Path) -> tuple[Path, Path]:
    pki.mkdir(parents=True, exist_ok=True)
    cert, key = pki / "plc.der", pki / "plc-key.pem"
    await setup_self_signed_certificate(key, cert, APP_URI, socket.gethostname(),
                                        [ExtendedKeyUsageOID.CLIENT_AUTH, ExtendedKeyUsageOID.SERVER_AUTH],
                                        {"commonName": "railhil example PLC"})
    return cert, key


def variant(name: str, value) -> ua.Variant:
    vtype = OUTPUTS.get(name) or INPUTS[name]
    if vtype in (ua.VariantType.Double, ua.VariantType.Float):
        return ua.Variant(float(value), vtype)
    return ua.Variant(int(value) if value == value else 0, vtype)


async def as_client(plc: Plc, args, password: str | None, stop: asyncio.Event) -> None:
    endpoint = args.endpoint or "opc.tcp://127.0.0.1:48400/railhil"
    cert, key = await certificate(args.pki)
    print(f"PLC: certificate {cert}; connecting to {endpoint}", flush=True)
    announced = False
    while not stop.is_set() and not plc.done:
        client = Client(endpoint, timeout=4)
        client.application_uri = APP_URI
        if password is not None:
            client.set_user(USER)
            client.set_password(password)
        try:
            if args.security != "None":          # (asks the endpoint for the bench's certificate)
                await client.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key),
                                          mode=ua.MessageSecurityMode.SignAndEncrypt)
            await client.connect()
        except Exception:                    # the bench is not there (yet): try again
            await asyncio.sleep(0.2)
            continue
        try:
            idx = await client.get_namespace_index(NAMESPACE)
            objects = client.nodes.objects
            ins = [await objects.get_child([f"{idx}:Train", f"{idx}:{n}"]) for n in INPUTS]
            outs = [await objects.get_child([f"{idx}:Brake", f"{idx}:{n}"]) for n in OUTPUTS]
            if not announced:
                print(f"PLC: on {endpoint} as its client ({args.security}), program {args.method}, scan "
                      f"{plc.program.p.scan_us // 1000} ms", flush=True)
                announced = True

            async def read(client=client, ins=ins):
                return await client.read_values(ins)

            async def write(values, client=client, outs=outs):
                await client.write_values(outs, [variant(n, values[n]) for n in OUTPUTS])

            await plc.cycle(read, write, stop)
        except Exception:                    # the bench went away: reconnect
            plc.reconnects += 1
            await asyncio.sleep(0.2)
        finally:
            try:
                await client.disconnect()
            except Exception:
                pass


async def as_server(plc: Plc, args, secret: str | None, stop: asyncio.Event) -> None:
    endpoint = args.endpoint or "opc.tcp://127.0.0.1:48410/plc"

    class Users:                                # the user "plc" with its password (any certificate)
        def get_user(self, iserver, username=None, password=None, certificate=None):
            if secret is None or (username == USER and password == secret):
                return User(role=UserRole.User, name=username)
            return None

    server = Server(user_manager=Users())
    await server.init()
    server.set_endpoint(endpoint)
    server.set_server_name("railhil example PLC")
    await server.set_application_uri(APP_URI)
    if args.security != "None":
        cert, key = await certificate(args.pki)
        await server.load_certificate(str(cert))
        await server.load_private_key(str(key))
        server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
    else:
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    server.set_identity_tokens([ua.UserNameIdentityToken] if secret is not None else
                               [ua.AnonymousIdentityToken])
    idx = await server.register_namespace(NAMESPACE)
    nodes = {}
    for obj_name, variables in (("Train", INPUTS), ("Brake", OUTPUTS)):
        obj = await server.nodes.objects.add_object(idx, obj_name)
        for name, vtype in variables.items():
            initial = 0.0 if vtype == ua.VariantType.Double else 0
            var = await obj.add_variable(idx, name, ua.Variant(initial, vtype), varianttype=vtype,
                                         datatype=ua.NodeId(getattr(ua.ObjectIds, vtype.name)))
            if obj_name == "Train":
                await var.set_writable()           # the bench writes what the PLC reads
            nodes[(obj_name, name)] = var
    async with server:
        print(f"PLC: serving {endpoint} ({args.security}), program {args.method}, scan "
              f"{plc.program.p.scan_us // 1000} ms", flush=True)

        async def read():
            return [server.read_attribute_value(nodes[("Train", n)].nodeid).Value.Value for n in INPUTS]

        async def write(values):
            for n in OUTPUTS:
                await server.write_attribute_value(nodes[("Brake", n)].nodeid,
                                                   ua.DataValue(variant(n, values[n])))

        await plc.cycle(read, write, stop)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    for name in ("asyncua", "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    password = os.environ.get(PASSWORD_ENV)
    if args.security != "None" and password is None:
        print(f"error: set {PASSWORD_ENV}: the PLC's user {USER!r} logs in with it", file=sys.stderr)
        return 2
    plc = Plc(StoppingProgram(diff=args.method == "adaptive_diff"), args.duration)

    async def run() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await (as_server if args.serve else as_client)(plc, args, password, stop)

    try:
        asyncio.run(run())
    except OSError as exc:
        print(f"error: {args.endpoint or 'the endpoint'}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    print(f"PLC: {plc.scans} scans, {plc.late} late, {plc.writes} writes, {plc.reconnects} reconnects",
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
