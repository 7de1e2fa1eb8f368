"""Small pure helpers for limits, as opendbc keeps them (apply_hysteresis, rate_limit)."""

from __future__ import annotations

import math

from numba.extending import register_jitable


@register_jitable
def clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def rate_limit(new: float, last: float, dw_step: float, up_step: float) -> float:
    """Limit the change of `new` relative to `last` to [-dw_step, +up_step]."""
    return clip(new, last - dw_step, last + up_step)


def finite_or(x: float, safe: float) -> tuple[float, bool]:
    """(x, True) when x is a finite number, else (safe, False): the cyclic loop never raises on data."""
    try:
        xf = float(x)
    except (TypeError, ValueError):
        return safe, False
    return (xf, True) if math.isfinite(xf) else (safe, False)
