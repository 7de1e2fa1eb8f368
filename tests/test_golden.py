"""Golden references in lockstep: every shipped scenario's trace.blf and truth.csv byte for byte
(golden_traces.json), and the default scenario's KPIs field by field.

A lockstep run is deterministic (same scenario, same seed -> the same trace.blf), so any change to what
the run computes shows here: a faster codec, bus model or node runtime must leave both untouched.

When a change is MEANT to change the run (physics, a controller, the DBC, the scenario, a python-can
release whose BLF writer lays bytes out differently), refresh the references:

    .venv/bin/python tests/test_golden.py

runs the default scenario and prints the two constants below; paste them here, and say in the commit
why the golden run changed.  `.venv/bin/python tests/test_golden.py --all` runs every scenario of
scenarios/ and writes golden_traces.json anew (about 20 s); `git diff` then shows which runs changed.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path

import pytest

#: sha256 of trace.blf of `railhil run scenarios/default.toml --lockstep`
GOLDEN_TRACE_SHA256 = "9577f7455f0024a015deaf682dedad5d192c55394a9b02ca4ae2378cf5084231"

#: KPIs of that run as kpis.json holds them (results.py rounds them when it writes them)
GOLDEN_KPIS = {
    "end_reason": "standstill",
    "frames_in_flight": 6,
    "frames_recorded": 49392,
    "frames_sent": 49398,
    "max_slip_speed_mps": [1.2831, 1.2432, 1.1927, 1.1483, 1.2918, 1.0717],
    "mean_abs_decel_error_mps2": 0.1002,
    "simulated_s": 29.4,
    "stopping_distance_m": 357.563,
    "time_to_stop_s": 27.9,
    "wsp_activations": [8, 8, 9, 9, 10, 11],
}
KPI_TOLERANCE = 1e-9      # the run is deterministic: equal up to float formatting

REFRESH = "if the change is intended, refresh the references: .venv/bin/python tests/test_golden.py"
ROOT = Path(__file__).resolve().parents[1]
GOLDEN_TRACES = Path(__file__).with_name("golden_traces.json")
SHIPPED = sorted((ROOT / "scenarios").glob("*.toml"))


def test_default_trace_is_byte_for_byte_the_golden_one(default_lockstep):
    trace = default_lockstep.out_dir / "trace.blf"
    digest = hashlib.sha256(trace.read_bytes()).hexdigest()
    assert digest == GOLDEN_TRACE_SHA256, f"the default lockstep trace changed (sha256 {digest}); {REFRESH}"


@pytest.mark.parametrize("key", sorted(GOLDEN_KPIS))
def test_default_kpis_are_the_golden_ones(default_lockstep, key):
    kpis = json.loads((default_lockstep.out_dir / "kpis.json").read_text())
    expected, got = GOLDEN_KPIS[key], kpis.get(key)
    if isinstance(expected, float) or (isinstance(expected, list) and expected
                                       and isinstance(expected[0], float)):
        assert got == pytest.approx(expected, abs=KPI_TOLERANCE), f"KPI {key}: {got} != {expected}; {REFRESH}"
    else:
        assert got == expected, f"KPI {key}: {got!r} != {expected!r}; {REFRESH}"


def _run_files(scenario: Path, out: Path) -> dict[str, str]:
    """Run `scenario` in lockstep into `out` (no figures): sha256 of each trace (.blf) and truth (.csv) it
    wrote, by file name."""
    from hil.report.run import run_scenario_lockstep
    from hil.scenario import load_scenario

    report = run_scenario_lockstep(load_scenario(scenario), out, plots=False)
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(report.out_dir.iterdir()) if p.suffix in (".blf", ".csv")}


@pytest.mark.parametrize("scenario", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_every_shipped_scenario_gives_its_golden_trace_and_truth(scenario, tmp_path):
    golden = json.loads(GOLDEN_TRACES.read_text())
    assert scenario.stem in golden, (f"scenario {scenario.name} has no golden trace; run .venv/bin/python "
                                     "tests/test_golden.py --all and commit golden_traces.json")
    got = _run_files(scenario, tmp_path / "run")
    assert got == golden[scenario.stem], (f"the lockstep run of {scenario.name} changed: "
                                          f"{got} != {golden[scenario.stem]}; --all: {REFRESH}")


def _current() -> tuple[str, dict]:
    """Run the default scenario now: (trace sha256, the golden subset of its KPIs)."""
    root = Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root))
    from hil.report.run import run_scenario_lockstep
    from hil.scenario import load_scenario

    with tempfile.TemporaryDirectory() as tmp:
        report = run_scenario_lockstep(load_scenario(root / "scenarios" / "default.toml"), Path(tmp) / "run")
        digest = hashlib.sha256((report.out_dir / "trace.blf").read_bytes()).hexdigest()
        kpis = json.loads((report.out_dir / "kpis.json").read_text())
    return digest, {key: kpis.get(key) for key in GOLDEN_KPIS}


def _write_every_golden_trace() -> None:
    sys.path.insert(0, str(ROOT))
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for scenario in SHIPPED:
            out[scenario.stem] = _run_files(scenario, Path(tmp) / scenario.stem)
            print(scenario.stem, out[scenario.stem], flush=True)
    GOLDEN_TRACES.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN_TRACES}")


if __name__ == "__main__" and "--all" in sys.argv[1:]:
    _write_every_golden_trace()
elif __name__ == "__main__":
    sha, values = _current()
    print(f'GOLDEN_TRACE_SHA256 = "{sha}"\n')
    print("GOLDEN_KPIS = {")
    for name, value in values.items():
        print(f"    {name!r}: {value!r},")
    print("}")
