"""Across a LAN: the dashboard's page on a host of its own, whose link dies without a word.

Broker (TCP and websockets, accounts on), dashboard server, coordinator and units run on the
broker's host; Chromium runs on another host and reaches them by the LAN address, as an
operator's laptop on Wi-Fi does. The page's link is cut at the bridge (no FIN, no RST): the page
must say that it hears nothing, and not blame the units for a silence that is its own.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import expect

from gridfleet.accounts import Accounts, default_accounts, write_accounts
from gridfleet.bench.lan import Host, Lan
from gridfleet.broker.embedded import BrokerSettings
from gridfleet.broker.mosquitto import mosquitto_conf, write_files
from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.server import DashboardServer
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.grid import Cell
from gridfleet.ports import free_port
from gridfleet.protocol import Topics
from gridfleet.system.broker_thread import BrokerThread

from support.browser import CHROMIUM, CHROMIUM_ARGS, VIEWPORT, WAIT_MS, OpenDashboard
from support.lan import LAN_SCENARIO, Processes
from support.mosquitto import MosquittoBroker, running_mosquitto
from support.operator_peer import OperatorPeer
from support.paths import REPO
from support.probe import MqttProbe
from support.security import login
from support.wait import wait_for

# A whole system and a keep-alive's wait (slow); a link cut: what the broker does (every broker).
pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.every_broker]

GRIDFLEET = [sys.executable, "-m", "gridfleet"]
STEP_S = 0.1
UNITS = ("unit1", "unit2")
# The page says it hears nothing after max(3 s, 10 steps) (hearing.js): 3 s at this step, and
# seconds more on a machine shared with other tests.
DEAF_WITHIN_S = 3 + 10
# MQTT.js gives up a connection whose ping goes unanswered after 1.5 keep-alives (10 s, the
# page's as every gridfleet client's: connection.js); at the old 30 s it took up to 45 s.
KEEP_ALIVE_S = 10
RECONNECTING_WITHIN_S = 1.5 * KEEP_ALIVE_S + 10


@pytest.fixture
def accounts() -> Accounts:
    return default_accounts(list(UNITS))


@pytest.fixture
def web_broker(
    broker: BrokerThread, test_lan: Lan, accounts: Accounts, topics: Topics, tmp_path: Path
) -> Iterator[tuple[str, str]]:
    """The kind of broker the test runs on (`broker`'s: amqtt or Mosquitto) with accounts,
    its TCP and websocket listeners on this machine's LAN address: (mqtt URL, ws URL)."""
    address = test_lan.address
    if isinstance(broker, MosquittoBroker):
        ws_port = free_port()
        passwd, acl = write_files(accounts, topics, tmp_path / "mosquitto")
        with running_mosquitto(
            tmp_path / "mosquitto",
            lambda port: mosquitto_conf(passwd, acl, host=address, port=port, ws_port=ws_port),
            host=address,
            on=test_lan.command([]),
            inside=test_lan.call,
        ) as port:
            yield f"mqtt://{address}:{port}", f"ws://{address}:{ws_port}"
        return
    running = BrokerThread(
        BrokerSettings(host=address, port=0, ws_port=0, accounts=accounts, root=topics.root)
    )
    test_lan.call(running.start)  # its event loop's thread, and so its sockets, on the LAN
    try:
        yield running.url, running.ws_url
    finally:
        running.stop()


@contextmanager
def chromium_on(host: Host, tmp_path: Path) -> Iterator[Any]:
    """Headless Chromium running on `host` (Playwright drives it over a pipe, which no
    namespace divides); closed at the end, before the LAN is taken down."""
    from playwright.sync_api import sync_playwright

    wrapper = tmp_path / "chromium-on-host"
    wrapper.write_text(f'#!/bin/sh\nexec ip netns exec {host.netns} {CHROMIUM} "$@"\n')
    wrapper.chmod(0o755)
    # Opened and closed within the test: Playwright's sync API keeps an event loop on this thread.
    with sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=str(wrapper), headless=True, args=CHROMIUM_ARGS
        )
        try:
            yield browser
        finally:
            browser.close()


def badge(page: Any) -> tuple[str, str]:
    """The broker badge: its state and its words."""
    state, text = page.evaluate(
        "() => { const c = document.querySelector('#conn'); return [c.dataset.state, c.textContent]; }"
    )
    return str(state), str(text)


def away(page: Any) -> list[str]:
    """The units the page shows as away or silent."""
    found = page.evaluate(
        """() => [...document.querySelectorAll('#units tbody tr[data-unit]')]
            .filter(tr => tr.classList.contains('silent') || tr.dataset.state === 'away')
            .map(tr => tr.dataset.unit)"""
    )
    return [str(unit) for unit in found]


def watch(page: Any, done: Callable[[tuple[str, str]], bool], timeout: float, what: str) -> None:
    """Poll the page until `done(badge)`; no unit may be shown away meanwhile."""

    def look() -> bool:
        shown = badge(page)
        marked = away(page)
        assert marked == [], f"units shown away for the page's own silence: {marked} ({shown})"
        return done(shown)

    wait_for(look, timeout, interval=0.1, what=what)


