"""AUTOSAR E2E Profiles 1, 2, 5 and 11 protection of CAN payloads: pure functions, no I/O, no clock.

Reference: AUTOSAR "E2E Protocol Specification" (PRS_E2EProtocol, R20-11; the functional part of the
former "Specification of SW-C End-to-End Communication Protection Library", SWS_E2ELibrary),
§6.3 Profile 1 and §6.4 Profile 2.  Bit offsets below are AUTOSAR's: bit ``k`` of a payload is bit
``k % 8`` of byte ``k // 8`` (so offset 8 is the low nibble of byte 1, offset 12 its high nibble).

Profile 1 (``P01Config``)
    CRC-8 SAE J1850 (polynomial 0x1D) over the implicit 16-bit data id and every payload byte but the
    CRC byte; a 4-bit alive counter 0..14 (15 is never sent); CRC byte and counter nibble at
    configurable offsets.  The data id enters the CRC by ``DataIdMode``: BOTH (low byte, then high
    byte), ALT (low byte on even counters, high byte on odd ones), LOW (low byte only), NIBBLE (low
    byte, then a zero byte; the low nibble of the high byte is sent explicitly in the payload and
    checked, so the data id has 12 bits).  The spec chains ``Crc_CalculateCRC8(.., Start=0xFF,
    IsFirstCall=FALSE)`` and XORs the result with 0xFF: the J1850 register therefore starts at 0x00
    and the final XOR cancels, i.e. CRC-8/GSM-A parameters (init 0x00, no final XOR) -- not the J1850
    catalogue CRC.  That is what the published examples need (0xCC for data id 0x123, zero payload).
Profile 2 (``P02Config``)
    CRC-8H2F (polynomial 0x2F, init 0xFF, final XOR 0xFF: CRC-8/AUTOSAR) over payload bytes 1..n-1
    and then one data id byte taken from a 16-entry DataIDList indexed by the counter; CRC in byte 0,
    4-bit counter 0..15 in the low nibble of byte 1 (fixed by the spec).  This is the checksum of
    VW MQB frames, whose per-message "magic" bytes are the DataIDList.
    The sender increments the counter *before* it writes it (spec), so its first frame carries 1;
    Profile 1 writes, then increments, so its first frame carries 0.

CRCs are computed by ``fastcrc`` (Rust, maintained): 134 ns per 9-byte CRC against 448 ns for a
256-entry table in Python and 270 ns for crcmod's C extension (measured on the 2-core dev machine).

Profile 5 (``P05Config``) and Profile 11 (``P11Config``): a device's own frames
    Supplier ECUs ("devices") bring their own CAN matrix and protect their frames with the newer
    profiles.  Their CRC and layout come from the PyPI package autosar-e2e (C, by python-can's
    maintainer; its top-level package is also named ``e2e``, hence the ``_autosar_p05`` /
    ``_autosar_p11`` aliases below).  Profile 5: CRC-16 (Crc_CalculateCRC16: CCITT-FALSE, poly
    0x1021, init 0xFFFF) over the protected bytes but the CRC, then the data id's low and high byte;
    the CRC little-endian at ``offset``, an 8-bit counter in the byte after it.  Profile 11: CRC-8
    SAE J1850 as Profile 1 (data id BOTH or NIBBLE), a 4-bit counter 0..14; CRC byte at ``offset``,
    counter in the low nibble of the next byte, the data-id nibble (NIBBLE) in its high nibble.
    Both senders write the counter, then increment it (the first frame carries 0).
    Their receiver, E2E_P05Check / E2E_P11Check (``counter_check``), is simpler than Profile 1's: no
    SYNC, no timeout counting; the counter delta alone decides, and a first frame is judged against
    the counter E2E_P0xCheckInit leaves, one step before 0 (one that does not follow it is INITIAL
    here: ``counter_check``).

Dispatch
    ``protect`` and ``check`` run Profiles 1 and 2 inline (the lockstep run calls them ~60,000 times)
    and hand any other configuration to its own ``protect(state, payload)`` / ``check(state,
    payload)`` (``ProtectionConfig``): P05Config, P11Config and hil.can.checksums'
    CounterChecksumConfig.  A Node carries any of them where it carries a P01Config.

Sender and receiver
    ``protect(config, state, payload) -> bytes`` fills counter (and data-id nibble) and CRC and
    advances ``state`` (a mutable ``ProtectState``: a sender must never resend a counter by
    forgetting to store the next one, which every receiver would report as REPEATED).
    ``check(config, state, payload) -> (new_state, Status)`` is the spec's receiver state machine as a
    pure transition function on an immutable ``CheckState`` (table-testable, replayable, and a state can
    be logged).  Call it once per receiver cycle with the newest payload received since the last
    call, or ``None`` when nothing arrived: the spec's ``NewDataAvailable`` flag.  Timeouts are
    counted in those cycles (``max_no_new_or_repeated_data``), not in microseconds.

Statuses (``Status``): the spec's E2E_P01CheckStatusType / E2E_P02CheckStatusType.  WRONGCRC is
called ``ERROR`` here (the issue's name): a CRC mismatch, a wrong data-id nibble, a payload of the
wrong length, or a P01 counter of 15 (where the spec returns E2E_E_INPUTERR_WRONG without a status).
Profiles 5 and 11 give a subset (E2E_P05CheckStatusType / E2E_P11CheckStatusType): OK, OKSOMELOST,
REPEATED, WRONGSEQUENCE, NONEWDATA and ERROR (a wrong CRC, length, data-id nibble or a P11 counter
of 15), never SYNC; and INITIAL for a first frame whose counter follows nothing (``counter_check``).
An ERROR frame changes only MaxDeltaCounter (the one step every cycle takes); unlike a missing frame
it does not count towards MaxNoNewOrRepeatedData.
``Status.usable`` says whether the payload may be used, per E2E_P0xMapStatusToSM with the current
(R4.2.2+) ``profileBehavior``: OK, OKSOMELOST and SYNC are usable; INITIAL (first frame, sequence not
yet known) is not.

Error detection: any single-bit error is an ERROR, except a flip of the counter bit that selects the
data id (P01 ALT: the counter's LSB; P02: any counter bit) where the data id changes too and the two
changes can cancel: ``counter_flip_collisions`` lists where a P02 DataIDList lets that happen.

Receivers never raise on received data: any ``bytes`` (any length, any content) or ``None`` gives
a status.  Configurations are validated when built and raise ``E2EConfigError`` (one line) for a value out
of range, ``TypeError`` for a value of the wrong type.
"""

