"""Web pages and the embedded broker's websocket listener: only the dashboard's host gets in.

As found: a page from another site, open in the operator's browser, connected to the no-accounts
default (`make run`), released the operator's stop and queued a job.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from gridfleet.broker import cli as broker_cli
from gridfleet.broker.certs import make_tls, write_tls
from gridfleet.broker.embedded import BrokerSettings
from gridfleet.broker.origins import dashboard_origins, refusal
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.errors import ConfigError
from gridfleet.ports import free_port
from gridfleet.system.broker_thread import BrokerThread

from support.browser import CHROMIUM, CHROMIUM_ARGS, EXCHANGE, blank_page_server
from support.output import Output
from support.probe import MqttProbe

DASHBOARD_PORT = free_port()  # the dashboard of `default_broker` (served or not)


DASHBOARD = ("http://127.0.0.1:5000", "http://localhost:5000")  # `gridfleet up`'s, by default


@pytest.mark.parametrize(
    ("host", "origin", "allowed"),
    [
        ("127.0.0.1:9001", None, True),  # not a browser
        ("127.0.0.1:9001", "http://127.0.0.1:9001", True),  # paho: the listener's own address
        ("127.0.0.1:9001", "http://127.0.0.1:5000", True),  # the dashboard
        ("127.0.0.1:9001", "http://localhost:5000", True),  # the dashboard by its other name
        ("localhost:9001", "http://LOCALHOST:5000/", True),
        ("[::1]:9001", "http://127.0.0.1:5000", True),
        ("127.0.0.1:9001", "http://localhost:5001", False),  # another page of this machine
        ("127.0.0.1:9001", "http://127.0.0.1:8080", False),
        ("127.0.0.1:9001", "http://127.0.0.1", False),
        ("127.0.0.1:9001", "https://127.0.0.1:5000", False),  # another scheme is another page
        ("127.0.0.1:9001", "https://evil.example", False),  # another site
        ("127.0.0.1:9001", "null", False),  # a sandboxed frame, a file
        ("evil.example:9001", "http://evil.example:5000", False),  # DNS rebinding
        ("fleet.lab:9001", "https://fleet.lab:5000", False),  # a name nobody configured
    ],
)
def test_without_accounts_only_the_dashboards_exact_origin_may_connect(
    host: str, origin: str | None, allowed: bool
) -> None:
    # As found: any page of this machine, on any port, counted as the dashboard's.
    assert (refusal(host, origin, DASHBOARD) is None) == allowed


def test_a_default_port_is_no_part_of_an_origin() -> None:
    assert refusal("127.0.0.1:9001", "http://127.0.0.1", ("http://127.0.0.1:80",)) is None
    assert refusal("127.0.0.1:9001", "https://localhost:443", ("https://localhost",)) is None
    assert refusal("127.0.0.1:9001", "http://127.0.0.1:80", ("https://127.0.0.1",)) is not None


def test_the_dashboards_origins_are_its_scheme_names_and_port() -> None:
    assert dashboard_origins(5000) == DASHBOARD
    assert dashboard_origins(5443, tls=True) == ("https://127.0.0.1:5443", "https://localhost:5443")
    assert dashboard_origins(80, hosts=("::1", "localhost")) == ("http://[::1]", "http://localhost")


@pytest.mark.parametrize(
    ("host", "origin", "allowed"),
    [
        ("127.0.0.1:9001", "http://127.0.0.1:5000", True),
        ("127.0.0.1:9001", "http://localhost:5001", True),  # loopback is one host, as before
        ("192.168.1.10:9001", "https://192.168.1.10:5000", True),  # on a LAN
        ("192.168.1.10:9001", "http://192.168.1.11:5000", False),  # another machine's page
        ("127.0.0.1:9001", "https://evil.example", False),
        ("127.0.0.1:9001", "null", False),
    ],
)
def test_with_accounts_pages_of_the_brokers_own_host_may_connect(
    host: str, origin: str | None, allowed: bool
) -> None:
    # A page there still needs a password: the rule stays as it was.
    assert (refusal(host, origin, accounts=True) is None) == allowed


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
    """The embedded broker as `gridfleet up` starts it by default: no accounts, ws on loopback,
    the dashboard's origins on its port (a free one here)."""
    settings = BrokerSettings(port=0, ws_port=0, ws_origins=dashboard_origins(DASHBOARD_PORT))
    with BrokerThread(settings) as running:
        yield running


def probe(url: str, origin: str | None) -> MqttProbe:
    made = MqttProbe(url)
    if origin is not None:
        made.client.ws_set_options(path="/", headers={"Origin": origin})
    return made


