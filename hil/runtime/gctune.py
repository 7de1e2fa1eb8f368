"""Garbage-collector settings for the cyclic loops.

A run allocates many short-lived objects (frames, decoded values) and keeps growing acyclic data
(truth snapshots, trace buffers).  With Python's default thresholds the collector re-scans that data
thousands of times per run; measured on the default lockstep scenario this costs about 10 % of the
wall time.  Inside a run the objects set up beforehand are frozen out of collection and the
first-generation threshold is raised; afterwards the defaults come back.  No full collection comes
first: with numba's compiler loaded (plant_sim.kernel) one took ~80 ms, 4 % of a default run; garbage
frozen with the rest is collectable again once the run ends.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager

LOOP_THRESHOLDS = (50_000, 50, 100)


@contextmanager
def loop_gc() -> Iterator[None]:
    old = gc.get_threshold()
    gc.freeze()
    gc.set_threshold(*LOOP_THRESHOLDS)
    try:
        yield
    finally:
        gc.set_threshold(*old)
        gc.unfreeze()
