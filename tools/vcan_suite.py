"""make test-vcan: the SocketCAN tests (tests/can/test_socketcan.py) on virtual CAN buses vcan0 and vcan1.

Where this machine's kernel has SocketCAN (a Linux box with the vcan module), the tests run here, on vcan0
and vcan1 (created, as root or through sudo, where missing). Where it has none (this development VM:
AF_CAN is refused), a Debian kernel is booted under qemu by virtme-ng, with this machine's files as its
root file system, read-only, and the project's .venv in it: the guest loads vcan and can-raw, creates
vcan0 and vcan1 and runs the same tests with the same venv, writing its JUnit XML and pytest's exit code
into OUT (a folder virtme-ng shares read-write), and this script reports them as its own.

What it needs and installs where missing: Debian's qemu-system-x86, linux-image-amd64 (vcan, can-raw and
9p as modules), busybox-static (virtme-ng's initramfs) and can-utils (candump, cansend: the peer no one
here wrote), with apt-get as root or through sudo, as .ci/run does; virtme-ng, the `vcan` extra of
pyproject.toml, with pip into this venv.

The VM runs under software emulation (qemu's TCG) by default: nested KVM hangs on the development VM.
VCAN_KVM=1 (or --kvm) asks for KVM. Under TCG the guest CPU is a Westmere (SSE4.2, no AVX): with qemu
7.2's `-cpu max`, which offers AVX2, numpy's argsort crashed the guest's Python (SIGSEGV) in every
real-time run. The guest's Python runs about 30x slower than the host's: the suite is kept small.

    python tools/vcan_suite.py [--out DIR] [--kvm] [-- PYTEST ARGS...]

Exit: pytest's exit code (0 all passed); 1 also when a test skipped for want of SocketCAN or can-utils
(a gap, not a pass); 2 when the suite cannot be run here (one line `error: ...`).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = ["tests/can/test_socketcan.py"]
OUT = ROOT / "runs" / "test-vcan"
CHANNELS = ("vcan0", "vcan1")
EXIT_CODE_FILE = "pytest-exit-code"
JUNIT_FILE = "junit.xml"
GAPS = ("no SocketCAN", "can-utils")   # a skip that says one of these is a gap in make test-vcan: it fails
VM_TIMEOUT_S = float(os.environ.get("VCAN_TIMEOUT_S", 14 * 60))   # the whole VM, boot to power-off
TEST_TIMEOUT_S = 900                   # pytest-timeout per test inside the VM (pyproject.toml: 300)
TCG_CPU = "Westmere"                   # the guest CPU under software emulation (module docstring)
GUEST_MEMORY = "2G"
GUEST_RMEM_MAX = 4 << 20               # the guest's net.core.rmem_max, as on the development host (below)
BOOTED = "test-vcan: guest up"         # the guest's first line: the host takes the boot time from it
# the folders virtme-ng gives the guest as writable overlays of the host's (writes stay in the guest)
GUEST_WRITABLE = ("/etc", "/home", "/opt", "/srv", "/tmp", "/usr", "/var")
DEBIAN = {"qemu-system-x86_64": "qemu-system-x86", "busybox": "busybox-static", "candump": "can-utils"}


class SetupError(Exception):
    """The suite cannot run here: one line, exit 2."""


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=OUT,
                   help=f"the JUnit XML and pytest's exit code (default {OUT.relative_to(ROOT)})")
    p.add_argument("--kvm", action="store_true", default=os.environ.get("VCAN_KVM") == "1",
                   help="boot the VM with KVM instead of software emulation (VCAN_KVM=1)")
    p.add_argument("--guest", action="store_true", help=argparse.SUPPRESS)   # inside the VM
    p.add_argument("pytest_args", nargs="*", help="more pytest arguments (after --), e.g. -k candump")
    args = p.parse_args(argv)
    try:
        if args.guest:
            return in_guest(args.out, args.pytest_args)
        args.out.mkdir(parents=True, exist_ok=True)
        for stale in (EXIT_CODE_FILE, JUNIT_FILE):
            (args.out / stale).unlink(missing_ok=True)
        start = time.monotonic()
        if kernel_has_socketcan():
            code = on_this_machine(args.out, args.pytest_args)
            where = "on this machine (its kernel has SocketCAN)"
        else:
            code, where = in_vm(args.out, args.pytest_args, args.kvm)
        return report(args.out, code, where, time.monotonic() - start)
    except SetupError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


# -- here: the kernel has SocketCAN ------------------------------------------------------------------------
def kernel_has_socketcan() -> bool:
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except (OSError, AttributeError):     # Errno 97: no CAN in this kernel; no AF_CAN: not Linux
        return False
    return True


def on_this_machine(out: Path, pytest_args: list[str]) -> int:
    if shutil.which("candump") is None:
        apt_install(["can-utils"])
    for name in CHANNELS:
        vcan_up(name)
    print(f"test-vcan: on this machine (kernel {os.uname().release}): {', '.join(CHANNELS)} up", flush=True)
    return subprocess.call(pytest_command(out, pytest_args), cwd=ROOT)


def vcan_up(name: str, root: list[str] | None = None) -> None:
    """The virtual CAN device `name`, up: created and set up where it is not (as root: `root`, by default
    `as_root()`)."""
    device = Path(f"/sys/class/net/{name}")
    if device.exists() and int((device / "flags").read_text(), 16) & 0x1:      # IFF_UP
        return
    root = as_root() if root is None else root
    if not device.exists():
        run(root + ["modprobe", "vcan"], f"cannot load the vcan module for {name}")
        run(root + ["ip", "link", "add", "dev", name, "type", "vcan"], f"cannot create {name}")
    run(root + ["ip", "link", "set", "up", name], f"cannot set {name} up")


def as_root() -> list[str]:
    """The prefix that runs a command as root: none for root, `sudo -n` where it works."""
    if os.geteuid() == 0:
        return []
    if shutil.which("sudo") and subprocess.call(["sudo", "-n", "true"], stderr=subprocess.DEVNULL) == 0:
        return ["sudo", "-n"]
    raise SetupError("this needs root (or sudo without a password) to install packages and create vcan "
                     "devices; `sudo make vcan` creates vcan0")


def apt_install(packages: list[str]) -> None:
    """Debian's packages, with apt-get as root or through sudo (as .ci/run's debian_install)."""
    if not shutil.which("apt-get"):
        raise SetupError(f"missing {' '.join(packages)} and no apt-get here: install them and run again")
    root = as_root()
    print(f"test-vcan: installing Debian's {' '.join(packages)}", flush=True)
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    install = root + ["apt-get", "install", "-y", "-q", "--no-install-recommends", *packages]
    if subprocess.call(install, env=env, stdout=subprocess.DEVNULL) != 0:
        subprocess.call(root + ["apt-get", "update", "-q"], env=env, stdout=subprocess.DEVNULL)
        run(install, f"apt-get could not install {' '.join(packages)}", env=env)


def run(cmd: list[str], what: str, **kw) -> None:
    proc = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if proc.returncode != 0:
        why = " ".join((proc.stderr or proc.stdout).split())[-300:]
        raise SetupError(f"{what}: {' '.join(cmd)} exited {proc.returncode}: {why}")


def pytest_command(out: Path, pytest_args: list[str]) -> list[str]:
    return [sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", "--timeout",
            str(TEST_TIMEOUT_S), "-m", "socketcan", *TESTS, "--junitxml", str(out / JUNIT_FILE), *pytest_args]


# -- in a VM: a Debian kernel under qemu, booted by virtme-ng -----------------------------------------------
def in_vm(out: Path, pytest_args: list[str], kvm: bool) -> tuple[int, str]:
    missing = [pkg for tool, pkg in DEBIAN.items() if shutil.which(tool) is None]
    if vcan_kernel() is None:
        missing.append("linux-image-amd64")
    if missing:
        apt_install(missing)
    kernel = vcan_kernel()
    if kernel is None:
        raise SetupError("no kernel in /boot with the vcan module in /lib/modules (linux-image-amd64)")
    vng = Path(sys.executable).parent / "vng"
    if not vng.exists():
        print("test-vcan: installing virtme-ng (the vcan extra)", flush=True)
        run([sys.executable, "-m", "pip", "install", "--quiet", "-c", str(ROOT / "constraints.txt"), "-e",
             f"{ROOT}[test,docs,vcan]"], "cannot install virtme-ng")
    if kvm and not os.access("/dev/kvm", os.R_OK | os.W_OK):
        raise SetupError("VCAN_KVM=1 but /dev/kvm cannot be opened here; without it: software emulation")
    release = kernel.name.removeprefix("vmlinuz-")
    cpus = min(os.cpu_count() or 1, 4)
    accel = "KVM" if kvm else f"software emulation (qemu TCG, a {TCG_CPU} CPU)"
    where = f"in a VM: Debian kernel {release} under qemu, {accel}, {cpus} CPUs"
    cmd = [str(vng), "--run", str(kernel), "--user", "root", "--cpus", str(cpus), "--memory", GUEST_MEMORY,
           "--rwdir", str(out)]
    home = Path.home()
    if not any(home.is_relative_to(d) for d in GUEST_WRITABLE):
        cmd += ["--overlay-rwdir", str(home)]      # caches (matplotlib's fonts, railhil's DBC) usable there
    if not kvm:
        cmd += ["--disable-kvm", f"--qemu-opts=-cpu {TCG_CPU}"]
    guest = [sys.executable, str(Path(__file__).resolve()), "--guest", "--out", str(out), "--", *pytest_args]
    cmd += ["--exec", " ".join(shell_quote(a) for a in guest)]
    print(f"test-vcan: booting {where}", flush=True)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    start = time.monotonic()
    booted = None
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, errors="replace", start_new_session=True)
    timer = threading.Timer(VM_TIMEOUT_S, os.killpg, (proc.pid, signal.SIGKILL))   # a guest that hangs
    timer.start()
    try:
        for line in proc.stdout:              # the guest's console, as it comes
            if booted is None and line.startswith(BOOTED):
                booted = time.monotonic() - start
                line = line.rstrip("\n") + f" ({booted:.1f} s after the boot began)\n"
            sys.stdout.write(line)
            sys.stdout.flush()
        proc.wait()
    finally:
        timer.cancel()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    if time.monotonic() - start >= VM_TIMEOUT_S:
        raise SetupError(f"the VM did not end within {VM_TIMEOUT_S:.0f} s (VCAN_TIMEOUT_S): stopped; its "
                         "console is above")
    code_file = out / EXIT_CODE_FILE
    if not code_file.exists():
        raise SetupError(f"the VM ended (qemu exit {proc.returncode}) without running the suite; its console "
                         "is above")
    if booted is not None:
        where += f"; booted, vcan0 and vcan1 up in {booted:.1f} s"
    return int(code_file.read_text()), where


def vcan_kernel() -> Path | None:
    """The newest kernel image in /boot whose modules have vcan (Debian's linux-image-amd64)."""
    found = []
    for image in Path("/boot").glob("vmlinuz-*"):
        release = image.name.removeprefix("vmlinuz-")
        if os.access(image, os.R_OK) and any(Path(f"/lib/modules/{release}").rglob("vcan.ko*")):
            found.append(image)
    return max(found, key=lambda p: p.stat().st_mtime, default=None)


def shell_quote(arg: str) -> str:
    return arg if re.fullmatch(r"[\w@%+=:,./-]+", arg) else "'" + arg.replace("'", "'\"'\"'") + "'"


# -- inside the VM ---------------------------------------------------------------------------------------
def in_guest(out: Path, pytest_args: list[str]) -> int:
    """vcan0 and vcan1 up, then the suite with the project's venv; its exit code into OUT."""
    print(f"{BOOTED}: kernel {os.uname().release}, {os.cpu_count()} CPUs, {cpu_model()}", flush=True)
    for module in ("vcan", "can-raw"):
        run(["modprobe", module], f"cannot load {module} in the guest")
    for name in CHANNELS:
        vcan_up(name, [])
    # a recorder, a host or candump that falls behind for a while (this guest is slow) keeps its frames in
    # its socket's receive buffer: railhil asks for 4 MiB, which the kernel caps at net.core.rmem_max
    # (208 KiB by default here; 4 MiB on the development host, as railhil's docs measure it)
    Path("/proc/sys/net/core/rmem_max").write_text(f"{GUEST_RMEM_MAX}\n")
    print(f"test-vcan: {', '.join(CHANNELS)} up; net.core.rmem_max {GUEST_RMEM_MAX}", flush=True)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(out / "numba")}    # the plant's compiled step, kept
    code = subprocess.call(pytest_command(out, pytest_args), cwd=ROOT, env=env)
    (out / EXIT_CODE_FILE).write_text(f"{code}\n")
    return code


def cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "CPU model unknown"


# -- the result ------------------------------------------------------------------------------------------
def report(out: Path, code: int, where: str, wall_s: float) -> int:
    """The suite's counts from its JUnit XML, and where and how long it ran; a skip for want of SocketCAN
    or can-utils fails the target (the tests are there to run, not to skip)."""
    junit = out / JUNIT_FILE
    if not junit.exists():
        print(f"error: no JUnit XML at {junit} (pytest exit {code})", file=sys.stderr)
        return code or 2
    suite = ET.parse(junit).getroot()
    suite = suite.find("testsuite") if suite.tag == "testsuites" else suite
    counts = {k: int(suite.get(k, 0)) for k in ("tests", "failures", "errors", "skipped")}
    passed = counts["tests"] - counts["failures"] - counts["errors"] - counts["skipped"]
    gaps = [f"{case.get('name')}: {skip.get('message', '')}" for case in suite.iter("testcase")
            for skip in case.findall("skipped") if any(g in skip.get("message", "") for g in GAPS)]
    print(f"test-vcan: {passed} passed, {counts['failures']} failed, {counts['errors']} errors, "
          f"{counts['skipped']} skipped in {wall_s:.0f} s wall, {where}; JUnit XML: {junit}", flush=True)
    for gap in gaps:
        print(f"error: skipped for want of SocketCAN or can-utils: {gap}", file=sys.stderr)
    return code if code or not gaps else 1


if __name__ == "__main__":
    sys.exit(main())
