"""hil.can.codec against cantools: the fast path must give cantools' values and bytes, for train_brake.dbc
and for every DBC of the external corpus cantools can load (property tests, hypothesis).

The corpus lives outside the repository; RAILHIL_CORPUS points to it
(default ../shared/corpus beside the repository).
"""

from __future__ import annotations

import functools
import math
import random
from pathlib import Path

import cantools
import numpy as np
import pytest
from cantools.database.errors import DecodeError, EncodeError
from conftest import CORPUS
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from hil.can.codec import Codec, FrameCodec, FrameError
from hil.can.dbc import parse_dbc_text

ROOT = Path(__file__).resolve().parents[2]
TRAIN_DBC = ROOT / "dbc" / "train_brake.dbc"
CORPUS_DBCS = sorted(CORPUS.glob("**/*.dbc")) if CORPUS.is_dir() else []
MAX_LEN = 64  # longest CAN FD payload; one drawn payload is cut to each message's length
PROPERTY = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@functools.cache
def load(path: Path) -> tuple[cantools.database.can.Database, Codec]:
    """cantools' database (read as railhil reads a DBC: a value table naming no signal is left out, as in
    opendbc's tesla_can.dbc) and our Codec; a DBC cantools rejects strictly is loaded with strict=False
    (opendbc's vw_mqb.dbc has overlapping signals)."""
    text = path.read_text(encoding="cp1252", errors="replace")
    try:
        db = parse_dbc_text(text)
    except Exception:
        db = parse_dbc_text(text, strict=False)
    return db, Codec(db)


def dbc_param(path: Path):
    """A test parameter per DBC; one cantools cannot load even with strict=False is skipped."""
    name = "train_brake" if path == TRAIN_DBC else str(path.relative_to(CORPUS))
    try:
        load(path)
    except Exception as exc:
        reason = f"cantools {cantools.__version__} cannot load {path.name}: {' '.join(str(exc).split())}"
        return pytest.param(path, id=name, marks=pytest.mark.skip(reason=reason))
    return pytest.param(path, id=name)


ALL_DBCS = [TRAIN_DBC, *CORPUS_DBCS]
DBC_PARAMS = [dbc_param(p) for p in ALL_DBCS]
LOADABLE = [p.values[0] for p in DBC_PARAMS if not p.marks]


def cantools_decode(message, data: bytes) -> dict[str, float]:
    return {k: float(v) for k, v in message.decode(data, decode_choices=False, scaling=True).items()}


def same(a: dict[str, float], b: dict[str, float]) -> bool:
    """Equal dicts of floats, NaN equal to NaN (IEEE float signals decode random bits to NaN)."""
    return a.keys() == b.keys() and all(
        x == y or (math.isnan(x) and math.isnan(y)) for x, y in ((a[k], b[k]) for k in a)
    )


def signal_bits(signal, length: int) -> int:
    """The signal's bits as a mask over int.from_bytes(payload, 'little'), walked bit by bit the way
    the DBC format defines it (Motorola: from the MSB at `start`, down a byte, then to the next byte's
    bit 7) -- independent of the codec's shift arithmetic."""
    mask = 0
    bit = signal.start
    for _ in range(signal.length):
        mask |= 1 << bit
        if signal.byte_order == "little_endian":
            bit += 1
        elif bit % 8 == 0:
            bit += 15
        else:
            bit -= 1
    return mask & ((1 << (8 * length)) - 1)


