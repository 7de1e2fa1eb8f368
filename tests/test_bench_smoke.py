"""`make bench` must run on a clean clone: each benchmark's fixed inputs still fit the DBC (the timed
loops themselves run only in `make bench`)."""

import sys

import pytest
from conftest import ROOT

sys.path.insert(0, str(ROOT / "bench"))


def test_codec_bench_frames_encode_and_match_cantools(monkeypatch):
    import bench_codec

    monkeypatch.setattr(bench_codec, "per_call_us", lambda fn, **_: (fn(), 1.0)[1])
    rows = bench_codec.run()
    assert rows and all("skipped" not in figure for label, figure in rows if "BECU1" in label)


def test_every_bench_module_is_registered_and_documented():
    import run_all

    for name in run_all.BENCHES:
        module = __import__(name)
        assert module.__doc__.strip() and callable(module.run)


def test_profile_counts_each_sample_for_its_innermost_component():
    import profile_lockstep as pl

    run = "<module> (bench/profile_lockstep.py:140);_profiled_runs (bench/profile_lockstep.py:78);" \
          "_once (bench/bench_lockstep.py:38);run_lockstep (hil/runtime/lockstep.py:263)"
    raw = [
        f"{run};Node.cycle (hil/runtime/node.py:465);Becu.step (firmware_py/becu.py:917) 5",
        f"{run};LockstepBus.send (hil/runtime/lockstep.py:83);Node.receive (hil/runtime/node.py:406);"
        "<lambda> (<railhil codec BCU_DEMAND, store>:1) 3",
        f"{run};Node.cycle (hil/runtime/node.py:465) 2",
        f"{run};prepare_lockstep (hil/runtime/lockstep.py:122);Becu.__init__ (firmware_py/becu.py:620) 4",
        f"{run};len (<builtin>:0) 1",                        # nothing else: the event loop's
        # the warm-up run, outside _profiled_runs, and a stack outside the run: not counted
        "<module> (bench/profile_lockstep.py:139);child (bench/profile_lockstep.py:88);"
        "run_lockstep (hil/runtime/lockstep.py:263);Becu.step (firmware_py/becu.py:917) 7",
        "<module> (bench/profile_lockstep.py:140);_profiled_runs (bench/profile_lockstep.py:78);"
        "load_dbc (hil/can/dbc.py:40) 6",
        "garbage without a count",
    ]
    counts, total = pl.shares(raw)
    controllers, node, codec, loop = (next(n for n, _ in pl.COMPONENTS if n.startswith(p))
                                      for p in ("controllers", "node dispatch", "codec", "event loop"))
    assert total == 15
    assert counts == {controllers: 5, codec: 3, node: 2, pl.SETUP: 4, loop: 1}


def test_a_native_profile_counts_mypycs_functions_for_their_modules_components():
    """On the compiled build py-spy --native names mypyc's C functions (a py-spy raw line of this build):
    each counts for its module's component, as the Python frame of the pure build does."""
    import profile_lockstep as pl

    from hil.build import COMPILED

    so = "(66a872f373b0a3a688fe__mypyc.cpython-311-x86_64-linux-gnu.so)"
    run = ("<module> (profile_lockstep.py:162);main (profile_lockstep.py:122);"
           "child (profile_lockstep.py:106);_profiled_runs (profile_lockstep.py:97);"
           "_once (bench_lockstep.py:44);"
           f"CPyPy_lockstep___run_lockstep {so};CPyDef_lockstep___run_lockstep {so};"
           f"CPyDef_lockstep___LockstepLoop___run {so}")
    raw = [f"{run};CPyDef_node___Node___cycle {so};CPyDef_becu___Becu___step {so};0x7f44 (libc.so.6) 5",
           f"{run};CPyDef_node___Node___cycle {so};CPyDef_rx___RxTable___take {so} 2",
           f"{run};CPyDef_bustiming___BitTimedBus___arbitrate {so} 3",
           f"{run};CPyDef_lockstep___LockstepLoop___deliver {so};CPyDef_e2e___E2eCheck___check {so} 1"]
    components = pl.native_keys(COMPILED)
    counts, total = pl.shares(raw, components)
    controllers, node, bus, e2e = (next(n for n, _ in components if n.startswith(p))
                                   for p in ("controllers", "node dispatch", "bit-timed bus", "E2E"))
    assert total == 11 and counts == {controllers: 5, node: 2, bus: 3, e2e: 1}
    assert pl.shares(raw) == ({}, 11)          # the Python frames' keys alone: no sample has a component


