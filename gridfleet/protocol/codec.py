"""JSON encoding and decoding of protocol messages, with errors that name the bad field."""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Callable
from datetime import UTC, datetime
from typing import TypeVar

from pydantic import ValidationError

from gridfleet.errors import ProtocolError
from gridfleet.protocol.constants import MAX_ID_CHARS, MAX_REQUEST_BYTES
from gridfleet.protocol.messages import Header, Message
from gridfleet.protocol.topics import validate_id

M = TypeVar("M", bound=Message)


def encode(message: Message) -> bytes:
    """Compact JSON bytes of `message`."""
    return message.model_dump_json(exclude_none=message.omits_nulls).encode("utf-8")


def decode(
    model: type[M], payload: bytes | bytearray | str, max_bytes: int = MAX_REQUEST_BYTES
) -> M:
    """Parse and validate `payload` as `model`; raise ProtocolError naming the problem."""
    name = model.__name__
    size = len(payload.encode("utf-8") if isinstance(payload, str) else payload)
    if size > max_bytes:
        raise ProtocolError(f"{name}: payload of {size} bytes exceeds the limit of {max_bytes}")
    try:
        return model.model_validate_json(payload, strict=True)  # "1.5" is no number on the wire
    except ValidationError as exc:
        if not any(e["type"] == "int_type" and isinstance(e["input"], float) for e in exc.errors()):
            raise ProtocolError(f"{name}: {describe(exc)}") from None
        first = exc
    # JSON has one kind of number: 3.0 is the integer 3 (JSON Schema says so too), which pydantic's
    # strict reading refuses. Read again with whole numbers written as integers (a float field
    # takes them), as JSON still: strict reading from Python would refuse times and arrays.
    try:
        whole = json.dumps(json.loads(payload, parse_float=_whole_as_int))
        return model.model_validate_json(whole, strict=True)
    except ValidationError as exc:
        raise ProtocolError(f"{name}: {describe(exc)}") from None
    except (ValueError, RecursionError):
        raise ProtocolError(f"{name}: {describe(first)}") from None


def _whole_as_int(text: str) -> int | float:
    """A JSON number's text as an int when it is a whole number (`3.0`, `1e2`), else a float."""
    number = float(text)
    return int(number) if number.is_integer() else number


def describe(exc: ValidationError) -> str:
    """One line naming the first bad field of a validation error (and how many more there are)."""
    errors = exc.errors(include_url=False)
    first = errors[0]
    where = ".".join(str(p) for p in first["loc"]) or "message"
    if first["type"] == "json_invalid":
        text = f"malformed JSON ({first['msg']})"
    else:
        text = f"field '{where}': {first['msg']}"
    if len(errors) > 1:
        text += f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})"
    return text


class HeaderStamper:
    """Makes headers for one sender: a counter per topic kind and a UTC timestamp."""

    def __init__(self, sender: str, clock: Callable[[], datetime] | None = None) -> None:
        self.sender = validate_id(sender, "sender")
        self._clock = clock or (lambda: datetime.now(UTC))
        self._seq: defaultdict[str, int] = defaultdict(int)

    def now(self) -> datetime:
        """The time by this stamper's clock (UTC), as its headers give it."""
        return self._clock()

    def __call__(self, kind: str) -> Header:
        """The next header for a message on a topic of `kind`."""
        seq = self._seq[kind]
        self._seq[kind] = seq + 1
        return Header(seq=seq, timestamp=self._clock(), sender=self.sender)


def reply_address(payload: bytes) -> tuple[str | None, str | None]:
    """(request id, reply_to) of a request that may not decode, each None where unreadable."""
    try:
        data = json.loads(payload) if len(payload) <= MAX_REQUEST_BYTES else None
    except (ValueError, RecursionError):  # RecursionError: nested too deeply
        return None, None
    if not isinstance(data, dict):
        return None, None
    request_id, reply_to = data.get("request_id"), data.get("reply_to")
    if not (isinstance(request_id, str) and 0 < len(request_id) <= MAX_ID_CHARS):
        return None, None  # as Request's own bound
    try:
        return request_id, validate_id(reply_to, "reply_to") if isinstance(reply_to, str) else None
    except ProtocolError:
        return request_id, None
