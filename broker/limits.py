"""How much one client may send or have queued at the embedded broker (and at Mosquitto)."""

from __future__ import annotations

from dataclasses import dataclass

from gridfleet.errors import ConfigError
from gridfleet.protocol.constants import MAX_VIEW_BYTES

# The largest MQTT packet (headers included, as Mosquitto's max_packet_size counts) a client may
# send: the protocol's largest message, a retained fleet view, plus room for any topic (at most
# 64 KiB). A bigger one disconnects its sender before its body is read.
MAX_PACKET_BYTES = MAX_VIEW_BYTES + 64 * 1024
# Per connection: live messages handed to it and not yet written out (QoS 0) or acknowledged
# (QoS 1). Past either limit the broker drops further messages for it, QoS 0 and 1 alike (as
# Mosquitto's max_queued_messages / max_queued_bytes). One message always fits, whatever its size.
MAX_QUEUED_MESSAGES = 1000
MAX_QUEUED_BYTES = 32 * 1024 * 1024


@dataclass(frozen=True)
class Limits:
    """What one client may cost the broker: the one place the three limits are bundled."""

    max_packet_bytes: int = MAX_PACKET_BYTES
    max_queued_messages: int = MAX_QUEUED_MESSAGES
    max_queued_bytes: int = MAX_QUEUED_BYTES

    def __post_init__(self) -> None:
        for name in ("max_packet_bytes", "max_queued_messages", "max_queued_bytes"):
            if getattr(self, name) < 1:
                raise ConfigError(f"broker {name} {getattr(self, name)} must be at least 1")
