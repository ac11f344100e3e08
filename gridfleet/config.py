"""Broker URLs: `mqtt://host:port` for TCP clients, `ws://host:port/path` for websocket clients.

Over TLS: `mqtts://` (default port 8883) and `wss://`; `?cafile=/path/ca.pem` names the CA that
signed the broker's certificate (without it the system's trusted CAs count). Where a component
takes a broker, it takes a list of them too, comma-separated (the nodes of one cluster): it is
on one at a time and moves to the next when that one dies or stops answering.
"""

from __future__ import annotations

import ipaddress
import os
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from urllib.parse import parse_qs, quote, unquote, urlsplit

from gridfleet.errors import ConfigError

DEFAULT_MQTT_URL = "mqtt://127.0.0.1:1883"
DEFAULT_WS_URL = "ws://127.0.0.1:9001"
_DEFAULT_PORTS = {"mqtt": 1883, "tcp": 1883, "ws": 80, "mqtts": 8883, "wss": 443}
_TLS = ("mqtts", "wss")
_WEBSOCKET = ("ws", "wss")
_OPTIONS = ("cafile",)


@dataclass(frozen=True)
class BrokerURL:
    """Where a broker listens: scheme (`mqtt`, `mqtts`, `ws`, `wss`), host, port, websocket path,
    login and, over TLS, the CA file to trust."""

    scheme: str
    host: str
    port: int
    path: str = "/"
    username: str | None = None
    password: str | None = field(default=None, repr=False)
    ca_file: str | None = None  # TLS only; None: the system's trusted CAs

    @property
    def tls(self) -> bool:
        """Whether the connection is encrypted (mqtts, wss)."""
        return self.scheme in _TLS

    @property
    def websocket(self) -> bool:
        """Whether this is MQTT over websockets (ws, wss)."""
        return self.scheme in _WEBSOCKET

    @property
    def transport(self) -> str:
        """paho's transport name for this URL."""
        return "websockets" if self.websocket else "tcp"

    def __str__(self) -> str:
        # Never the password: this is what logs and messages show.
        tail = self.path if self.websocket and self.path != "/" else ""
        user = f"{self.username}@" if self.username else ""
        return f"{self.scheme}://{user}{self.host}:{self.port}{tail}"


def broker_urls(text: str) -> list[str]:
    """The URLs of a comma-separated list of brokers (one URL is a list of one), as given."""
    return [item.strip() for item in text.split(",")]


def parse_brokers(text: str) -> tuple[BrokerURL, ...]:
    """Parse a comma-separated list of broker URLs; ConfigError naming an empty, bad or repeated
    one, or URLs that log in as different accounts (one component is one account)."""
    items = broker_urls(text)
    if len(items) > 1 and not all(items):
        raise ConfigError(
            f"broker list {redacted(text)!r}: an empty item (two commas, or one at an end)"
        )
    brokers = tuple(parse_broker_url(item) for item in items)
    seen: set[tuple[str, str, int, str]] = set()
    for broker in brokers:
        where = (broker.scheme, broker.host.lower(), broker.port, broker.path)
        if where in seen:
            raise ConfigError(f"broker list {redacted(text)!r}: {broker} is in it twice")
        seen.add(where)
    if len({b.username for b in brokers}) > 1:
        raise ConfigError(
            f"broker list {redacted(text)!r}: every broker of a list logs in as one account"
        )
    return brokers


def broker_login(text: str) -> str | None:
    """The account a broker URL, or a list of them, logs in as (None: anonymous)."""
    return parse_brokers(text)[0].username


def parse_broker_url(url: str) -> BrokerURL:
    """Parse one broker URL; a bad one raises ConfigError saying what is wrong."""
    if "," in url:
        raise ConfigError(f"broker URL {redacted(url)!r}: one URL here, not a list")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        raise ConfigError(f"broker URL {redacted(url)!r}: {exc}") from None
    scheme = parts.scheme.lower()
    if scheme not in _DEFAULT_PORTS:
        raise ConfigError(
            f"broker URL {redacted(url)!r}: scheme must be mqtt://, mqtts://, ws:// or wss://"
        )
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
    ca_file = _ca_file(url, scheme, parts.query)
    path = parts.path or "/"
    return BrokerURL(scheme, parts.hostname, port, path, username, password, ca_file)


