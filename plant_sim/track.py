"""The track: rail condition θ(x) (seed 000 §2.1), gradient and curvature (eq. (5) seed 003) along x.

x [m] is the track position in the running direction. The three profiles are merged once, when the
track is built, into one table of intervals [x_k, x_k+1) on which θ is affine in x and gradient and
curvature are constant, so a look-up is one `np.searchsorted` and a few gathers for any number of cars.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import numpy as np

from plant_sim.errors import PlantConfigError
from plant_sim.params import RAIL_CONDITIONS

CHORD_M = 30.48  # 100 ft chord of the degree-of-curvature definition D = (180/π) · 30.48 / R


class TrackSample(NamedTuple):
    """Everything the plant needs at positions x (n,), from one look-up."""

    theta: np.ndarray          # (n, 3) rail condition θ(x)
    sin_grade: np.ndarray      # (n,) sin of the slope angle, + = uphill in the running direction
    curvature_deg: np.ndarray  # (n,) degree of curvature D_c [°]
    next_change_m: np.ndarray  # (n,) where the interval holding x ends (inf for the last one)
    anchor_m: np.ndarray       # (n,) on that interval θ(x') = theta_anchor + dtheta_per_m · (x' − anchor_m)
    theta_anchor: np.ndarray   # (n, 3)
    dtheta_per_m: np.ndarray   # (n, 3), non-zero only inside a smooth blend or a table


def _theta_of(cond, where: str) -> np.ndarray:
    if isinstance(cond, str):
        if cond not in RAIL_CONDITIONS:
            raise PlantConfigError(f"unknown rail condition {cond!r} {where}; known conditions: "
                                   + ", ".join(sorted(RAIL_CONDITIONS)))
        return np.array(RAIL_CONDITIONS[cond], dtype=float)
    try:
        theta = np.array(cond, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise PlantConfigError(f"rail condition {cond!r} {where}: expected a name ("
                               + ", ".join(sorted(RAIL_CONDITIONS)) + ") or a tuple (θ1, θ2, θ3)") from None
    t1, t2, t3 = theta
    # μ̄ = √σ/(θ1 + θ2 σ + θ3 σ²) needs a positive denominator for σ ≥ 0 and θ3 > 0 for its peak σ̄°
    if not (np.all(np.isfinite(theta)) and t1 > 0.0 and t3 > 0.0 and (t2 >= 0.0 or t2 * t2 < 4.0 * t1 * t3)):
        raise PlantConfigError(f"rail condition θ = {tuple(theta.tolist())} {where}: need θ1 > 0, θ3 > 0 "
                               "and θ1 + θ2 σ + θ3 σ² > 0 for all σ ≥ 0")
    return theta


def _knots(points: Iterable[Sequence[float]], what: str) -> tuple[np.ndarray, np.ndarray]:
    rows = []
    for k, p in enumerate(points):
        try:
            x, val = (float(c) for c in p)
        except (TypeError, ValueError):
            raise PlantConfigError(f"{what} point {k}: expected (x_m, value), got {p!r}") from None
        if not math.isfinite(x) or math.isnan(val):
            raise PlantConfigError(f"{what} point {k}: x_m must be finite and the value a number, got {p!r}")
        rows.append((x, val))
    x = np.array([r[0] for r in rows], dtype=float)
    val = np.array([r[1] for r in rows], dtype=float)
    if x.size > 1 and not np.all(np.diff(x) > 0.0):
        raise PlantConfigError(f"{what}: positions must be strictly increasing, got {x.tolist()}")
    return x, val


def _piecewise_constant(x: np.ndarray, knot_x: np.ndarray, knot_val: np.ndarray, before: float) -> np.ndarray:
    """Value of the last knot at or before x (`before` ahead of the first knot)."""
    idx = np.searchsorted(knot_x, x, side="right") - 1
    return np.where(idx >= 0, knot_val[np.maximum(idx, 0)] if knot_val.size else before, before)


class Track:
    """Immutable track profile. Build it with `from_segments` or `from_table`."""

    __slots__ = ("_x", "_anchor", "_theta0", "_dtheta", "_sin", "_curv", "_next")

    def __init__(self, theta_pieces: Sequence[tuple[float, np.ndarray, np.ndarray]],
                 gradient: Iterable[Sequence[float]] = (), curvature: Iterable[Sequence[float]] = ()) -> None:
        """theta_pieces: (x_start, θ at x_start, dθ/dx) in increasing x_start, the first starting at −inf with
        dθ/dx = 0. gradient: (x_m, gradient_permille); curvature: (x_m, radius_m), 0 or inf = straight;
        both piecewise constant from each point on, 0 (flat, straight) before the first point."""
        gx, gval = _knots(gradient, "gradient")
        cx, crad = _knots(curvature, "curvature")
        if not np.all(np.isfinite(gval)):
            raise PlantConfigError(f"gradient: permille values must be finite, got {gval.tolist()}")
        tan = gval / 1000.0                                               # ‰ → tan θ
        sin_knots = tan / np.sqrt(1.0 + tan * tan)                        # sin θ of the slope angle
        with np.errstate(divide="ignore"):
            deg_knots = np.where((crad == 0.0) | np.isinf(crad), 0.0,
                                 (180.0 / math.pi) * CHORD_M / np.abs(crad))  # D_c, eq. (5) seed 003
        t_start = np.array([p[0] for p in theta_pieces], dtype=float)
        t_val = np.array([p[1] for p in theta_pieces], dtype=float).reshape(-1, 3)
        t_slope = np.array([p[2] for p in theta_pieces], dtype=float).reshape(-1, 3)

        starts = np.unique(np.concatenate([t_start[1:], gx, cx]))
        grid = np.concatenate([[-np.inf], starts])
        anchor = grid.copy()
        anchor[0] = starts[0] if starts.size else 0.0                     # θ is constant on (−inf, x_1)
        j = np.searchsorted(t_start, anchor, side="right") - 1
        j[0] = 0                                                          # (−inf, x_1) is the first piece
        dx = np.where(j > 0, anchor - t_start[j], 0.0)
        theta0 = t_val[j] + t_slope[j] * dx[:, None]
        dtheta = t_slope[j]
        sin_g = _piecewise_constant(anchor, gx, sin_knots, 0.0)
        curv = _piecewise_constant(anchor, cx, deg_knots, 0.0)
        sin_g[0] = curv[0] = 0.0                                          # before every knot: flat, straight
        nxt = np.concatenate([grid[1:], [np.inf]])
        for name, arr in (("_x", grid), ("_anchor", anchor), ("_theta0", theta0), ("_dtheta", dtheta),
                          ("_sin", sin_g), ("_curv", curv), ("_next", nxt)):
            arr = np.ascontiguousarray(arr)
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    def __setattr__(self, name, value):
        raise AttributeError("Track is immutable")

    # ----------------------------------------------------------------------------------------------- builders
    @classmethod
    def from_segments(cls, segments: Iterable[Sequence], gradient: Iterable[Sequence[float]] = (),
                      curvature: Iterable[Sequence[float]] = (), transition_m: float = 0.0) -> Track:
        """Rail condition by segments `(start_m, condition)` or `(start_m, condition, transition_m)`.

        condition is a name of RAIL_CONDITIONS or a tuple (θ1, θ2, θ3). Segments are in increasing
        start_m; the first one's condition also holds before its start. Entering segment k, θ changes
        abruptly at start_m (transition 0, the default) or blends linearly from the previous segment's θ
        over [start_m, start_m + transition) (the per-segment value overrides the keyword default); the
        transition must fit in the segment.
        """
        segs = [tuple(s) for s in segments]
        if not segs:
            raise PlantConfigError("track: at least one rail segment is needed")
        starts, thetas, trans = [], [], []
        for k, seg in enumerate(segs):
            if len(seg) not in (2, 3):
                raise PlantConfigError(f"rail segment {k}: expected (start_m, condition[, transition_m]), "
                                       f"got {seg!r}")
            start = float(seg[0])
            tr = float(seg[2]) if len(seg) == 3 else float(transition_m)
            where = f"in rail segment {k} (from {start} m)"
            if not math.isfinite(start):
                raise PlantConfigError(f"rail segment {k}: start_m must be finite, got {seg[0]!r}")
            if not (math.isfinite(tr) and tr >= 0.0):
                raise PlantConfigError(f"rail segment {k}: transition_m must be >= 0, got {tr!r}")
            if starts and start <= starts[-1]:
                raise PlantConfigError(f"rail segment {k}: start {start} m is not after the previous "
                                       f"segment's start {starts[-1]} m")
            starts.append(start)
            thetas.append(_theta_of(seg[1], where))
            trans.append(tr)
        for k in range(1, len(segs) - 1):
            if trans[k] > starts[k + 1] - starts[k]:
                raise PlantConfigError(f"rail segment {k}: transition {trans[k]} m does not fit in the "
                                       f"segment ({starts[k + 1] - starts[k]} m long)")
        zero = np.zeros(3)
        pieces = [(-math.inf, thetas[0], zero)]
        for k in range(1, len(segs)):
            if trans[k] > 0.0:                                   # linear blend of θ over the transition
                pieces.append((starts[k], thetas[k - 1], (thetas[k] - thetas[k - 1]) / trans[k]))
                pieces.append((starts[k] + trans[k], thetas[k], zero))
            else:                                                # abrupt change at the segment start
                pieces.append((starts[k], thetas[k], zero))
        # a blend that ends exactly where the next segment starts leaves two pieces at one x: keep the last
        dedup: dict[float, tuple[float, np.ndarray, np.ndarray]] = {}
        for piece in pieces:
            dedup[piece[0]] = piece
        return cls(list(dedup.values()), gradient=gradient, curvature=curvature)

    @classmethod
    def from_table(cls, x_m: Sequence[float], theta_rows: Sequence[Sequence[float]],
                   gradient: Iterable[Sequence[float]] = (),
                   curvature: Iterable[Sequence[float]] = ()) -> Track:
        """θ(x) as a table: linear between the rows at strictly increasing x_m, constant beyond the ends."""
        x = np.asarray(x_m, dtype=float).reshape(-1)
        rows = np.asarray(theta_rows, dtype=float)
        if x.size == 0 or rows.shape != (x.size, 3):
            raise PlantConfigError(f"track table: need one θ row (3 values) per position, got {x.size} "
                                   f"positions and θ of shape {rows.shape}")
        if not np.all(np.isfinite(x)) or (x.size > 1 and not np.all(np.diff(x) > 0.0)):
            raise PlantConfigError(f"track table: positions must be finite and strictly increasing, "
                                   f"got {x.tolist()}")
        thetas = [_theta_of(r, f"in track table row {k} (at {x[k]} m)") for k, r in enumerate(rows)]
        zero = np.zeros(3)
        pieces = [(-math.inf, thetas[0], zero)]
        for k in range(x.size - 1):
            pieces.append((x[k], thetas[k], (thetas[k + 1] - thetas[k]) / (x[k + 1] - x[k])))
        pieces.append((x[-1], thetas[-1], zero))
        return cls(pieces, gradient=gradient, curvature=curvature)

    # ----------------------------------------------------------------------------------------------- look-ups
    def _index(self, x) -> tuple[np.ndarray, np.ndarray]:
        x = np.atleast_1d(np.asarray(x, dtype=float))
        return x, np.searchsorted(self._x, x, side="right") - 1

    def theta_at(self, x) -> np.ndarray:
        """Rail condition θ(x), shape (n, 3)."""
        x, i = self._index(x)
        return self._theta0[i] + self._dtheta[i] * (x - self._anchor[i])[:, None]

    def sin_grade_at(self, x) -> np.ndarray:
        """sin θ of the slope at x, shape (n,); + = uphill in the running direction."""
        return self._sin[self._index(x)[1]].copy()

    def curvature_degree_at(self, x) -> np.ndarray:
        """Degree of curvature D_c = (180/π) · 30.48 / R [°] at x, shape (n,); 0 on straight track."""
        return self._curv[self._index(x)[1]].copy()

    def sample(self, x) -> TrackSample:
        """All profiles at x in one look-up, plus where each x's interval ends (the plant caches on it)."""
        x, i = self._index(x)
        theta = self._theta0[i] + self._dtheta[i] * (x - self._anchor[i])[:, None]
        return TrackSample(theta, self._sin[i], self._curv[i], self._next[i], self._anchor[i],
                           self._theta0[i], self._dtheta[i])

    @property
    def knots_m(self) -> np.ndarray:
        """Starts of the intervals on which θ is affine and gradient and curvature are constant."""
        return self._x[1:]