def test_a_foreign_origin_cannot_connect_over_websockets(default_broker: BrokerThread) -> None:
    url = default_broker.ws_url
    with pytest.raises(AssertionError, match="could not connect"):
        probe(url, "https://evil.example").connect(timeout=5)
    with probe(url, f"http://127.0.0.1:{DASHBOARD_PORT}"), probe(url, None):
        pass  # the dashboard's own page, and a client that is not a browser


def test_a_page_on_another_local_port_cannot_connect_over_websockets(
    default_broker: BrokerThread,
) -> None:
    # As found: a page from http://localhost:<another port> connected to the no-accounts
    # default, released the operator's stop and queued jobs.
    url, other = default_broker.ws_url, free_port()
    for page in (f"http://localhost:{other}", f"http://127.0.0.1:{other}"):
        with pytest.raises(AssertionError, match="could not connect"):
            probe(url, page).connect(timeout=5)
    for page in dashboard_origins(DASHBOARD_PORT):
        with probe(url, page):
            pass


def broker_settings(*argv: str) -> BrokerSettings:
    """What `gridfleet broker ARGV` would run."""
    parser = argparse.ArgumentParser()
    broker_cli.add_arguments(parser)
    return broker_cli.settings_from(parser.parse_args(list(argv)))


def test_gridfleet_broker_takes_the_default_dashboards_pages_or_those_it_is_given(
    tmp_path: Path,
) -> None:
    assert broker_settings().ws_origins == DASHBOARD
    given = broker_settings("--ws-origin", "https://fleet.lab:8443")
    assert given.ws_origins == ("https://fleet.lab:8443",)
    write_tls(make_tls(), tmp_path)
    tls = broker_settings(
        "--tls-cert", str(tmp_path / "server.pem"), "--tls-key", str(tmp_path / "server.key")
    )
    assert tls.ws_origins == ("https://127.0.0.1:5000", "https://localhost:5000")


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_gridfleet_up_lets_in_its_own_dashboards_page_alone(
    tmp_path: Path, playfield: Path
) -> None:
    # `up --port 0` too: the broker must know the port the dashboard will be on.
    argv = ["up", "--no-robots", "--mqtt-port", "0", "--ws-port", "0", "--port", "0"]
    argv += ["--scenario", str(playfield), "--db", str(tmp_path / "jobs.db")]
    proc = subprocess.Popen(
        [sys.executable, "-m", "gridfleet", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    out = Output(proc)
    try:
        ws = out.wait(r"listening on mqtt://\S+ and (ws://\S+)", timeout=90)[1]
        page = out.wait(r"gridfleet is running: open (http://127\.0\.0\.1:(\d+))", timeout=90)
        port = int(page[2])
        for origin in dashboard_origins(port):
            with probe(ws, origin):
                pass
        for other in (f"http://localhost:{free_port()}", f"http://127.0.0.1:{port + 1}"):
            with pytest.raises(AssertionError, match="could not connect"):
                probe(ws, other).connect(timeout=5)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(30)


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
def test_chromium_pages_from_other_sites_and_ports_are_refused(
    chromium_resolving_evil: Any, default_broker: BrokerThread
) -> None:
    browser = chromium_resolving_evil
    with blank_page_server() as port:
        page = f"http://127.0.0.1:{port}/"
        # A page of this machine that is not the dashboard's: refused.
        assert from_page(browser, page, default_broker.ws_url) == "closed"
        # The same page as the dashboard of a broker that knows its origin, and at a name that
        # resolves to it.
        origins = (f"http://127.0.0.1:{port}",)
        with BrokerThread(BrokerSettings(port=0, ws_port=0, ws_origins=origins)) as broker:
            url = broker.ws_url
            assert from_page(browser, page, url) == "got hi"
            assert from_page(browser, f"http://evil.test:{port}/", url) == "closed"  # another site
            rebound = f"ws://evil.test:{url.rsplit(':', 1)[1]}"  # DNS rebinding: evil.test names 127.0.0.1
            assert from_page(browser, f"http://evil.test:{port}/", rebound) == "closed"


@pytest.mark.parametrize("bad", ["fleet.lab:5000", "ftp://fleet.lab", "https://", "https://a/b"])
def test_a_ws_origin_that_is_no_origin_is_refused_in_one_line(bad: str) -> None:
    with pytest.raises(ConfigError, match="is not a web page's origin: give scheme://host"):
        BrokerSettings(ws_origins=(bad,))
    BrokerSettings(ws_origins=("https://fleet.lab:5000", "http://10.0.0.5"))  # origins are fine