from __future__ import annotations

import enum
import importlib
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol

import fastcrc

from hil.errors import RailhilError

# The PyPI package autosar-e2e installs a top-level package named ``e2e`` -- not this module
# (hil.can.e2e): its profile modules are imported by their full names, under names that say whose.
_autosar_p05 = importlib.import_module("e2e.p05")
_autosar_p11 = importlib.import_module("e2e.p11")

__all__ = [
    "CheckState",
    "DataIdMode",
    "E2EConfigError",
    "P01Config",
    "P02Config",
    "P05Config",
    "P11Config",
    "PCheckStatus",
    "ProtectState",
    "ProtectionConfig",
    "Status",
    "check",
    "counter_check",
    "counter_flip_collisions",
    "crc8_h2f",
    "crc8_sae_j1850",
    "map_status_to_sm",
    "protect",
]

_J1850 = fastcrc.crc8.sae_j1850   # poly 0x1D, init 0xFF, xorout 0xFF; `initial` = a previous result
_H2F = fastcrc.crc8.autosar       # poly 0x2F, init 0xFF, xorout 0xFF; `initial` = a previous result

P01_COUNTER_MODULO = 15           # PRS §6.3: the Profile 1 counter runs 0..14, 15 is invalid
P02_COUNTER_MODULO = 16           # PRS §6.4: the Profile 2 counter runs 0..15
P01_MAX_LENGTH = 30               # bytes; Profile 1 DataLength is at most 240 bits
P02_MAX_LENGTH = 256              # bytes; Profile 2 DataLength is at most 2048 bits
NO_NEW_COUNTER_CAP = 14           # the spec's NoNewOrRepeatedDataCounter saturates at 14
P01_MAX_DELTA_CAP = 14            # MaxDeltaCounter saturates at the largest possible counter delta
P02_MAX_DELTA_CAP = 15
P05_COUNTER_MODULO = 256          # Profile 5: 8-bit counter 0..255
P05_HEADER = 3                    # bytes: CRC (2, little-endian), then the counter
P05_MAX_LENGTH = 4096             # bytes; Profile 5 DataLength is 3*8..4096*8 bits
P11_COUNTER_MODULO = 15           # Profile 11: 4-bit counter 0..14, 15 is invalid (as Profile 1)
P11_MAX_LENGTH = 30               # bytes; Profile 11 DataLength is at most 240 bits (as Profile 1)


class E2EConfigError(RailhilError, ValueError):
    """An E2E configuration that the profile does not allow (the message names the field)."""


class DataIdMode(enum.Enum):
    """How Profile 1 puts its 16-bit data id into the CRC (E2E_P01DataIDMode)."""

    BOTH = 0
    ALT = 1
    LOW = 2
    NIBBLE = 3


class Status(enum.Enum):
    """Result of one receiver cycle (E2E_P0xCheckStatusType; WRONGCRC is called ERROR)."""

    OK = "OK"                        # new data, counter +1
    NONEWDATA = "NONEWDATA"          # nothing received this cycle
    ERROR = "ERROR"                  # CRC / data-id nibble / length / counter value wrong: discard
    SYNC = "SYNC"                    # valid, but resynchronising after a timeout or a wrong sequence
    INITIAL = "INITIAL"              # first valid frame: its sequence cannot be judged yet
    REPEATED = "REPEATED"            # same counter as the last valid frame
    OKSOMELOST = "OKSOMELOST"        # valid, 1..MaxDeltaCounter-1 frames lost before it
    WRONGSEQUENCE = "WRONGSEQUENCE"  # valid CRC, but more frames lost than MaxDeltaCounter allows

    @property
    def usable(self) -> bool:
        """True if the payload may be used: E2E_P0xMapStatusToSM (profileBehavior TRUE) gives E2E_P_OK."""
        return map_status_to_sm(self) is PCheckStatus.OK


