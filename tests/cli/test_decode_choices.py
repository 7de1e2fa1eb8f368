"""`railhil trace decode` shows values as cantools shows them: a value in its signal's value table by the
table's name (``Enable=Enabled``), any other by its number and its DBC unit (``AverageRadius=1.8 m``);
``--raw`` the numbers; csv and jsonl carry the number, the name and the unit.

Checked on motohawk.dbc line by line, on every corpus DBC that has value tables (names, numbers and
units frame by frame against cantools' ``decode_message(decode_choices=True)``, in the three formats,
the table parsed by its documented grammar), and against the ``cantools decode`` command itself.

The corpus lives outside the repository; RAILHIL_CORPUS points to it (default ../shared/corpus).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import random
import re
import subprocess
import sys
from pathlib import Path

import can
import pytest
from cantools.database.can import Database
from cantools.database.namedsignalvalue import NamedSignalValue
from conftest import CORPUS, assert_one_line_error, railhil

from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.errors import DbcError
from hil.trace.fastdecode import table_word

ROOT = Path(__file__).resolve().parents[2]
NO_CORPUS = f"no trace corpus at {CORPUS} (set RAILHIL_CORPUS)"
CANTOOLS_DBC = CORPUS / "cantools" / "tests" / "files" / "dbc"
MOTOHAWK = CANTOOLS_DBC / "motohawk.dbc"
TRAIN_DBC = ROOT / "dbc" / "train_brake.dbc"


def with_value_tables(path: Path) -> bool:
    """A DBC cantools loads (as railhil loads it) with at least one signal with a value table."""
    try:
        db = load_dbc(path)
    except DbcError:  # cantools rejects it (tesla_can, vw_mqb): not a DBC trace decode takes
        return False
    return any(s.choices for m in db.messages for s in m.signals)


TABLE_DBCS = sorted(p for p in CORPUS.rglob("*.dbc") if with_value_tables(p)) if CORPUS.is_dir() else []
TABLE_PARAMS = [pytest.param(p, id=p.name) for p in TABLE_DBCS] or [
    pytest.param(None, marks=pytest.mark.skip(reason=NO_CORPUS))]


# --- the table format: its words, and a parser of its grammar --------------------------------------


@pytest.mark.parametrize("text, choice, shown", [
    ("Enabled", True, "Enabled"),
    ("m", False, "m"),
    ("m/s^2", False, "m/s^2"),
    ("°/s", False, "°/s"),
    ("-", False, "-"),
    ("2WD", True, "2WD"),            # not a number: as it is
    ("1", False, "1"),               # a unit may look like a number: it follows one
    ("1", True, '"1"'),              # a name never passes for a number
    ("-2.5", True, '"-2.5"'),
    ("inf", True, '"inf"'),
    ("NaN", True, '"NaN"'),
    ("1_000", True, '"1_000"'),      # float() reads it
    ("Signal error", True, '"Signal error"'),
    ("deg C", False, '"deg C"'),
    ("#%=*ä'", True, '"#%=*ä\'"'),
    ("a=b", False, '"a=b"'),
    ("", True, '""'),
    ("tab\there", True, '"tab\\there"'),
    ('say "hi"', True, '"say \\"hi\\""'),
    ("back\\slash", True, '"back\\\\slash"'),
    ("nb\xa0space", True, '"nb\xa0space"'),
])
def test_table_word(text, choice, shown):
    assert table_word(text, choice) == shown
    if shown.startswith('"'):
        assert json.loads(shown) == text


PAIR = re.compile(r'(\w+)=("(?:[^"\\]|\\.)*"|[^\s"]+)(?: ("(?:[^"\\]|\\.)*"|[^\s"=]+)(?= |$))?')


def table_signals(body: str) -> dict[str, tuple[str | float, str]]:
    """The documented grammar of the table's signals: ``NAME=VALUE`` separated by one space; VALUE is a
    number where float() reads it, else a value-table name (a JSON string when quoted); a number may be
    followed by one space and its unit (a JSON string when quoted, never with a bare ``=``).
    {signal: (name or number, unit)}."""
    out: dict[str, tuple[str | float, str]] = {}
    pos = 0
    while pos < len(body):
        m = PAIR.match(body, pos)
        assert m, f"not NAME=VALUE at {body[pos:pos + 40]!r}"
        name, value, unit = m.groups()
        if value.startswith('"'):
            shown: str | float = json.loads(value)
        else:
            try:
                shown = float(value)
            except ValueError:
                shown = value
        unit = "" if unit is None else json.loads(unit) if unit.startswith('"') else unit
        assert not (unit and isinstance(shown, str)), f"a unit after a name: {m.group(0)!r}"
        out[name] = (shown, unit)
        pos = m.end()
        assert pos == len(body) or body[pos] == " ", body[pos:pos + 40]
        pos += 1
    return out


def table_body(line: str) -> str:
    """The signals of a table line (after the t_s, id and name columns)."""
    m = re.match(r"\s*\S+  \S+\s+\S+\s+(.*)$", line)
    assert m, line
    return m.group(1)


def test_table_grammar_reads_what_table_word_writes():
    body = " ".join([f"A={table_word('Signal error', True)}", "B=1.8 m", f"C=2 {table_word('deg C')}",
                     f"D={table_word('1', True)}", f"E=-3 {table_word('a=b')}", "F=Enabled", "G=1e+20"])
    assert table_signals(body) == {"A": ("Signal error", ""), "B": (1.8, "m"), "C": (2.0, "deg C"),
                                   "D": ("1", ""), "E": (-3.0, "a=b"), "F": ("Enabled", ""), "G": (1e20, "")}


# --- motohawk.dbc ------------------------------------------------------------------------------------

MOTOHAWK_LOG = ("(1.000000) can0 1F0#A5B6D90000000000\n"   # Enable 1, AverageRadius 1.8, Temperature 244.14
                "(2.000000) can0 1F0#0000000000000000\n"   # Enable 0
                "(3.000000) can0 123#00\n")                # an id motohawk.dbc does not know


@pytest.fixture
def motohawk_log(tmp_path) -> Path:
    if not MOTOHAWK.is_file():
        pytest.skip(NO_CORPUS)
    path = tmp_path / "motohawk.log"
    path.write_text(MOTOHAWK_LOG)
    return path


#: the motohawk log's times as recorded (1.0, 2.0, 3.0), as cantools prints them: by default `trace decode`
#: gives them from the first frame (hil.cli.trace.timebase)
AS_RECORDED = ("--absolute",)


def test_motohawk_table_shows_names_and_units(capsys, motohawk_log):
    code, out, err = railhil(capsys, "trace", "decode", motohawk_log, "--dbc", MOTOHAWK, *AS_RECORDED)
    assert code == 0, err
    lead = "0x1F0       ExampleMessage  "
    assert out.splitlines() == [
        "              t_s  id          name            signals",
        f"         1.000000  {lead}Enable=Enabled AverageRadius=1.8 m Temperature=244.14 degK",
        f"         2.000000  {lead}Enable=Disabled AverageRadius=0 m Temperature=250 degK",
        "         3.000000  0x123       ?               data=00",
    ]
    assert "2 frames decoded, 1 with ids not in" in err


def test_motohawk_raw_shows_numbers_with_their_units(capsys, motohawk_log):
    code, out, err = railhil(capsys, "trace", "decode", motohawk_log, "--dbc", MOTOHAWK, "--raw")
    assert code == 0, err
    lines = out.splitlines()
    assert lines[1].endswith("ExampleMessage  Enable=1 - AverageRadius=1.8 m Temperature=244.14 degK")
    assert lines[2].endswith("ExampleMessage  Enable=0 - AverageRadius=0 m Temperature=250 degK")


def test_motohawk_csv_carries_number_unit_and_name(capsys, motohawk_log):
    for raw in (False, True):
        code, out, err = railhil(capsys, "trace", "decode", motohawk_log, "--dbc", MOTOHAWK, *AS_RECORDED,
                                 "--format", "csv", *(["--raw"] if raw else []))
        assert code == 0, err
        lines = out.splitlines()
        assert lines[0] == "t,id,name,signal,value,error,unit,choice"
        assert lines[1:] == [
            f"1.000000,0x1F0,ExampleMessage,Enable,1.0,,-,{'' if raw else 'Enabled'}",
            "1.000000,0x1F0,ExampleMessage,AverageRadius,1.8,,m,",
            "1.000000,0x1F0,ExampleMessage,Temperature,244.14,,degK,",
            f"2.000000,0x1F0,ExampleMessage,Enable,0.0,,-,{'' if raw else 'Disabled'}",
            "2.000000,0x1F0,ExampleMessage,AverageRadius,0.0,,m,",
            "2.000000,0x1F0,ExampleMessage,Temperature,250.0,,degK,",
            "3.000000,0x123,,,00,,,",
        ]


def test_motohawk_jsonl_keeps_numbers_and_adds_names_and_units(capsys, motohawk_log):
    code, out, err = railhil(capsys, "trace", "decode", motohawk_log, "--dbc", MOTOHAWK, *AS_RECORDED,
                             "--format", "jsonl")
    assert code == 0, err
    first, second, unknown = out.splitlines()
    assert first == ('{"t": 1.0, "id": "0x1F0", "name": "ExampleMessage", '
                     '"signals": {"Enable": 1.0, "AverageRadius": 1.8, "Temperature": 244.14}, '
                     '"choices": {"Enable": "Enabled"}, '
                     '"units": {"Enable": "-", "AverageRadius": "m", "Temperature": "degK"}}')
    assert json.loads(second)["choices"] == {"Enable": "Disabled"}
    assert json.loads(unknown) == {"t": 3.0, "id": "0x123", "name": None, "data": "00"}
    code, out, err = railhil(capsys, "trace", "decode", motohawk_log, "--dbc", MOTOHAWK, "--format", "jsonl",
                             "--raw")
    assert code == 0, err
    row = json.loads(out.splitlines()[0])
    assert list(row) == ["t", "id", "name", "signals", "units"]
    assert row["signals"] == {"Enable": 1.0, "AverageRadius": 1.8, "Temperature": 244.14}


def test_motohawk_signal_filter_keeps_the_names_and_units_of_its_signals(capsys, motohawk_log):
    code, out, err = railhil(capsys, "trace", "decode", motohawk_log, "--dbc", MOTOHAWK, *AS_RECORDED,
                             "--format", "jsonl", "--signal", "Enable")
    assert code == 0, err
    assert [json.loads(line) for line in out.splitlines()] == [
        {"t": t, "id": "0x1F0", "name": "ExampleMessage", "signals": {"Enable": v}, "choices": {"Enable": n},
         "units": {"Enable": "-"}} for t, v, n in ((1.0, 1.0, "Enabled"), (2.0, 0.0, "Disabled"))]


# --- every corpus DBC with value tables, against cantools -----------------------------------------


def frames_for(db: Database, codec: Codec, seed: str) -> list[can.Message]:
    """Frames of every message of a DBC with value tables: each value of each table in turn (given by its
    name, the other signals random within their range), then random payloads (values outside the
    tables)."""
    rng = random.Random(seed)
    frames = []
    t = 0.0
    for message in db.messages:
        if not any(s.choices for s in message.signals):
            continue
        fc = codec.get(message.frame_id)
        keys = {s.name: sorted(s.choices) for s in message.signals if s.choices}
        payloads = []
        for i in range(max(map(len, keys.values()))):
            values: dict[str, float | str] = {}
            for s in message.signals:
                if s.name in keys:
                    values[s.name] = str(s.choices[keys[s.name][i % len(keys[s.name])]])
                else:
                    lo = s.minimum if s.minimum is not None else 0.0
                    hi = s.maximum if s.maximum is not None else 0.0
                    values[s.name] = rng.uniform(min(lo, hi), max(lo, hi))
            payloads.append(fc.encode(values))
        payloads += [rng.randbytes(message.length) for _ in range(4)]
        for data in payloads:
            t += 0.001
            frames.append(can.Message(timestamp=round(t, 6), arbitration_id=message.frame_id,
                                      is_extended_id=message.is_extended_frame, data=data))
    return frames


def candump(frames: list[can.Message]) -> str:
    return "".join(f"({m.timestamp:.6f}) can0 {m.arbitration_id:0{8 if m.is_extended_id else 3}X}#"
                   f"{bytes(m.data).hex().upper()}\n" for m in frames)


def cantools_decoded(db: Database, msg: can.Message) -> tuple[dict[str, float], dict[str, str]] | None:
    """(numbers, names of the values in their tables) as cantools decodes the frame; None if it cannot."""
    try:
        named = db.decode_message(msg.arbitration_id, bytes(msg.data), decode_choices=True,
                                  force_extended_id=msg.is_extended_id)
        numbers = db.decode_message(msg.arbitration_id, bytes(msg.data), decode_choices=False,
                                    force_extended_id=msg.is_extended_id)
    except Exception:  # noqa: BLE001 - cantools raises several types (a multiplexer value it does not know)
        return None
    return ({k: float(v) for k, v in numbers.items()},
            {k: str(v) for k, v in named.items() if isinstance(v, NamedSignalValue)})


@pytest.mark.parametrize("dbc", TABLE_PARAMS)
def test_every_value_table_dbc_decodes_as_cantools(capsys, tmp_path, dbc):
    db = load_dbc(dbc)
    codec = Codec(db)
    frames = frames_for(db, codec, dbc.name)
    trace = tmp_path / "t.log"
    trace.write_text(candump(frames))
    expected = [cantools_decoded(db, m) for m in frames]
    units = {(m.frame_id, s.name): s.unit for m in db.messages for s in m.signals if s.unit}
    assert sum(e is not None and bool(e[1]) for e in expected) >= len(frames) // 3  # names are seen
    outputs = {}
    for fmt in ("jsonl", "table", "csv"):
        for raw in (False, True):
            code, out, err = railhil(capsys, "trace", "decode", trace, "--dbc", dbc, "--format", fmt,
                                     *(["--raw"] if raw else []))
            assert code == 0, err
            outputs[fmt, raw] = out
    # jsonl: the numbers, the names of the values in their tables, the units
    for raw in (False, True):
        rows = [json.loads(line) for line in outputs["jsonl", raw].splitlines()]
        assert len(rows) == len(frames)
        for msg, row, exp in zip(frames, rows, expected, strict=True):
            if exp is None:
                assert "error" in row
                continue
            numbers, names = exp
            assert row["signals"] == {k: v if math.isfinite(v) else repr(v) for k, v in numbers.items()}
            assert row["units"] == {k: units[msg.arbitration_id, k] for k in numbers
                                    if (msg.arbitration_id, k) in units}
            if raw:
                assert "choices" not in row
            else:
                assert row["choices"] == names
    # table: each signal by its name where cantools names it, else its number (10 digits) and unit
    for raw in (False, True):
        lines = outputs["table", raw].splitlines()[1:]
        assert len(lines) == len(frames)
        for msg, line, exp in zip(frames, lines, expected, strict=True):
            if exp is None:
                continue
            numbers, names = exp
            shown = table_signals(table_body(line))
            assert list(shown) == list(numbers)
            for k, number in numbers.items():
                if k in names and not raw:
                    assert shown[k] == (names[k], ""), line
                else:
                    value, unit = shown[k]
                    assert value == float(f"{number:.10g}"), line
                    assert unit == units.get((msg.arbitration_id, k), ""), line
    # csv: one row per signal with its number, unit and name
    for raw in (False, True):
        rows = list(csv.DictReader(io.StringIO(outputs["csv", raw])))
        decoded = [(msg, exp) for msg, exp in zip(frames, expected, strict=True) if exp is not None]
        signal_rows = [r for r in rows if r["signal"]]
        assert len(signal_rows) == sum(len(exp[0]) for _, exp in decoded)
        it = iter(signal_rows)
        for msg, (numbers, names) in decoded:
            for k, number in numbers.items():
                r = next(it)
                assert r["signal"] == k and float(r["value"]) == number
                assert r["unit"] == units.get((msg.arbitration_id, k), "")
                assert r["choice"] == ("" if raw else names.get(k, ""))


# --- the `cantools decode` command ----------------------------------------------------------------

CLI_DBCS = ["motohawk.dbc", "abs.dbc", "choices.dbc", "socialledge.dbc", "multiplex_choices.dbc",
            "toyota_prius_2010_pt.dbc"]


def cantools_cli_signals(line: str, db: Database) -> tuple[str, dict[str, str]]:
    """(message name, {signal: its text}) of one line of ``cantools decode --single-line``:
    ``(t) can0 ID#DATA :: Name(Sig: value unit, Sig: name, ...)``, cut at the signal names, which come in
    the message's order (a name or unit may hold ", ")."""
    head, _, decoded = line.partition(" :: ")
    name, _, rest = decoded.partition("(")
    assert rest.endswith(")"), line
    rest = rest[:-1]
    order = [s.name for s in db.get_message_by_name(name).signals]
    found = [(rest.index(f"{s}: ") if rest.startswith(f"{s}: ") else rest.find(f", {s}: ") + 2, s)
             for s in order if rest.startswith(f"{s}: ") or f", {s}: " in rest]
    found.sort()
    texts = {}
    for k, (at, s) in enumerate(found):
        end = found[k + 1][0] - 2 if k + 1 < len(found) else len(rest)
        texts[s] = rest[at + len(s) + 2: end]
    return name, texts


