"""hil.trace.fastdecode, the fast path of `railhil trace decode`, writes byte for byte what the per-frame path
writes (``hil.cli.trace.decode.decode(..., fast=False)``): stdout in the three formats, with value-table
names and with --raw, the summary on stderr, and the TraceError of a bad trace after the same frames.
On every corpus trace, on traces of every corpus DBC and of generated DBCs (Intel and Motorola, signed,
IEEE float, scale and offset, value tables with odd names and values outside them, units, CAN FD
lengths) written with python-can's writers, and on generated candump text; with the filters, block
sizes and --raw drawn by hypothesis.  The values, names and units it prints are cantools' own.

The corpus lives outside the repository; RAILHIL_CORPUS points to it (default ../shared/corpus).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import can
import numpy as np
import pytest
from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion
from cantools.database.namedsignalvalue import NamedSignalValue
from conftest import CORPUS
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import hil.trace.fastdecode as fastdecode
from hil.can.codec import Codec, FrameError
from hil.can.dbc import load_dbc
from hil.cli.trace.decode import decode, decoded_rows, row_texts, select
from hil.errors import DbcError
from hil.trace.columns import BLOCK_FRAMES, FrameBlock
from hil.trace.fastdecode import BlockDecoder
from hil.trace.readers import TraceError

ROOT = Path(__file__).resolve().parents[2]
NO_CORPUS = f"no trace corpus at {CORPUS} (set RAILHIL_CORPUS)"
CANTOOLS_DBC = CORPUS / "cantools" / "tests" / "files" / "dbc"
CANDUMP = CORPUS / "SavvyCAN" / "examples" / "candump.log"
PRIUS = CORPUS / "opendbc" / "opendbc" / "dbc" / "toyota_prius_2010_pt.dbc"
TRAIN_DBC = ROOT / "dbc" / "train_brake.dbc"
FORMATS = ("table", "csv", "jsonl")
SUFFIXES = (".log", ".asc", ".trc", ".blf", ".gz")


def loadable(path: Path) -> bool:
    try:
        load_dbc(path)
    except DbcError:  # cantools rejects it (tesla_can, vw_mqb): not a DBC trace decode takes
        return False
    return True


CORPUS_TRACES = sorted(p for p in CORPUS.rglob("*") if p.is_file() and p.suffix.lower() in SUFFIXES) \
    if CORPUS.is_dir() else []
CORPUS_DBCS = sorted(p for p in CORPUS.rglob("*.dbc") if loadable(p)) if CORPUS.is_dir() else []
TRACE_PARAMS = [pytest.param(p, id=str(p.relative_to(CORPUS))) for p in CORPUS_TRACES] or [
    pytest.param(None, marks=pytest.mark.skip(reason=NO_CORPUS))]
_loaded: dict[Path, tuple[Database, Codec]] = {}


def codec_of(dbc: Path) -> Codec:
    """The DBC's codec, loaded once (cantools' parser is the slow part of a small test)."""
    return loaded(dbc)[1]


def loaded(dbc: Path) -> tuple[Database, Codec]:
    if dbc not in _loaded:
        db = load_dbc(dbc)
        _loaded[dbc] = db, Codec(db)
    return _loaded[dbc]


def both_paths(capsys, trace: Path, dbc: Path, fmt: str, *, codec: Codec | None = None, ids=(), messages=(),
               signals=(), start=None, end=None, block_frames: int = BLOCK_FRAMES, raw: bool = False
               ) -> tuple[str, str, str | None]:
    """(stdout, stderr, TraceError message or None) of `trace decode`, the same on both paths."""
    codec = codec or codec_of(dbc)
    sel = select(argparse.Namespace(ids=[str(i) for i in ids], messages=list(messages), signals=list(signals),
                                    dbc=dbc), codec)
    outcomes = []
    for fast in (True, False):
        capsys.readouterr()
        error = None
        try:
            decode(trace, codec, sel, fmt, start, end, str(dbc), fast=fast, block_frames=block_frames,
                   raw=raw)
        except TraceError as exc:
            error = str(exc)
        out, err = capsys.readouterr()
        outcomes.append((out, err, error))
    (fast_out, fast_err, fast_error), (ref_out, ref_err, ref_error) = outcomes
    assert fast_error == ref_error
    assert fast_err == ref_err
    if fast_out != ref_out:  # the first line that differs, not two pages of text
        ours, theirs = fast_out.splitlines(), ref_out.splitlines()
        pairs = enumerate(zip(ours, theirs, strict=False))
        line = next((i for i, (a, b) in pairs if a != b), min(len(ours), len(theirs)))
        pytest.fail(f"{fmt} output differs at line {line}:\n  fast: {ours[line:line + 1]!r}\n"
                    f"  ref:  {theirs[line:line + 1]!r}\n  lines {len(ours)} {len(theirs)}")
    return outcomes[0]


def cantools_signals(db: Database, msg: can.Message) -> dict:
    values = db.decode_message(msg.arbitration_id, bytes(msg.data), decode_choices=False,
                               force_extended_id=msg.is_extended_id)
    return {k: float(v) if math.isfinite(v) else repr(float(v)) for k, v in values.items()}


def cantools_choices(db: Database, msg: can.Message) -> dict[str, str] | None:
    """The value-table names cantools decodes (decode_choices=True); None where it raises (its int() of the
    NaN or infinite raw value of a float signal with a table)."""
    try:
        values = db.decode_message(msg.arbitration_id, bytes(msg.data), decode_choices=True,
                                   force_extended_id=msg.is_extended_id)
    except (ValueError, OverflowError):
        return None
    return {k: str(v) for k, v in values.items() if isinstance(v, NamedSignalValue)}


def assert_jsonl_is_cantools(out: str, trace: Path, db: Database, raw: bool = False) -> int:
    """Every decoded row of jsonl output (no filter) holds cantools' values of its frame, the names of
    the values in their tables (none with --raw) and the DBC units."""
    frames = list(can.LogReader(str(trace)))
    rows = [json.loads(line) for line in out.splitlines()]
    assert len(rows) == len(frames)
    decoded = 0
    for msg, row in zip(frames, rows, strict=True):
        if "signals" in row:
            assert row["signals"] == cantools_signals(db, msg)
            message = db.get_message_by_frame_id(msg.arbitration_id, force_extended_id=msg.is_extended_id)
            expected = cantools_choices(db, msg)
            if raw:
                assert "choices" not in row
            elif expected is not None:
                assert row["choices"] == expected
            assert row["units"] == {k: message.get_signal_by_name(k).unit for k in row["signals"]
                                    if message.get_signal_by_name(k).unit}
            decoded += 1
    return decoded


# --- the corpus ------------------------------------------------------------------------------------


@pytest.mark.parametrize("trace", TRACE_PARAMS)
def test_every_corpus_trace(capsys, trace):
    dbcs = [PRIUS, CANTOOLS_DBC / "abs.dbc", CANTOOLS_DBC / "vehicle.dbc", CANTOOLS_DBC / "socialledge.dbc"]
    for dbc in dbcs:
        for fmt in FORMATS:
            for raw in (False, True):
                both_paths(capsys, trace, dbc, fmt, raw=raw)


@pytest.mark.skipif(not CANDUMP.is_file(), reason=NO_CORPUS)
def test_candump_with_filters_and_small_blocks(capsys):
    codec = codec_of(PRIUS)
    names = [fc.name for fc in codec]
    for k, fmt in enumerate(FORMATS * 2):
        out, err, error = both_paths(
            capsys, CANDUMP, PRIUS, fmt, ids=[0x25, 0xB4, 0x7FF][: k % 3 + 1],
            messages=names[k: k + 2] if k % 2 else (), signals=("SPEED",) if k > 4 else (),
            start=None if k < 3 else 1436509052.5, end=None if k % 3 else 1436509057.0,
            block_frames=[BLOCK_FRAMES, 1000, 7][k % 3], raw=k % 4 == 3)
        assert error is None and "frames decoded" in err


@pytest.mark.skipif(not CANDUMP.is_file(), reason=NO_CORPUS)
def test_signal_texts_kept_in_dictionaries_and_started_again(capsys, monkeypatch):
    """Signals of any width keep their texts in a dictionary when SMALL_BITS is 0, which starts again
    once it holds CACHE_LIMIT texts: the same output."""
    monkeypatch.setattr(fastdecode, "SMALL_BITS", 0)
    monkeypatch.setattr(fastdecode, "CACHE_LIMIT", 3)
    for fmt in FORMATS:
        for raw in (False, True):
            both_paths(capsys, CANDUMP, PRIUS, fmt, block_frames=500, raw=raw)


# --- traces of every corpus DBC, written by python-can ----------------------------------------------


@st.composite
def frames_of(draw, codec: Codec, most: int = 40) -> list[can.Message]:
    """Frames for a DBC: its messages with random data of their length (or one byte more or less) or with
    values from their value tables, unknown ids, remote and error frames, a message's id with the
    other 11/29-bit kind, CAN FD."""
    fcs = list(codec)
    frames = []
    t = draw(st.sampled_from([0.0, 12.5, 1_700_000_000.0]))
    for _ in range(draw(st.integers(1, most))):
        t += draw(st.sampled_from([0.0, 1e-6, 0.001, 0.37]))
        kind = draw(st.sampled_from(["data"] * 6 + ["named"] * 3
                                    + ["short", "long", "unknown", "remote", "error", "flip"]))
        fc = draw(st.sampled_from(fcs))
        arb, ext, length = fc.frame_id, bool(fc.is_extended_id), fc.length
        if kind == "short":
            length = max(length - draw(st.integers(1, 3)), 0)
        elif kind == "long":
            length = min(length + 1, 64)
        elif kind == "unknown":
            ext = draw(st.booleans())
            arb = draw(st.integers(0, 0x1FFFFFFF if ext else 0x7FF).filter(lambda i: codec.get(i) is None))
        elif kind == "flip":
            ext = not ext
            arb &= 0x7FF
        data = draw(st.binary(min_size=length, max_size=length))
        if kind == "named":  # a value of each table (by its name), the other signals' values random
            named = {s.name: draw(st.sampled_from([str(v) for v in s.choices.values()]))
                     for s in fc.message.signals if s.choices}
            try:
                data = fc.encode({**fc.decode(data), **named})
            except FrameError:  # a multiplexer value the DBC does not define
                data = fc.encode(named)
        fd = length > 8
        if fd:  # a CAN FD frame holds one of the FD lengths
            data = data.ljust(next(n for n in (12, 16, 20, 24, 32, 48, 64) if n >= length), b"\0")
        if kind == "remote":
            frames.append(can.Message(timestamp=t, arbitration_id=arb, is_extended_id=ext,
                                      is_remote_frame=True, dlc=min(length, 8)))
        elif kind == "error":
            frames.append(can.Message(timestamp=t, is_error_frame=True, arbitration_id=arb,
                                      dlc=min(length, 8), data=data[:8]))
        else:
            frames.append(can.Message(timestamp=t, arbitration_id=arb, is_extended_id=ext, data=data,
                                      is_fd=fd, dlc=len(data)))
    return frames


def write(path: Path, frames: list[can.Message]) -> Path:
    """The frames written with python-can's writer for the suffix."""
    with can.Logger(str(path)) as writer:
        for msg in frames:
            writer.on_message_received(msg)
    return path


