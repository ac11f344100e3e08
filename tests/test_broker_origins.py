"""Web pages and the embedded broker's websocket listener: only the dashboard's host gets in.

As found: a page from another site, open in the operator's browser, connected to the no-accounts
default (`make run`), released the operator's stop and queued a job.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from gridfleet.broker.embedded import BrokerSettings
from gridfleet.broker.origins import refusal
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.errors import ConfigError
from gridfleet.system.broker_thread import BrokerThread

from support.browser import CHROMIUM, CHROMIUM_ARGS, EXCHANGE, blank_page_server
from support.probe import MqttProbe


@pytest.mark.parametrize(
    ("host", "origin", "allowed"),
    [
        ("127.0.0.1:9001", None, True),  # not a browser
        ("127.0.0.1:9001", "http://127.0.0.1:5000", True),  # the dashboard
        ("127.0.0.1:9001", "http://localhost:5000", True),  # loopback by another name
        ("[::1]:9001", "http://127.0.0.1:5000", True),
        ("192.168.1.10:9001", "https://192.168.1.10:5000", True),  # on a LAN
        ("192.168.1.10:9001", "http://192.168.1.11:5000", False),  # another machine's page
        ("127.0.0.1:9001", "https://evil.example", False),  # another site
        ("127.0.0.1:9001", "null", False),  # a sandboxed frame, a file
        ("evil.example:9001", "http://evil.example:5000", False),  # DNS rebinding
        ("fleet.lab:9001", "https://fleet.lab:5000", False),  # a name nobody configured
    ],
)
def test_which_pages_may_connect(host: str, origin: str | None, allowed: bool) -> None:
    assert (refusal(host, origin) is None) == allowed


def test_with_accounts_a_lan_broker_is_reached_by_the_machines_name() -> None:
    # People on a LAN use the machine's name; a rebinding page would still need a password.
    assert refusal("fleet.lab:9001", "http://fleet.lab:5000", accounts=True) is None
    assert refusal("fleet.lab:9001", "https://evil.example", accounts=True) is not None


def test_configured_origins_are_let_in_with_their_names() -> None:
    extra = ("https://fleet.lab:5000",)
    assert refusal("fleet.lab:9001", "https://fleet.lab:5000", extra) is None
    assert refusal("fleet.lab:9001", "https://other.lab:5000", extra) is not None


@pytest.fixture(scope="module")
def default_broker() -> Iterator[BrokerThread]:
    """The embedded broker as `gridfleet up` starts it by default: no accounts, ws on loopback."""
    with BrokerThread(BrokerSettings(port=0, ws_port=0)) as running:
        yield running


def probe(url: str, origin: str | None) -> MqttProbe:
    made = MqttProbe(url)
    if origin is not None:
        made.client.ws_set_options(path="/", headers={"Origin": origin})
    return made


def test_a_foreign_origin_cannot_connect_over_websockets(default_broker: BrokerThread) -> None:
    url = default_broker.ws_url
    assert url is not None
    with pytest.raises(AssertionError, match="could not connect"):
        probe(url, "https://evil.example").connect(timeout=5)
    with probe(url, "http://127.0.0.1:5000"), probe(url, None):
        pass  # the dashboard's own page, and a client that is not a browser


@pytest.fixture(scope="module")
def chromium_resolving_evil() -> Iterator[Any]:
    """Headless Chromium in which evil.test resolves to 127.0.0.1 (a DNS-rebinding site)."""
    if not CHROMIUM.exists():
        pytest.fail(f"{CHROMIUM} is not installed (apt-get install chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        args = [*CHROMIUM_ARGS, "--host-resolver-rules=MAP evil.test 127.0.0.1"]
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=args)
        yield browser
        browser.close()


def from_page(browser: Any, page_url: str, broker_url: str) -> str:
    """What MQTT.js on the page at `page_url` gets from `broker_url`."""
    bundle = DashboardSettings().node_modules / "mqtt" / "dist" / "mqtt.min.js"
    if not bundle.exists():
        pytest.fail(f"{bundle} is missing: run 'npm ci' in dashboard/")
    context = browser.new_context()
    try:
        page = context.new_page()
        page.goto(page_url)
        page.add_script_tag(path=str(bundle))
        return str(page.evaluate(EXCHANGE, broker_url))
    finally:
        context.close()


@pytest.mark.browser
def test_chromium_pages_from_other_sites_are_refused(
    chromium_resolving_evil: Any, default_broker: BrokerThread
) -> None:
    url = default_broker.ws_url
    assert url is not None
    ws_port = url.rsplit(":", 1)[1]
    browser = chromium_resolving_evil
    with blank_page_server() as port:
        # The same page at this machine's address, and at a name that resolves to it.
        assert from_page(browser, f"http://127.0.0.1:{port}/", url) == "got hi"
        assert from_page(browser, f"http://evil.test:{port}/", url) == "closed"  # another site
        rebound = f"ws://evil.test:{ws_port}"  # DNS rebinding: evil.test now names 127.0.0.1
        assert from_page(browser, f"http://evil.test:{port}/", rebound) == "closed"


@pytest.mark.parametrize("bad", ["fleet.lab:5000", "ftp://fleet.lab", "https://", "https://a/b"])
def test_a_ws_origin_that_is_no_origin_is_refused_in_one_line(bad: str) -> None:
    with pytest.raises(ConfigError, match="is not a web page's origin: give scheme://host"):
        BrokerSettings(ws_origins=(bad,))
    BrokerSettings(ws_origins=("https://fleet.lab:5000", "http://10.0.0.5"))  # origins are fine