def _ca_file(url: str, scheme: str, query: str) -> str | None:
    """The `cafile` option of a URL's query; ConfigError for any other option or a plain scheme."""
    try:
        options = parse_qs(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise ConfigError(f"broker URL {redacted(url)!r}: cannot read options {query!r}") from None
    for name, values in options.items():
        if name not in _OPTIONS:
            raise ConfigError(
                f"broker URL {redacted(url)!r}: unknown option {name!r} (known: cafile)"
            )
        if len(values) != 1 or not values[0]:
            raise ConfigError(f"broker URL {redacted(url)!r}: give one non-empty {name}=FILE")
    ca_file = options.get("cafile", [None])[0]
    if ca_file is not None and scheme not in _TLS:
        raise ConfigError(
            f"broker URL {redacted(url)!r}: a CA file is for TLS: use mqtts:// or wss://"
        )
    # Checked here, where every component reads its URL at start-up, not at the first connect.
    if ca_file is not None and not os.path.isfile(ca_file):
        raise ConfigError(f"{ca_file}: no such CA file ('gridfleet accounts tls' makes one)")
    return ca_file


def each_broker(url: str, change: Callable[[str], str]) -> str:
    """A list of broker URLs (or one) with `change` made to each."""
    return ",".join(change(item) for item in broker_urls(url))


def with_ca_file(url: str, ca_file: str) -> str:
    """`url` (or each of a list) trusting the CA in `ca_file` (an absolute path in `?cafile=`;
    any earlier one goes). In a list that mixes TLS and plain URLs, the TLS ones only."""
    # Absolute: the URL is handed to child processes that may run elsewhere.
    query = "cafile=" + quote(os.path.abspath(ca_file), safe="/")
    any_tls = any(urlsplit(one).scheme.lower() in _TLS for one in broker_urls(url))

    def change(one: str) -> str:
        parts = urlsplit(one)
        if any_tls and parts.scheme.lower() not in _TLS:
            return one  # a plain URL of the list: a CA is not its business
        return parts._replace(query=query).geturl()

    return each_broker(url, change)


def with_credentials(url: str, username: str, password: str) -> str:
    """`url` (or each of a list) logging in as `username` (any credentials it had are replaced)."""
    login = f"{quote(username, safe='')}:{quote(password, safe='')}@"

    def change(one: str) -> str:
        parts = urlsplit(one)
        return parts._replace(netloc=login + parts.netloc.rsplit("@", 1)[-1]).geturl()

    return each_broker(url, change)


def names_owned_id(name: str, client_id: str) -> bool:
    """Whether `client_id` is one account `name` may use: `name`, or `name` followed by '-' or '@'
    and more (protocol.md §10). Where several account names fit, the longest owns it."""
    return client_id == name or client_id.startswith((f"{name}-", f"{name}@"))


# A vehicle's own MQTT client id, as its vendor set it: printable ASCII without spaces.
CLIENT_ID = re.compile(r"[!-~]{1,64}")


def owner_of(client_id: str, names: Iterable[str]) -> str | None:
    """The account that owns `client_id`: the longest name it is, or starts with plus '-' or '@'.

    `unit1-3fa2c1d0` and `coordinator@hall.b` belong to `unit1` and `coordinator`; `unit10-x`
    belongs to `unit10`, not `unit1`.
    """
    owners = [name for name in names if names_owned_id(name, client_id)]
    return max(owners, key=len, default=None)


def owned_client_id(username: str | None, wanted: str) -> str:
    """`wanted`, made one that `username`'s account owns when it logs in with one.

    A broker with accounts lets an account use only client ids it owns (`names_owned_id`: so
    nobody can take over the coordinator's or a unit's connection); `cli-3fa2c1` logging in as
    `operator` becomes `operator-cli-3fa2c1`.
    """
    if not username or names_owned_id(username, wanted):
        return wanted
    return f"{username}-{wanted}"


def names_this_machine(authority: str) -> bool:
    """Whether a Host header (`127.0.0.1:9001`, `[::1]:5000`, `localhost:5000`) names this machine
    by an IP address or `localhost`, as a browser does that was not led there by another name
    (DNS rebinding)."""
    name = host_of(authority)
    if name == "localhost":
        return True
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def host_of(authority: str) -> str:
    """The host of `host:port` (`::1` of `[::1]:9001`), lowercased; "" when there is none."""
    return (urlsplit(f"//{authority}").hostname or "").lower()


def redacted(url: str) -> str:
    """`url` (or each of a list) with any password replaced by `***`, for messages."""

    def hide(one: str) -> str:
        password = urlsplit(one).password
        return one if password is None else one.replace(f":{password}@", ":***@", 1)

    return each_broker(url, hide)


MAX_STEP_S = 60.0


def check_step(step_s: float, flag: str = "--step") -> float:
    """`step_s` when it is a usable step period; otherwise ConfigError in the words every command uses."""
    if not 0 < step_s <= MAX_STEP_S:
        raise ConfigError(
            f"{flag} {step_s:g}: the step period must be in (0, {MAX_STEP_S:g}] seconds"
        )
    return step_s


def is_loopback(host: str) -> bool:
    """Whether `host` is a loopback address (or `localhost`)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