@st.composite
def filters(draw, codec: Codec, frames: list[can.Message]) -> dict:
    out: dict = {}
    if draw(st.integers(0, 3)) == 0:
        out["ids"] = draw(st.lists(st.sampled_from([m.arbitration_id for m in frames] + [0x7FF]), max_size=3))
    if draw(st.integers(0, 3)) == 0:
        out["messages"] = draw(st.lists(st.sampled_from([fc.name for fc in codec]), min_size=1, max_size=2))
    signal_names = sorted({s for fc in codec for s in fc.signal_names})
    if signal_names and draw(st.integers(0, 3)) == 0:
        out["signals"] = draw(st.lists(st.sampled_from(signal_names), min_size=1, max_size=3))
    times = [m.timestamp for m in frames]
    if draw(st.integers(0, 3)) == 0:
        out["start"] = draw(st.sampled_from(times))
    if draw(st.integers(0, 3)) == 0:
        out["end"] = max(draw(st.sampled_from(times)), out.get("start", -math.inf))
    return out


DBC_PARAMS = [pytest.param(p, id=p.name) for p in CORPUS_DBCS + [TRAIN_DBC]]


@pytest.mark.parametrize("dbc", DBC_PARAMS)
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                 HealthCheck.too_slow])
@given(data=st.data(), suffix=st.sampled_from([".log", ".blf", ".asc"]), fmt=st.sampled_from(FORMATS),
       block_frames=st.sampled_from([3, BLOCK_FRAMES]), raw=st.booleans())
