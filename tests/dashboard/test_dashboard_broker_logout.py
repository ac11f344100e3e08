"""The broker login the page is handed, after logout: on the embedded amqtt and on Mosquitto."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from flask import Flask
from flask.testing import FlaskClient

from gridfleet.accounts import Accounts, default_accounts
from gridfleet.broker.embedded import BrokerSettings
from gridfleet.config import with_credentials
from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.revoke import SessionRevoker
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.protocol import HeaderStamper, Topics, encode
from gridfleet.protocol.messages import BrokerRevoke
from gridfleet.session_login import make_session_password, read_session_password
from gridfleet.system.broker_thread import BrokerThread

from support.mosquitto import mosquitto_with_accounts
from support.probe import MqttProbe, login_refused
from support.wait import wait_for

pytestmark = pytest.mark.every_broker  # whether a login is taken is the broker's to say

ROOT = "logout"
T = Topics(ROOT)
MOSQUITTO_WHY = (
    "Mosquitto checks only its password_file, which cannot verify a per-session password: the "
    "page is handed the account's own, which logout cannot take back; docs/operating.md, "
    "Safety: 'The broker login the page is handed'"
)


@dataclass(frozen=True)
class Broker:
    """A broker with the accounts: its URL (no login in it), and whether it is the embedded one."""

    url: str
    embedded: bool

    def login(self, name: str, password: str) -> str:
        """This broker's URL with a login."""
        return with_credentials(self.url, name, password)


@pytest.fixture(scope="module")
def accounts() -> Accounts:
    return default_accounts(["unit1"])


@pytest.fixture(
    scope="module",
    params=[
        "amqtt",
        pytest.param("mosquitto", marks=pytest.mark.xfail(strict=True, reason=MOSQUITTO_WHY)),
    ],
)
def broker(
    request: pytest.FixtureRequest, accounts: Accounts, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Broker]:
    """A broker with the accounts; the embedded one checks session passwords."""
    if request.param == "amqtt":
        settings = BrokerSettings(port=0, ws_port=None, accounts=accounts, root=ROOT)
        with BrokerThread(settings) as running:
            yield Broker(running.url, embedded=True)
    else:
        directory: Path = tmp_path_factory.mktemp("mosquitto")
        with mosquitto_with_accounts(accounts, T, directory) as url:
            yield Broker(url, embedded=False)


@pytest.fixture
def dashboard(accounts: Accounts) -> Iterator[Callable[[Broker], FlaskClient]]:
    """Factory: the dashboard as `gridfleet up` runs it beside a broker (session passwords on
    its own); its threads that talk to the broker are stopped at the end."""
    apps: list[Flask] = []

    def make(broker: Broker) -> FlaskClient:
        settings = DashboardSettings(
            broker_ws="ws://127.0.0.1:9",
            root=ROOT,
            accounts=accounts,
            audit_broker=broker.url,
            session_passwords=broker.embedded,
        )
        app = create_app(settings)
        apps.append(app)
        return app.test_client()

    yield make
    for app in apps:
        revoker, audit = app.extensions["gridfleet_revoker"], app.extensions["gridfleet_audit"]
        if revoker is not None:
            revoker.stop()
        if audit is not None:  # no coordinator here: it ends once its report's time is up
            audit.stop(timeout=0)


def log_in(web: FlaskClient, broker: Broker, accounts: Accounts) -> str:
    """Log in to the page as the operator; the broker URL with the login the page is handed."""
    login = {"username": "operator", "password": accounts.get("operator").password}
    assert web.post("/api/login", json=login).status_code == 200
    handed = web.get("/api/settings").get_json()["mqtt"]
    return broker.login(handed["username"], handed["password"])


def test_the_broker_login_handed_to_the_page_stops_working_at_logout(
    broker: Broker, accounts: Accounts, dashboard: Callable[[Broker], FlaskClient]
) -> None:
    web = dashboard(broker)
    url = log_in(web, broker, accounts)
    with MqttProbe(url):  # while logged in, the page gets in
        pass
    assert web.post("/api/logout", json={}).status_code == 200
    # What a copy of the page's settings (a shared machine, a log, a script) holds after logout:
    # refused once the broker has heard of the logout (a moment: the dashboard's own link).
    wait_for(lambda: login_refused(url), timeout=5.0, what="the handed login refused after logout")


