"""Trace reading and decoding: column reader, `trace decode`, `timing` against python-can and cantools.

All figures come from one run on traces generated here, in a temporary directory, with python-can's
writers: 10⁶ frames of dbc/train_brake.dbc (8 cars: every cyclic message at its GenMsgCycleTime,
each with its own phase and up to 0.3 ms of jitter, payloads encoded by hil.can.codec with counters
counting and smooth values), as BLF; the first 200 000 of them as candump -L text (.log).

(a) the `timing` read path in this process: ``hil.trace.columns.read_columns`` against python-can's
    ``can.LogReader`` with the per-frame loop ``hil.trace.timing.frame_arrays`` (equal columns checked);
(b) ``railhil trace decode X.log --dbc dbc/train_brake.dbc`` against ``cantools decode
    dbc/train_brake.dbc < X.log``, both as subprocesses with defaults, output to /dev/null, best of 2
    each (interpreter start-up and imports included, as a user sees them); also railhil on the
    10⁶-frame BLF (no cantools figure: ``cantools decode`` reads candump text only).  With
    ``--large``, the same comparison on all 10⁶ frames as candump text (cantools takes a minute):
    the ratio grows with the trace, as start-up weighs less;
(c) ``railhil timing X.blf --dbc dbc/train_brake.dbc`` on the 10⁶-frame BLF as a subprocess, end to
    end (interpreter start-up included); while the CLI still reads with ``frame_arrays(open_trace())``,
    also the same command with ``read_trace_columns`` wired in (the outputs are checked equal);
(d) writing BLF, as the lockstep runner does a frame at a time: ``hil.trace.writers.BlfWriter.write_frame``
    against python-can's ``BLFWriter.on_message_received`` with the ``can.Message`` built for it (as
    hil/runtime/lockstep.py builds it), on the first 200 000 frames, side by side in one run (the
    rounds alternate; best of 5 each; the files checked byte-identical), with the containers compressed
    beside the writing thread (as ``open_writer`` makes it) and in it (as python-can does); and zlib
    alone at python-can's level on the same containers, the floor for a writer that compresses in its
    own thread.

    python bench/bench_trace.py [--large]
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import can
import numpy as np
from bench_plain import verdict
from can.io import blf as blf_format

ISSUE = "#8"                  # the issue that set the goals printed here (bench/run_all.py)
DECODE_GOAL = 5.0             # railhil trace decode ≥ 5× cantools decode on the same trace (issue #8)
BLF_WRITE_GOAL = 3.0          # write_frame ≥ 3× python-can's on_message_received, a frame each (issue #8)
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from hil.can.codec import Codec  # noqa: E402
from hil.can.dbc import load_dbc  # noqa: E402
from hil.trace.columns import read_columns  # noqa: E402
from hil.trace.timing import frame_arrays  # noqa: E402
from hil.trace.writers import BLF_COMPRESS_THREADS, BlfWriter  # noqa: E402

DBC = ROOT / "dbc" / "train_brake.dbc"
BIN = Path(sys.executable).parent
BLF_FRAMES = 1_000_000
LOG_FRAMES = 200_000
WRITE_FRAMES = 200_000   # (d): frames written to BLF a frame at a time
WRITE_ROUNDS = 5         # (d): rounds of python-can, write_frame (beside), write_frame (in the thread)
POOL = 256  # payloads per message, used in turn: 8-bit and 4-bit counters count without a jump
JITTER_S = 0.3e-3  # each frame late by up to this (uniform), like arbitration delay on a loaded bus
SEED = 8

# `railhil timing` with hil.trace.columns.read_trace_columns in place of frame_arrays(open_trace(...)),
# for as long as hil/cli/timing.py reads the slow way (the change proposed in issue #8)
WIRED = """
import sys
import hil.cli.timing as cli
from hil.cli.main import main
from hil.trace.columns import read_trace_columns

class Opened:
    def __init__(self, path):
        self.path, self.name, self.skipped, self.first_skipped = path, str(path), 0, ""

def columns(opened):
    arrays, trace = read_trace_columns(opened.path)
    opened.skipped, opened.first_skipped = trace.skipped, trace.first_skipped
    return arrays

