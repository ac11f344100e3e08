"""What the page needs to know (broker, topic root, map, who logs in): built and checked without
any I/O."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from gridfleet.accounts import Account, Accounts
from gridfleet.config import (
    BrokerURL,
    each_broker,
    owned_client_id,
    parse_broker_url,
    parse_brokers,
    redacted,
)
from gridfleet.dashboard.login import LOGIN_ROLES
from gridfleet.errors import ConfigError
from gridfleet.grid import GridMap
from gridfleet.protocol import Topics, validate_id
from gridfleet.protocol.constants import DEFAULT_ROOT

PACKAGE_DIR = Path(__file__).resolve().parent
NODE_MODULES = PACKAGE_DIR / "node_modules"  # the checkout's (npm ci)
MQTT_BUNDLE = Path("mqtt") / "dist" / "mqtt.esm.js"
# An installed wheel's copy: its build takes it from node_modules (setup.py).
BUILT_BUNDLE = PACKAGE_DIR / "vendor" / "mqtt.esm.js"
INSTALL_HINT = (
    "MQTT.js is not installed: run 'npm ci' in the dashboard/ folder "
    "(or 'make install' at the top of the repository), then reload the page."
)
LOGIN_FIRST = "log in to see the fleet"
# Who may read the audit trail (protocol.md §6.8), and so see the page's Audit view.
AUDIT_ROLES = ("operator", "dashboard")
# Who may change the fleet from the page (protocol.md §10: the roles that may send requests).
CHANGE_ROLES = ("operator", "dashboard")
# A broker listening on every address: the browser reaches it where it reached the page.
WILDCARD_HOSTS = ("0.0.0.0", "::")


@dataclass(frozen=True)
class DashboardSettings:
    """Where the page finds the broker, which fleet it shows, and an optional starting map."""

    broker_ws: str = "ws://127.0.0.1:9001"
    root: str = DEFAULT_ROOT
    client_prefix: str = "dashboard"
    map: GridMap | None = None
    colors: dict[str, str] = field(default_factory=dict)
    node_modules: Path = NODE_MODULES
    # With accounts, people log in before the page gets any broker credentials.
    accounts: Accounts | None = field(default=None, repr=False)
    # Their file: the HTTP API reads it again when it changes (a revoked token stops at once).
    accounts_file: Path | None = None
    secret_key: bytes | None = field(default=None, repr=False)  # None: a random one per start
    https: bool = False  # the page is served over HTTPS: its cookie goes over HTTPS only
    # Where the dashboard itself reports logins for the audit (with accounts; None: nowhere).
    audit_broker: str | None = None
    # The broker checks page sessions' own passwords (the embedded one, with accounts): the page
    # gets one per session, taken back at logout, instead of the account's (session_login.py).
    session_passwords: bool = False

    def __post_init__(self) -> None:
        brokers = parse_brokers(self.broker_ws)  # a bad, empty or repeated item, named
        for url in brokers:
            self._check_page_broker(url, len(brokers) > 1)
        if self.audit_broker is not None:
            parse_brokers(self.audit_broker)
        if self.accounts is not None and not any(
            a.role in LOGIN_ROLES for a in self.accounts.accounts.values()
        ):
            raise ConfigError(
                "the accounts have no operator or dashboard account: nobody could log in "
                "('gridfleet accounts add NAME --role operator --file FILE')"
            )
        if self.session_passwords:
            self._check_session_passwords()
        Topics(self.root)  # raises ProtocolError naming a bad root
        validate_id(self.client_prefix, "client id prefix")

    def _check_page_broker(self, url: BrokerURL, in_list: bool) -> None:
        """Refuse a broker URL (`url`, one of --broker-ws's) the browser cannot use as given."""
        where = f" (in the list {redacted(self.broker_ws)!r})" if in_list else ""
        if not url.websocket:
            raise ConfigError(
                f"dashboard broker URL {str(url)!r}{where}: the page needs a websocket URL, "
                "ws://host:port or wss://host:port"
            )
        if url.username is not None:
            raise ConfigError(
                f"dashboard broker URL {url}{where}: no login in the URL (every visitor would "
                "get it): give --accounts FILE and people log in at the page"
            )
        if url.ca_file is not None:
            raise ConfigError(
                f"dashboard broker URL {url}{where}: a browser trusts a CA only from its own "
                "certificate store: import the CA file there and leave out ?cafile="
            )

    def _check_session_passwords(self) -> None:
        """Session passwords need accounts, a dashboard account and a broker to tell logouts."""
        if self.accounts is None:
            raise ConfigError(
                "session passwords are for a dashboard with accounts: give --accounts"
            )
        if not any(a.role == "dashboard" for a in self.accounts.accounts.values()):
            raise ConfigError(
                "session passwords are taken back at logout by a dashboard account, and the "
                "accounts have none ('gridfleet accounts add dashboard --role dashboard')"
            )
        if self.audit_broker is None:
            raise ConfigError(
                "session passwords need the broker the dashboard tells of logouts (--audit-broker)"
            )

    @property
    def mqtt_bundle(self) -> Path:
        """Path of the MQTT.js browser bundle: inside node_modules, else the wheel's copy."""
        bundle = self.node_modules / MQTT_BUNDLE
        if self.node_modules == NODE_MODULES and not bundle.is_file() and BUILT_BUNDLE.is_file():
            return BUILT_BUNDLE
        return bundle


def browser_broker_url(broker_ws: str, page_host: str | None) -> str:
    """The broker's websocket URL (or each of a list) as the browser reaches it.

    A broker on a wildcard address (0.0.0.0) is reached at the host the page came from (its Host
    header): the dashboard cannot know which of the machine's addresses a browser used.
    """
    host = urlsplit(f"//{page_host}").hostname if page_host else None

    def reached(one: str) -> str:
        url = parse_broker_url(one)
        if url.host not in WILDCARD_HOSTS or not host:
            return one
        netloc = f"[{host}]" if ":" in host else host
        return urlsplit(one)._replace(netloc=f"{netloc}:{url.port}").geturl()

    return each_broker(broker_ws, reached)


def settings_payload(
    settings: DashboardSettings,
    bundle_present: bool,
    user: Account | None = None,
    page_host: str | None = None,
    broker_password: str | None = None,
) -> dict[str, Any]:
    """The JSON body of /api/settings; with accounts, for a logged-in `user` only.

    The page connects to the broker as the person who logged in (their own account), not as one
    shared dashboard account: the broker's rules and logs then apply to each person, and removing
    a person's account from the file shuts them out of the broker as well as the page.
    `broker_password`: this session's own (session_login.py), handed out instead of the account's.
    """
    assert settings.accounts is None or user is not None, "no settings before the login"
    grid = settings.map
    return {
        "broker_ws": browser_broker_url(settings.broker_ws, page_host),
        "login": {
            "required": settings.accounts is not None,
            "user": None if user is None else user.name,
        },
        # Whether the page shows the Audit view: the audit is for operator and dashboard accounts
        # (protocol.md §6.8); without accounts anybody may read it.
        "audit": user is None or user.role in AUDIT_ROLES,
        # Whether the page offers what changes the fleet beyond its forms (closing and opening
        # zones): the people's accounts; a viewer's page shows the zones without buttons.
        "may_change": user is None or user.role in CHANGE_ROLES,
        "mqtt": None
        if user is None
        else {"username": user.name, "password": broker_password or user.password},
        "root": settings.root,
        "prefix": Topics(settings.root).prefix,
        "client_prefix": owned_client_id(
            None if user is None else user.name, settings.client_prefix
        ),
        "map": None
        if grid is None
        else {
            "name": grid.name,
            "width": grid.width,
            "height": grid.height,
            "rows": grid.rows(),
            "obstacles": [],
        },
        "colors": dict(settings.colors),
        "mqtt_js": {"available": bundle_present, "hint": None if bundle_present else INSTALL_HINT},
    }
