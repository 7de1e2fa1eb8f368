"""The nodes of seed 003's consensus-braking study:
hil.assembly hands a scenario with a [consensus] section to this module.

`node_names` gets the foundation's node list (PLANT first) and returns this study's; `build_node`
returns the study's own node for `name`, or None to let hil.assembly build the foundation's.
"""

from __future__ import annotations

from cantools.database.can import Database

from hil.codec import Codec
from hil.node import Node
from hil.scenario import Scenario


def node_names(scenario: Scenario, names: list[str]) -> list[str]:
    return names


def build_node(name: str, scenario: Scenario, db: Database, codec: Codec,
               dbc_name: str = "DBC") -> Node | None:
    return None
