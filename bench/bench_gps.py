"""GPS fix on the serial line, NMEA 0183 (RMC + GGA) against the framed binary protocol, side by side.

Per fix: bytes on the line, the time it occupies a 9600-baud 8N1 UART, and the cost of encoding and of
decoding it with the streaming readers (µs, best of 7). The same 200 fixes of the seeded receiver
model feed both.

    python bench/bench_gps.py
"""

from __future__ import annotations

import sys
import timeit
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from hil.links.gpsserial import DEFAULT_BAUDRATE, line_time_us  # noqa: E402
from hil.links.nmea import PROTOCOLS  # noqa: E402
from plant_sim.gps import GpsModel, GpsParams  # noqa: E402

N = 200


def _fixes():
    params = GpsParams(rate_hz=10.0, dropout_rate_per_h=0.0, instability_rate_per_h=0.0)
    model = GpsModel(params, 1)
    return [model.fix(k * params.period_us, 56.95, 24.1, 25.0, 70.0) for k in range(N)]


def per_call_us(fn, n_items: int, repeat: int = 7, number: int = 3) -> float:
    """Best of `repeat` runs of `number` calls of fn, in µs per item (fn handles n_items)."""
    return min(timeit.Timer(fn).repeat(repeat=repeat, number=number)) / number / n_items * 1e6


def run() -> list[tuple[str, str]]:
    fixes = _fixes()
    rows = []
    for name, (enc_cls, reader_cls) in PROTOCOLS.items():
        enc = enc_cls()
        stream = b"".join(enc.encode(f) for f in fixes)
        per_fix = len(stream) / N
        got = reader_cls().feed(stream)
        assert len(got) == (2 if name == "nmea" else 1) * N, name
        t_enc = per_call_us(lambda enc=enc: [enc.encode(f) for f in fixes], N)
        t_dec = per_call_us(lambda cls=reader_cls, s=stream: cls().feed(s), N)
        line_ms = line_time_us(round(per_fix), DEFAULT_BAUDRATE) / 1000.0
        load_10hz = line_ms * 10 / 1000.0      # fraction of the line a 10 Hz receiver occupies
        rows.append((f"{name}: bytes per fix / line time at {DEFAULT_BAUDRATE} baud",
                     f"{per_fix:.0f} B / {line_ms:.1f} ms (line load at 10 Hz: {load_10hz:.0%})"))
        rows.append((f"{name}: encode / decode per fix", f"{t_enc:.1f} µs / {t_dec:.1f} µs"))
    return rows


if __name__ == "__main__":
    for label, figure in run():
        print(f"  {label:<58} {figure}")