def test_each_page_session_is_handed_its_own_password(
    broker: Broker, accounts: Accounts, dashboard: Callable[[Broker], FlaskClient]
) -> None:
    if not broker.embedded:
        pytest.xfail(MOSQUITTO_WHY)
    web, other = dashboard(broker), dashboard(broker)
    url, second = log_in(web, broker, accounts), log_in(other, broker, accounts)
    handed = web.get("/api/settings").get_json()["mqtt"]["password"]
    assert handed != accounts.get("operator").password  # the account's never reaches the page
    assert read_session_password(handed) is not None
    assert second != url
    # One browser's logout leaves the other's session, and its login, working.
    assert other.post("/api/logout", json={}).status_code == 200
    wait_for(lambda: login_refused(second), timeout=5.0, what="the second session's login refused")
    with MqttProbe(url):
        pass
    assert web.post("/api/logout", json={}).status_code == 200


def test_a_connection_open_with_the_session_password_is_closed_at_logout(
    broker: Broker, accounts: Accounts, dashboard: Callable[[Broker], FlaskClient]
) -> None:
    if not broker.embedded:
        pytest.xfail(MOSQUITTO_WHY)
    web = dashboard(broker)
    url = log_in(web, broker, accounts)
    operator = broker.login("operator", accounts.get("operator").password)
    with MqttProbe(url) as page, MqttProbe(operator) as console:
        assert page.client.is_connected()
        assert web.post("/api/logout", json={}).status_code == 200
        wait_for(lambda: not page.client.is_connected(), timeout=5.0, what="the page's link closed")
        # The account's own password and connections are untouched: only that session is over.
        assert console.client.is_connected()
        with MqttProbe(operator):
            pass


def test_only_a_dashboard_account_revokes_a_session(
    broker: Broker, accounts: Accounts, dashboard: Callable[[Broker], FlaskClient]
) -> None:
    if not broker.embedded:
        pytest.xfail(MOSQUITTO_WHY)
    web = dashboard(broker)
    url = log_in(web, broker, accounts)
    claim = read_session_password(web.get("/api/settings").get_json()["mqtt"]["password"])
    assert claim is not None
    operator = broker.login("operator", accounts.get("operator").password)
    goal = T.unit("goal", "unit1")
    with MqttProbe(url) as page, MqttProbe(operator, "operator-intruder") as intruder:
        page.subscribe(f"{T.prefix}/#")
        forged = BrokerRevoke(
            header=HeaderStamper("operator-intruder")("revoke"),
            sid=claim.sid,
            expires=claim.expires,
        )
        intruder.publish(T.fleet("revoke"), encode(forged))
        # The broker deals with one client's messages in order: once the page hears the goal
        # published after it, the operator's revocation has been dealt with.
        intruder.publish(goal, b"after the revocation")
        page.wait(goal, lambda m: m.payload == b"after the revocation")
        assert page.client.is_connected()
        assert not page.received(T.fleet("revoke"))  # a revocation is passed to nobody
    with MqttProbe(url):  # the session's login still works
        pass
    assert web.post("/api/logout", json={}).status_code == 200  # the dashboard's own does revoke
    wait_for(lambda: login_refused(url), timeout=5.0, what="the handed login refused after logout")


def test_a_restarted_broker_hears_the_revocations_again(accounts: Accounts) -> None:
    settings = BrokerSettings(port=0, ws_port=None, accounts=accounts, root=ROOT)
    operator = accounts.get("operator")
    with BrokerThread(settings) as running:
        broker = Broker(running.url, embedded=True)
        copy = broker.login(
            "operator", make_session_password("operator", operator.password, "s1", 4_000_000_000)
        )
        with MqttProbe(copy):  # a session password the broker can check
            pass
        login = broker.login("dashboard", accounts.get("dashboard").password)
        revoker = SessionRevoker(login, T, "dashboard").start()
        try:
            revoker.revoke("s1", 4_000_000_000)
            wait_for(lambda: login_refused(copy), timeout=5.0, what="the revoked login refused")
            running.stop()  # forgets what it was told
            running.start()
            wait_for(lambda: revoker.sent >= 2, timeout=10.0, what="the revocation said again")
            wait_for(lambda: login_refused(copy), timeout=5.0, what="refused after the restart")
        finally:
            revoker.stop()


def test_a_connection_made_with_a_session_password_ends_with_the_session(
    accounts: Accounts,
) -> None:
    settings = BrokerSettings(port=0, ws_port=None, accounts=accounts, root=ROOT)
    operator = accounts.get("operator")
    ends = int(time.time()) + 2
    with BrokerThread(settings) as running:
        broker = Broker(running.url, embedded=True)
        page_login = make_session_password("operator", operator.password, "s2", ends)
        with MqttProbe(broker.login("operator", page_login)) as page:
            wait_for(
                lambda: not page.client.is_connected(), timeout=10.0, what="hung up at its end"
            )
            assert time.time() >= ends - 0.5  # by the broker's clock, not earlier
