"""Tiny device-facing payloads (direction, emergency stop): plain text, no JSON library needed."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal, get_args

from gridfleet.errors import ProtocolError
from gridfleet.protocol.constants import (
    DIRECTION_NONE,
    ESTOP_ENGAGED,
    ESTOP_RELEASED,
    ESTOP_SEPARATOR,
    ID_PATTERN,
    MAX_ESTOP_BYTES,
    MAX_ESTOP_REASON,
)
from gridfleet.squares import Direction

_BY_RE = re.compile(ID_PATTERN)


def encode_direction(direction: Direction | None) -> bytes:
    """`N`, `E`, `S`, `W`, or `-` for no intended move."""
    return DIRECTION_NONE.encode() if direction is None else direction.value.encode()


def decode_direction(payload: bytes | str) -> Direction | None:
    """Inverse of encode_direction; anything else raises ProtocolError."""
    text = payload.decode("ascii", "replace") if isinstance(payload, bytes | bytearray) else payload
    if text == DIRECTION_NONE:
        return None
    try:
        return Direction(text)
    except ValueError:
        raise ProtocolError(f"direction: {text[:20]!r} is not one of N E S W -") from None


@dataclass(frozen=True)
class EstopSignal:
    """The latched emergency stop: engaged or released, by whom, and why."""

    engaged: bool
    by: str
    reason: str = ""

    def __post_init__(self) -> None:
        if not _BY_RE.fullmatch(self.by):
            raise ProtocolError(f"estop: 'by' {self.by!r} is not a valid id")
        if len(self.reason) > MAX_ESTOP_REASON or any(c in self.reason for c in "\r\n\x00"):
            raise ProtocolError(
                f"estop: reason must be one line of at most {MAX_ESTOP_REASON} characters"
            )


def encode_estop(signal: EstopSignal) -> bytes:
    """`engaged|<by>|<reason>` or `released|<by>|<reason>` in UTF-8."""
    state = ESTOP_ENGAGED if signal.engaged else ESTOP_RELEASED
    return ESTOP_SEPARATOR.join((state, signal.by, signal.reason)).encode()


def decode_estop(payload: bytes | str) -> EstopSignal:
    """Parse an emergency-stop payload; anything malformed raises ProtocolError."""
    if isinstance(payload, bytes | bytearray):
        if len(payload) > MAX_ESTOP_BYTES:
            raise ProtocolError(f"estop: payload of {len(payload)} bytes exceeds {MAX_ESTOP_BYTES}")
        try:
            text = payload.decode("utf-8")
        except UnicodeDecodeError:
            raise ProtocolError("estop: payload is not UTF-8") from None
    else:
        text = payload
    parts = text.split(ESTOP_SEPARATOR, 2)
    if len(parts) < 2 or parts[0] not in (ESTOP_ENGAGED, ESTOP_RELEASED):
        raise ProtocolError(
            f"estop: {text[:40]!r} is not 'engaged|<by>|<reason>' or 'released|<by>|<reason>'"
        )
    return EstopSignal(parts[0] == ESTOP_ENGAGED, parts[1], parts[2] if len(parts) == 3 else "")


def decode_press(payload: bytes | str, source: str) -> EstopSignal | None:
    """A stop press of `source` (its own `stop` topic): engaged, or None when cleared (empty).

    A press can only engage, and names its source: `released|...`, or another `by`, raises
    ProtocolError like any malformed payload (only an operator releases, on `fleet/estop`).
    """
    if len(payload) == 0:
        return None
    signal = decode_estop(payload)
    if not signal.engaged:
        raise ProtocolError(
            f"stop press of {source}: a press can only engage; release on fleet/estop"
        )
    if signal.by != source:
        raise ProtocolError(f"stop press of {source}: it names {signal.by!r} as its source")
    return signal


DeviceConnection = Literal["online", "offline", "broken"]
DEVICE_STATES: tuple[DeviceConnection, ...] = get_args(DeviceConnection)
DEVICE_WILL: DeviceConnection = "broken"  # what a device's last will says


def encode_device_connection(state: DeviceConnection) -> bytes:
    """`online`, `offline` or `broken` (the last will), plain ASCII."""
    if state not in DEVICE_STATES:
        raise ProtocolError(f"device connection: {state!r} is not one of online offline broken")
    return state.encode()


def decode_device_connection(payload: bytes | str) -> DeviceConnection:
    """Inverse of encode_device_connection; anything else raises ProtocolError."""
    text = payload.decode("ascii", "replace") if isinstance(payload, bytes | bytearray) else payload
    if text not in DEVICE_STATES:
        raise ProtocolError(f"device connection: {text[:20]!r} is not one of online offline broken")
    return text
