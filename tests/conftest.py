"""Shared fixtures: one lockstep run of the default scenario per test session (it is deterministic)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "scenarios" / "default.toml"


@pytest.fixture(scope="session")
def default_lockstep(tmp_path_factory):
    """The default scenario run in lockstep with its own seed; returns the RunReport."""
    from hil.run import run_scenario_lockstep
    from hil.scenario import load_scenario

    out = tmp_path_factory.mktemp("default-lockstep")
    return run_scenario_lockstep(load_scenario(DEFAULT), out)