cli.open_trace, cli.frame_arrays = Opened, columns
raise SystemExit(main(sys.argv[1:]))
"""


def synthesise(n: int) -> tuple[np.ndarray, np.ndarray, list[bytes]]:
    """The first `n` frames of the DBC's cyclic messages on one bus: times [s], ids, payloads."""
    db = load_dbc(DBC)
    codec = Codec(db)
    rng = np.random.default_rng(SEED)
    cyclic = [m for m in db.messages if m.cycle_time and m.cycle_time > 0 and not m.is_extended_frame]
    rate = sum(1e3 / m.cycle_time for m in cyclic)  # frames per second
    duration = n / rate * 1.01 + 1.0
    times, ids, payload_of = [], [], []
    for m in cyclic:
        period = m.cycle_time / 1e3
        k = np.arange(int(duration / period) + 1)
        t = 100.0 + rng.uniform(0, period) + k * period + rng.uniform(0, JITTER_S, len(k))
        times.append(t)
        ids.append(np.full(len(k), m.frame_id))
        fc = codec.by_name(m.name)
        phase = rng.uniform(0, 2 * np.pi, len(m.signals))
        pool = []
        for i in range(POOL):
            values = {}
            for s, ph in zip(m.signals, phase, strict=True):
                lo = s.minimum if s.minimum is not None else 0.0
                hi = s.maximum if s.maximum is not None else 1.0
                if "counter" in s.name.lower():
                    values[s.name] = i % (int(hi) + 1)
                elif s.length == 1 or s.choices:
                    values[s.name] = float(round(lo + (hi - lo) * (0.5 + 0.5 * math.sin(2 * np.pi * i / POOL
                                                                                      + ph))))
                else:
                    values[s.name] = lo + (hi - lo) * (0.5 + 0.45 * math.sin(2 * np.pi * i / POOL + ph))
            pool.append(fc.encode(values))
        payload_of.append(pool)
    t = np.concatenate(times)
    which = np.concatenate([np.full(len(x), i) for i, x in enumerate(times)])
    seq = np.concatenate([np.arange(len(x)) for x in times])
    order = np.argsort(t, kind="stable")[:n]
    payloads = [payload_of[w][s % POOL]
                for w, s in zip(which[order].tolist(), seq[order].tolist(), strict=True)]
    return t[order], np.concatenate(ids)[order], payloads


def write(path: Path, t: np.ndarray, ids: np.ndarray, payloads: list[bytes]) -> Path:
    """The frames written with python-can's writer for the suffix (can.Logger)."""
    with can.Logger(str(path)) as writer:
        for ts, arb, data in zip(t.tolist(), ids.tolist(), payloads, strict=True):
            writer.on_message_received(can.Message(timestamp=ts, arbitration_id=arb, is_extended_id=False,
                                                   data=data, channel=0))
    return path


def wall(argv: list[str], stdin: Path | None = None) -> tuple[float, subprocess.CompletedProcess]:
    """Wall time [s] of one subprocess, stdin from `stdin` (or /dev/null), stdout to /dev/null."""
    with open(stdin if stdin is not None else os.devnull, "rb") as inp:
        t0 = time.perf_counter()
        proc = subprocess.run(argv, stdin=inp, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT)
        elapsed = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(map(str, argv))} failed ({proc.returncode}): "
                           f"{proc.stderr.decode()[-300:]}")
    return elapsed, proc


def captured(argv: list[str]) -> tuple[float, str]:
    """Wall time [s] and stdout of one subprocess."""
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, cwd=ROOT, text=True)
    elapsed = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(map(str, argv))} failed ({proc.returncode}): {proc.stderr[-300:]}")
    return elapsed, proc.stdout


