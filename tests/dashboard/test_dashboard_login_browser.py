"""The dashboard's login in real Chromium against a broker with accounts: nothing before the login
(not even a websocket), then the fleet and the stop's release as the person who logged in."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from playwright.sync_api import expect

from gridfleet.accounts import Accounts, default_accounts
from gridfleet.broker.embedded import BrokerSettings
from gridfleet.config import with_credentials
from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.server import DashboardServer
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.grid import Cell
from gridfleet.protocol import Topics, decode_estop
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread

from support.browser import VIEWPORT, OpenDashboard
from support.fleet_peer import CoordinatorPeer, UnitPeer, publish
from support.paths import MAPS
from support.probe import MqttProbe, login_refused
from support.wait import wait_for

pytestmark = pytest.mark.browser

PLAYFIELD = MAPS / "playfield.toml"
ROOT = "t/login"  # the accounts' rules are made for one root


@pytest.fixture(scope="module")
def accounts() -> Accounts:
    return default_accounts([u.id for u in load_scenario(PLAYFIELD).units])


@pytest.fixture(scope="module")
def secured_broker(accounts: Accounts) -> Iterator[BrokerThread]:
    """A broker that lets in only the accounts, each within its role's rules."""
    with BrokerThread(BrokerSettings(port=0, ws_port=0, accounts=accounts, root=ROOT)) as running:
        yield running


@pytest.fixture
def login_as(secured_broker: BrokerThread, accounts: Accounts) -> Iterator[Any]:
    """Factory: a probe on the secured broker logged in as an account."""
    made: list[MqttProbe] = []

    def make(name: str) -> MqttProbe:
        account = accounts.get(name)
        url = with_credentials(secured_broker.url, account.name, account.password)
        probe = MqttProbe(url).connect()
        made.append(probe)
        return probe

    yield make
    for probe in made:
        probe.close()


@pytest.fixture
def dashboard(
    request: pytest.FixtureRequest, chromium: Any, secured_broker: BrokerThread, accounts: Accounts
) -> Iterator[tuple[OpenDashboard, list[Any]]]:
    """The page of a dashboard with accounts, opened anonymously, and the websockets it opens;
    its param True: the page gets a session's own broker password (`--session-passwords`)."""
    scenario = load_scenario(PLAYFIELD)
    sessions = bool(getattr(request, "param", False))
    settings = DashboardSettings(
        broker_ws=secured_broker.ws_url,
        root=ROOT,
        map=scenario.grid,
        colors={u.id: u.color for u in scenario.units},
        accounts=accounts,
        audit_broker=secured_broker.url if sessions else None,
        session_passwords=sessions,
    )
    server = DashboardServer(create_app(settings)).start()
    context = chromium.new_context(viewport=VIEWPORT)
    page = context.new_page()
    page.set_default_timeout(10000)
    sockets: list[Any] = []
    page.on("websocket", lambda ws: sockets.append(ws))
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(f"{server.url}/?client=dash-login")
    yield OpenDashboard(page, server, "dash-login", errors), sockets
    context.close()
    server.stop()
    assert errors == []


def log_in(page: Any, user: str, password: str) -> None:
    form = page.locator("#login-form")
    form.locator("input[name=username]").fill(user)
    form.locator("input[name=password]").fill(password)
    form.locator("button[type=submit]").click()


def test_anonymous_page_shows_the_login_and_opens_no_mqtt_connection(
    dashboard: tuple[OpenDashboard, list[Any]], accounts: Accounts
) -> None:
    dash, sockets = dashboard
    page = dash.page
    expect(page.locator("#login-form")).to_be_visible()
    expect(page.locator("#map-pane")).to_be_hidden()
    expect(page.locator("#stop")).to_be_hidden()
    log_in(page, "operator", "not the password at all")
    expect(page.locator("#login-message")).to_have_text("wrong user name or password")
    log_in(page, "unit1", accounts.get("unit1").password)
    expect(page.locator("#login-message")).to_contain_text("log in with an operator")
    expect(page.locator("#login-form")).to_be_visible()
    html = page.content()
    assert not any(a.password in html for a in accounts.accounts.values())
    # Every answer the page waited for has come: a connection would have been opened by now.
    assert sockets == []
    expect(page.locator("#conn")).to_have_attribute("data-state", "connecting")


@pytest.mark.parametrize(
    "dashboard", [False, True], indirect=True, ids=["account-password", "session-password"]
)
def test_logged_in_page_shows_the_fleet_releases_the_stop_and_logs_out(
    dashboard: tuple[OpenDashboard, list[Any]],
    login_as: Any,
    accounts: Accounts,
    secured_broker: BrokerThread,
) -> None:
    dash, sockets = dashboard
    page = dash.page
    topics = Topics(ROOT)
    coordinator = login_as("coordinator")
    coordinator.subscribe(topics.fleet("estop"))
    publish(coordinator, "estop", topics.fleet("estop"), b"engaged|coordinator|test stop")
    unit = UnitPeer(login_as("unit1"), topics, "unit1")
    unit.connection("online")
    unit.state(Cell(0, 0))
    CoordinatorPeer(coordinator, topics).status("online")

    log_in(page, "operator", accounts.get("operator").password)
    dash.wait_connected()
    expect(page.locator("#login")).to_be_hidden()
    expect(page.locator("#user")).to_have_text("operator")
    assert len(sockets) == 1 and sockets[0].url.startswith(secured_broker.ws_url)
    wait_for(lambda: dash.drawn_units().get("unit1") == (0, 0), what="unit1 drawn at [0, 0]")
    expect(page.locator("#units tr[data-unit='unit1']")).to_be_visible()

    # The stop engaged elsewhere shows; the operator releases it, under the operator's account.
    expect(page.locator("body")).to_have_attribute("data-estop", "engaged")
    dash.hold_release()
    # Reaches the coordinator only if the broker let the page's account write the latch.
    coordinator.wait(topics.fleet("estop"), lambda m: not decode_estop(m.payload).engaged)
    expect(page.locator("body")).to_have_attribute("data-estop", "released")
    # And STOP on the page engages it: the latch names the page's own id, which the operator
    # account owns (a fixed name was dropped by the broker: the stop must always get through).
    dash.press_stop()
    page_id = page.evaluate("document.body.dataset.clientId")
    by_page = (True, page_id)
    coordinator.wait(
        topics.fleet("estop"),
        lambda m: (decode_estop(m.payload).engaged, decode_estop(m.payload).by) == by_page,
    )
    expect(page.locator("body")).to_have_attribute("data-estop", "engaged")
    handed = page.evaluate("fetch('/api/settings').then(r => r.json()).then(b => b.mqtt)")
    own = handed["password"] == accounts.get("operator").password
    assert own != (dash.server.app.extensions["gridfleet_revoker"] is not None)

    page.locator("#logout").click()
    expect(page.locator("#login-form")).to_be_visible()
    # The page closes its broker connection and reloads: the closed socket, or (when the close
    # takes longer than the page's 1 s wait, on a loaded machine) the document that held it is
    # gone, which ends its connections too. Playwright reports no close for those.
    reloaded = page.evaluate("performance.getEntriesByType('navigation')[0].type")
    assert sockets[0].is_closed() or reloaded == "reload", reloaded
    assert len(sockets) == 1  # the reloaded page opened none
    status = page.evaluate("fetch('/api/settings').then(r => r.status)")
    assert status == 401
    if not own:  # a copy of what the page was handed opens nothing now
        copy = with_credentials(secured_broker.url, handed["username"], handed["password"])
        wait_for(lambda: login_refused(copy), timeout=5.0, what="the handed login refused")
