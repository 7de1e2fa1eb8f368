"""The protection of a device's own frames: what its device file (or its DBC) declares, as the E2E
configuration a node protects and checks them with (hil.can.e2e, hil.can.checksums).

A device file names signals, not bit offsets: the CRC signal of an AUTOSAR profile (where the profile's
layout starts; default byte 0), the counter and checksum signals of a plain counter/checksum.  Their place
in the frame comes from the DBC (either byte order).  `filled_signals` says which signals of a message the
sender's protection writes, so that the map need not (and must not) give them a source.
"""

from __future__ import annotations

from cantools.database.can import Message, Signal

from hil.can.attributes import e2e_config
from hil.can.checksums import CounterChecksumConfig
from hil.can.e2e import DataIdMode, E2EConfigError, P01Config, P02Config, P05Config, P11Config
from hil.devices.description import ProtectionSpec
from hil.errors import DbcError, DeviceError


def signal_bits(signal: Signal) -> list[int]:
    """The payload bits a signal occupies, in AUTOSAR numbering (bit k is bit k % 8 of byte k // 8), from
    its least significant bit up."""
    if signal.byte_order == "little_endian":
        return list(range(signal.start, signal.start + signal.length))
    byte, bit = divmod(signal.start, 8)           # a Motorola signal starts at its most significant bit
    out = []
    for _ in range(signal.length):
        out.append(byte * 8 + bit)
        bit -= 1
        if bit < 0:
            byte, bit = byte + 1, 7
    return out[::-1]


def _signal(msg: Message, name: str, where: str, role: str) -> Signal:
    sig = next((s for s in msg.signals if s.name == name), None)
    if sig is None:
        names = ", ".join(s.name for s in msg.signals)
        raise DeviceError(f"{where}: {role} = {name!r}: {msg.name} has no such signal (its signals: {names})")
    return sig


def _byte_of(msg: Message, name: str | None, where: str, role: str, width: int = 8) -> int:
    """The bit offset of the byte-aligned field `name` (`width` bits, default a byte); 0 when None."""
    if name is None:
        return 0
    bits = sorted(signal_bits(_signal(msg, name, where, role)))
    if bits[0] % 8 or bits != list(range(bits[0], bits[0] + width)):
        raise DeviceError(f"{where}: {role} = {name!r}: expected a signal of {width} bits starting on a "
                          f"byte, it occupies bits {bits[0]}..{bits[-1]}")
    return bits[0]


def message_protection(spec: ProtectionSpec | None, msg: Message, where: str):
    """The E2E configuration of a device message: from its device-file entry `spec`, else from railhil's
    own DBC attributes (E2EProfile), else None (unprotected)."""
    if spec is None:
        try:
            return e2e_config(msg)
        except DbcError as exc:
            raise DeviceError(f"{where}: {exc}") from None
    length = msg.length
    try:
        if spec.profile == "P01":
            mode = DataIdMode.NIBBLE if spec.data_id_mode == "nibble" else DataIdMode.BOTH
            crc = _byte_of(msg, spec.crc, where, "crc")
            return P01Config(spec.data_id, mode, length=length, crc_offset=crc, counter_offset=crc + 8,
                             data_id_nibble_offset=crc + 12, max_delta_counter_init=spec.max_delta_counter,
                             name=msg.name)
        if spec.profile == "P02":
            if spec.crc is not None and _byte_of(msg, spec.crc, where, "crc") != 0:
                raise DeviceError(f"{where}: crc = {spec.crc!r}: profile P02's CRC is byte 0")
            return P02Config(tuple(spec.data_id_list), length=length,
                             max_delta_counter_init=spec.max_delta_counter, name=msg.name)
        if spec.profile == "P05":
            return P05Config(spec.data_id, length=length, offset=_byte_of(msg, spec.crc, where, "crc", 16),
                             max_delta_counter=spec.max_delta_counter, name=msg.name)
        if spec.profile == "P11":
            mode = DataIdMode.NIBBLE if spec.data_id_mode == "nibble" else DataIdMode.BOTH
            return P11Config(spec.data_id, mode, length=length, offset=_byte_of(msg, spec.crc, where, "crc"),
                             max_delta_counter=spec.max_delta_counter, name=msg.name)
        counter = bits = None
        if spec.counter is not None:
            counter_bits = sorted(signal_bits(_signal(msg, spec.counter, where, "counter")))
            counter, bits = counter_bits[0], len(counter_bits)
            if counter_bits != list(range(counter, counter + bits)) or counter // 8 != counter_bits[-1] // 8:
                raise DeviceError(f"{where}: counter = {spec.counter!r}: expected a counter of at most 8 "
                                  f"bits inside one byte, it occupies bits {counter}..{counter_bits[-1]}")
        return CounterChecksumConfig(length=length, counter_offset=counter, counter_bits=bits or 4,
                                     max_delta_counter=spec.max_delta_counter, checksum=spec.checksum,
                                     checksum_offset=_byte_of(msg, spec.checksum_signal, where,
                                                              "checksum_signal"),
                                     name=msg.name)
    except E2EConfigError as exc:
        raise DeviceError(f"{where}: {exc}") from None


def layout_bits(config) -> set[int]:
    """The payload bits a protection writes (CRC, counter, checksum, data-id nibble)."""
    if config is None:
        return set()
    if isinstance(config, P01Config):
        bits = set(range(config.crc_offset, config.crc_offset + 8))
        bits |= set(range(config.counter_offset, config.counter_offset + 4))
        if config.data_id_mode is DataIdMode.NIBBLE:
            bits |= set(range(config.data_id_nibble_offset, config.data_id_nibble_offset + 4))
        return bits
    if isinstance(config, P02Config):
        return set(range(0, 12))
    if isinstance(config, P05Config):
        return set(range(config.offset, config.offset + 24))
    if isinstance(config, P11Config):
        nibble = config.data_id_mode is DataIdMode.NIBBLE
        return set(range(config.offset, config.offset + (16 if nibble else 12)))
    bits: set[int] = set()
    if config.counter_offset is not None:
        bits |= set(range(config.counter_offset, config.counter_offset + config.counter_bits))
    if config.checksum is not None:
        bits |= set(range(config.checksum_offset, config.checksum_offset + 8))
    return bits


def filled_signals(msg: Message, config) -> set[str]:
    """The signals of `msg` its sender's protection writes: those lying wholly in the protection's bits."""
    bits = layout_bits(config)
    return {s.name for s in msg.signals if bits and set(signal_bits(s)) <= bits}


def describe(config) -> str:
    """One line for reports: the protection of a message ("none" without one)."""
    return "none" if config is None else config.describe()