class PCheckStatus(enum.Enum):
    """Profile-independent status (E2E_PCheckStatusType), the input of the E2E state machine."""

    OK = "OK"
    REPEATED = "REPEATED"
    WRONGSEQUENCE = "WRONGSEQUENCE"
    ERROR = "ERROR"
    NONEWDATA = "NONEWDATA"


_SM_NEW = {Status.OK: PCheckStatus.OK, Status.OKSOMELOST: PCheckStatus.OK, Status.SYNC: PCheckStatus.OK,
           Status.INITIAL: PCheckStatus.WRONGSEQUENCE, Status.WRONGSEQUENCE: PCheckStatus.WRONGSEQUENCE,
           Status.REPEATED: PCheckStatus.REPEATED, Status.NONEWDATA: PCheckStatus.NONEWDATA,
           Status.ERROR: PCheckStatus.ERROR}
_SM_LEGACY = {**_SM_NEW, Status.INITIAL: PCheckStatus.OK, Status.SYNC: PCheckStatus.WRONGSEQUENCE}


def map_status_to_sm(status: Status, profile_behavior: bool = True) -> PCheckStatus:
    """E2E_P01MapStatusToSM / E2E_P02MapStatusToSM: ``profile_behavior`` True is the R4.2.2+ mapping
    (INITIAL -> WRONGSEQUENCE, SYNC -> OK), False the legacy one (INITIAL -> OK, SYNC -> WRONGSEQUENCE)."""
    return (_SM_NEW if profile_behavior else _SM_LEGACY)[status]


def crc8_sae_j1850(data: bytes, start: int = 0xFF, first_call: bool = True) -> int:
    """AUTOSAR Crc_CalculateCRC8: CRC-8 SAE J1850 (poly 0x1D, init 0xFF, final XOR 0xFF).

    With ``first_call`` False the CRC continues from ``start``, the result of an earlier call (the
    spec XORs it with 0xFF back into the register)."""
    return _J1850(data) if first_call else _J1850(data, initial=start)


def crc8_h2f(data: bytes, start: int = 0xFF, first_call: bool = True) -> int:
    """AUTOSAR Crc_CalculateCRC8H2F: CRC-8H2F (poly 0x2F, init 0xFF, final XOR 0xFF); chaining as
    ``crc8_sae_j1850``."""
    return _H2F(data) if first_call else _H2F(data, initial=start)


# A value of the wrong type is a TypeError, as the compiled build's annotations make it before these checks
# run (mypyc checks a native class's fields when they are set); a value out of range an E2EConfigError.  A
# bool is an int, as to mypy (compiled, an int field holds True as 1).

def _check_int(where: str, name: str, value: object, low: int, high: int, unit: str = "") -> int:
    expected = f"{where}: {name} = {value!r}, expected an integer {low}..{high}{unit}"
    if not isinstance(value, int):
        raise TypeError(expected)
    if not low <= value <= high:
        raise E2EConfigError(expected)
    return value


