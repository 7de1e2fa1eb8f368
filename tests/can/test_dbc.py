"""The schema: loads, matches its generator, every cyclic frame has a cycle time, safety frames first."""

import importlib.util
import os
import sys
from pathlib import Path

import pytest

from hil.can.busload import declared_bitrate
from hil.can.dbc import DEFAULT_DBC, load_dbc
from hil.errors import DbcError

ROOT = Path(__file__).resolve().parents[2]
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


# -- the loaded-DBC cache (hil.can.dbc._cached) ---------------------------------------------------------

def _signals(db):
    return [(m.name, m.frame_id, m.length, m.cycle_time, [(s.name, s.start, s.length, s.byte_order, s.scale,
             s.offset, s.minimum, s.maximum, s.unit, s.choices and dict(s.choices)) for s in m.signals])
            for m in db.messages]


def test_a_dbc_parsed_once_is_loaded_from_the_cache_as_it_was_parsed(tmp_path, monkeypatch):
    import diskcache

    where = tmp_path / "cache"
    monkeypatch.setenv("RAILHIL_DBC_CACHE", str(where))
    first = load_dbc(DEFAULT_DBC)
    with diskcache.Cache(str(where)) as cache:
        assert len(cache) == 1                     # parsed and kept
    again = load_dbc(DEFAULT_DBC)
    assert again is not first and _signals(again) == _signals(first)
    assert again.dbc.attributes.keys() == first.dbc.attributes.keys()
    monkeypatch.setenv("RAILHIL_DBC_CACHE", "off")
    assert _signals(load_dbc(DEFAULT_DBC)) == _signals(first)


def test_a_dbc_rewritten_in_place_is_parsed_anew_whatever_its_time(tmp_path, monkeypatch):
    """The cache is keyed by the bytes: a file rewritten with the same size and modification time (as
    within one tick of the kernel's file clock) is not served from the cache as the old one."""
    monkeypatch.setenv("RAILHIL_DBC_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "x.dbc"
    text = 'VERSION ""\nBU_: A B\nBO_ 256 ONE: 8 A\n SG_ S : 0|8@1+ (1,0) [0|255] "" B\n'
    path.write_text(text)
    stat = path.stat()
    assert [m.name for m in load_dbc(path).messages] == ["ONE"]
    path.write_text(text.replace("ONE", "TWO"))                       # the same size
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))           # and the same time
    assert [m.name for m in load_dbc(path).messages] == ["TWO"]


def test_a_broken_cache_does_not_stop_a_dbc_loading(tmp_path, monkeypatch):
    where = tmp_path / "cache"
    where.mkdir()
    (where / "cache.db").write_bytes(b"not a sqlite database" * 100)
    monkeypatch.setenv("RAILHIL_DBC_CACHE", str(where))
    assert len(load_dbc(DEFAULT_DBC).messages) > 0
    unwritable = tmp_path / "file"
    unwritable.write_text("")
    monkeypatch.setenv("RAILHIL_DBC_CACHE", str(unwritable / "below"))   # cannot be made
    assert len(load_dbc(DEFAULT_DBC).messages) > 0