def test_a_page_whose_link_dies_says_it_hears_nothing_and_does_not_blame_the_units(
    test_lan: Lan,
    web_broker: tuple[str, str],
    accounts: Accounts,
    topics: Topics,
    tmp_path: Path,
) -> None:
    if not CHROMIUM.exists():  # before anything is started
        pytest.skip(f"{CHROMIUM} is not installed (apt-get install chromium; .ci/run does)")
    mqtt_url, ws_url = web_broker
    accounts_file = tmp_path / "accounts.toml"
    write_accounts(accounts, accounts_file)
    scenario = tmp_path / "lan-page.toml"
    scenario.write_text(LAN_SCENARIO)
    common = ["--broker", mqtt_url, "--accounts", str(accounts_file), "--root", topics.root]
    processes = Processes(tmp_path, test_lan)
    processes.start(
        "coordinator",
        [*GRIDFLEET, "coordinator", "--map", str(REPO / "maps" / "playfield.map"), *common,
         "--step", str(STEP_S), "--db", str(tmp_path / "jobs.db")],
    )  # fmt: skip
    processes.start(
        "robots",
        [*GRIDFLEET, "robots", "--scenario", str(scenario), *common, "--step", str(STEP_S)],
    )
    settings = DashboardSettings(broker_ws=ws_url, root=topics.root, accounts=accounts)
    server = DashboardServer(create_app(settings), host=test_lan.address)
    test_lan.call(server.start)  # listening on the LAN address, where the page's host reaches it
    probe = test_lan.call(MqttProbe(login(mqtt_url, accounts, "operator")).connect)
    operator = OperatorPeer(probe, topics)
    laptop = test_lan.host("web")
    try:
        with chromium_on(laptop, tmp_path) as browser:
            context = browser.new_context(viewport=VIEWPORT)
            page = context.new_page()
            page.set_default_timeout(WAIT_MS)
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            console: list[str] = []
            page.on("console", lambda message: console.append(f"{message.type}: {message.text}"))
            dash = OpenDashboard(page, server, "dash-lan", errors)
            run(dash, laptop, operator, accounts)
            assert errors == []
    except Exception as exc:
        said = "\n".join([*errors, *console][-30:])
        raise AssertionError(f"{exc}\n--- the page said\n{said}\n{processes.tails()}") from exc
    finally:
        processes.stop()
        probe.close()
        server.stop()


def run(dash: OpenDashboard, laptop: Host, operator: OperatorPeer, accounts: Accounts) -> None:
    """The test proper, on the page opened on the laptop's host."""
    page = dash.page
    page.goto(f"{dash.server.url}/?client={dash.client_id}")
    form = page.locator("#login-form")
    try:
        expect(form).to_be_visible()
    except AssertionError as exc:
        # Twice in CI under load the page fetched main.js and nothing after it (no module, no
        # settings), so the form never showed; the cause is not known. What this test is about
        # comes later: one reload, as a person would, and the first look's words kept.
        print(f"the login form did not show; reloading: {exc}")
        page.reload()
        expect(form).to_be_visible()
    form.locator("input[name=username]").fill("dashboard")
    form.locator("input[name=password]").fill(accounts.get("dashboard").password)
    form.locator("button[type=submit]").click()
    dash.wait_connected(30_000)

    # Live: both units on the map, neither away, and unit1 moves when sent somewhere.
    wait_for(lambda: set(dash.drawn_units()) == set(UNITS), 60, what="both units on the map")
    wait_for(lambda: len(page.locator("#units tbody tr[data-unit]").all()) == 2, 30, what="rows")
    wait_for(lambda: away(page) == [], 30, what="no unit away")
    assert operator.set_goal("unit1", Cell(0, 9), timeout=30).accepted
    wait_for(lambda: dash.drawn_units()["unit1"] != (0, 0), 30, what="unit1 moving on the page")

    # The laptop falls off the LAN without a word; the fleet carries on without it.
    laptop.cut()
    cut_at = time.monotonic()
    watch(page, lambda b: b[0] == "deaf", DEAF_WITHIN_S, "the page saying it hears nothing")
    text = badge(page)[1]
    assert "nothing heard for" in text and "this page's link may be down" in text, text
    # MQTT.js's keep-alive then gives the connection up, and the page still blames nobody.
    watch(page, lambda b: b[0] == "reconnecting", RECONNECTING_WITHIN_S, "the keep-alive")
    assert time.monotonic() - cut_at <= RECONNECTING_WITHIN_S + 1

    # Plugged in again: connected, the units live, and the page follows a move.
    laptop.heal()
    dash.wait_connected(60_000)
    wait_for(lambda: away(page) == [], 30, what="no unit away after the heal")
    before = dash.drawn_units()["unit1"]
    assert operator.set_goal("unit1", Cell(9, 9), timeout=30).accepted
    wait_for(lambda: dash.drawn_units()["unit1"] != before, 30, what="unit1 moving again")
    assert badge(page)[0] == "connected"
