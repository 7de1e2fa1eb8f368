"""Progress bars (hil.progress): drawn on a terminal, silent in a pipe or a file, so that `make bench > log`
or a CI log holds a command's results and not a bar's carriage-return updates; and a command whose
output is not a terminal still prints its result."""

from __future__ import annotations

import io
import os
import select
import subprocess
import sys

from conftest import ROOT

from hil.progress import progress_bar

STOP = ROOT / "scenarios" / "stop_30kmh.toml"


def drawn(enabled: bool) -> bytes:
    """What a bar of 3 steps, `enabled` or not, writes to a pseudo-terminal."""
    master, slave = os.openpty()
    try:
        with os.fdopen(slave, "w", closefd=False) as tty:
            bar = progress_bar(3, enabled=enabled, file=tty, desc="steps", mininterval=0)
            for _ in range(3):
                bar.update()
            bar.close()
            tty.flush()
        out = b""
        while select.select([master], [], [], 0)[0]:       # what is there now: the writes are done
            out += os.read(master, 4096)
        return out
    finally:
        os.close(master)
        os.close(slave)


def test_a_bar_draws_on_a_terminal_unless_turned_off():
    out = drawn(True)
    assert b"\r" in out and b"3/3" in out
    assert drawn(False) == b""                       # -q


def test_a_bar_writes_nothing_to_a_stream_that_is_not_a_terminal():
    stream = io.StringIO()
    bar = progress_bar(3, file=stream, desc="steps", mininterval=0)
    assert bar.disable
    for _ in range(3):
        bar.update()
    bar.n = 2                                        # as hil.cli.run.Progress and bench_bus set it
    bar.refresh()
    bar.set_postfix_str("v=0 km/h")
    bar.close()
    assert stream.getvalue() == ""


def test_a_campaign_into_pipes_prints_its_result_and_no_progress_bar(tmp_path):
    """`railhil campaign` without -q, stdout and stderr to pipes (as `make bench > log` or CI): the summary
    and the files on stdout, and not one carriage return in either stream."""
    campaign = tmp_path / "c.toml"
    campaign.write_text(f'base = "{STOP}"\nname = "piped"\nseed = 1\n[set]\nmax_duration_s = 0.5\n'
                        '"train.cars" = 1\n[random]\nn = 2\n"seed" = { integers = [1, 1000] }\n')
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "hil", "campaign", str(campaign), "--jobs", "1", "-o",
                           str(out)], cwd=ROOT, capture_output=True, timeout=300)
    stdout, stderr = proc.stdout.decode(), proc.stderr.decode()
    assert proc.returncode == 0, stderr
    assert "2 of 2 points finished (2 ok, 0 from cache, 0 failed)" in stdout
    assert f"files: {out / 'results.csv'}" in stdout
    assert "\r" not in stdout and "\r" not in stderr
    assert "point/s" not in stderr and "s/point" not in stderr
