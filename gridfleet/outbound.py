"""What a pure core says: messages to publish, as values (no MQTT client, no I/O).

The cores (coordinator, unit, device) return these; their shells hand them to an MQTT endpoint
(`gridfleet/endpoint.py`), which is the only place that knows a client library.
"""

from __future__ import annotations

from dataclasses import dataclass

from gridfleet.protocol import TOPICS, ErrorReport, Header, encode
from gridfleet.protocol.constants import MAX_TEXT
from gridfleet.protocol.messages import Message


@dataclass(frozen=True)
class Outbound:
    """One message to publish: topic, payload bytes, QoS and retain flag."""

    topic: str
    payload: bytes
    qos: int
    retain: bool

    @classmethod
    def of(cls, kind: str, topic: str, message: Message | bytes) -> Outbound:
        """A message on a topic of `kind`, with the QoS and retain flag protocol.md gives it."""
        spec = TOPICS[kind]
        payload = message if isinstance(message, bytes) else encode(message)
        return cls(topic, payload, spec.qos, spec.retained)


def error_report(header: Header, topic: str, reason: str, request_id: str | None = None) -> bytes:
    """The payload of an `errors` report about a message refused on `topic`, cut to the limits."""
    return encode(
        ErrorReport(
            header=header, topic=topic[:256], reason=reason[:MAX_TEXT], request_id=request_id
        )
    )
