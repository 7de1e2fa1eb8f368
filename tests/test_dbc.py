"""The schema: loads, matches its generator, every cyclic frame has a cycle time, safety frames first."""

import importlib.util
import sys
from pathlib import Path

import pytest

from hil.can.busload import declared_bitrate
from hil.can.dbc import DEFAULT_DBC, load_dbc
from hil.errors import DbcError

ROOT = Path(__file__).resolve().parents[1]
SAFETY = ("BCU_EMERGENCY", "DESK_CMD", "DESK_TARGET", "ACD_BRAKE_REQ", "BCU_DEMAND",
          "BCU_BRAKE_CORR") + tuple(f"BECU{i}_{what}" for what in ("PRESS_CMD", "STATUS")
                                    for i in range(1, 9))


def test_dbc_matches_its_generator():
    path = ROOT / "dbc" / "generator" / "train_brake.py"
    spec = importlib.util.spec_from_file_location("train_brake_generator", path)
    gen = importlib.util.module_from_spec(spec)
    sys.modules["train_brake_generator"] = gen
    spec.loader.exec_module(gen)
    assert DEFAULT_DBC.read_text() == gen.render(), \
        "dbc/train_brake.dbc differs from its generator: run .venv/bin/python dbc/generator/train_brake.py"


def test_schema_content():
    db = load_dbc()
    assert declared_bitrate(db) == 500_000
    assert {n.name for n in db.nodes} == {"PLANT", "BCU", "ACD", "DESK"} | {f"BECU{i}" for i in range(1, 9)}
    for m in db.messages:
        assert m.cycle_time and m.cycle_time > 0, m.name
        assert m.comment, m.name
        for s in m.signals:
            assert s.comment, f"{m.name}.{s.name} has no comment"
    safety_ids = [db.get_message_by_name(n).frame_id for n in SAFETY]
    other_ids = [m.frame_id for m in db.messages if m.name not in SAFETY]
    assert max(safety_ids) < min(other_ids), "safety frames must have the lowest identifiers"
    for name in SAFETY:
        sigs = {s.name for s in db.get_message_by_name(name).signals}
        assert {"COUNTER", "CHECKSUM", "SecOCFreshness", "SecOCMAC"} <= sigs, name
    assert {m.name for m in db.messages if any(s.name == "CHECKSUM" for s in m.signals)} == set(SAFETY)


@pytest.mark.parametrize("content, expected", [
    (None, "no such DBC file"),
    ("BO_ 1 X: 8 A\n SG_ S : 0|70@1+ (1,0) [0|0] \"\" B\n", "not a loadable DBC"),
])
def test_bad_dbc_is_one_clear_error(tmp_path, content, expected):
    path = tmp_path / "bad.dbc"
    if content is not None:
        path.write_text(content)
    with pytest.raises(DbcError) as err:
        load_dbc(path)
    assert expected in str(err.value) and str(path) in str(err.value)
    assert "\n" not in str(err.value)
