"""`make bench` must run on a clean clone: each benchmark's fixed inputs still fit the DBC (the timed
loops themselves run only in `make bench`)."""

import sys

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
        f"{run};LockstepBus.send (hil/runtime/lockstep.py:83);Node.receive_frame (hil/runtime/node.py:406);"
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
