"""SecOC keys from the scenario, a key file or the environment (issue #19): which one wins, that a run
really authenticates with it, and one line naming where it looked for a key that is missing or bad."""

from __future__ import annotations

from pathlib import Path

import can
import pytest
from conftest import assert_one_line_error, railhil

from hil.can.attributes import authentic_length, secoc_data_id
from hil.can.dbc import load_dbc
from hil.can.secoc import SecOcReceiver
from hil.runtime.node import DEV_SECOC_KEY
from hil.scenario import load_scenario
from hil.scenario.params import KEY_ENV, KEY_FILE_ENV, secoc_keys

ROOT = Path(__file__).resolve().parents[2]
STOP = ROOT / "scenarios" / "stop_30kmh.toml"
K_ENV, K_FILE, K_MSG, K_SCEN = "11" * 16, "22" * 16, "33" * 16, "44" * 16


@pytest.fixture(autouse=True)
def no_key_env(monkeypatch):
    monkeypatch.delenv(KEY_ENV, raising=False)
    monkeypatch.delenv(KEY_FILE_ENV, raising=False)


def scenario_with(tmp_path: Path, secoc: str) -> Path:
    path = tmp_path / "s.toml"                   # stop_30kmh.toml names no file of its own (DBC: the default)
    path.write_text(STOP.read_text() + "\n[secoc]\n" + secoc + "\n")
    return path


def test_each_source_over_the_one_before(tmp_path, monkeypatch):
    (tmp_path / "keys.toml").write_text(f'key = "{K_FILE}"\n[keys]\nBCU_DEMAND = "{K_MSG}"\n')
    monkeypatch.setenv(KEY_ENV, K_ENV)
    assert secoc_keys(load_scenario(STOP)) == {"*": bytes.fromhex(K_ENV)}
    keys = secoc_keys(load_scenario(scenario_with(tmp_path, 'key_file = "keys.toml"')))   # beside it
    assert keys == {"*": bytes.fromhex(K_FILE), "BCU_DEMAND": bytes.fromhex(K_MSG)}
    keys = secoc_keys(load_scenario(scenario_with(tmp_path, f'key_file = "keys.toml"\nkey = "{K_SCEN}"')))
    assert keys == {"*": bytes.fromhex(K_SCEN), "BCU_DEMAND": bytes.fromhex(K_MSG)}
    monkeypatch.setenv(KEY_FILE_ENV, str(tmp_path / "keys.toml"))      # the file named by the environment
    assert secoc_keys(load_scenario(STOP))["BCU_DEMAND"] == bytes.fromhex(K_MSG)


def test_a_run_authenticates_with_the_key_files_key(tmp_path, capsys, monkeypatch):
    (tmp_path / "keys.toml").write_text(f'key = "{K_FILE}"\n')
    monkeypatch.setenv(KEY_FILE_ENV, str(tmp_path / "keys.toml"))
    code, _, err = railhil(capsys, "run", STOP, "--lockstep", "--out", tmp_path / "run", "-q",
                           "--set", "max_duration_s=3.0")
    assert code == 0, err
    db = load_dbc()
    demand = db.get_message_by_name("BCU_DEMAND")
    ours, dev = (SecOcReceiver(k, secoc_data_id(demand)) for k in (bytes.fromhex(K_FILE), DEV_SECOC_KEY))
    with can.LogReader(str(next((tmp_path / "run").glob("trace.*")))) as reader:
        frames = [bytes(m.data) for m in reader if m.arbitration_id == demand.frame_id]
    assert len(frames) > 250 and authentic_length(demand) == 4
    assert all(ours.verify(f).accepted for f in frames)
    assert not any(dev.verify(f).accepted for f in frames)


@pytest.mark.parametrize("env, file_text, secoc, needles", [
    ({KEY_ENV: "zz"}, None, "", ("environment variable RAILHIL_SECOC_KEY", "32 hex digits")),
    ({KEY_FILE_ENV: "/nonexistent/keys.toml"}, None, "",
     ("SecOC key file /nonexistent/keys.toml", "$RAILHIL_SECOC_KEY_FILE", "no such file")),
    ({}, None, 'key_file = "missing.toml"', ("missing.toml", "[secoc] key_file", "no such file")),
    ({}, "key = ", 'key_file = "keys.toml"', ("keys.toml", "not valid TOML")),
    ({}, '[keys]\nBCU_DEMAND = "0011"\n', 'key_file = "keys.toml"',
     ("keys.toml", "keys.BCU_DEMAND", "got 4")),
    ({}, 'secret = "x"\n', 'key_file = "keys.toml"', ("keys.toml", "unknown entry 'secret'")),
    ({}, "", 'key_file = "keys.toml"', ("keys.toml", "holds no key")),
    ({}, None, "require_key = true", ("no SecOC key", "[secoc] key", "$RAILHIL_SECOC_KEY_FILE not set",
                                     "$RAILHIL_SECOC_KEY (not set)")),
])
def test_a_missing_or_bad_key_is_one_line_naming_where(tmp_path, capsys, monkeypatch, env, file_text, secoc,
                                                      needles):
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    if file_text is not None:
        (tmp_path / "keys.toml").write_text(file_text)
    path = scenario_with(tmp_path, secoc) if secoc else STOP
    code, _, err = railhil(capsys, "run", path, "--lockstep", "--out", tmp_path / "run", "-q")
    assert_one_line_error(code, err, *needles)
    assert not (tmp_path / "run").exists()
