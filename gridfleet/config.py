"""Broker URLs: `mqtt://host:port` for TCP clients, `ws://host:port/path` for websocket clients."""

from __future__ import annotations

from dataclasses import dataclass, field
from urllib.parse import quote, unquote, urlsplit

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
    username: str | None = None
    password: str | None = field(default=None, repr=False)

    @property
    def transport(self) -> str:
        """paho's transport name for this URL."""
        return "websockets" if self.scheme == "ws" else "tcp"

    def __str__(self) -> str:
        # Never the password: this is what logs and messages show.
        tail = self.path if self.scheme == "ws" and self.path != "/" else ""
        user = f"{self.username}@" if self.username else ""
        return f"{self.scheme}://{user}{self.host}:{self.port}{tail}"


def parse_broker_url(url: str) -> BrokerURL:
    """Parse a broker URL; a bad one raises ConfigError saying what is wrong."""
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        raise ConfigError(f"broker URL {redacted(url)!r}: {exc}") from None
    scheme = parts.scheme.lower()
    if scheme not in _DEFAULT_PORTS:
        raise ConfigError(f"broker URL {redacted(url)!r}: scheme must be mqtt:// or ws://")
    if not parts.hostname:
        raise ConfigError(
            f"broker URL {redacted(url)!r}: no host (expected e.g. {DEFAULT_MQTT_URL})"
        )
    if scheme == "tcp":
        scheme = "mqtt"
    if parts.password is not None and not parts.username:
        raise ConfigError(f"broker URL {redacted(url)}: a password needs a user (user:pass@host)")
    username = unquote(parts.username) if parts.username else None
    password = unquote(parts.password) if parts.password is not None else None
    port = port or _DEFAULT_PORTS[scheme]
    return BrokerURL(scheme, parts.hostname, port, parts.path or "/", username, password)


def with_credentials(url: str, username: str, password: str) -> str:
    """`url` logging in as `username` (any credentials it had are replaced)."""
    parts = urlsplit(url)
    host = parts.netloc.rsplit("@", 1)[-1]
    login = f"{quote(username, safe='')}:{quote(password, safe='')}@"
    return parts._replace(netloc=login + host).geturl()


def redacted(url: str) -> str:
    """`url` with any password replaced by `***`, for messages."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    return url.replace(f":{parts.password}@", ":***@", 1)


MAX_STEP_S = 60.0


def check_step(step_s: float, flag: str = "--step") -> float:
    """`step_s` when it is a usable step period; otherwise ConfigError in the words every command uses."""
    if not 0 < step_s <= MAX_STEP_S:
        raise ConfigError(
            f"{flag} {step_s:g}: the step period must be in (0, {MAX_STEP_S:g}] seconds"
        )
    return step_s