@pytest.mark.parametrize("name", CLI_DBCS)
def test_equals_the_cantools_decode_command(capsys, tmp_path, name):
    """``cantools decode`` prints `Sig: name` for a value in its table and `Sig: number unit` for any
    other; railhil's table shows the same name, or the same number and unit."""
    dbc = next((p for p in TABLE_DBCS if p.name == name), None)
    if dbc is None:
        pytest.skip(NO_CORPUS)
    db = load_dbc(dbc)
    frames = [m for m in frames_for(db, Codec(db), name) if cantools_decoded(db, m) is not None]
    text = candump(frames)
    proc = subprocess.run([sys.executable, "-m", "cantools", "decode", "--single-line", str(dbc)], input=text,
                          capture_output=True, text=True, encoding="utf-8", timeout=120,
                          env={**os.environ, "PYTHONIOENCODING": "utf-8"})
    assert proc.returncode == 0, proc.stderr
    theirs = proc.stdout.splitlines()
    trace = tmp_path / "t.log"
    trace.write_text(text)
    code, out, err = railhil(capsys, "trace", "decode", trace, "--dbc", dbc)
    assert code == 0, err
    ours = out.splitlines()[1:]
    assert len(theirs) == len(ours) == len(frames)
    units = {(m.name, s.name): s.unit for m in db.messages for s in m.signals if s.unit}
    named = 0
    for line, mine in zip(theirs, ours, strict=True):
        message, texts = cantools_cli_signals(line, db)
        shown = table_signals(table_body(mine))
        assert list(shown) == list(texts), (line, mine)
        for sig, text in texts.items():
            value, unit = shown[sig]
            if isinstance(value, str):  # a name: the very text cantools prints
                assert text == value, (line, mine)
                named += 1
            else:
                unit_text = units.get((message, sig))
                if unit_text:
                    assert text.endswith(" " + unit_text) and unit == unit_text, (line, mine)
                    text = text[: -len(unit_text) - 1]
                assert float(f"{float(text):.10g}") == value, (line, mine)
    assert named


