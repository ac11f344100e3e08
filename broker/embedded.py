"""amqtt embedded in-process, as an async context manager that reports the ports it bound."""

from __future__ import annotations

import asyncio
import logging
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import TracebackType
from typing import Any
from urllib.parse import urlsplit

from pydantic import BaseModel, ConfigDict, ValidationError

from gridfleet.accounts import Accounts, rules
from gridfleet.broker.gate import Gate
from gridfleet.broker.limits import MAX_PACKET_BYTES, MAX_QUEUED_BYTES, MAX_QUEUED_MESSAGES, Limits
from gridfleet.broker.stats import BrokerFigures
from gridfleet.broker.tls import amqtt_listener_context
from gridfleet.config import is_loopback
from gridfleet.errors import ConfigError
from gridfleet.protocol import Topics
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.textfile import read_text
from gridfleet.tls import server_context

log = logging.getLogger("gridfleet.broker")
# amqtt's shutdown first drains its unbounded broadcast queue: after an overload that took longer
# than the 15 s a supervisor waits after SIGTERM (measured in the chaos soak). Bounded here.
SHUTDOWN_S = 5.0


class _BrokerTable(BaseModel):
    """The [broker] table of a config file: TOML's own types, no key it does not know."""

    model_config = ConfigDict(extra="forbid", strict=True)

    host: str | None = None
    port: int | None = None
    ws_port: int | None = None
    max_connections: int | None = None
    tls_cert: str | None = None
    tls_key: str | None = None
    max_packet_bytes: int | None = None
    max_queued_messages: int | None = None
    max_queued_bytes: int | None = None


@dataclass(frozen=True)
class BrokerSettings:
    """Where the embedded broker listens; port 0 picks a free port, ws_port None disables ws."""

    host: str = "127.0.0.1"
    port: int = 1883
    ws_port: int | None = 9001
    max_connections: int = -1
    accounts: Accounts | None = field(default=None, repr=False)  # None: anonymous, loopback only
    root: str = DEFAULT_ROOT  # the topic root the accounts' rules are made for
    tls_cert: Path | None = None  # with tls_key: the listeners are mqtts and wss
    tls_key: Path | None = None
    max_packet_bytes: int = MAX_PACKET_BYTES  # a bigger packet disconnects its sender
    max_queued_messages: int = MAX_QUEUED_MESSAGES  # per client; past them, messages are dropped
    max_queued_bytes: int = MAX_QUEUED_BYTES
    # Web pages (origins, e.g. http://127.0.0.1:5000) that may use the websocket listener:
    # without accounts these alone; with, also those on the host the browser reached the
    # broker at (broker/origins.py). `gridfleet up` and `gridfleet broker` pass the dashboard's.
    ws_origins: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("port", "ws_port"):
            value = getattr(self, name)
            if value is not None and not 0 <= value <= 65535:
                raise ConfigError(f"broker {name} {value} is outside 0..65535")
        _ = self.limits  # a limit below 1: ConfigError in one clear line, now
        for origin in self.ws_origins:
            parts = urlsplit(origin)
            if parts.scheme not in ("http", "https") or not parts.hostname or parts.path.strip("/"):
                raise ConfigError(
                    f"--ws-origin {origin!r} is not a web page's origin: give scheme://host[:port], "
                    "e.g. https://fleet.example:5000"
                )
        if self.accounts is None and not is_loopback(self.host):
            raise ConfigError(
                f"listening on {self.host} lets anyone on that network drive the fleet: give "
                "--accounts FILE (make one with 'gridfleet accounts init --scenario FILE --out "
                "FILE'), or listen on 127.0.0.1"
            )
        if (self.tls_cert is None) != (self.tls_key is None):
            raise ConfigError(
                "TLS needs both a certificate and its key (--tls-cert FILE --tls-key FILE; "
                "'gridfleet accounts tls' makes them)"
            )
        if self.tls_cert is not None and self.tls_key is not None:
            server_context(self.tls_cert, self.tls_key)  # a bad file: one clear line, now

    @property
    def limits(self) -> Limits:
        """What one client may cost the broker, as one value."""
        return Limits(self.max_packet_bytes, self.max_queued_messages, self.max_queued_bytes)

    @property
    def tls(self) -> bool:
        """Whether the listeners are mqtts and wss."""
        return self.tls_cert is not None

    def amqtt_config(self) -> dict[str, Any]:
        """The amqtt configuration dictionary (with accounts: their topic rules)."""
        # Each listener says everything: amqtt fills unset keys from the one named `default`.
        tls: dict[str, Any] = {"ssl": False}
        if self.tls_cert is not None:
            tls = {"ssl": True, "certfile": str(self.tls_cert), "keyfile": str(self.tls_key)}
        listeners: dict[str, Any] = {
            "default": {
                "type": "tcp",
                "bind": f"{self.host}:{self.port}",
                "max_connections": self.max_connections,
                **tls,
            },
        }
        if self.ws_port is not None:
            listeners["ws"] = {
                "type": "ws",
                "bind": f"{self.host}:{self.ws_port}",
                "max_connections": self.max_connections,
                **tls,
            }
        # Plugins must be explicit: amqtt's defaults (packet loggers, $SYS) halve throughput.
        if self.accounts is None:
            plugins: dict[str, Any] = {
                "amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}
            }
        else:
            # No auth plugin: the broker's Gate checks the accounts (broker/gate.py), and amqtt
            # with no auth plugin refuses anyone who got past it some other way.
            topics = Topics(self.root)
            allowed = {a.name: rules(a, topics) for a in self.accounts.accounts.values()}
            plugins = {
                "amqtt.plugins.topic_checking.TopicAccessControlListPlugin": {
                    "acl": {name: list(r.subscribe) for name, r in allowed.items()},
                    "publish_acl": {name: list(r.publish) for name, r in allowed.items()},
                },
            }
        return {"listeners": listeners, "plugins": plugins}