def best(fn, repeat: int) -> float:
    """Best wall time [s] of `repeat` calls."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def rate(frames: int, seconds: float) -> str:
    return f"{frames / seconds / 1e3:,.0f} k frames/s ({seconds:.2f} s)"


def timing_uses_columns() -> bool:
    import hil.cli.timing as cli
    return hasattr(cli, "read_trace_columns") or hasattr(cli, "read_columns")


def best_wall(argv: list, repeat: int, stdin: Path | None = None
              ) -> tuple[float, subprocess.CompletedProcess]:
    """Best wall time [s] of `repeat` runs of a subprocess (see `wall`), and the last run."""
    runs = [wall(argv, stdin) for _ in range(repeat)]
    return min(t for t, _ in runs), runs[-1][1]


def decode_rows(log: Path, frames: int) -> list[tuple[str, str]]:
    """(b): `railhil trace decode` against `cantools decode` on one candump -L trace of `frames` frames."""
    size = f"{frames // 1000}k" if frames < 10 ** 6 else f"{frames // 10 ** 6}M"
    t_rail, proc = best_wall([BIN / "railhil", "trace", "decode", log, "--dbc", DBC], 2)
    # every frame decoded: the whole job, or no figure
    assert f"{frames} frames decoded" in proc.stderr.decode(), proc.stderr[-300:]
    t_cant, _ = best_wall([BIN / "cantools", "decode", DBC], 2, stdin=log)
    return [(f"(b) railhil trace decode .log {size} (subprocess, best of 2)", rate(frames, t_rail)),
            (f"(b) cantools decode < .log {size} (subprocess, best of 2)", rate(frames, t_cant)),
            (f"(b) ratio railhil / cantools, {size} frames (goal >= {DECODE_GOAL:g}x)",
             verdict(t_cant / t_rail, DECODE_GOAL))]


def blf_write_rows(tmp: Path, t: np.ndarray, ids: np.ndarray, payloads: list[bytes]) -> list[tuple[str, str]]:
    """(d): BLF written a frame at a time, `BlfWriter.write_frame` against Message + python-can."""
    import zlib

    frames = list(zip(t.tolist(), ids.tolist(), payloads, strict=True))
    n = len(frames)
    size = f"{n // 1000}k"
    files = {"python-can": tmp / "python-can.blf", "beside": tmp / "beside.blf", "in": tmp / "in.blf"}

    def python_can() -> None:
        with can.BLFWriter(str(files["python-can"])) as writer:
            for ts, arb, data in frames:
                writer.on_message_received(can.Message(timestamp=ts, arbitration_id=arb, is_extended_id=False,
                                                       data=data, dlc=len(data), channel=0, check=False))

    def railhil(name: str, threads: int):
        def write() -> None:
            with BlfWriter(str(files[name]), compress_threads=threads) as writer:
                write_frame = writer.write_frame
                for ts, arb, data in frames:
                    write_frame(ts, arb, False, data)
        return write

    runs = {"python-can": python_can, "beside": railhil("beside", BLF_COMPRESS_THREADS),
            "in": railhil("in", 0)}
    times: dict[str, list[float]] = {name: [] for name in runs}
    cpu: dict[str, list[float]] = {name: [] for name in runs}   # this thread's CPU time: not the helper's
    for _ in range(WRITE_ROUNDS):                       # side by side: a load that comes and goes hits all
        for name, fn in runs.items():
            c0 = time.thread_time()
            times[name].append(best(fn, 1))
            cpu[name].append(time.thread_time() - c0)
    reference = files["python-can"].read_bytes()
    for name in ("beside", "in"):                       # the same job, else no figure
        assert files[name].read_bytes() == reference, f"{name}: not python-can's file"
    us = {name: min(ts) / n * 1e6 for name, ts in times.items()}
    cpu_us = {name: min(ts) / n * 1e6 for name, ts in cpu.items()}

    containers = []                                     # zlib alone on the file's containers
    with open(files["python-can"], "rb") as f:
        f.seek(blf_format.FILE_HEADER_SIZE)
        while head := f.read(blf_format.OBJ_HEADER_BASE_STRUCT.size):
            obj_size = blf_format.OBJ_HEADER_BASE_STRUCT.unpack(head)[3]
            body = f.read(obj_size - len(head))
            f.read(obj_size % 4)                        # python-can's padding
            containers.append(zlib.decompress(body[blf_format.LOG_CONTAINER_STRUCT.size:]))
    t_zlib = best(lambda: [zlib.compress(c, -1) for c in containers], 3)

    label = f"(d) BLF write {size}, a frame at a time (best of {WRITE_ROUNDS})"
    return [(f"{label}: python-can on_message_received (incl. can.Message)",
             f"{us['python-can']:.2f} µs/frame"),
            (f"{label}: railhil write_frame, compressed beside (open_writer's)",
             f"{us['beside']:.2f} µs/frame (the writing thread's CPU: {cpu_us['beside']:.2f} µs/frame, "
             f"python-can's: {cpu_us['python-can']:.2f})"),
            (f"{label}: railhil write_frame, compressed in the writing thread", f"{us['in']:.2f} µs/frame"),
            (f"(d) of which zlib at python-can's level ({len(containers)} containers, best of 3)",
             f"{t_zlib / n * 1e6:.2f} µs/frame"),
            ("(d) BLF write: railhil write_frame vs python-can on_message_received (incl. can.Message) "
             f"(goal >= {BLF_WRITE_GOAL:g}x)",
             f"{verdict(us['python-can'] / us['beside'], BLF_WRITE_GOAL)} (compressed in the writing thread: "
             f"{us['python-can'] / us['in']:.1f}x)")]


def run(large: bool = False) -> list[tuple[str, str]]:
    rows: list[tuple[str, str]] = []
    with tempfile.TemporaryDirectory(prefix="railhil-bench-trace-") as tmp:
        t0 = time.perf_counter()
        t, ids, payloads = synthesise(BLF_FRAMES)
        blf = write(Path(tmp) / "train_1M.blf", t, ids, payloads)
        log = write(Path(tmp) / "train_200k.log", t[:LOG_FRAMES], ids[:LOG_FRAMES], payloads[:LOG_FRAMES])
        rows.append(("traces generated (python-can BLFWriter, CanutilsLogWriter)",
                     f"{BLF_FRAMES:,} + {LOG_FRAMES:,} frames in {time.perf_counter() - t0:.1f} s"))
        write_rows = blf_write_rows(Path(tmp), t[:WRITE_FRAMES], ids[:WRITE_FRAMES], payloads[:WRITE_FRAMES])
        del t, ids, payloads  # 10⁶ payloads: not to weigh on what is measured next

        # (a) the read path of `timing`, in this process
        ours = read_columns(blf)
        t_ours = best(lambda: read_columns(blf), 3)
        t1 = time.perf_counter()
        theirs = frame_arrays(can.LogReader(blf))
        t_theirs = time.perf_counter() - t1
        for c in ("t", "arbitration_id", "extended", "dlc", "kind", "fd"):  # the same job, else no figure
            assert np.array_equal(getattr(ours, c), getattr(theirs, c)), c
        assert len(ours) == BLF_FRAMES
        rows.append(("(a) BLF 1M to columns: read_columns (best of 3)", rate(BLF_FRAMES, t_ours)))
        rows.append(("(a) BLF 1M to columns: can.LogReader + frame_arrays", rate(BLF_FRAMES, t_theirs)))
        rows.append(("(a) ratio read_columns / python-can", f"{t_theirs / t_ours:.1f}x"))

        # (b) decoding candump text, railhil against cantools
        rows += decode_rows(log, LOG_FRAMES)
        t_blf, proc = best_wall([BIN / "railhil", "trace", "decode", blf, "--dbc", DBC], 2)
        assert f"{BLF_FRAMES} frames decoded" in proc.stderr.decode(), proc.stderr[-300:]
        rows.append(("(b) railhil trace decode .blf 1M (subprocess, best of 2)", rate(BLF_FRAMES, t_blf)))
        if large:
            t, ids, payloads = synthesise(BLF_FRAMES)
            big = write(Path(tmp) / "train_1M.log", t, ids, payloads)
            del t, ids, payloads
            rows += decode_rows(big, BLF_FRAMES)

        # (c) `railhil timing` on the 1M-frame BLF, end to end
        argv = ["timing", blf, "--dbc", DBC]
        t_cli, out_cli = captured([BIN / "railhil", *argv])
        assert f"{BLF_FRAMES} frames" in out_cli, out_cli[:200]
        shipped = "read_columns" if timing_uses_columns() else "frame_arrays(open_trace())"
        rows.append((f"(c) railhil timing BLF 1M, as shipped ({shipped})", rate(BLF_FRAMES, t_cli)))
        if not timing_uses_columns():
            runs = [captured([sys.executable, "-c", WIRED, *argv]) for _ in range(2)]
            assert all(out == out_cli for _, out in runs), "the wired command must print the same report"
            t_wired = min(t for t, _ in runs)
            rows.append(("(c) railhil timing BLF 1M, read_trace_columns wired in (best of 2)",
                         rate(BLF_FRAMES, t_wired)))
            rows.append(("(c) ratio wired / shipped", f"{t_cli / t_wired:.1f}x"))
        t_start = min(captured([BIN / "railhil", "timing", "--help"])[0] for _ in range(2))
        rows.append(("(c) of which start-up, imports (railhil timing --help, best of 2)", f"{t_start:.2f} s"))
        rows += write_rows                              # (d), measured above
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--large", action="store_true",
                        help="also compare trace decode with cantools decode on 10^6 frames of candump text "
                             "(cantools takes about a minute)")
    rows = run(parser.parse_args().large)
    width = max(len(label) for label, _ in rows)
    print(f"trace reading and decoding (python-can {can.__version__}, Python {sys.version.split()[0]}, "
          f"{os.cpu_count()} CPUs)")
    for label, figure in rows:
        print(f"  {label:<{width}}  {figure}")


if __name__ == "__main__":
    main()
