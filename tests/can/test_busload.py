"""Frame lengths (Davis et al. 2007) and the static bus load of train_brake.dbc."""

from __future__ import annotations

from pathlib import Path

import cantools
import pytest
from conftest import CORPUS

from hil.can.busload import (
    BusLoad,
    frame_bits,
    functions_of,
    optional_function,
    static_load,
    train_frame_ids,
    with_functions,
)
from hil.errors import DbcError

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def db():
    return cantools.database.load_file(str(ROOT / "dbc" / "train_brake.dbc"))


# Davis, Burns, Bril, Lukkien 2007, eq. (15): g + 8s + 13 + floor((g + 8s - 1) / 4), g = 34 / 54
@pytest.mark.parametrize(
    ("dlc", "extended", "stuffed", "bits"),
    [
        (8, False, True, 135),
        (8, True, True, 160),
        (0, False, True, 55),
        (0, True, True, 80),
        (1, False, True, 65),
        (4, True, True, 120),
        (8, False, False, 111),
        (8, True, False, 131),
        (0, False, False, 47),
        (12, False, True, 135),  # classic CAN: DLC 9..15 carries 8 bytes
    ],
)
def test_frame_bits(dlc: int, extended: bool, stuffed: bool, bits: int) -> None:
    assert frame_bits(dlc, extended, worst_case_stuffing=stuffed) == bits


@pytest.mark.parametrize("s", range(9))
def test_frame_bits_closed_forms(s: int) -> None:
    assert frame_bits(s, extended=False) == 55 + 10 * s
    assert frame_bits(s, extended=True) == 80 + 10 * s


@pytest.mark.parametrize("dlc", [-1, 16])
def test_frame_bits_rejects_impossible_dlc(dlc: int) -> None:
    with pytest.raises(ValueError, match="DLC"):
        frame_bits(dlc, extended=False)


def test_train_frame_ids_rule(db) -> None:
    names = {db.get_message_by_frame_id(i).name for i in train_frame_ids(db, 6)}
    assert "BECU6_PRESS_CMD" in names and "PLANT_CAR6_SENSORS" in names and "BECU6_STATUS" in names
    assert not any(n.startswith(("BECU7", "BECU8", "PLANT_CAR7", "PLANT_CAR8")) for n in names)
    assert not any(n.startswith(("RADIO_", "ACD_")) for n in names)
    assert {"BCU_EMERGENCY", "DESK_CMD", "DESK_TARGET", "BCU_DEMAND", "BCU_STATUS"} <= names
    assert len(names) == 5 + 5 * 6
    assert len(train_frame_ids(db, 1)) == 5 + 5
    with pytest.raises(ValueError, match="1..8"):
        train_frame_ids(db, 9)
    with pytest.raises(ValueError, match="1..8"):
        train_frame_ids(db, 0)


def test_six_car_default_worst_case_load_is_at_most_60_percent(db) -> None:
    load = static_load(db, frame_ids=train_frame_ids(db, 6))
    print(f"\n6-car default run:\n{load.table()}")
    assert isinstance(load, BusLoad)
    assert load.bitrate_bps == 500_000  # the DBC's Baudrate
    assert load.worst_case_stuffing
    # 1680 frames/s of 135 bit: 50 (20 ms) + 2 * 10 + 100 + 6 * (100 + 100 + 20 + 20 + 10) + 10 (100 ms)
    assert load.bits_per_s == pytest.approx(1680 * 135)
    assert load.total == pytest.approx(1680 * 135 / 500_000)
    assert load.total <= 0.60
    assert sum(r.share for r in load.rows) == pytest.approx(1.0)
    assert sum(r.load for r in load.rows) == pytest.approx(load.total)
    row = next(r for r in load.rows if r.name == "BCU_EMERGENCY")
    assert (row.frame_id, row.dlc, row.cycle_ms, row.bits) == (0x10, 8, 20.0, 135)


def test_eight_car_full_load(db) -> None:
    base = with_functions(db, [])             # the base train's frames of 8 cars (no optional function)
    load = static_load(base)
    print(f"\n8-car full load: {100 * load.total:.1f} % ({load.bits_per_s:.0f} bit/s)")
    assert len(load.rows) == len(base.messages) < len(db.messages)
    assert load.bits_per_s == pytest.approx((1680 + 2 * 250) * 135)
    unstuffed = static_load(base, worst_case_stuffing=False)
    assert unstuffed.total == pytest.approx(load.total * 111 / 135)
    # with the anti-collision device: its request (100 ms) and the radio link's three frames (1 s)
    acd = static_load(with_functions(db, ["anticollision"]))
    assert acd.bits_per_s - load.bits_per_s == pytest.approx(sum(
        1000 / m.cycle_time * 135 for m in db.messages if optional_function(m) == "anticollision"))


def test_optional_functions_are_chosen_by_name(db) -> None:
    assert {"preview_slip", "anticollision", "consensus", "precise_stop",
            "balises"} <= set(functions_of(db))
    assert with_functions(db, ["all"]) is db
    stop = with_functions(db, ["precise_stop"])
    names = {m.name for m in stop.messages}
    assert "BCU_STOP" in names and "PLANT_BTM" not in names
    with pytest.raises(DbcError, match="'nope'.*consensus"):
        with_functions(db, ["nope"])


def test_explicit_bitrate_wins(db) -> None:
    assert static_load(db, bitrate_bps=250_000).total == pytest.approx(2 * static_load(db).total)


def test_unknown_frame_id_is_named(db) -> None:
    with pytest.raises(DbcError, match="0x7ff"):
        static_load(db, frame_ids=[0x10, 0x7FF])


def test_dbc_without_baudrate_needs_a_bitrate() -> None:
    path = CORPUS / "cantools/tests/files/dbc/motohawk.dbc"
    if not path.is_file():
        pytest.skip(f"corpus file {path} not present")
    corpus_db = cantools.database.load_file(str(path))
    with pytest.raises(ValueError, match="no 'Baudrate' attribute.*bitrate_bps"):
        static_load(corpus_db)
    assert static_load(corpus_db, bitrate_bps=500_000).bitrate_bps == 500_000


def test_event_frames_do_not_count() -> None:
    dbc = """VERSION ""
BU_: A
BO_ 1 CYCLIC: 8 A
 SG_ X : 0|8@1+ (1,0) [0|255] "" A
BO_ 2 EVENT: 8 A
 SG_ Y : 0|8@1+ (1,0) [0|255] "" A
BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 1 10;
"""
    small = cantools.database.load_string(dbc, database_format="dbc")
    load = static_load(small, bitrate_bps=125_000)
    assert [r.name for r in load.rows] == ["CYCLIC"]
    assert load.total == pytest.approx(135 * 100 / 125_000)