def test_traces_of_every_corpus_dbc(capsys, tmp_path_factory, dbc, data, suffix, fmt, block_frames, raw):
    codec = codec_of(dbc)
    frames = data.draw(frames_of(codec))
    trace = write(tmp_path_factory.mktemp("trace") / f"t{suffix}", frames)
    chosen = data.draw(filters(codec, frames))
    out, err, error = both_paths(capsys, trace, dbc, fmt, block_frames=block_frames, raw=raw, **chosen)
    assert error is None
    if fmt == "jsonl" and not chosen:
        assert_jsonl_is_cantools(out, trace, loaded(dbc)[0], raw)


# --- generated DBCs: every layout the columnar path decodes ----------------------------------------

SCALES = [1, 2, 3, 0.5, 0.1, -1, -0.25, 1e-3, 1.5e6, 7.3e-7]
OFFSETS = [0, 1, -40, 0.5, -1.5, 1000, 1e9]
# value-table names and units as DBCs have them, and those the table format must quote
CHOICE_NAMES = ["Zero", "One", "SNA", "Signal error", "1", "-2.5", "inf", "NaN", "", "#%=*ä'", "tab\there",
                "  two  spaces", "new\nline", "a=b", "Ünïcode"]
UNITS = ["", "", "", "m", "km/h", "°/s", "deg C", "a=b", "-", "1/min", "%"]