@dataclass(frozen=True, slots=True)
class P01Config:
    """Profile 1 configuration of one protected frame (E2E_P01ConfigType).

    Offsets are in bits from the start of the payload (AUTOSAR numbering, module docstring); the
    defaults are railhil's DBC layout: CHECKSUM = byte 0, COUNTER = low nibble of byte 1, and in
    NIBBLE mode the data-id nibble in the high nibble of byte 1.
    """

    data_id: int                                   # 16-bit data id (12-bit in NIBBLE mode)
    data_id_mode: DataIdMode = DataIdMode.BOTH
    length: int = 8                                # payload bytes protected (DataLength / 8)
    crc_offset: int = 0                            # bits, multiple of 8
    counter_offset: int = 8                        # bits, multiple of 4
    data_id_nibble_offset: int = 12                # bits, multiple of 4; NIBBLE mode only
    max_delta_counter_init: int = 1                # counter steps allowed between two valid frames
    max_no_new_or_repeated_data: int = 14          # cycles without new data before a resync (SYNC)
    sync_counter_init: int = 0                     # valid frames reported SYNC after a resync
    name: str = "E2E profile 1"                    # frame name, used in error messages only
    _id_even: bytes = field(init=False, repr=False, compare=False)
    _id_odd: bytes = field(init=False, repr=False, compare=False)
    _crc_even: int = field(init=False, repr=False, compare=False)   # the CRC after the data id, by
    _crc_odd: int = field(init=False, repr=False, compare=False)    # the counter's parity

    def __post_init__(self) -> None:
        w = self.name
        if not isinstance(self.data_id_mode, DataIdMode):
            raise TypeError(f"{w}: data_id_mode = {self.data_id_mode!r}, expected one of "
                            f"{', '.join(m.name for m in DataIdMode)}")
        nibble = self.data_id_mode is DataIdMode.NIBBLE
        _check_int(w, "data_id", self.data_id, 0, 0x0FFF if nibble else 0xFFFF,
                   " (12 bits in NIBBLE mode)" if nibble else "")
        _check_int(w, "length", self.length, 2, P01_MAX_LENGTH, " bytes")
        bits = self.length * 8
        _check_int(w, "crc_offset", self.crc_offset, 0, bits - 8, " bits")
        _check_int(w, "counter_offset", self.counter_offset, 0, bits - 4, " bits")
        _check_int(w, "max_delta_counter_init", self.max_delta_counter_init, 1, P01_MAX_DELTA_CAP)
        _check_int(w, "max_no_new_or_repeated_data", self.max_no_new_or_repeated_data, 0, NO_NEW_COUNTER_CAP)
        _check_int(w, "sync_counter_init", self.sync_counter_init, 0, P01_MAX_DELTA_CAP)
        if self.crc_offset % 8:
            raise E2EConfigError(f"{w}: crc_offset = {self.crc_offset}, expected a multiple of 8 bits")
        if self.counter_offset % 4:
            raise E2EConfigError(f"{w}: counter_offset = {self.counter_offset}, "
                                 "expected a multiple of 4 bits")
        if self.counter_offset // 8 == self.crc_offset // 8:
            raise E2EConfigError(f"{w}: counter_offset {self.counter_offset} lies in the CRC byte "
                                 f"(crc_offset {self.crc_offset})")
        if nibble:
            _check_int(w, "data_id_nibble_offset", self.data_id_nibble_offset, 0, bits - 4, " bits")
            if self.data_id_nibble_offset % 4:
                raise E2EConfigError(f"{w}: data_id_nibble_offset = {self.data_id_nibble_offset}, "
                                     "expected a multiple of 4 bits")
            if self.data_id_nibble_offset // 8 == self.crc_offset // 8 \
                    or self.data_id_nibble_offset == self.counter_offset:
                raise E2EConfigError(f"{w}: data_id_nibble_offset {self.data_id_nibble_offset} overlaps "
                                     "the CRC byte or the counter nibble")
        low, high = self.data_id & 0xFF, self.data_id >> 8
        even = {DataIdMode.BOTH: (low, high), DataIdMode.ALT: (low,), DataIdMode.LOW: (low,),
                DataIdMode.NIBBLE: (low, 0)}[self.data_id_mode]
        odd = (high,) if self.data_id_mode is DataIdMode.ALT else even
        object.__setattr__(self, "_id_even", bytes(even))
        object.__setattr__(self, "_id_odd", bytes(odd))
        object.__setattr__(self, "_crc_even", _J1850(bytes(even), initial=0xFF))
        object.__setattr__(self, "_crc_odd", _J1850(bytes(odd), initial=0xFF))

    def describe(self) -> str:
        """One line for reports, e.g. "AUTOSAR E2E P01, data id 0x123 (BOTH)"."""
        return f"AUTOSAR E2E P01, data id 0x{self.data_id:X} ({self.data_id_mode.name})"


