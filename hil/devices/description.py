"""The device file: a TOML description of a device that takes a bench node's place, checked as it is read.

    replaces = "BECU3"                  # the bench node the device takes the place of
    dbc = "acme_becu.dbc"               # the device's own CAN matrix (path beside this file)
    node = "EBC7"                       # the device's node (BU_) in it
    model = "acme_becu:BrakeControl"    # lockstep: the device's control law (a module beside this file)

    [bus]                               # the device's own python-can bus in real time (bus = "bench": the
    interface = "udp_multicast"         # bench's); any keyword python-can's can.Bus takes
    channel = "239.74.163.9"

    [protection.VEH_BRAKE_DEMAND]       # the protection of a device message, where its DBC does not say
    profile = "P05"
    data_id = 0x1234

    [receive.VEH_WHEEL]                 # every signal the device receives, and where the bench takes it
    WheelSpeed = { from = "PLANT_CAR3_SENSORS.AxleSpeed", scale = "0.46 m" }

    [send.BECU3_PRESS_CMD]              # every signal the replaced node sent, and the device signal for it
    CylPressureSet = { from = "EBC7_VALVE_CMD.PressureSetpoint" }

    [trigger]                           # when a target message is sent (default: with its first source's
    BECU3_STATUS = "cycle"              # frame where both have one cycle time, else at its own cycle)

    ignore = ["VEH_DIAG_REQ"]           # (top level) device messages the bench does not send it

This module reads the file into a `DeviceSpec` (pydantic: an unknown key or a wrong type is one line
naming the file and the key); hil.devices.device checks it against the DBCs.  docs/devices.md is the
user's page for the format.
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Annotated, Literal

from pydantic import (
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    ValidationError,
    field_validator,
    model_validator,
)

from hil.errors import DeviceError
from hil.resources import read_toml
from hil.scenario.base import Strict

BusValue = StrictStr | StrictInt | StrictFloat | StrictBool
Number = StrictInt | StrictFloat


class MapEntry(Strict):
    """Where one target signal takes its value: a source signal (`from`), or a constant (`value`).

    The value goes from the source's unit (its DBC's unit string, or `unit`) to the target's by pint, then
    is multiplied by `scale` (a number, or a quantity such as "0.46 m" whose unit joins the conversion) and
    `offset` is added (in the target's unit, or a quantity).  `choices` maps the source's value-table names
    to the target's instead.  While the source is older than `stale_ms` (default: three of its message's
    cycles) or not yet received, the target carries `default`, or, without one, the last value it had."""

    source: Annotated[str | None, Field(alias="from")] = None   # "MESSAGE.Signal", "truth.QUANTITY"
    value: Number | StrictStr | None = None     # a constant: a number, a quantity ("40 t"), a choice name
    unit: StrictStr | None = None               # the source's unit where its DBC gives none, or another
    scale: Number | StrictStr = 1.0             # a number, or a quantity text ("0.46 m")
    offset: Number | StrictStr = 0.0            # in the target's unit, or a quantity text
    choices: dict[str, str] | None = None       # source value-table name -> target value-table name
    default: Number | StrictStr | None = None   # while the source is stale: a number, quantity or choice
    stale_ms: Annotated[float, Field(gt=0, le=3_600_000)] | None = None

    model_config = {**Strict.model_config, "populate_by_name": True}

    @model_validator(mode="after")
    def _one_source(self) -> MapEntry:
        if (self.source is None) == (self.value is None):
            raise ValueError("give exactly one of 'from' (a signal, or truth.QUANTITY) and 'value' "
                             "(a constant)")
        if self.value is not None and (self.choices is not None or self.default is not None
                                       or self.stale_ms is not None):
            raise ValueError("a constant ('value') takes no 'choices', 'default' or 'stale_ms'")
        if self.choices is not None and (self.unit is not None or self.scale != 1.0 or self.offset != 0.0):
            raise ValueError("'choices' maps names: it takes no 'unit', 'scale' or 'offset'")
        return self


class ProtectionSpec(Strict):
    """The protection of one device message (the DBC says nothing of it; railhil's own DBCs use the message
    attributes E2EProfile, E2EDataID, E2EDataIDList).

    AUTOSAR E2E: `profile` P01, P02, P05 or P11 with its `data_id` (P02: `data_id_list`, 16 bytes), the
    CRC at the start of the signal named `crc` (default: byte 0) and the profile's own counter after it.
    Otherwise a plain rolling counter (`counter`: the counter signal) and/or a one-byte checksum over the
    other bytes of the frame (`checksum` "xor" or "sum", in the signal `checksum_signal`)."""

    profile: Literal["P01", "P02", "P05", "P11"] | None = None
    data_id: Annotated[int, Field(ge=0, le=0xFFFF)] | None = None
    data_id_list: list[Annotated[int, Field(ge=0, le=255)]] | None = None
    data_id_mode: Literal["both", "nibble"] = "both"     # P01 / P11
    crc: StrictStr | None = None                          # the CRC signal: where the profile's layout starts
    counter: StrictStr | None = None                      # the rolling counter signal (no profile)
    checksum: Literal["xor", "sum"] | None = None         # the checksum over the other bytes (no profile)
    checksum_signal: StrictStr | None = None
    max_delta_counter: Annotated[int, Field(ge=1, le=254)] = 1   # counter steps allowed between two frames

    @model_validator(mode="after")
    def _consistent(self) -> ProtectionSpec:
        if self.profile is not None:
            if self.counter is not None or self.checksum is not None or self.checksum_signal is not None:
                raise ValueError(f"profile {self.profile} has its own counter and CRC: give no 'counter', "
                                 "'checksum' or 'checksum_signal'")
            if self.profile == "P02":
                if self.data_id_list is None or len(self.data_id_list) != 16:
                    raise ValueError("profile P02 needs data_id_list: 16 data id bytes, one per counter "
                                     "value")
            elif self.data_id is None:
                raise ValueError(f"profile {self.profile} needs data_id")
            return self
        if self.counter is None and self.checksum is None:
            raise ValueError("give a profile (P01, P02, P05, P11), or a 'counter' signal and/or a 'checksum' "
                             "(\"xor\" or \"sum\") with its 'checksum_signal'")
        if (self.checksum is None) != (self.checksum_signal is None):
            raise ValueError("'checksum' (\"xor\" or \"sum\") and 'checksum_signal' go together")
        return self


#: OPC UA built-in data types a variable may have: name -> (lowest, highest value it carries)
OPCUA_TYPES = {
    "Boolean": (0, 1), "SByte": (-2**7, 2**7 - 1), "Byte": (0, 2**8 - 1),
    "Int16": (-2**15, 2**15 - 1), "UInt16": (0, 2**16 - 1), "Int32": (-2**31, 2**31 - 1),
    "UInt32": (0, 2**32 - 1), "Int64": (-2**63, 2**63 - 1), "UInt64": (0, 2**64 - 1),
    "Float": (-3.4028234663852886e38, 3.4028234663852886e38),
    "Double": (-1.7976931348623157e308, 1.7976931348623157e308),
}


class VariableSpec(Strict):
    """One OPC UA variable of a device (transport = "opcua"): its data type, engineering unit and, for an
    integer that carries named states, its value table; `node_id` where the PLC's server does not name it
    by its object and variable (browse path Objects/OBJECT/VARIABLE in the device's namespace)."""

    type: Literal[tuple(OPCUA_TYPES)]                      # the variable's built-in data type
    unit: StrictStr | None = None                          # its engineering unit (pint: "m", "km/h", "bar")
    choices: dict[str, StrictStr] | None = None            # an integer's values: "1" = "RELEASE"
    node_id: StrictStr | None = None                       # e.g. "ns=3;s=\"DB_Stop\".\"S\""
    minimum: Number | None = None                          # the range the device accepts (default: the
    maximum: Number | None = None                          # data type's)

    @model_validator(mode="after")
    def _consistent(self) -> VariableSpec:
        if self.choices is not None:
            if self.type in ("Float", "Double"):
                raise ValueError(f"'choices' names the values of an integer; this variable is a {self.type}")
            bad = [k for k in self.choices if not k.lstrip("-").isdigit()]
            if bad:
                raise ValueError(f"choices: {bad[0]!r} is not an integer (write \"1\" = \"RELEASE\")")
        return self


class OpcUaSpec(Strict):
    """[opcua] of a device file: how the bench and the device (a PLC) talk OPC UA.

    role "server": the bench serves the device's variables at `endpoint` and the PLC's client reads and
    writes them; role "client": the bench connects to the PLC's own server at `endpoint`.  `security`
    "SignAndEncrypt" (default) or "Sign" with Basic256Sha256, or "None" (said in the run's summary);
    `trust`: the certificate files (DER or PEM) of the PLC the bench trusts; `certificate` and
    `private_key`: the bench's own (default: created on first use under the pki folder and kept);
    `user` and `password_env` (the environment variable that holds the password)."""

    role: Literal["server", "client"]
    endpoint: StrictStr                                    # opc.tcp://host:port/path
    namespace: StrictStr = "urn:railhil:device"            # the namespace URI of the device's variables
    security: Literal["SignAndEncrypt", "Sign", "None"] = "SignAndEncrypt"
    trust: list[StrictStr] = Field(default_factory=list)   # the PLC's certificate files, beside this file
    certificate: StrictStr | None = None                   # the bench's certificate (DER or PEM) ...
    private_key: StrictStr | None = None                   # ... and its private key (PEM)
    pki: StrictStr | None = None                           # where the bench's own are created (default:
    #                                                        ~/.local/share/railhil/pki)
    user: StrictStr | None = None                          # user name the PLC logs in with (server) or the
    password_env: StrictStr | None = None                  # bench does (client); its password's variable
    cycle_ms: Annotated[float, Field(gt=0, le=60_000)] = 100.0   # the PLC's scan cycle
    input_cycle_ms: Annotated[float, Field(ge=1, le=60_000)] = 10.0   # how often the bench updates an
    #                                                        object it writes from truth or constants only
    #                                                        (one with a frame source: on each frame)
    stamp: StrictStr | None = None                         # "OBJECT.Variable" the bench counts up with each
    echo: StrictStr | None = None                          # update, and the PLC's echo of the count it read
    silent_after_ms: Annotated[float, Field(gt=0, le=600_000)] | None = None   # default: 3 cycles

    @model_validator(mode="after")
    def _consistent(self) -> OpcUaSpec:
        if not self.endpoint.startswith("opc.tcp://"):
            raise ValueError(f"endpoint {self.endpoint!r}: expected opc.tcp://HOST:PORT[/PATH]")
        if (self.stamp is None) != (self.echo is None):
            raise ValueError("'stamp' and 'echo' go together: the bench's count and the PLC's echo of it")
        if (self.certificate is None) != (self.private_key is None):
            raise ValueError("'certificate' and 'private_key' go together (the bench's own)")
        if (self.user is None) != (self.password_env is None):
            raise ValueError("'user' and 'password_env' go together")
        if self.security != "None" and not self.trust:
            raise ValueError(f"security {self.security!r} needs 'trust': the PLC's certificate file(s)")
        return self


class DeviceSpec(Strict):
    """A device file, as read (paths still relative to it)."""

    description: str = ""
    replaces: StrictStr                                    # the bench node, e.g. BECU3
    transport: Literal["can", "opcua"] = "can"             # its frames on a CAN bus, or OPC UA variables
    dbc: StrictStr | None = None                           # the device's DBC, beside the file (CAN)
    opcua: OpcUaSpec | None = None                         # OPC UA: the link ...
    reads: dict[str, dict[str, VariableSpec]] = Field(default_factory=dict)    # ... the variables the device
    writes: dict[str, dict[str, VariableSpec]] = Field(default_factory=dict)   # reads and writes, by object
    node: StrictStr | None = None                          # its node in that DBC; default: its only sender
    model: StrictStr | None = None                         # "module:Class", the module beside the file
    model_cycle_ms: Annotated[float, Field(gt=0, le=10_000)] | None = None   # default: its frames' cycle
    bus: Literal["bench"] | dict[str, BusValue] = Field(default_factory=dict)
    protection: dict[str, ProtectionSpec] = Field(default_factory=dict)     # by device message
    receive: dict[str, dict[str, MapEntry]] = Field(default_factory=dict)   # device message -> signal
    send: dict[str, dict[str, MapEntry]] = Field(default_factory=dict)      # bench message -> signal
    trigger: dict[str, str] = Field(default_factory=dict)  # target message -> "cycle" or a source message
    ignore: list[StrictStr] = Field(default_factory=list)  # device messages the gateway does not send it

    @model_validator(mode="after")
    def _transport(self) -> DeviceSpec:
        if self.transport == "can":
            if self.dbc is None:
                raise ValueError("key 'dbc' is missing: the device's own CAN matrix (or transport = "
                                 "\"opcua\")")
            if self.opcua is not None or self.reads or self.writes:
                raise ValueError("[opcua], [reads] and [writes] describe an OPC UA device: give transport = "
                                 "\"opcua\" (and no dbc)")
            return self
        if self.dbc is not None or self.bus:
            raise ValueError("an OPC UA device has no 'dbc' or [bus]: its variables are [reads] and [writes]")
        if self.opcua is None:
            raise ValueError("transport \"opcua\" needs [opcua]: role, endpoint, security")
        if not self.writes:
            raise ValueError("transport \"opcua\" needs [writes.OBJECT]: the variables the device writes")
        both = set(self.reads) & set(self.writes)
        if both:
            raise ValueError(f"object {sorted(both)[0]!r} is in [reads] and [writes]: an object's variables "
                             "go one way")
        return self

    @field_validator("model")
    @classmethod
    def _module_class(cls, v):
        if v is not None:
            module, _, name = v.partition(":")
            if not module or not name or not module.replace(".", "").replace("_", "").isalnum():
                raise ValueError(f"{v!r} is not \"module:Class\" (a Python module beside the device file and "
                                 "a class in it)")
        return v


def _describe(err: dict) -> str:
    loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
    if err["type"] == "extra_forbidden":
        return f"key '{loc}' is not a device-file key{_closest(err['loc'])}"
    if err["type"] == "missing":
        return f"key '{loc}' is missing"
    shown = repr(err.get("input"))
    if len(shown) > 60:
        shown = shown[:57] + "..."
    message = err["msg"].removeprefix("Value error, ")
    if err["type"] == "value_error":                  # a model's own check: the table, not its input
        return f"key '{loc}': {message}"
    return f"key '{loc}' = {shown}: {message}"


def _closest(loc: tuple) -> str:
    """'; did you mean ...' for an unknown key, from the fields of the table it sits in."""
    model = DeviceSpec
    if len(loc) >= 3 and loc[0] in ("receive", "send"):
        model = MapEntry
    elif len(loc) >= 3 and loc[0] in ("reads", "writes"):
        model = VariableSpec
    elif len(loc) == 2 and loc[0] == "opcua":
        model = OpcUaSpec
    elif len(loc) >= 2 and loc[0] == "protection":
        model = ProtectionSpec
    elif len(loc) != 1:
        return ""
    fields = [f.alias or name for name, f in model.model_fields.items()]
    close = difflib.get_close_matches(str(loc[-1]), fields, n=1, cutoff=0.5)
    return f"; did you mean '{close[0]}'?" if close else f"; valid keys here: {', '.join(fields)}"


def read_device_file(path: str | Path) -> DeviceSpec:
    """The device file at `path`, validated; a DeviceError (one line naming the file and the key) if not."""
    path = Path(path)
    where = str(path)
    data = read_toml(path, DeviceError, where, "no such device file")
    try:
        return DeviceSpec.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise DeviceError(f"{where}: {_describe(errors[0])}{more}") from None
