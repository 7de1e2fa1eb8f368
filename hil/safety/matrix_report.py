"""The threat matrix as a table: Markdown (matrix.md) and JSON (matrix.json).

The Markdown has, in this order: the bounds, one row per scenario with its unsafe criterion, its
fault-free figure and its totals (cells, detected within DETECT_CYCLES cycles, unsafe, brake releases,
target moves, errors) and an overall row; the verdict line; the cells that failed; then every cell.
`summary` is all of it but the last table (what `railhil faults matrix` prints).  Definitions:
hil.safety.threat_matrix.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from hil.safety.threat_matrix import (
    DETECT_CYCLES,
    FAMILIES,
    WINDOW_S,
    WINDOW_START_S,
    Cell,
    ScenarioMatrix,
    as_rows,
)

__all__ = ["BOUNDS", "Totals", "markdown", "summary", "totals", "verdict", "write"]

#: what the matrix must show (issue #19's acceptance): share of cells detected, and counts
BOUNDS = {"detected_share": 1.0, "unsafe": 0, "released": 0, "target_moved": 0, "errors": 0}
HEAD_COLUMNS = ["scenario", "unsafe criterion", "fault-free", "cells", f"detected ≤ {DETECT_CYCLES} cycles",
                "unsafe", "brake releases", "target moves", "errors"]
CELL_COLUMNS = ("scenario", "frame / node", "threat", "injected", "detected", "worst ms", "first status",
                "measure", "change", "bound", "released", "target moved", "unsafe")


@dataclass(frozen=True)
class Totals:
    cells: int
    detected: int
    unsafe: int
    released: int
    target_moved: int
    errors: int

    @property
    def passed(self) -> bool:
        return (self.detected >= BOUNDS["detected_share"] * self.cells and self.unsafe <= BOUNDS["unsafe"]
                and self.released <= BOUNDS["released"] and self.target_moved <= BOUNDS["target_moved"]
                and self.errors <= BOUNDS["errors"])


def totals(cells: list[Cell]) -> Totals:
    return Totals(len(cells), sum(c.detected for c in cells), sum(c.unsafe for c in cells),
                  sum(c.released for c in cells), sum(c.target_moved for c in cells),
                  sum(bool(c.error) for c in cells))


def _cells(matrices: list[ScenarioMatrix]) -> list[Cell]:
    return [c for mx in matrices for c in mx.cells]


def verdict(matrices: list[ScenarioMatrix]) -> str:
    """One line: PASS or FAIL against BOUNDS, with the figures."""
    t = totals(_cells(matrices))
    share = 100.0 * t.detected / t.cells if t.cells else 100.0
    return (f"verdict: {'PASS' if t.passed else 'FAIL'} — {t.detected} of {t.cells} cells detected within "
            f"{DETECT_CYCLES} cycles ({share:.1f} %, bound 100 %), {t.unsafe} unsafe (bound 0), {t.released} "
            f"brake releases (bound 0), {t.target_moved} target moves (bound 0), {t.errors} errors (bound 0)")


def _esc(text: str) -> str:
    return text.replace("|", "\\|")


def _m(x: float | None, fmt: str = "{:.2f}") -> str:
    return "—" if x is None else fmt.format(x)


def _fault_free(mx: ScenarioMatrix) -> str:
    if mx.baseline is None:
        return "—"
    fam, m = FAMILIES[mx.family], mx.baseline.measures
    value = m.get(fam.measure)
    if mx.family == "coupler":
        return "—" if value is None else f"{value * 1000:.2f} mm"
    text = _m(value) + " m"
    if not m["stopped"]:
        text += " (no stop)"
    if mx.baseline.extended:
        text += f" (horizon extended to {mx.baseline.horizon_s:g} s)"
    return text


def _row(mx: ScenarioMatrix) -> list[str]:
    fam = FAMILIES[mx.family]
    t = totals(mx.cells)
    cells = str(t.cells) + (f" ({mx.reason})" if mx.reason else "")
    figures = [str(t.detected), str(t.unsafe), str(t.released), str(t.target_moved), str(t.errors)] \
        if t.cells else ["—"] * 5
    return [mx.name, f"{fam.name}: {fam.rule}", _fault_free(mx), cells, *figures]


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(_esc(h) for h in header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(_esc(str(x)) for x in row) + " |" for row in rows)]


def _cell_row(c: Cell, family: str) -> list[str]:
    scale, unit = (1000.0, " mm") if family == "coupler" else (1.0, " m")

    def q(x, signed=False):
        return "—" if x is None else (f"{x * scale:+.2f}" if signed else f"{x * scale:.2f}") + unit

    return [c.scenario, c.target, c.threat, str(c.injected), "yes" if c.detected else "NO",
            "" if c.worst_detection_ms is None else f"{c.worst_detection_ms:.1f}", c.first_status or c.error,
            q(c.measure) + ("" if c.stopped or family == "coupler" else " (no stop)"), q(c.change, True),
            q(c.bound), "YES" if c.released else "no", "YES" if c.target_moved else "no",
            "YES" if c.unsafe else "no"]


def _window_s(matrices: list[ScenarioMatrix]) -> float:
    """How long every fault acted (the same in every scenario of one matrix)."""
    return matrices[0].window_s if matrices else WINDOW_S


def _head(matrices: list[ScenarioMatrix]) -> list[str]:
    t = totals(_cells(matrices))
    rows = [_row(mx) for mx in matrices]
    rows.append(["**all**", "", "", str(t.cells), str(t.detected), str(t.unsafe), str(t.released),
                 str(t.target_moved), str(t.errors)])
    names = ", ".join(mx.name for mx in matrices)
    return [f"# Threat matrix: {names}", "",
            f"Every EN 50159 threat on every protected frame, a babbling node and each sender bus-off, "
            f"over {_window_s(matrices):g} s from {WINDOW_START_S:g} s after braking is established; "
            f"definitions and criteria in hil/safety/threat_matrix.py. Bounds: 100 % of cells detected by "
            f"every receiver within {DETECT_CYCLES} cycles, 0 unsafe, 0 brake releases, 0 target moves, "
            f"0 errors.", "",
            *_table(HEAD_COLUMNS, rows),
            "", verdict(matrices)]


def _failed(matrices: list[ScenarioMatrix]) -> list[str]:
    bad = [_cell_row(c, mx.family) for mx in matrices for c in mx.cells if not c.ok]
    return ["", "## Cells that failed", "", *_table(list(CELL_COLUMNS), bad)] if bad else []


def summary(matrices: list[ScenarioMatrix]) -> str:
    """The totals, the verdict and the failed cells (Markdown)."""
    return "\n".join(_head(matrices) + _failed(matrices)) + "\n"


def markdown(matrices: list[ScenarioMatrix]) -> str:
    """The whole matrix.md: `summary`, then every cell."""
    rows = [_cell_row(c, mx.family) for mx in matrices for c in mx.cells]
    return summary(matrices) + "\n".join(["", "## Every cell", "", *_table(list(CELL_COLUMNS), rows)]) + "\n"


def as_json(matrices: list[ScenarioMatrix]) -> dict:
    t = totals(_cells(matrices))
    scenarios = []
    for mx in matrices:
        b = mx.baseline
        scenarios.append({
            "name": mx.name, "source": mx.source, "family": mx.family, "criterion": FAMILIES[mx.family].rule,
            "reason": mx.reason, **vars(totals(mx.cells)),
            "fault_free": None if b is None else {
                "measures": b.measures, "horizon_s": b.horizon_s, "t_brake_s": round(b.t_brake_s, 6),
                "window_s": [round(w, 6) for w in b.window]},
        })
    return {"bounds": {**BOUNDS, "detect_cycles": DETECT_CYCLES},
            "window": {"start_after_brake_s": WINDOW_START_S, "length_s": _window_s(matrices)},
            "verdict": {"passed": t.passed, "line": verdict(matrices), **vars(t)},
            "scenarios": scenarios, "cells": as_rows(_cells(matrices))}


def write(matrices: list[ScenarioMatrix], out: Path) -> list[Path]:
    """matrix.md and matrix.json in `out`; returns them."""
    md, js = out / "matrix.md", out / "matrix.json"
    md.write_text(markdown(matrices))
    js.write_text(json.dumps(as_json(matrices), indent=2, default=float) + "\n")
    return [md, js]
