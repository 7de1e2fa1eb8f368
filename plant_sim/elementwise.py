"""The array face of the scalar physics: apply a scalar function element by element over numpy arrays.

The plant steps its cars with scalar functions on Python floats (see `plant_sim.plant`); tests, the
truth the plant reports every 10 ms and other callers that hold arrays use these wrappers, so each
equation has exactly one implementation. numpy only broadcasts the arguments and collects the results.
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import repeat

import numpy as np


def elementwise(fn: Callable[..., float], *arrays, params: tuple = ()) -> np.ndarray:
    """fn(a_1, ..., a_k, *params) for every element of the broadcast arrays a_1 ... a_k.

    Returns a float64 array of the arrays' broadcast shape. Elements are passed as Python numbers
    (floats stay floats, ints stay ints); params are passed unchanged to every call.
    """
    arrs = np.broadcast_arrays(*(np.asarray(a) for a in arrays))
    shape = arrs[0].shape if arrs else ()
    cols = [a.ravel().tolist() for a in arrs]
    cols += [repeat(p) for p in params]
    return np.fromiter(map(fn, *cols), dtype=float, count=int(np.prod(shape))).reshape(shape)
