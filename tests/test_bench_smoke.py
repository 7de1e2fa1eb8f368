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
