"""The one exception tree at railhil's boundaries (cf. python-can's can/exceptions.py).

Every error a user can cause — a bad scenario, DBC, trace, binding or bus — is a RailhilError whose
message names the file, key, frame or value and what was expected.  The CLI prints it on one line
(`error: ...`) and exits with `exit_code`; `--debug` shows the traceback.
"""

from __future__ import annotations


class RailhilError(Exception):
    exit_code = 2


class ScenarioError(RailhilError, ValueError):
    """A scenario file that does not load or validate."""


class DbcError(RailhilError, ValueError):
    """A DBC file that does not load, or lacks what railhil needs from it."""


class BindingError(RailhilError, KeyError):
    """A node uses a signal name the DBC does not have."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class DeviceError(RailhilError, ValueError):
    """A device description (hil.devices: the device file, its DBC, its map) that cannot be used: names the
    file and the key, and what was expected."""


class FmuError(RailhilError, ValueError):
    """An FMU (hil.fmi) that cannot be used, or a map of its variables that does not fit it: names the file
    and the variable, and what was expected."""


class BusError(RailhilError, OSError):
    """A python-can bus that cannot be opened or used."""

    exit_code = 3


class NodeDied(RailhilError, RuntimeError):
    """A node process of a real-time run ended unexpectedly."""

    exit_code = 4


class SerialLinkError(RailhilError, OSError):
    """A serial line (the GPS link) whose port cannot be opened or used: names the port and what was
    expected (a device path such as /dev/ttyUSB0, or a pyserial URL such as loop://)."""