@st.composite
def generated_dbc(draw) -> str:
    """A DBC (as text) of 1-3 messages of 1-64 bytes with up to 8 signals each that do not overlap:
    Intel and Motorola, unsigned and signed, 1 to 64 bits, IEEE float32/64, integer and float scale
    and offset, units, some with value tables (raw values -3 to 9, names that need quoting)."""
    messages, ids = [], set()
    for i in range(draw(st.integers(1, 3))):
        length = draw(st.sampled_from([1, 2, 3, 5, 7, 8, 8, 8, 12, 16, 24, 64]))
        extended = draw(st.booleans())
        frame_id = draw(st.integers(0, 0x1FFFFFFF if extended else 0x7FF).filter(lambda x: x not in ids))
        ids.add(frame_id)
        used, signals = 0, []
        for k in range(draw(st.integers(0, 8))):
            big = draw(st.booleans())
            is_float = draw(st.integers(0, 7)) == 0
            n = draw(st.sampled_from([32, 64])) if is_float else draw(st.integers(1, 64))
            if n > 8 * length:
                continue
            shift = draw(st.integers(0, 8 * length - n))  # the payload's LSB as one integer (hil.can.codec)
            bits = ((1 << n) - 1) << shift
            if big:
                bits = int.from_bytes(bits.to_bytes(length, "big"), "little")
            if used & bits:
                continue
            used |= bits
            if big:  # cantools' start bit of a Motorola signal: its MSB, numbered as in the DBC
                msb = 8 * length - shift - n
                start = 8 * (msb // 8) + 7 - msb % 8
            else:
                start = shift
            with_choices = draw(st.integers(0, 7 if is_float else 2)) == 0
            choices = draw(st.dictionaries(st.integers(-3, 9), st.sampled_from(CHOICE_NAMES), min_size=1,
                                           max_size=5)) if with_choices else None
            conversion = BaseConversion.factory(scale=draw(st.sampled_from(SCALES)),
                                                offset=draw(st.sampled_from(OFFSETS)),
                                                choices=choices, is_float=is_float)
            signals.append(Signal(f"S{k}", start=start, length=n,
                                  byte_order="big_endian" if big else "little_endian",
                                  is_signed=not is_float and draw(st.booleans()), conversion=conversion,
                                  unit=draw(st.sampled_from(UNITS)) or None))
        messages.append(Message(frame_id, f"M{i}", length, signals, is_extended_frame=extended))
    return Database(messages).as_dbc_string()


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                  HealthCheck.too_slow])
@given(text=generated_dbc(), data=st.data(), suffix=st.sampled_from([".log", ".blf"]),
       fmt=st.sampled_from(FORMATS), block_frames=st.sampled_from([4, BLOCK_FRAMES]), raw=st.booleans())
