"""The receive table a controller reads its inputs from: `step(now_us, rx)`.

`RxTable` holds the latest value of each input signal, NaN until first received, with the time it was
received.  The node runtime (hil.runtime.node) fills it from the frames it receives (`update`, `take`);
a unit test builds one with `RxTable.received(values, t_us)` and refreshes it with `receive`; a device
that adds inputs of its own to those its node received merges them with `copy_from` and `receive`;
`copy` is a snapshot of the table as a controller saw it in one cycle.  A controller asks
`rx.age_us(name, now_us)` how old an input is (None: never received), so a test and a run on the bus
exercise the same freshness and time-out logic.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from enum import Enum

NAN = float("nan")


class RxTable(Mapping[str, float]):
    """Latest value of each input signal, NaN until first received, with its reception time."""

    def __init__(self, names: Iterable[str]) -> None:
        self._values: dict[str, float] = {n: NAN for n in names}
        self._times: dict[str, int] = {}
        self.version = 0            # bumps on every update: lets a node cache derived arrays
        # E2E status of each protected message, this cycle (hil.can.e2e.Status, set by the node runtime)
        self.e2e: dict[str, Enum] = {}

    @classmethod
    def received(cls, values: Mapping[str, float], t_us: int) -> RxTable:
        """A table of the names in `values`, each received at `t_us` with its value; a NaN value counts as
        not received (no reception time)."""
        table = cls(values)
        table.receive(values, t_us)
        return table

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    @property
    def latest(self) -> dict[str, float]:
        """The table itself as a dict, name -> latest value (read it, do not change it): a reader of many
        names at once looks them up without a Mapping call each."""
        return self._values

    def age_us(self, name: str, now_us: int) -> int | None:
        """Time since `name` was last received [µs]; None: never received."""
        t = self._times.get(name)
        return None if t is None else now_us - t

    def receive(self, values: Mapping[str, float], t_us: int) -> None:
        """Each of `values` (name -> value) received at `t_us`; a NaN value is not received: the name reads
        NaN and has no reception time, as before its first frame.  A name the table does not have is
        added."""
        store, times = self._values, self._times
        for name, value in values.items():
            store[name] = value
            if math.isnan(value):
                times.pop(name, None)
            else:
                times[name] = t_us
        self.version += 1

    def copy(self) -> RxTable:
        """A snapshot: a table with this one's values, reception times, version and E2E statuses, in tables
        of its own, so that what either receives later leaves the other as it is."""
        snap = RxTable(())
        snap._values, snap._times = dict(self._values), dict(self._times)
        snap.version = self.version
        snap.e2e = dict(self.e2e)
        return snap

    def copy_from(self, other: RxTable, names: Iterable[str]) -> None:
        """`names` as `other` holds them: each value with its reception time (or none: not received)."""
        store, times, their_times = self._values, self._times, other._times
        for name in names:
            store[name] = other._values[name]
            if name in their_times:
                times[name] = their_times[name]
            else:
                times.pop(name, None)
        self.version += 1

    def update(self, pairs: Sequence[tuple[str, str]], values: Mapping[str, float], t_us: int) -> None:
        """A frame's `values` (DBC signal -> value) received at `t_us`, stored by `pairs` (signal, key)."""
        store, times = self._values, self._times
        try:
            for signal, key in pairs:
                store[key] = values[signal]
                times[key] = t_us
        except KeyError:                 # a multiplexed frame carries only its page's signals
            for signal, key in pairs:
                if signal in values:
                    store[key] = values[signal]
                    times[key] = t_us
        self.version += 1

    def take(self, store: Callable[[bytes, dict[str, float], dict[str, int], int], None], data: bytes,
             t_us: int) -> None:
        """`update` from a frame's payload: `store` (FrameCodec.storer of the pairs) decodes them into the
        table."""
        store(data, self._values, self._times, t_us)
        self.version += 1