# --- decode ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("path", DBC_PARAMS)
@PROPERTY
@given(payload=st.binary(min_size=MAX_LEN, max_size=MAX_LEN))
@example(payload=bytes(MAX_LEN))
@example(payload=b"\xff" * MAX_LEN)
@example(payload=b"\x55\xaa" * (MAX_LEN // 2))
def test_decode_equals_cantools(path: Path, payload: bytes) -> None:
    db, codec = load(path)
    for message in db.messages:
        data = payload[: message.length]
        try:
            expected = cantools_decode(message, data)
        except DecodeError:  # a multiplexer value the DBC does not define
            with pytest.raises(FrameError):
                codec[message.frame_id].decode(data)
            continue
        got = codec[message.frame_id].decode(data)
        assert same(got, expected), (message.name, data.hex(), got, expected)
        assert all(type(v) is float for v in got.values())


# --- encode(decode(data)) -------------------------------------------------------------------------


@pytest.mark.parametrize("path", DBC_PARAMS)
@PROPERTY
@given(payload=st.binary(min_size=MAX_LEN, max_size=MAX_LEN))
@example(payload=bytes(MAX_LEN))
@example(payload=b"\xff" * MAX_LEN)
def test_encode_decode_round_trips_used_bits(path: Path, payload: bytes) -> None:
    """encode(decode(data)) gives back the bits of every signal present whose value is inside the
    DBC range (or one of its choices), and 0 where no signal is; a value outside the range comes
    back saturated into it, and counted.

    Not compared bit for bit: an IEEE float signal holding NaN or inf (saturated, counted), and an
    integer signal whose raw value is beyond 2**53 (a float cannot hold it exactly)."""
    db, codec = load(path)
    for message in db.messages:
        data = payload[: message.length]
        fc = codec[message.frame_id]
        try:
            raw = message.decode(data, decode_choices=False, scaling=False)
        except DecodeError:
            continue
        values = fc.decode(data)
        compared = 0
        saturated = {}
        expected_clamps = 0
        inexact = 0  # beyond 2**53: float(raw) may round to just outside the bits' range
        for signal in message.signals:
            if signal.name not in values:  # another multiplexer branch
                continue
            value = values[signal.name]
            tol = abs(signal.scale) * 1e-6
            lo, hi = signal.minimum, signal.maximum
            if lo is not None and hi is not None and lo > hi:   # an inverted range declares nothing
                lo = hi = None                                   # (tesla_can.dbc: [1|0])
            if signal.is_float and not math.isfinite(value):
                expected_clamps += 1
            elif raw[signal.name] not in (signal.choices or {}) and (
                (lo is not None and value < lo - tol) or (hi is not None and value > hi + tol)
            ):
                expected_clamps += 1
                saturated[signal.name] = signal
            elif signal.is_float or abs(raw[signal.name]) <= 2**53:
                compared |= signal_bits(signal, message.length)
            else:
                inexact += 1
        before = fc.clamped
        encoded = fc.encode(values)
        assert expected_clamps <= fc.clamped - before <= expected_clamps + inexact, (message.name, data.hex())
        word, sent = int.from_bytes(data, "little"), int.from_bytes(encoded, "little")
        assert len(encoded) == message.length
        assert sent & compared == word & compared, (message.name, data.hex(), encoded.hex())
        used = functools.reduce(lambda m, s: m | signal_bits(s, message.length), message.signals, 0)
        assert sent & ~used == 0, (message.name, "unused bits must encode as 0")
        if saturated and not message.is_multiplexed():
            again = fc.decode(encoded)
            for name, signal in saturated.items():
                half = abs(signal.scale) / 2
                assert signal.minimum - half <= again[name] <= signal.maximum + half, (message.name, name)


# --- encode of in-range values --------------------------------------------------------------------


def in_range_value(signal, rng: random.Random) -> float | int:
    """A physical value cantools' strict encode accepts, by one of several recipes: anywhere in the
    range, on the raw grid, half-way between two grid points (rounding ties), at the ends, a choice."""
    conv = signal.conversion
    if signal.is_float:
        lo, hi = signal.minimum, signal.maximum
        if lo is None or hi is None:
            lo, hi = (-3.0e38, 3.0e38) if signal.length == 32 else (-1e300, 1e300)
        return rng.choice([rng.uniform(lo, hi), 0.0, rng.uniform(-1, 1), float(rng.randint(-1000, 1000))])
    n = signal.length
    raw_lo, raw_hi = (-(1 << (n - 1)), (1 << (n - 1)) - 1) if signal.is_signed else (0, (1 << n) - 1)
    ends = sorted(float(conv.raw_to_scaled(r, False)) for r in (raw_lo, raw_hi))
    lo = signal.minimum if signal.minimum is not None else ends[0]
    hi = signal.maximum if signal.maximum is not None else ends[1]
    # the raw values whose physical value is in [lo, hi]
    a, b = sorted(((lo - conv.offset) / conv.scale, (hi - conv.offset) / conv.scale))
    k_lo, k_hi = max(raw_lo, math.ceil(a)), min(raw_hi, math.floor(b))
    if k_lo > k_hi:
        return rng.uniform(lo, hi)
    k = rng.randint(k_lo, k_hi)
    recipe = rng.randrange(7)
    if recipe == 0:
        return rng.uniform(lo, hi)
    if recipe == 1:
        return conv.raw_to_scaled(k, False)  # on the grid (an int for integer conversions)
    if recipe == 2 and k < k_hi:
        return (k + 0.5) * conv.scale + conv.offset  # a rounding tie
    if recipe == 3:
        return lo
    if recipe == 4:
        return hi
    if recipe == 5 and signal.choices:
        return conv.raw_to_scaled(rng.choice(list(signal.choices)), False)
    return float(conv.raw_to_scaled(k, False))


def one_branch(tree: list, values: dict, rng: random.Random) -> dict:
    """The values of the signals of one random branch of cantools' signal_tree, selectors set."""
    out = {}
    for node in tree:
        if isinstance(node, str):
            out[node] = values[node]
            continue
        for selector, branches in node.items():
            mux = rng.choice(sorted(branches))
            out[selector] = mux
            out.update(one_branch(branches[mux], values, rng))
    return out


@pytest.mark.parametrize("path", DBC_PARAMS)
@PROPERTY
@given(seed=st.integers(0, 2**64 - 1))
def test_encode_in_range_equals_cantools(path: Path, seed: int) -> None:
    """Where cantools' strict encode accepts the values, our bytes are cantools' bytes and nothing
    is counted as clamped.  (Values come from random.Random(seed): a few hundred per example.)"""
    rng = random.Random(seed)
    db, codec = load(path)
    accepted = 0
    for message in db.messages:
        fc = codec[message.frame_id]
        values = {s.name: in_range_value(s, rng) for s in message.signals}
        if message.is_multiplexed():  # strict wants exactly one branch's signals
            values = one_branch(message.signal_tree, values, rng)
        try:
            expected = message.encode(values, scaling=True, padding=False, strict=True)
        except Exception:  # e.g. a value whose raw value the bits cannot hold: cantools raises
            continue
        accepted += 1
        before = fc.clamped
        got = fc.encode(values)
        assert got == expected, (message.name, values, got.hex(), expected.hex())
        assert fc.clamped == before, (message.name, values)
    if path == TRAIN_DBC:
        assert accepted == len(db.messages)
    else:
        assert accepted > 0 or not db.messages


# --- the fast path --------------------------------------------------------------------------------


def train() -> tuple[cantools.database.can.Database, Codec]:
    return load(TRAIN_DBC)


def test_every_train_brake_frame_takes_the_fast_path() -> None:
    db, codec = train()
    assert len(codec) == len(db.messages)
    slow = [(fc.name, fc.fallback_reason) for fc in codec if fc.fallback_reason is not None]
    assert slow == []


def test_multiplexed_messages_fall_back_to_cantools() -> None:
    path = CORPUS / "cantools/tests/files/dbc/multiplex.dbc"
    if not path.is_file():
        pytest.skip(f"corpus file {path} not present")
    _, codec = load(path)
    assert all("multiplexed" in (fc.fallback_reason or "") for fc in codec)


def test_codec_lookup() -> None:
    db, codec = train()
    fc = codec[49]
    assert isinstance(fc, FrameCodec)
    assert (fc.frame_id, fc.name, fc.length, fc.is_extended_id) == (49, "BECU1_PRESS_CMD", 8, False)
    assert fc.signal_names == ("CHECKSUM", "COUNTER", "WspValve", "ValveCmd", "CylPressureSet",
                               "SecOCFreshness", "SecOCMAC")
    assert codec.by_name("BECU1_PRESS_CMD") is fc
    assert codec.get(49) is fc
    assert codec.get(0x7FF) is None
    assert 49 in codec and 0x7FF not in codec
    with pytest.raises(KeyError, match="0x7ff"):
        codec[0x7FF]
    with pytest.raises(KeyError, match="BECU1_PRESS_CMD"):
        codec.by_name("BECU1_PRES_CMD")


# --- saturation: never raise, saturate, count -----------------------------------------------------

NOMINAL = {"CHECKSUM": 0x5A, "COUNTER": 7, "WspValve": 1, "CylPressureSet": 250_000.0, "ValveCmd": 0.2,
           "SecOCFreshness": 0xA5, "SecOCMAC": 0x123456}


@pytest.mark.parametrize(
    ("signal", "value", "decoded", "counted"),
    [
        ("ValveCmd", 5.0, 1.0, 1),  # above the DBC maximum
        ("ValveCmd", -1.5, -1.0, 1),
        ("ValveCmd", math.inf, 1.0, 1),
        ("ValveCmd", -math.inf, -1.0, 1),
        ("ValveCmd", math.nan, 0.0, 1),  # NaN -> raw 0, the value of a missing signal
        ("ValveCmd", 1.0 + 5e-11, 1.0, 0),  # within cantools' tolerance of 1e-6 * scale
        ("ValveCmd", np.float64(-0.5), -0.5, 0),
        ("ValveCmd", np.float32(0.5), 0.5, 0),
        ("ValveCmd", None, 0.0, 0),
        ("CylPressureSet", 1e12, 511_000.0, 1),
        ("CylPressureSet", -3.0, 0.0, 1),
        ("CylPressureSet", 12_500.0, 12_000.0, 0),  # 12.5 -> 12: round half to even, as cantools
        ("CylPressureSet", 13_500.0, 14_000.0, 0),  # 13.5 -> 14
        ("WspValve", 3, 2.0, 1),  # the bits hold 3, the DBC range stops at 2
        ("WspValve", "VENT", 2.0, 0),  # a choice name
        ("WspValve", "BOGUS", 0.0, 1),
        ("WspValve", True, 1.0, 0),
        ("COUNTER", 16, 15.0, 1),
        ("COUNTER", object(), 0.0, 1),
    ],
)
def test_encode_saturates_and_counts(signal: str, value, decoded: float, counted: int) -> None:
    db, codec = train()
    fc = codec.by_name("BECU1_PRESS_CMD")
    before = fc.clamped
    out = fc.decode(fc.encode({**NOMINAL, signal: value}))
    assert out[signal] == decoded
    assert fc.clamped - before == counted
    others = {k: v for k, v in out.items() if k != signal}
    assert others == {k: float(v) for k, v in NOMINAL.items() if k != signal}


def test_missing_signals_encode_as_raw_zero_without_counting() -> None:
    db, codec = train()
    fc = codec.by_name("PLANT_CAR1_SENSORS")
    before = fc.clamped
    assert fc.encode({}) == bytes(8)
    assert fc.decode(fc.encode({"AccelLong": -1.5})) == {
        "AxleSpeed": 0.0, "CylPressure": 0.0, "AccelLong": -1.5, "SensorCounter": 0.0
    }
    assert fc.clamped == before
    assert codec.clamped >= fc.clamped


def test_in_range_encode_equals_cantools_strict_on_the_tolerance_edge() -> None:
    db, codec = train()
    message = db.get_message_by_name("BECU1_PRESS_CMD")
    values = {**NOMINAL, "ValveCmd": -1.0 - 9e-11, "CylPressureSet": 511_000.0 + 9e-6}
    assert codec[49].encode(values) == message.encode(values, strict=True)


SNA_DBC = """VERSION ""
BU_: A
BO_ 100 SNA_MSG: 2 A
 SG_ Level : 0|8@1+ (1,0) [0|100] "%" A
 SG_ Temp : 8|8@1- (0.5,-10) [-20|40] "degC" A
VAL_ 100 Level 254 "ERROR" 255 "SNA" ;
"""


def test_out_of_range_choice_is_sent_as_cantools_sends_it() -> None:
    db = cantools.database.load_string(SNA_DBC, database_format="dbc")
    fc = Codec(db)[100]
    message = db.get_message_by_name("SNA_MSG")
    for level in (255, "SNA", 254, 100, 0):
        values = {"Level": level, "Temp": 39.25}  # 39.25 -> raw 98.5 -> 98 (half to even)
        assert fc.encode(values) == message.encode(values, strict=True)
    assert fc.clamped == 0
    assert fc.decode(fc.encode({"Level": 200, "Temp": -99.0})) == {"Level": 100.0, "Temp": -20.0}
    assert fc.clamped == 2


def test_fallback_path_saturates_too() -> None:
    path = CORPUS / "cantools/tests/files/dbc/multiplex.dbc"
    if not path.is_file():
        pytest.skip(f"corpus file {path} not present")
    db, codec = load(path)
    message = db.messages[0]
    fc = codec[message.frame_id]
    selector = next(s for s in message.signals if s.is_multiplexer)
    ids = sorted({i for s in message.signals for i in (s.multiplexer_ids or [])})
    before = fc.clamped
    fc.encode({selector.name: 1000, **{s.name: math.nan for s in message.signals if not s.is_multiplexer}})
    assert fc.decode(fc.encode({selector.name: 1000}))[selector.name] == float(ids[0])
    assert fc.clamped > before


# --- malformed payloads ---------------------------------------------------------------------------


def test_short_payload_raises_frame_error_long_payload_is_truncated() -> None:
    db, codec = train()
    fc = codec.by_name("BCU_DEMAND")
    with pytest.raises(FrameError, match="BCU_DEMAND"):
        fc.decode(b"\x00" * 7)
    assert issubclass(FrameError, ValueError) and issubclass(FrameError, DecodeError)
    data = bytes(range(1, 13))
    message = db.get_message_by_name("BCU_DEMAND")
    assert fc.decode(data) == cantools_decode(message, data)
    assert fc.decode(bytearray(data[:8])) == cantools_decode(message, data[:8])


def test_encode_error_free_on_every_corpus_message_with_garbage() -> None:
    """Whatever a node hands over, encode returns a payload of the message's length."""
    garbage = [math.nan, math.inf, -math.inf, 1e300, -1e300, "x", None, 2**70]
    for path in LOADABLE:
        db, codec = load(path)
        for fc in codec:
            for g in garbage:
                assert len(fc.encode(dict.fromkeys(fc.signal_names, g))) == fc.length


def test_encode_error_is_not_what_cantools_would_raise() -> None:
    """Sanity check of the premise: cantools raises where we saturate."""
    db, codec = train()
    message = db.get_message_by_name("BECU1_PRESS_CMD")
    with pytest.raises(EncodeError):
        message.encode({**NOMINAL, "ValveCmd": 5.0}, strict=True)


MAPPED_DBCS = {"train_brake.dbc", "abs.dbc", "floating_point.dbc", "motohawk.dbc", "multiplex_choices.dbc",
               "signed.dbc"}   # ours; a multiplexed one (cantools' path); IEEE floats; big-endian; signed
MAPPED_VALUES = [0.0, 1.0, -1.0, 0.5, 250_000.0, 1e9, -1e9, math.nan, math.inf, "x", None, 2**70, True]


@PROPERTY
@given(seed=st.integers(0, 2**64 - 1))
@pytest.mark.parametrize("path", [p for p in LOADABLE if p.name in MAPPED_DBCS], ids=lambda p: p.name)
def test_the_mapped_encoder_equals_encode_of_the_values_it_stands_for(path: Path, seed: int) -> None:
    """FrameCodec.encoder(fields, counter)(outputs, count) is encode({signal: outputs.get(key, 0.0) for
    fields} with the counter), bytes and saturation counts alike: for a random subset of each message's
    signals mapped to output keys (some missing from the outputs), a random counter signal, and values in
    range, out of range, non-finite and not numbers (the fast path and the cantools fallback)."""
    rng = random.Random(seed)
    db, codec = load(path)
    _, twin = load(path)                      # counts its saturations on its own
    for fc in codec:
        names = list(fc.signal_names)
        fields = [(name, f"out.{name}") for name in names if rng.random() < 0.7]
        counter = rng.choice([None, *names])
        outputs = {key: rng.choice(MAPPED_VALUES) for _, key in fields if rng.random() < 0.8}
        count = rng.randrange(15)
        values = {sig: outputs.get(key, 0.0) for sig, key in fields}
        if counter is not None:
            values[counter] = count
        other = twin.by_name(fc.name)
        before, other_before = fc.clamped, other.clamped
        assert fc.encoder(fields, counter)(outputs, count) == other.encode(values), (fc.name, fields, outputs)
        assert fc.clamped - before == other.clamped - other_before, fc.name


@PROPERTY
@given(seed=st.integers(0, 2**64 - 1), payload=st.binary(min_size=MAX_LEN, max_size=MAX_LEN))
@pytest.mark.parametrize("path", [p for p in LOADABLE if p.name in MAPPED_DBCS], ids=lambda p: p.name)
def test_the_storer_sets_what_decode_gives_for_the_pairs_it_stands_for(path: Path, seed: int,
                                                                        payload: bytes) -> None:
    """FrameCodec.storer(pairs)(data, values, times, t) sets values[key] = decode(data)[signal] and
    times[key] = t for each (signal, key) of a random subset of each message's signals, and nothing else
    (the fast path and the cantools fallback, which sets only the multiplexed signals the frame carries);
    on a short payload it raises FrameError as decode does."""
    rng = random.Random(seed)
    _, codec = load(path)
    for fc in codec:
        pairs = [(name, f"in.{name}") for name in fc.signal_names if rng.random() < 0.6]
        data = payload[:fc.length]
        try:
            decoded = fc.decode(data)
        except FrameError:                    # a multiplexer value the DBC does not define
            with pytest.raises(FrameError):
                fc.storer(pairs)(data, {}, {}, 7)
            continue
        values, times = {"other": 1.0}, {"other": 3}
        fc.storer(pairs)(data, values, times, 7)
        carried = [(sig, key) for sig, key in pairs if sig in decoded]   # all but another mux branch's
        assert same(values, {"other": 1.0, **{key: decoded[sig] for sig, key in carried}}), fc.name
        assert all(type(values[key]) is float for _, key in carried), fc.name
        assert times == {"other": 3, **{key: 7 for _, key in carried}}, fc.name
        if fc.length:
            with pytest.raises(FrameError):
                fc.storer(pairs)(data[:-1], {}, {}, 7)