def test_traces_of_generated_dbcs(capsys, tmp_path_factory, text, data, suffix, fmt, block_frames, raw):
    folder = tmp_path_factory.mktemp("gen")
    dbc = folder / "gen.dbc"
    dbc.write_text(text, encoding="cp1252")  # cantools reads a DBC as cp1252
    db = load_dbc(dbc)
    codec = Codec(db)
    assume(any(fc.fallback_reason is None for fc in codec))
    frames = data.draw(frames_of(codec, most=60))
    trace = write(folder / f"t{suffix}", frames)
    chosen = data.draw(filters(codec, frames))
    out, err, error = both_paths(capsys, trace, dbc, fmt, codec=codec, block_frames=block_frames, raw=raw,
                                 **chosen)
    assert error is None
    if fmt == "jsonl" and not chosen:
        assert_jsonl_is_cantools(out, trace, db, raw)


def test_value_tables_in_every_combination(capsys, tmp_path):
    """Three signals with value tables in one message (an 8-bit and a 20-bit one kept in a dictionary)
    and one without: every combination of values in and outside the tables, in its frame, with names
    that must be quoted -- the jsonl ``choices`` items with their commas, the table's words, the csv
    columns -- the same on both paths and equal to cantools."""
    def signal(name: str, start: int, length: int, choices: dict | None, unit: str | None) -> Signal:
        return Signal(name, start=start, length=length, unit=unit,
                      conversion=BaseConversion.factory(scale=1, offset=0, choices=choices))

    signals = [signal("A", 0, 2, {0: "Off", 1: "Signal error"}, "-"),
               signal("B", 8, 8, {1: "1", 3: "On"}, None),
               signal("C", 16, 20, {0: "Zero", 2: "a=b"}, "deg C"),
               signal("D", 40, 8, None, "m/s")]
    dbc = tmp_path / "tables.dbc"
    dbc.write_text(Database([Message(0x123, "M", 8, signals)]).as_dbc_string(), encoding="cp1252")
    codec = Codec(load_dbc(dbc))
    combinations = [(a, b, c) for a in range(3) for b in (0, 1, 3) for c in (0, 1, 2)]
    frames = [can.Message(timestamp=1.0 + k / 100, arbitration_id=0x123, is_extended_id=False,
                          data=codec[0x123].encode({"A": a, "B": b, "C": c, "D": k}))
              for k, (a, b, c) in enumerate(combinations)]
    trace = write(tmp_path / "t.blf", frames)
    for fmt in FORMATS:
        for raw in (False, True):
            for block_frames in (5, BLOCK_FRAMES):
                out, _, error = both_paths(capsys, trace, dbc, fmt, codec=codec, block_frames=block_frames,
                                           raw=raw)
                assert error is None
            if fmt == "jsonl":
                assert assert_jsonl_is_cantools(out, trace, load_dbc(dbc), raw) == len(frames)
    out, _, _ = both_paths(capsys, trace, dbc, "table", codec=codec)
    assert 'A="Signal error" B="1" C="a=b" D=' in out and "A=2 - B=0 C=1 \"deg C\" D=" in out


# --- candump text: the bulk parser, python-can's parser, errors -------------------------------------

seconds_text = st.one_of(
    st.floats(0, 5e9).map(lambda t: f"{t:.6f}"),
    st.builds(lambda i, f: f"{i}.{f}", st.from_regex(r"[0-9]{1,11}", fullmatch=True),
              st.from_regex(r"[0-9]{1,9}", fullmatch=True)),
    st.sampled_from(["0.000000", "0.000050", "0.000100", "0.000099", "00012.500000", "100.100000",
                     "3999999999.999999", "4000000000.000001", "9007199254.740993",
                     "99999999999999999999.5"]),
)
ODD_LINES = ["(1.000001) can0 123#R", "(2.0) can1 123##1A0B", "(3.25) can0 20000080#0000000000000000",
             "(3.25) can0 20000001#00", "(4.0)  can0  123#0A0B", "", "   ", "(5.0) can0 123#00 x"]


