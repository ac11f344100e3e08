"""How much one client may send or have queued at the embedded broker (and at Mosquitto)."""

from __future__ import annotations

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