@dataclass(frozen=True, slots=True)
class P02Config:
    """Profile 2 configuration of one protected frame (E2E_P02ConfigType).

    CRC in byte 0, counter in the low nibble of byte 1 (fixed by the profile).
    """

    data_id_list: tuple[int, ...]                  # 16 data id bytes, indexed by the counter
    length: int = 8                                # payload bytes protected (DataLength / 8)
    max_delta_counter_init: int = 1                # counter steps allowed between two valid frames
    max_no_new_or_repeated_data: int = 14          # cycles without new data before a resync (SYNC)
    sync_counter_init: int = 0                     # valid frames reported SYNC after a resync
    name: str = "E2E profile 2"                    # frame name, used in error messages only
    _ids: tuple[bytes, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        w = self.name
        ids = self.data_id_list
        expected = f"{w}: data_id_list = {ids!r}, expected a tuple of 16 data id bytes (one per counter)"
        if not isinstance(ids, tuple):
            raise TypeError(expected)
        if len(ids) != 16:
            raise E2EConfigError(expected)
        for i, value in enumerate(ids):
            _check_int(w, f"data_id_list[{i}]", value, 0, 255)
        _check_int(w, "length", self.length, 2, P02_MAX_LENGTH, " bytes")
        _check_int(w, "max_delta_counter_init", self.max_delta_counter_init, 1, P02_MAX_DELTA_CAP)
        _check_int(w, "max_no_new_or_repeated_data", self.max_no_new_or_repeated_data, 0, NO_NEW_COUNTER_CAP)
        _check_int(w, "sync_counter_init", self.sync_counter_init, 0, P02_MAX_DELTA_CAP)
        object.__setattr__(self, "_ids", tuple(bytes((v,)) for v in ids))

    def describe(self) -> str:
        """One line for reports: the profile and its DataIDList as hex."""
        return f"AUTOSAR E2E P02, DataIDList {bytes(self.data_id_list).hex()}"


class ProtectionConfig(Protocol):
    """A frame protection that protects and checks with its own methods: P05Config, P11Config and
    hil.can.checksums.CounterChecksumConfig.  ``protect`` and ``check`` hand it any configuration
    but a P01Config or P02Config; its methods have their contracts."""

    @property
    def length(self) -> int:
        """Bytes protected."""
        ...

    @property
    def name(self) -> str:
        """The frame's name, used in error messages only."""
        ...

    def protect(self, state: ProtectState, payload: bytes) -> bytes: ...

    def check(self, state: CheckState, payload: bytes | None) -> tuple[CheckState, Status]: ...

    def describe(self) -> str: ...


Config = P01Config | P02Config | ProtectionConfig


@dataclass(slots=True)
class ProtectState:
    """Sender state (E2E_P0xProtectStateType): the counter the next ``protect`` starts from
    (P01, P11: 0..14; P02: 0..15; P05: 0..255; a counter/checksum: 0..counter_modulo-1)."""

    counter: int = 0


class CheckState(NamedTuple):
    """Receiver state (E2E_P0xCheckStateType without Status and NewDataAvailable, which are the
    output and the input of ``check``).  The default is the spec's E2E_P0xCheckInit.

    Immutable (a NamedTuple: built in 0.3 µs against 1.1 µs for a frozen dataclass, and ``check``
    builds one per frame); ``state._replace(...)`` derives a changed copy.

    Profiles 5 and 11 and the plain counter (``counter_check``) use three fields: E2E_P05/P11
    CheckStateType's Counter is ``last_valid_counter`` (the counter of the last frame whose CRC was
    right), ``wait_for_first_data`` True stands for E2E_P0xCheckInit's Counter (the modulo - 1) until
    such a frame comes, and ``lost_data`` counts the frames lost before the last OK/OKSOMELOST one;
    the other three stay 0.
    """

    last_valid_counter: int = 0
    max_delta_counter: int = 0
    wait_for_first_data: bool = True
    lost_data: int = 0                             # frames lost before the last OK/OKSOMELOST one
    no_new_or_repeated_data_counter: int = 0
    sync_counter: int = 0


# --- CRC over a payload -----------------------------------------------------------------------------

def _p01_crc(cfg: P01Config, data: bytes | bytearray, counter: int) -> int:
    """E2E_P01Protect's CRC (PRS §6.3): over the data id (per mode), then the payload bytes before and
    after the CRC byte, each Crc_CalculateCRC8 call continuing the last (start 0xFF, not first call),
    and the result XORed with 0xFF.  The data id part depends only on the counter's parity: it is
    computed once, when the configuration is built."""
    crc = cfg._crc_odd if counter & 1 else cfg._crc_even
    i = cfg.crc_offset >> 3
    if i:
        crc = _J1850(data[:i], initial=crc)
    if i + 1 < cfg.length:
        crc = _J1850(data[i + 1:cfg.length], initial=crc)
    return crc ^ 0xFF


def _p02_crc(cfg: P02Config, data: bytes | bytearray, counter: int) -> int:
    """E2E_P02Protect's CRC (PRS §6.4): Crc_CalculateCRC8H2F over bytes 1..length-1 (first call), then over
    DataIDList[counter] continuing it."""
    return _H2F(data[1:cfg.length] + cfg._ids[counter])


def _nibble(data: bytes | bytearray, offset: int) -> int:
    return (data[offset >> 3] >> (offset & 4)) & 0x0F


def _with_nibble(data: bytearray, offset: int, value: int) -> None:
    i, shift = offset >> 3, offset & 4
    data[i] = (data[i] & ~(0x0F << shift) & 0xFF) | ((value & 0x0F) << shift)


# --- sender -----------------------------------------------------------------------------------------

def protect(config: Config, state: ProtectState, payload: bytes) -> bytes:
    """E2E_P01Protect / E2E_P02Protect: ``payload`` with its counter (and, in P01 NIBBLE mode, the
    data-id nibble) and CRC filled in; advances ``state.counter``.  Any other configuration
    (``ProtectionConfig``) protects by its own ``config.protect(state, payload)``.

    ``payload`` has ``config.length`` bytes (or more: bytes past the protected length are returned
    unchanged); the CHECKSUM/COUNTER fields' old contents are ignored.  A payload that is too short
    or a state counter out of range is a programming error of the sender: ``E2EConfigError``.
    """
    n = len(payload)
    if n < config.length:
        raise E2EConfigError(f"{config.name}: payload of {n} bytes, expected {config.length}")
    if isinstance(config, P01Config):
        data = bytearray(payload)
        counter = state.counter
        if not 0 <= counter < P01_COUNTER_MODULO:
            raise E2EConfigError(f"{config.name}: sender counter {counter!r}, expected 0..14")
        _with_nibble(data, config.counter_offset, counter)
        if config.data_id_mode is DataIdMode.NIBBLE:
            _with_nibble(data, config.data_id_nibble_offset, config.data_id >> 8)
        data[config.crc_offset >> 3] = _p01_crc(config, data, counter)
        state.counter = (counter + 1) % P01_COUNTER_MODULO
        return bytes(data)
    if not isinstance(config, P02Config):
        return config.protect(state, payload)
    data = bytearray(payload)
    if not 0 <= state.counter < P02_COUNTER_MODULO:
        raise E2EConfigError(f"{config.name}: sender counter {state.counter!r}, expected 0..15")
    counter = state.counter = (state.counter + 1) % P02_COUNTER_MODULO
    data[1] = (data[1] & 0xF0) | counter
    data[0] = _p02_crc(config, data, counter)
    return bytes(data)


# --- receiver ---------------------------------------------------------------------------------------

def check(config: Config, state: CheckState, payload: bytes | None) -> tuple[CheckState, Status]:
    """E2E_P01Check / E2E_P02Check as a pure function: (new state, status) for one receiver cycle.

    ``payload`` is the newest frame received since the last call, or ``None`` when nothing arrived
    (the spec's NewDataAvailable = FALSE).  Never raises on the payload's length or contents.
    Any other configuration (``ProtectionConfig``) checks by its own ``config.check(state, payload)``.
    """
    if isinstance(config, P01Config):
        cap = P01_MAX_DELTA_CAP
    elif isinstance(config, P02Config):
        cap = P02_MAX_DELTA_CAP
    else:
        return config.check(state, payload)
    max_delta = min(state.max_delta_counter + 1, cap)
    if payload is not None and len(payload) == config.length:     # a frame of the right length: the usual
        if isinstance(config, P01Config):
            received = _nibble(payload, config.counter_offset)
            if received != 0x0F \
                    and (config.data_id_mode is not DataIdMode.NIBBLE
                         or _nibble(payload, config.data_id_nibble_offset) == config.data_id >> 8) \
                    and payload[config.crc_offset >> 3] == _p01_crc(config, payload, received):
                return _sequence(config, state, max_delta, received, P01_COUNTER_MODULO)
        else:
            received = payload[1] & 0x0F
            if payload[0] == _p02_crc(config, payload, received):
                return _sequence(config, state, max_delta, received, P02_COUNTER_MODULO)
    last, _, wait, lost, no_new, sync = state
    if payload is None:
        return CheckState(last, max_delta, wait, lost, min(no_new + 1, NO_NEW_COUNTER_CAP), sync), \
            Status.NONEWDATA
    return CheckState(last, max_delta, wait, lost, no_new, sync), Status.ERROR


def _sequence(config: P01Config | P02Config, state: CheckState, max_delta: int, received: int,
              modulo: int) -> tuple[CheckState, Status]:
    """The counter part of the check, for a frame whose CRC (and data-id nibble) is right."""
    last, _, wait, lost_before, no_new, sync_counter = state
    init = config.max_delta_counter_init
    if wait:
        return CheckState(received, init, False, lost_before, no_new, sync_counter), Status.INITIAL
    delta = (received - last) % modulo
    if delta == 0:
        return CheckState(last, max_delta, False, lost_before, min(no_new + 1, NO_NEW_COUNTER_CAP),
                          sync_counter), Status.REPEATED
    if delta > max_delta:
        sync = config.sync_counter_init
        if sync > 0:
            return CheckState(received, init, False, lost_before, 0, sync), Status.WRONGSEQUENCE
        return CheckState(last, max_delta, False, lost_before, 0, sync), Status.WRONGSEQUENCE
    lost = delta - 1
    if no_new > config.max_no_new_or_repeated_data:
        return CheckState(received, init, False, lost, 0, config.sync_counter_init), Status.SYNC
    if sync_counter > 0:
        return CheckState(received, init, False, lost, 0, sync_counter - 1), Status.SYNC
    return CheckState(received, init, False, lost, 0, 0), Status.OK if delta == 1 else Status.OKSOMELOST


def counter_flip_collisions(config: P02Config) -> tuple[tuple[int, int], ...]:
    """(counter, bit) pairs where flipping that bit of the counter nibble leaves the CRC valid.

    CRC-8H2F detects every single-bit error of a fixed message, but in Profile 2 a counter bit flip
    also swaps the data id byte (DataIDList[c] for DataIDList[c ^ 1 << bit]): the two changes can
    cancel.  The CRC is affine in the payload, so whether they cancel depends only on the list and
    the length, not on the payload; a DataIDList for which this returns pairs lets such a flip
    through as a valid frame (about one random list in eight does).  Use it to vet a list.
    """
    found = []
    zero = bytearray(config.length)
    for counter in range(P02_COUNTER_MODULO):
        zero[1] = counter
        crc = _p02_crc(config, zero, counter)
        for bit in range(4):
            flipped = counter ^ (1 << bit)
            zero[1] = flipped
            if _p02_crc(config, zero, flipped) == crc:
                found.append((counter, bit))
            zero[1] = counter
    return tuple(found)


# --- Profiles 5 and 11: configurations that protect and check themselves -----------------------------

def counter_check(state: CheckState, received: int, modulo: int,
                  max_delta_counter: int) -> tuple[CheckState, Status]:
    """The counter part of E2E_P05Check / E2E_P11Check (PRS_E2EProtocol, "Do checks"), for a frame
    whose CRC (or checksum) is right: the delta from the last received counter, modulo ``modulo``,
    gives REPEATED (0), OK (1), OKSOMELOST (2..max_delta_counter) or WRONGSEQUENCE (more).  The
    received counter becomes the last one in each case: a wrong sequence re-anchors the count.

    First frame: a state still waiting for its first data stands for the counter E2E_P05CheckInit
    and E2E_P11CheckInit leave, the modulo - 1 (0xFF: SWS_E2E_00451; 0x0E for Profile 11), one step
    before 0.  A first frame with counter 0 is therefore OK (usable: these profiles have no
    INITIAL), with counter c in 1..max_delta_counter OKSOMELOST.  A first frame whose counter
    follows nothing the receiver knew (any other: the sender counted before the receiver listened, a
    device started before the bench) is reported INITIAL, not the PRS's WRONGSEQUENCE or REPEATED:
    either way it is not used, and it anchors the count; the E2E state machine above the check
    (E2E_SMCheck) does not count a start-up's first frame as an error either.
    """
    last = modulo - 1 if state.wait_for_first_data else state.last_valid_counter
    delta = (received - last) % modulo
    if delta == 1:
        return CheckState(received, 0, False, 0, 0, 0), Status.OK
    if 0 < delta <= max_delta_counter:
        return CheckState(received, 0, False, delta - 1, 0, 0), Status.OKSOMELOST
    if state.wait_for_first_data:
        return CheckState(received, 0, False, 0, 0, 0), Status.INITIAL
    if delta == 0:
        return CheckState(received, 0, False, state.lost_data, 0, 0), Status.REPEATED
    return CheckState(received, 0, False, state.lost_data, 0, 0), Status.WRONGSEQUENCE


def _sender_copy(config: ProtectionConfig, payload: bytes) -> bytearray:
    """A writable copy of a payload to protect, which must hold the protected length (as ``protect``)."""
    if len(payload) < config.length:
        raise E2EConfigError(f"{config.name}: payload of {len(payload)} bytes, expected {config.length}")
    return bytearray(payload)


@dataclass(frozen=True, slots=True)
class P05Config:
    """Profile 5 configuration of one protected frame (E2E_P05ConfigType), computed by autosar-e2e.

    A 3-byte header at ``offset``: the CRC-16's low byte, its high byte, then the 8-bit counter.  The
    CRC covers every protected byte but its own two (the counter included), then the data id's low
    and high byte (implicit: the data id is not sent).
    """

    data_id: int                                   # 16-bit data id
    length: int = 8                                # payload bytes protected (DataLength / 8), header included
    offset: int = 0                                # bits, multiple of 8: where the header starts
    max_delta_counter: int = 1                     # counter steps allowed between two valid frames
    name: str = "E2E profile 5"                    # frame name, used in error messages only
    _header: int = field(init=False, repr=False, compare=False)   # offset in bytes

    def __post_init__(self) -> None:
        w = self.name
        _check_int(w, "data_id", self.data_id, 0, 0xFFFF)
        _check_int(w, "length", self.length, P05_HEADER, P05_MAX_LENGTH, " bytes")
        _check_int(w, "offset", self.offset, 0, (self.length - P05_HEADER) * 8, " bits")
        if self.offset % 8:
            raise E2EConfigError(f"{w}: offset = {self.offset}, expected a multiple of 8 bits")
        _check_int(w, "max_delta_counter", self.max_delta_counter, 1, P05_COUNTER_MODULO - 1)
        object.__setattr__(self, "_header", self.offset >> 3)

    def describe(self) -> str:
        """One line for reports, e.g. "AUTOSAR E2E P05, data id 0x1234"."""
        return f"AUTOSAR E2E P05, data id 0x{self.data_id:X}"

    def protect(self, state: ProtectState, payload: bytes) -> bytes:
        """E2E_P05Protect: ``payload`` with the counter ``state.counter`` and the CRC written, then
        the counter advanced (255 -> 0).  Errors of the sender as ``protect``."""
        data = _sender_copy(self, payload)
        counter = state.counter
        if not 0 <= counter < P05_COUNTER_MODULO:
            raise E2EConfigError(f"{self.name}: sender counter {counter!r}, expected 0..255")
        data[self._header + 2] = counter
        _autosar_p05.e2e_p05_protect(data, self.data_id, length=self.length, offset=self._header,
                                     increment_counter=False)
        state.counter = (counter + 1) % P05_COUNTER_MODULO
        return bytes(data)

    def check(self, state: CheckState, payload: bytes | None) -> tuple[CheckState, Status]:
        """E2E_P05Check as a pure function, as ``check``: NONEWDATA for ``None``; ERROR for a wrong
        length or CRC (the state unchanged); else ``counter_check``.  Never raises on the payload."""
        if payload is None:
            return state, Status.NONEWDATA
        if len(payload) != self.length or not _autosar_p05.e2e_p05_check(
                payload, self.data_id, length=self.length, offset=self._header):
            return state, Status.ERROR
        return counter_check(state, payload[self._header + 2], P05_COUNTER_MODULO, self.max_delta_counter)


_P11_MODES = {DataIdMode.BOTH: _autosar_p11.E2E_P11_DATAID_BOTH,
              DataIdMode.NIBBLE: _autosar_p11.E2E_P11_DATAID_NIBBLE}


@dataclass(frozen=True, slots=True)
class P11Config:
    """Profile 11 configuration of one protected frame (E2E_P11ConfigType), computed by autosar-e2e.

    CRC-8 SAE J1850 over the data id (BOTH: low byte, high byte; NIBBLE: low byte, then a zero byte)
    and every protected byte but the CRC byte.  The layout is autosar-e2e's: the CRC byte at
    ``offset``, the counter in the low nibble of the next byte and, in NIBBLE mode, the low nibble of
    the data id's high byte in its high nibble (the spec's CRCOffset, CounterOffset and
    DataIDNibbleOffset at offset, offset + 8 and offset + 12).
    """

    data_id: int                                   # 16-bit data id (12-bit in NIBBLE mode)
    data_id_mode: DataIdMode = DataIdMode.BOTH     # BOTH or NIBBLE
    length: int = 8                                # payload bytes protected (DataLength / 8)
    offset: int = 0                                # bits, multiple of 8: the CRC byte
    max_delta_counter: int = 1                     # counter steps allowed between two valid frames
    name: str = "E2E profile 11"                   # frame name, used in error messages only
    _header: int = field(init=False, repr=False, compare=False)   # offset in bytes
    _mode: int = field(init=False, repr=False, compare=False)     # autosar-e2e's data id mode

    def __post_init__(self) -> None:
        w = self.name
        if not isinstance(self.data_id_mode, DataIdMode):
            raise TypeError(f"{w}: data_id_mode = {self.data_id_mode!r}, expected BOTH or NIBBLE")
        if self.data_id_mode not in _P11_MODES:
            raise E2EConfigError(f"{w}: data_id_mode = {self.data_id_mode!r}, expected BOTH or NIBBLE")
        nibble = self.data_id_mode is DataIdMode.NIBBLE
        _check_int(w, "data_id", self.data_id, 0, 0x0FFF if nibble else 0xFFFF,
                   " (12 bits in NIBBLE mode)" if nibble else "")
        _check_int(w, "length", self.length, 2, P11_MAX_LENGTH, " bytes")
        _check_int(w, "offset", self.offset, 0, (self.length - 2) * 8, " bits")
        if self.offset % 8:
            raise E2EConfigError(f"{w}: offset = {self.offset}, expected a multiple of 8 bits")
        _check_int(w, "max_delta_counter", self.max_delta_counter, 1, P11_COUNTER_MODULO - 1)
        object.__setattr__(self, "_header", self.offset >> 3)
        object.__setattr__(self, "_mode", _P11_MODES[self.data_id_mode])

    def describe(self) -> str:
        """One line for reports, e.g. "AUTOSAR E2E P11, data id 0x123 (NIBBLE)"."""
        return f"AUTOSAR E2E P11, data id 0x{self.data_id:X} ({self.data_id_mode.name})"

    def protect(self, state: ProtectState, payload: bytes) -> bytes:
        """E2E_P11Protect: ``payload`` with the counter ``state.counter`` (and, in NIBBLE mode, the
        data-id nibble) and the CRC written, then the counter advanced (14 -> 0).  Errors of the
        sender as ``protect``."""
        data = _sender_copy(self, payload)
        counter = state.counter
        if not 0 <= counter < P11_COUNTER_MODULO:
            raise E2EConfigError(f"{self.name}: sender counter {counter!r}, expected 0..14")
        i = self._header + 1
        data[i] = (data[i] & 0xF0) | counter
        _autosar_p11.e2e_p11_protect(data, self.data_id, data_id_mode=self._mode, length=self.length,
                                     offset=self._header, increment_counter=False)
        state.counter = (counter + 1) % P11_COUNTER_MODULO
        return bytes(data)

    def check(self, state: CheckState, payload: bytes | None) -> tuple[CheckState, Status]:
        """E2E_P11Check as a pure function, as ``check``: NONEWDATA for ``None``; ERROR for a wrong
        length, CRC or data-id nibble or a counter of 15 (the state unchanged); else
        ``counter_check``.  Never raises on the payload."""
        if payload is None:
            return state, Status.NONEWDATA
        if len(payload) != self.length:
            return state, Status.ERROR
        received = payload[self._header + 1] & 0x0F
        # e2e.p11's check asks for a writable buffer (it writes nothing): hence the copy
        if received == 0x0F or not _autosar_p11.e2e_p11_check(
                bytearray(payload), self.data_id, data_id_mode=self._mode, length=self.length,
                offset=self._header):
            return state, Status.ERROR
        return counter_check(state, received, P11_COUNTER_MODULO, self.max_delta_counter)