@st.composite
def candump_text(draw, codec: Codec) -> str:
    ids = [(fc.frame_id, bool(fc.is_extended_id), fc.length) for fc in codec]
    lines = []
    for _ in range(draw(st.integers(1, 60))):
        choice = draw(st.integers(0, 9))
        if choice == 0:
            lines.append(draw(st.sampled_from(ODD_LINES)))
            continue
        arb, ext, length = draw(st.sampled_from(ids)) if choice > 2 else (
            draw(st.integers(0, 0x7FF)), False, draw(st.integers(0, 8)))
        length = max(0, length + draw(st.sampled_from([0, 0, 0, 0, -1, 1])))
        data = draw(st.binary(min_size=length, max_size=length)).hex()
        data = data.upper() if draw(st.booleans()) else data
        lines.append(f"({draw(seconds_text)}) can0 {arb:0{8 if ext else 3}X}#{data}"
                     f"{draw(st.sampled_from(['', ' R', ' T']))}")
    if draw(st.integers(0, 5)) == 0:  # python-can cannot read a line: an error after the frames before it
        bad = draw(st.sampled_from(["hello world", "(4.0) can0 123#GG"]))
        lines.insert(draw(st.integers(0, len(lines))), bad)
    return "\n".join(lines) + draw(st.sampled_from(["", "\n"]))


CANDUMP_DBCS = ["abs.dbc", "motohawk.dbc", "j1939.dbc", "signed.dbc", "floating_point.dbc", "multiplex.dbc",
                "choices.dbc", "multiplex_choices.dbc"]


@pytest.mark.skipif(not CANTOOLS_DBC.is_dir(), reason=NO_CORPUS)
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), name=st.sampled_from(CANDUMP_DBCS), fmt=st.sampled_from(FORMATS),
       block_frames=st.sampled_from([1, 5, BLOCK_FRAMES]), raw=st.booleans())
def test_generated_candump_text(capsys, tmp_path_factory, data, name, fmt, block_frames, raw):
    """The timestamps printed from the text as written where it is the float's format, odd lines
    for python-can, and a line python-can cannot read: the same output and the same error."""
    dbc = CANTOOLS_DBC / name
    trace = tmp_path_factory.mktemp("log") / "t.log"
    trace.write_text(data.draw(candump_text(codec_of(dbc))))
    chosen = data.draw(st.sampled_from([{}, {}, {"start": 1.0}, {"end": 1e9}]))
    both_paths(capsys, trace, dbc, fmt, block_frames=block_frames, raw=raw, **chosen)


def test_text_that_cannot_be_decoded(capsys, tmp_path):
    """A byte that is not UTF-8 after 20 000 frames: the frames before it, then the same error."""
    trace = tmp_path / "bad.log"
    good = b"".join(b"(%d.%06d) can0 %03X#0011223344556677\n" % (100 + i // 1000, i % 1000, 0x25 + i % 3)
                    for i in range(20_000))
    trace.write_bytes(good + b"(200.000000) can0 025#\xff\n" + good[:500])
    for fmt in FORMATS:
        out, err, error = both_paths(capsys, trace, TRAIN_DBC, fmt, block_frames=3000)
        assert error is not None and "UnicodeDecodeError" in error and err == ""
        assert out.count("\n") > 15_000


def test_frames_whose_timestamp_is_not_a_float():
    """A Message with an int timestamp (no python-can reader makes one) is taken one by one, from the
    Message itself: the text of the per-frame path."""
    codec = codec_of(TRAIN_DBC)
    fc = next(iter(codec))
    messages = [can.Message(timestamp=ts, arbitration_id=fc.frame_id, is_extended_id=False,
                            data=bytes(fc.length)) for ts in (1, 2.5, np.float64(3.25), 4)]
    sel = select(argparse.Namespace(ids=[], messages=[], signals=[], dbc=TRAIN_DBC), codec)
    for fmt in FORMATS:
        texts = row_texts(fmt, 20)
        counts = dict.fromkeys(("decoded", "unknown", "remote", "error", "failed"), 0)

        def slow(m: can.Message, texts=texts, counts=counts) -> str:
            return texts(decoded_rows((m,), codec, sel, None, None, counts))

        decoder = BlockDecoder(codec, fmt, width=20, ids=None, names=None, signals=None, start=None, end=None,
                               slow=slow, counts=counts)
        block = FrameBlock.from_messages(messages)
        assert block.special is not None and block.special.tolist() == [True, False, True, True]
        assert decoder.text(block) == texts(decoded_rows(messages, codec, sel, None, None, dict(counts)))
        assert counts["decoded"] == 4
