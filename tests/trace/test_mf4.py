"""MF4 (ASAM MDF 4 bus logging): a run records its trace as MF4, every trace tool reads it (fast, and
the same as python-can's reader), and `railhil trace export` writes decoded signals as MF4, Parquet and
CSV with their names, units and value tables, equal to cantools' decoding."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import can
import cantools
import numpy as np
import pytest

from hil.cli.main import main
from hil.trace.columns import BlockReader, read_columns
from hil.trace.readers import open_trace
from hil.trace.timing import frame_arrays
from hil.trace.writers import Mf4Writer

asammdf = pytest.importorskip("asammdf", reason="asammdf is not installed: no MF4 here")

ROOT = Path(__file__).resolve().parents[2]
DBC = ROOT / "dbc" / "train_brake.dbc"
FIELDS = ("t", "arbitration_id", "extended", "dlc", "kind", "fd")


@pytest.fixture(scope="module")
def mf4_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("mf4") / "run"
    assert main(["run", "default", "--lockstep", "--set", "trace.format=mf4", "--out", str(out), "-q"]) == 0
    return out


def frames_of(path: Path) -> list[tuple]:
    with can.LogReader(str(path)) as reader:
        return [(m.timestamp, m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in reader]


def test_a_run_records_its_trace_as_mf4_that_asammdf_and_python_can_open(mf4_run, default_lockstep):
    trace = mf4_run / "trace.mf4"
    assert trace.is_file() and not (mf4_run / "trace.blf").exists()
    assert json.loads((mf4_run / "run.json").read_text())["trace"] == "trace.mf4"
    mdf = asammdf.MDF(str(trace))
    groups = {g.channel_group.acq_name: g for g in mdf.groups}
    assert "CAN_DataFrame" in [c.name for g in mdf.groups for c in g.channels] and groups
    mdf.close()
    # the same frames as the BLF trace of the same run; the timestamps to within BLF's 1 ns steps (the
    # MF4 keeps the run's exact float seconds: its epoch is 0)
    mf4, blf = frames_of(trace), frames_of(default_lockstep.out_dir / "trace.blf")
    assert [f[1:] for f in mf4] == [f[1:] for f in blf]
    assert max(abs(a[0] - b[0]) for a, b in zip(mf4, blf, strict=True)) < 2e-9
    kpis = json.loads((mf4_run / "kpis.json").read_text())
    blf_kpis = json.loads((default_lockstep.out_dir / "kpis.json").read_text())
    assert kpis["stopping_distance_m"] == blf_kpis["stopping_distance_m"]
    assert kpis["frames_recorded"] == blf_kpis["frames_recorded"] and kpis["frames_lost"] == 0


def test_the_mf4_trace_of_a_lockstep_run_is_the_same_file_every_time(mf4_run, tmp_path):
    again = tmp_path / "again"
    assert main(["run", "default", "--lockstep", "--set", "trace.format=mf4", "--out", str(again), "-q"]) == 0
    assert (again / "trace.mf4").read_bytes() == (mf4_run / "trace.mf4").read_bytes()


def test_timing_on_the_mf4_gives_the_verdicts_of_the_blf(mf4_run, default_lockstep, capsys):
    verdicts = {}
    for trace in (mf4_run / "trace.mf4", default_lockstep.out_dir / "trace.blf"):
        code = main(["timing", str(trace), "--dbc", str(DBC), "--ignore", "*7_*", "--ignore", "*8_*",
                     "--format", "json"])
        report = json.loads(capsys.readouterr().out)
        verdicts[trace.suffix] = (code, {m["name"]: m["verdict"] for m in report["messages"]})
    assert verdicts[".mf4"] == verdicts[".blf"] and verdicts[".mf4"][0] == 0


def _mixed_frames() -> list[can.Message]:
    """Data frames of both id kinds, remote and error frames, out of step across the groups."""
    out = []
    for k in range(300):
        t = 1.0 + k * 0.001
        out.append(can.Message(timestamp=t, arbitration_id=0x100 + k % 5, data=bytes([k % 256] * (k % 9)),
                               is_extended_id=False))
        if k % 7 == 0:
            out.append(can.Message(timestamp=t + 0.0002, arbitration_id=0x18FF0000 + k, is_extended_id=True,
                                   data=bytes(range(8))))
        if k % 50 == 0:
            out.append(can.Message(timestamp=t + 0.0001, arbitration_id=0x321, is_remote_frame=True, dlc=4,
                                   is_extended_id=False))
        if k % 90 == 0:
            out.append(can.Message(timestamp=t + 0.0003, is_error_frame=True, arbitration_id=0, data=b""))
    return out


@pytest.mark.parametrize("writer", ["railhil", "python-can"])
def test_the_fast_mf4_columns_are_python_cans_reader_column_for_column(tmp_path, writer):
    path = tmp_path / f"{writer}.mf4"
    w = Mf4Writer(str(path), start_time_s=0.0) if writer == "railhil" else can.io.MF4Writer(str(path))
    for m in _mixed_frames():
        w.on_message_received(m)
    w.stop()
    fast, slow = read_columns(path), frame_arrays(open_trace(path))
    assert len(fast) == len(slow) > 300
    for f in FIELDS:
        a, b = getattr(fast, f), getattr(slow, f)
        assert a.dtype == b.dtype and np.array_equal(a, b), f
    with can.LogReader(str(path)) as reader:
        messages = list(reader)
    (block,) = list(BlockReader(path))
    assert [block.payload[i, : block.length[i]].tobytes() for i in range(len(block))] == \
        [bytes(m.data) for m in messages]


def test_railhils_mf4_writer_writes_what_python_cans_writes(tmp_path, default_lockstep):
    with can.LogReader(str(default_lockstep.out_dir / "trace.blf")) as reader:
        messages = list(reader)[:5000]
    ours, theirs = tmp_path / "ours.mf4", tmp_path / "theirs.mf4"
    for w in (Mf4Writer(str(ours), start_time_s=0.0), can.io.MF4Writer(str(theirs))):
        for m in messages:
            w.on_message_received(m)
        w.stop()
    a, b = frames_of(ours), frames_of(theirs)
    assert [x[1:] for x in a] == [x[1:] for x in b]                 # ids, kinds, data: the same
    assert max(abs(x[0] - y[0]) for x, y in zip(a, b, strict=True)) < 1e-6   # theirs: 0.2 µs steps
    assert [x[0] for x in a] == [m.timestamp for m in messages]            # ours: exact


def railhil(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=300)


def test_bad_mf4_files_are_one_line_errors(tmp_path, mf4_run):
    plain = tmp_path / "signals.mf4"
    mdf = asammdf.MDF(version="4.10")
    mdf.append([asammdf.Signal(np.arange(5.0), np.arange(5.0), name="speed", unit="m/s")])
    mdf.save(str(plain), overwrite=True)
    cut = tmp_path / "cut.mf4"
    data = (mf4_run / "trace.mf4").read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    junk = tmp_path / "junk.mf4"
    junk.write_text("not an MDF file\n")
    for path, needle in ((plain, "not an MF4 CAN bus-logging file"), (cut, "not readable as an ASAM MDF4"),
                         (junk, "not readable as an ASAM MDF4")):
        proc = railhil("trace", "stats", str(path))
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.startswith(f"error: {path}") and needle in proc.stderr
        assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr


# ----------------------------------------------------------------------------------- trace export
@pytest.fixture(scope="module")
def cantools_decoded(mf4_run) -> dict[str, dict]:
    """message -> {t: [...], signal: [values...]} decoded by cantools itself, frame by frame."""
    db = cantools.database.load_file(str(DBC))
    out: dict[str, dict] = {}
    with can.LogReader(str(mf4_run / "trace.mf4")) as reader:
        for m in reader:
            msg = db.get_message_by_frame_id(m.arbitration_id)
            values = msg.decode(bytes(m.data), decode_choices=False)
            table = out.setdefault(msg.name, {"t": []})
            table["t"].append(m.timestamp)
            for k, v in values.items():
                table.setdefault(k, []).append(float(v))
    return out


def test_export_mf4_has_every_signal_with_its_unit_and_cantools_values(mf4_run, tmp_path, cantools_decoded):
    out = tmp_path / "signals.mf4"
    assert main(["trace", "export", str(mf4_run / "trace.mf4"), "--dbc", str(DBC), "-o", str(out)]) == 0
    db = cantools.database.load_file(str(DBC))
    mdf = asammdf.MDF(str(out))
    by_group = {g.channel_group.acq_name: i for i, g in enumerate(mdf.groups)}
    assert set(by_group) == set(cantools_decoded)                   # one channel group per message
    checked = 0
    for name, i in by_group.items():
        msg = db.get_message_by_name(name)
        ref = cantools_decoded[name]
        for sig in msg.signals:
            raw = mdf.get(sig.name, group=i, raw=True)
            assert raw.unit == (sig.unit or ""), (name, sig.name)
            assert np.array_equal(raw.timestamps, np.asarray(ref["t"]))
            samples = np.asarray(raw.samples, dtype=float)
            assert np.allclose(samples, ref[sig.name], rtol=0, atol=1e-9), sig.name
            by_name = mdf.get(f"{name}.{sig.name}", raw=True)       # MESSAGE.SIGNAL, as asammdf names it
            assert np.array_equal(by_name.samples, raw.samples)
            if sig.choices:                                         # the value table as the conversion
                named = mdf.get(sig.name, group=i)
                expect = [str(sig.choices.get(int(v), "")).encode() for v in ref[sig.name]]
                got = [bytes(x) for x in named.samples]
                assert got == [e if e else got[k] for k, e in enumerate(expect)]
            checked += 1
    mdf.close()
    assert checked > 150


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_export_parquet_and_csv_are_tidy_rows_equal_to_cantools(mf4_run, tmp_path, cantools_decoded, suffix):
    import pandas as pd

    out = tmp_path / f"signals{suffix}"
    assert main(["trace", "export", str(mf4_run / "trace.mf4"), "--dbc", str(DBC), "-o", str(out),
                 "--message", "BCU_STATUS", "--message", "BCU_DEMAND"]) == 0
    frame = pd.read_parquet(out) if suffix == ".parquet" else pd.read_csv(out, keep_default_na=False)
    assert list(frame.columns) == ["t", "id", "message", "signal", "value", "unit", "choice"]
    assert set(frame["message"]) == {"BCU_STATUS", "BCU_DEMAND"}
    assert set(frame["id"]) == {"0x028", "0x160"}                  # hex as trace decode prints it
    db = cantools.database.load_file(str(DBC))
    for (message, signal), rows in frame.groupby(["message", "signal"], sort=False):
        sig = db.get_message_by_name(message).get_signal_by_name(signal)
        assert np.allclose(rows["value"].to_numpy(float), cantools_decoded[message][signal], atol=1e-9)
        assert set(rows["unit"]) <= {sig.unit or ""}
        if sig.choices:
            assert list(rows["choice"]) == [str(sig.choices.get(int(v), "")) for v in rows["value"]]


def test_export_bad_output_is_one_line_and_leaves_nothing(mf4_run, tmp_path, monkeypatch, capsys):
    assert main(["trace", "export", str(mf4_run / "trace.mf4"), "--dbc", str(DBC), "-o",
                 str(tmp_path / "x.xlsx")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: -o ") and "'.xlsx'" in err and ".mf4" in err and err.count("\n") == 1
    assert main(["trace", "export", str(mf4_run / "trace.mf4"), "--dbc", str(DBC), "-o",
                 str(tmp_path / "no" / "such" / "x.csv")]) == 2
    assert "no such folder" in capsys.readouterr().err
    import hil.trace.export as export

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(export, "_write_rows", broken)
    out = tmp_path / "half.csv"
    assert main(["trace", "export", str(mf4_run / "trace.mf4"), "--dbc", str(DBC), "-o", str(out)]) == 2
    assert "cannot write the export: No space left on device" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".half*"))          # nothing half-written


def test_import_can_leaves_asammdf_until_an_mf4_file_is_opened(tmp_path):
    """hil.can.lazy_mf4: after `import hil`, `import can` does not load asammdf (0.64 s of pandas and
    canmatrix); the first MF4Writer or MF4Reader does, and python-can's MF4 works as without railhil."""
    code = f"""
import sys
import hil, can
from hil.trace.writers import Mf4Writer
assert "asammdf" not in sys.modules and "pandas" not in sys.modules, "loaded on import"
assert can.io.mf4.asammdf is None
with can.Logger({str(tmp_path / "plain.mf4")!r}) as w:
    w.on_message_received(can.Message(timestamp=1.5, arbitration_id=0x123, is_extended_id=False, data=b"ab"))
assert "asammdf" in sys.modules and can.io.mf4.asammdf is not None
w = Mf4Writer({str(tmp_path / "ours.mf4")!r}, start_time_s=0.0)
w.on_message_received(can.Message(timestamp=2.5, arbitration_id=0x42, is_extended_id=False, data=b"z"))
w.stop()
for name, want in (("plain", (1.5, 0x123, b"ab")), ("ours", (2.5, 0x42, b"z"))):
    got = [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in can.LogReader(f"{tmp_path}/{{name}}.mf4")]
    assert got == [want], (name, got)
print("ok")
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


def test_without_asammdf_python_cans_own_error_comes_at_the_first_mf4_file(tmp_path):
    """Where asammdf is really missing, the deferred imports fail as they would have on `import can`, and
    python-can's own error follows (not an ImportError of railhil's making)."""
    code = f"""
import sys
class NoAsammdf:
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] == "asammdf":
            raise ModuleNotFoundError(name)
sys.meta_path.insert(0, NoAsammdf())
import hil, can
try:
    can.Logger({str(tmp_path / "x.mf4")!r})
except NotImplementedError as exc:
    print("python-can:", exc)
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "python-can: The asammdf package was not found" in proc.stdout, \
        (proc.stdout, proc.stderr)