# --- bad input and odd output ----------------------------------------------------------------------


def test_bad_options_with_raw_are_one_line_errors(capsys, tmp_path):
    trace = tmp_path / "t.log"
    trace.write_text("(1.000000) can0 028#0000000000000000\n")
    code, _, err = railhil(capsys, "trace", "decode", trace, "--dbc", TRAIN_DBC, "--raw", "--signal", "Mod")
    assert_one_line_error(code, err, "train_brake.dbc", "'Mod'", "Mode")
    code, _, err = railhil(capsys, "trace", "decode", tmp_path / "none.log", "--dbc", TRAIN_DBC, "--raw")
    assert_one_line_error(code, err, "none.log", "no such trace file")


def test_a_unit_stdout_cannot_encode_is_escaped_not_an_error(tmp_path):
    """abs.dbc's Yaw_Rate is in °/s: on an ASCII stdout it is written as \\xb0/s, not a traceback."""
    dbc = CANTOOLS_DBC / "abs.dbc"
    if not dbc.is_file():
        pytest.skip(NO_CORPUS)
    trace = tmp_path / "t.log"
    trace.write_text("(1.000000) can0 070#A5B6D90000000000\n")
    proc = subprocess.run([sys.executable, "-m", "hil", "trace", "decode", str(trace), "--dbc", str(dbc)],
                          capture_output=True, cwd=ROOT, timeout=120,
                          env={**os.environ, "PYTHONIOENCODING": "ascii"})
    assert proc.returncode == 0, proc.stderr
    assert b"Yaw_Rate=69.945 \\xb0/s" in proc.stdout
