"""Broker URLs: `mqtt://host:port` for TCP clients, `ws://host:port/path` for websocket clients."""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import urlsplit

from gridfleet.errors import ConfigError

DEFAULT_MQTT_URL = "mqtt://127.0.0.1:1883"
DEFAULT_WS_URL = "ws://127.0.0.1:9001"
_DEFAULT_PORTS = {"mqtt": 1883, "tcp": 1883, "ws": 80}


@dataclass(frozen=True)
class BrokerURL:
    """Where a broker listens: scheme (`mqtt` or `ws`), host, port and websocket path."""

    scheme: str
    host: str
    port: int
    path: str = "/"

    @property
    def transport(self) -> str:
        """paho's transport name for this URL."""
        return "websockets" if self.scheme == "ws" else "tcp"

    def __str__(self) -> str:
        tail = self.path if self.scheme == "ws" and self.path != "/" else ""
        return f"{self.scheme}://{self.host}:{self.port}{tail}"


def parse_broker_url(url: str) -> BrokerURL:
    """Parse a broker URL; a bad one raises ConfigError saying what is wrong."""
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        raise ConfigError(f"broker URL {url!r}: {exc}") from None
    scheme = parts.scheme.lower()
    if scheme not in _DEFAULT_PORTS:
        raise ConfigError(f"broker URL {url!r}: scheme must be mqtt:// or ws://")
    if not parts.hostname:
        raise ConfigError(f"broker URL {url!r}: no host (expected e.g. {DEFAULT_MQTT_URL})")
    if scheme == "tcp":
        scheme = "mqtt"
    return BrokerURL(scheme, parts.hostname, port or _DEFAULT_PORTS[scheme], parts.path or "/")
