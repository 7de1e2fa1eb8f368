"""python-can's bus flags (`can.cli.add_bus_arguments`) as railhil's commands read them: `railhil run
--realtime`, `railhil node` and `railhil trace replay` take the same flags into one bus configuration."""

from __future__ import annotations

import argparse

#: the destinations of python-can's bus flags
BUS_KEYS = ("channel", "interface", "bitrate", "fd", "data_bitrate", "can_filters", "timing", "bus_kwargs")


def bus_config_from_args(args: argparse.Namespace) -> dict:
    """The bus configuration the flags give (only those present; --bus-kwargs merged in)."""
    config: dict = {}
    for key in BUS_KEYS:
        if key in args:
            value = getattr(args, key)
            if key == "bus_kwargs":
                config.update(value)
            else:
                config[key] = value
    return config
