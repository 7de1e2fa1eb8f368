"""The scenario section [preview]: seed 000 (Picasso et al.): slip-reference generators with preview.

Its presence in a scenario makes hil.assembly hand the run's nodes to hil/preview_nodes.py.
"""

from __future__ import annotations

from hil.specbase import Strict


class PreviewSpec(Strict):
    """[preview] of a scenario file."""
