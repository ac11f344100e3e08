"""The broker's side of TLS: amqtt's listeners get gridfleet's server context."""

from __future__ import annotations

import ssl
from typing import Any

from gridfleet.tls import server_context


def amqtt_listener_context(listener: Any) -> ssl.SSLContext:
    """Stands in for amqtt's `Broker._create_ssl_context(listener)` on a broker instance."""
    return server_context(listener["certfile"], listener["keyfile"])
