"""The scenario section [consensus]: seed 003: observer-driven consensus braking.

Its presence in a scenario makes hil.assembly hand the run's nodes to hil/consensus_nodes.py.
"""

from __future__ import annotations

from hil.specbase import Strict


class ConsensusSpec(Strict):
    """[consensus] of a scenario file."""
