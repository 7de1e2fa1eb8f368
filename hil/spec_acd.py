"""The scenario section [acd]: seed 002, the anti-collision device, a
leader train, signals and the radio link.

Its presence in a scenario makes hil.assembly hand the run's nodes to hil/acd_nodes.py.
"""

from __future__ import annotations

from hil.specbase import Strict


class AcdSpec(Strict):
    """[acd] of a scenario file."""
