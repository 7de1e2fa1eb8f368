"""The plant's ground truth as a run keeps it: when the train stands, and truth.csv in the run folder.

The plant node records the truth (hil.runtime.plant_node.TruthLog, or a study's own: `Truth`); the run
writes it to truth.csv (`write_truth_csv`); the report and a run folder read in Python read it back
(`read_truth_csv`).  A train stands when every car is slower than STANDSTILL_MPS: the lockstep and
real-time runs end on it (`PlantView.standstill`), the KPIs find the stop by it.
"""

from __future__ import annotations

import csv
import warnings
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from hil.errors import RailhilError

STANDSTILL_MPS = 0.01            # every car slower than this counts as standing still (chosen)


class Truth(Protocol):
    """A run's ground truth (hil.runtime.plant_node.TruthLog, a study's own): flat columns, t_s first."""

    def columns(self) -> dict[str, np.ndarray]: ...


# runtime-checkable: a run checks its plant node's controller with isinstance, which a protocol that mypyc
# compiles does not allow; this module is not compiled
@runtime_checkable
class PlantView(Protocol):
    """What a run reads of its plant node's controller (hil.runtime.plant_node.PlantController, a study's):
    whether the train stands, its truth, a glance at speeds and positions for progress reports."""

    standstill: bool

    @property
    def truth(self) -> Truth: ...

    def glance(self) -> dict[str, np.ndarray]: ...


def write_truth_csv(columns: dict[str, np.ndarray], path: Path) -> None:
    """truth.csv: a header of the column names, then one line per sample, every value to 6 significant
    digits (`%.6g`), as csv.writer writes them (CRLF line ends); one format operation per line."""
    names = list(columns)
    rows = np.column_stack([columns[n] for n in names])
    line = ",".join(["%.6g"] * len(names)) + "\r\n"
    with path.open("w", newline="") as f:
        csv.writer(f).writerow(names)
        f.write("".join([line % tuple(row) for row in rows.tolist()]))


def read_truth_csv(path: Path) -> dict[str, np.ndarray]:
    """truth.csv (written by `write_truth_csv`) back as columns, each a 1-d array (numpy's C reader
    `loadtxt`: a fifth of `genfromtxt`'s time on a default run's truth); unreadable: RailhilError."""
    try:
        with path.open(newline="") as f:
            names = next(csv.reader(f), [])
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)      # "input contained no data": no samples
                data = np.loadtxt(f, delimiter=",", ndmin=2, dtype=float)
    except OSError as exc:
        raise RailhilError(f"{path}: cannot read the truth of a run: {exc}") from None
    except ValueError as exc:
        raise RailhilError(f"{path}: not a truth.csv of railhil (numbers under a header): "
                           f"{' '.join(str(exc).split())}") from None
    if data.size and data.shape[1] != len(names):
        raise RailhilError(f"{path}: {data.shape[1]} values per line under {len(names)} column names")
    return {name: (data[:, k].copy() if data.size else np.zeros(0)) for k, name in enumerate(names)}
