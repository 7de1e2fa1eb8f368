"""What the DBC's attributes say about a message: its AUTOSAR E2E protection (`E2EProfile` = P01/P02,
`E2EDataID`, `E2EDataIDList`), its SecOC authentication (`SecOCDataID`), the signals its sending node fills
itself (counters, CRC, SecOC trailer) and the pages of a multiplexed status frame.

The node runtime (hil.runtime.node) protects and checks frames by these; fault injection, the threat
matrix, the FMU ports and the devices' gateways read them too.  A DBC whose attributes are incomplete is a
DbcError naming the message.
"""

from __future__ import annotations

from collections.abc import Iterable

from hil.can import e2e, secoc
from hil.errors import DbcError

E2E_COUNTER = "COUNTER"          # the alive counter signal of a protected (or counted) message


def _attribute(msg, name: str):
    attrs = getattr(getattr(msg, "dbc", None), "attributes", None) or {}
    a = attrs.get(name)
    if a is None:
        return None
    choices = getattr(a.definition, "choices", None)
    if choices and isinstance(a.value, int) and not isinstance(a.value, bool):
        return choices[a.value] if isinstance(choices, (list, tuple)) else choices.get(a.value, a.value)
    return a.value


def e2e_config(msg) -> e2e.P01Config | e2e.P02Config | None:
    """The E2E configuration the DBC gives a message, or None.

    Message attributes: `E2EProfile` ("NONE", "P01", "P02"); `E2EDataID` (P01: 16-bit data id, mode
    BOTH, CRC in byte 0 and counter in the low nibble of byte 1 as the CHECKSUM/COUNTER signals of
    our DBC); P02 needs `E2EDataIDList` (16 bytes as hex, e.g. "1F1F...", one per counter value)."""
    profile = _attribute(msg, "E2EProfile")
    if profile in (None, "NONE", "None", 0):
        return None
    where = f"message {msg.name}"
    try:
        if profile == "P01":
            data_id = _attribute(msg, "E2EDataID")
            if data_id is None:
                raise DbcError(f"{where}: E2EProfile P01 needs the E2EDataID attribute")
            return e2e.P01Config(int(data_id), length=authentic_length(msg), name=msg.name)
        if profile == "P02":
            text = _attribute(msg, "E2EDataIDList")
            try:
                ids = tuple(bytes.fromhex(str(text)))
            except ValueError:
                ids = ()
            if len(ids) != 16:
                raise DbcError(f"{where}: E2EProfile P02 needs E2EDataIDList = 16 bytes as 32 hex digits, "
                               f"got {text!r}")
            return e2e.P02Config(ids, length=authentic_length(msg), name=msg.name)
    except e2e.E2EConfigError as exc:
        raise DbcError(f"{where}: {exc}") from None
    raise DbcError(f"{where}: E2EProfile {profile!r} is not one of NONE, P01, P02")


def secoc_data_id(msg) -> int | None:
    """The message's SecOC data id (attribute `SecOCDataID` > 0), or None: not authenticated."""
    value = _attribute(msg, "SecOCDataID")
    return int(value) if value else None


def authentic_length(msg) -> int:
    """Bytes of the frame before a SecOC trailer (freshness byte + 3 MAC bytes), all without one."""
    return msg.length - secoc.AUTH_BYTES if secoc_data_id(msg) else msg.length


def bench_filled_signals(msg) -> set[str]:
    """The signals of a message that its sending node fills itself, not its controller: the E2E CRC and
    counter (CHECKSUM, COUNTER), the alive counter of a message without E2E (COUNTER), the SecOC trailer
    (SecOCFreshness, SecOCMAC)."""
    names = {s.name for s in msg.signals}
    filled = names & {"CHECKSUM", E2E_COUNTER} if e2e_config(msg) is not None else names & {E2E_COUNTER}
    if secoc_data_id(msg):
        filled |= names & {"SecOCFreshness", "SecOCMAC"}
    return filled


def multiplexer_pages(msg, fields: Iterable[tuple[str, str]]) -> tuple[str, tuple[int, ...]] | None:
    """(multiplexer signal, its values in the DBC's order) of a multiplexed message whose multiplexer is not
    among the signals a node sets (`fields`): the node sends one page a frame, in turn (a status frame
    that pages through its contents).  None for any other message."""
    if not msg.is_multiplexed():
        return None
    set_by_node = {sig for sig, _ in fields}
    for item in msg.signal_tree:
        if isinstance(item, dict):
            (mux, pages), = item.items()
            return None if mux in set_by_node else (mux, tuple(int(v) for v in pages))
    return None