def load_settings(path: str | Path, base: BrokerSettings | None = None) -> BrokerSettings:
    """Read a TOML file with a [broker] table (host, port, ws_port, max_connections, tls_cert,
    tls_key, the max_packet_bytes/max_queued_* limits; files are relative to the TOML file)."""
    p = Path(path)
    try:
        data = tomllib.loads(read_text(p, "broker config", ConfigError))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: cannot read broker config: {exc}") from None
    table = data.get("broker", {})
    if not isinstance(table, dict):
        raise ConfigError(f"{p}: [broker] must be a table")
    try:
        settings = _BrokerTable.model_validate(table)
    except ValidationError as exc:
        error = exc.errors()[0]
        key = str(error["loc"][0])
        if error["type"] == "extra_forbidden":
            known = ", ".join(sorted(_BrokerTable.model_fields))
            raise ConfigError(f"{p}: unknown broker setting {key!r} (known: {known})") from None
        kind = "str" if key in ("host", "tls_cert", "tls_key") else "int"
        raise ConfigError(f"{p}: broker setting {key!r} must be {kind}") from None
    changes: dict[str, Any] = settings.model_dump(exclude_unset=True)
    for key in ("tls_cert", "tls_key"):
        if key in changes:  # next to the config file, wherever the broker is started
            changes[key] = p.parent / changes[key]
    return replace(base or BrokerSettings(), **changes)


class EmbeddedBroker:
    """amqtt running in the current event loop; `async with` starts and stops it."""

    def __init__(self, settings: BrokerSettings | None = None) -> None:
        self.settings = settings or BrokerSettings()
        self._broker: Any = None
        self.abandoned = False  # stopped without amqtt finishing its shutdown (see SHUTDOWN_S)
        self.port: int | None = None
        self.ws_port: int | None = None

    @property
    def url(self) -> str:
        """The TCP URL clients connect to."""
        scheme = "mqtts" if self.settings.tls else "mqtt"
        return f"{scheme}://{self.settings.host}:{self.port}"

    @property
    def ws_url(self) -> str | None:
        """The websocket URL (for the dashboard), None when ws is disabled."""
        scheme = "wss" if self.settings.tls else "ws"
        return None if self.ws_port is None else f"{scheme}://{self.settings.host}:{self.ws_port}"

    async def start(self) -> None:
        """Bind the listeners; raises ConfigError when a port cannot be bound."""
        from gridfleet.broker.amqtt_broker import (
            make_broker,  # imported late: amqtt is slow to import
        )

        s = self.settings
        self._broker = make_broker(
            s.amqtt_config(),
            gate=None if s.accounts is None else Gate(s.accounts, root=s.root),
            limits=s.limits,
            ws_origins=s.ws_origins,
        )
        # amqtt's own context asks clients for certificates, which breaks browsers (broker/tls.py).
        self._broker._create_ssl_context = amqtt_listener_context
        amqtt_log = logging.getLogger("amqtt.broker")
        level = amqtt_log.level
        # amqtt logs a bind failure with a traceback; ours below is the one line a user needs.
        amqtt_log.setLevel(logging.CRITICAL)
        try:
            await self._broker.start()
        except Exception as exc:  # amqtt wraps bind errors in its own BrokerError
            self._broker = None
            ports = f"port {self.settings.port}" + (
                f" or {self.settings.ws_port}" if self.settings.ws_port is not None else ""
            )
            raise ConfigError(
                f"broker cannot listen on {self.settings.host} {ports} ({exc}): is another "
                "broker running? Pick other ports (0 picks free ones)"
            ) from None
        finally:
            amqtt_log.setLevel(level)
        self.port = self._bound_port("default")
        self.ws_port = self._bound_port("ws") if self.settings.ws_port is not None else None
        log.debug(
            "broker listening on %s%s", self.url, f" and {self.ws_url}" if self.ws_url else ""
        )

    def allow_origins(self, origins: tuple[str, ...]) -> None:
        """Let the pages of `origins` in from now on, too (a dashboard started after the broker,
        on a port not known before); call it on the broker's loop."""
        self.settings = replace(self.settings, ws_origins=(*self.settings.ws_origins, *origins))
        if self._broker is not None:
            self._broker.ws_origins = self.settings.ws_origins

    def figures(self) -> BrokerFigures | None:
        """Its totals and its state now (None: not running); call it on the broker's loop."""
        return None if self._broker is None else self._broker.figures()

    def _bound_port(self, listener: str) -> int:
        server = self._broker._servers[listener]
        return int(server.instance.sockets[0].getsockname()[1])

    async def stop(self) -> None:
        """Close every connection and the listeners."""
        if self._broker is None:
            return
        broker, self._broker = self._broker, None
        # asyncio.wait, not wait_for: wait_for would wait on for a shutdown that ignores its cancel.
        shutdown = asyncio.ensure_future(broker.shutdown())
        done, _ = await asyncio.wait({shutdown}, timeout=SHUTDOWN_S)
        if done and shutdown.exception() is None:
            log.info("broker stopped")
            return
        self.abandoned = True
        shutdown.cancel()
        for server in broker._servers.values():  # the ports at least are let go
            if server.instance is not None:
                server.instance.close()
        why = (
            f"not done after {SHUTDOWN_S:g} s" if not done else f"failed: {shutdown.exception()!r}"
        )
        log.warning(
            "broker stopped without draining: its shutdown was %s "
            "(messages still queued for clients are dropped)",
            why,
        )

    async def __aenter__(self) -> EmbeddedBroker:
        await self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.stop()
