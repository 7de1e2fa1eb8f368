"""Per-frame cost of railhil's FrameCodec against cantools' Message.encode/decode, side by side.

Both are measured in this one process on the same frames and values: railhil's
``FrameCodec.encode(values)`` / ``decode(data)`` against cantools called as a user would,
``message.encode(values)`` / ``message.decode(data)`` with their defaults (strict range check,
choices decoded).  Frames: three of train_brake.dbc and one all-Motorola (big-endian) message of
opendbc's toyota_prius_2010_pt.dbc from the corpus
(RAILHIL_CORPUS, default ../shared/corpus beside the repository).

    python bench/bench_codec.py
"""

from __future__ import annotations

import os
import sys
import timeit
from pathlib import Path

import cantools

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from hil.can.codec import Codec  # noqa: E402

CORPUS = Path(os.environ.get("RAILHIL_CORPUS", Path(__file__).resolve().parents[2] / "shared" / "corpus"))
FRAMES = [
    (ROOT / "dbc" / "train_brake.dbc", "BECU1_PRESS_CMD",
     {"CHECKSUM": 0x5A, "COUNTER": 7, "WspValve": 1, "CylPressureSet": 251_000.0, "ValveCmd": -0.432,
      "SecOCFreshness": 99, "SecOCMAC": 0xABCDEF}),
    (ROOT / "dbc" / "train_brake.dbc", "PLANT_CAR1_SENSORS",
     {"AxleSpeed": 61.235, "CylPressure": 180_000.0, "AccelLong": -0.987, "SensorCounter": 200}),
    (ROOT / "dbc" / "train_brake.dbc", "BCU_DEMAND",
     {"CHECKSUM": 0xC3, "COUNTER": 12, "Mode": 1, "BrakeStep": 5, "TargetDecel": 0.85,
      "SecOCFreshness": 17, "SecOCMAC": 0x123456}),
    (CORPUS / "opendbc/opendbc/dbc/toyota_prius_2010_pt.dbc", "STEERING_IPAS",  # Motorola, 6 signals
     {"STATE": 3, "ANGLE": 1234, "SET_ME_X10": 16, "SET_ME_X00_1": 0, "DIRECTION_CMD": 2, "CHECKSUM": 0x77}),
]


def per_call_us(fn, budget_s: float = 0.05, repeat: int = 7) -> float:
    """Best of `repeat` runs of about `budget_s` each, in µs per call."""
    timer = timeit.Timer(fn)
    probe = 200
    number = max(probe, int(probe * budget_s / max(timer.timeit(number=probe), 1e-9)))
    return min(timer.repeat(repeat=repeat, number=number)) / number * 1e6


def run() -> list[tuple[str, str]]:
    rows: list[tuple[str, str]] = []
    loaded: dict[Path, tuple] = {}
    for path, name, values in FRAMES:
        if not path.is_file():
            rows.append((f"{name}", f"skipped: {path} not found"))
            continue
        if path not in loaded:
            db = cantools.database.load_file(str(path))
            loaded[path] = (db, Codec(db))
        db, codec = loaded[path]
        message, fc = db.get_message_by_name(name), codec.by_name(name)
        data = message.encode(values)
        # the same job: equal bytes and values, else the figures compare nothing
        assert fc.encode(values) == data, name
        assert fc.decode(data) == {
            k: float(v) for k, v in message.decode(data, decode_choices=False).items()
        }, name
        for op, ours, theirs in (
            ("encode", lambda fc=fc, v=values: fc.encode(v), lambda m=message, v=values: m.encode(v)),
            ("decode", lambda fc=fc, d=data: fc.decode(d), lambda m=message, d=data: m.decode(d)),
        ):
            t_ours, t_theirs = per_call_us(ours), per_call_us(theirs)
            label = f"{name} ({len(message.signals)} sig.) {op}"
            rows.append((f"{label}: railhil", f"{t_ours:.2f} µs"))
            rows.append((f"{label}: cantools", f"{t_theirs:.2f} µs"))
            rows.append((f"{label}: ratio cantools/railhil", f"{t_theirs / t_ours:.1f}x"))
    return rows


def main() -> None:
    rows = run()
    width = max(len(label) for label, _ in rows)
    print(f"codec per frame, railhil FrameCodec vs cantools Message (cantools {cantools.__version__}, "
          f"Python {sys.version.split()[0]})")
    for label, figure in rows:
        print(f"  {label:<{width}}  {figure:>10}")


if __name__ == "__main__":
    main()