def _gateway_kpis(device_p99_us: float, machine: dict) -> dict:
    way = {"frames": 2940, "p50_us": 170.0, "p99_us": device_p99_us, "max_us": 1509}
    return {
        "devices": {"BECU3": {
            "node": "EBC7", "dbc": "/x/acme_becu.dbc", "verdict": "PASS",
            "latency": {"device_to_bench": way,
                        "bench_to_device": {"frames": 0, "p50_us": None, "p99_us": None, "max_us": None}},
            "processing": {"to_bench": {**way, "frames": 3042, "p99_us": 412546.0},
                           "to_device": {"frames": 0, "p50_us": None, "p99_us": None, "max_us": None}},
            "device": {"frames": 4440, "timing": "PASS", "protection_clean": True},
            "bench": {"timing": "PASS"}}},
        "realtime": {"held": False, "misses_bench": 14, "misses_machine": 48, "worst_node": "BECU3",
                     "machine": machine},
        "simulated_s": 29.4, "end_reason": "standstill", "stopping_distance_m": 357.6, "stopped": True,
    }


def test_gateway_bench_judges_each_direction_against_its_goal_beside_the_probe():
    import bench_gateway

    probe = {"cycles": 5879, "p50_us": 47, "p99_us": 126, "worst_stall_us": 3435, "stalls": 11}
    rows = dict(bench_gateway.rows(_gateway_kpis(1000.4, probe), "EBC-7: 3449 cycles"))
    goals = {label: figure for label, figure in rows.items() if "goal" in label}
    assert set(goals) == {"gateway latency p99, device → bench (goal ≤ 1 ms)",
                          "gateway latency p99, bench → device (goal ≤ 1 ms)"}
    assert goals["gateway latency p99, device → bench (goal ≤ 1 ms)"].startswith("1000 us: NOT met (machine "
                                                                                 "probe p99 126 us")
    assert goals["gateway latency p99, bench → device (goal ≤ 1 ms)"].startswith("no routed frames: NOT met")
    met = dict(bench_gateway.rows(_gateway_kpis(321.0, {"error": "no CPU"}), ""))
    assert met["gateway latency p99, device → bench (goal ≤ 1 ms)"] == "321 us: met (machine probe failed)"
    assert rows["  its own (reception to send), device → bench, 3042 frames"].endswith(
        "(102 frames more than the traces count in the run)")
    assert "  the device's or the gateway's frames that did not PASS" not in rows
    failed = _gateway_kpis(321.0, probe)
    failed["devices"]["BECU3"]["device"]["messages"] = {"EBC7_VALVE_CMD": {"verdict": "FAIL",
                                                                         "reason": "2 frames missed"},
                                                      "EBC7_STATUS": {"verdict": "PASS"}}
    why = dict(bench_gateway.rows(failed, ""))["  the device's or the gateway's frames that did not PASS"]
    assert why == "device EBC7_VALVE_CMD: 2 frames missed"
    held = rows["  real time: bench misses / machine misses (all nodes)"]
    assert held == "NOT HELD: 14 / 48 (worst node: BECU3)"
    assert all(len(label) <= 62 for label in rows)


def test_gateway_bench_says_in_one_line_why_the_firmware_did_not_start(tmp_path):
    import bench_gateway

    fake = tmp_path / "ebc7.py"
    fake.write_text("import sys\n"
                    "print('error: cannot open the bus: OSError: no such group', file=sys.stderr)\n"
                    "sys.exit(2)\n")
    expected = r"did not start: it exited \(exit 2\): cannot open the bus"
    with pytest.raises(RuntimeError, match=expected) as err:
        bench_gateway.start_firmware(bench_gateway.own_group(), fake)
    assert "\n" not in str(err.value)
