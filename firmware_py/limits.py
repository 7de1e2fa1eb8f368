"""Small pure helpers for limits, as opendbc keeps them (apply_hysteresis, rate_limit).

`clip` is defined in firmware_py.governor_kernel, where numba can compile it into the governor's
prediction (with the PI step that calls it); the controllers import it from here.
"""

from __future__ import annotations

import math

from firmware_py.governor_kernel import clip

__all__ = ["clip", "finite_or", "rate_limit"]


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
