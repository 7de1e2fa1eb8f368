"""Shared fixtures: one lockstep run of the default scenario per test session (it is deterministic)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "scenarios" / "default.toml"


@pytest.fixture(scope="session")
def default_lockstep(tmp_path_factory):
    """The default scenario run in lockstep with its own seed; returns the RunReport."""
    from hil.runtime.run import run_scenario_lockstep
    from hil.scenario import load_scenario

    out = tmp_path_factory.mktemp("default-lockstep")
    return run_scenario_lockstep(load_scenario(DEFAULT), out)


def railhil(capsys, *args) -> tuple[int, str, str]:
    """`railhil ARGS` run in-process through hil.cli.main: (exit code, stdout, stderr)."""
    from hil.cli.main import main

    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, err: str, *needles: str) -> None:
    """Bad input: exit 2 and one line `error: ...` naming each of `needles`, no traceback."""
    assert code == 2, (code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]
