"""MQTT.js in real Chromium over wss to the embedded broker with TLS (the dashboard's path), with
the local CA trusted the way a person would: in the browser's certificate store (NSS)."""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from gridfleet.broker.certs import make_tls, write_tls
from gridfleet.broker.embedded import BrokerSettings
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.system.broker_thread import BrokerThread

from support.browser import CHROMIUM, CHROMIUM_ARGS, EXCHANGE, blank_page_server

pytestmark = pytest.mark.browser


def tls_dir(out: Path) -> Path:
    """A new CA and server certificate for 127.0.0.1 and localhost in `out`."""
    write_tls(make_tls(), out)
    return out


def wss_broker(tls: Path) -> BrokerThread:
    """The embedded broker serving `tls`'s certificate, on free ports (not started)."""
    files = {"tls_cert": tls / "server.pem", "tls_key": tls / "server.key"}
    return BrokerThread(BrokerSettings(port=0, ws_port=0, **files))


@pytest.fixture(scope="module")
def trusted(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The certificate files whose CA the browser trusts."""
    return tls_dir(tmp_path_factory.mktemp("trusted"))


@pytest.fixture(scope="module")
def browser(trusted: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """Headless Chromium whose certificate store (in its own HOME) trusts the `trusted` CA."""
    if not CHROMIUM.exists() or shutil.which("certutil") is None:
        pytest.fail("needs chromium and certutil (apt-get install chromium libnss3-tools)")
    home = tmp_path_factory.mktemp("home")
    nssdb = f"sql:{home / '.pki' / 'nssdb'}"
    (home / ".pki" / "nssdb").mkdir(parents=True)
    subprocess.run(["certutil", "-d", nssdb, "-N", "--empty-password"], check=True, timeout=30)
    add = ["certutil", "-d", nssdb, "-A", "-t", "C,,", "-n", "gridfleet test CA"]
    subprocess.run([*add, "-i", str(trusted / "ca.pem")], check=True, timeout=30)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        launched = pw.chromium.launch(
            executable_path=str(CHROMIUM),
            headless=True,
            args=CHROMIUM_ARGS,
            env={**os.environ, "HOME": str(home)},
        )
        yield launched
        launched.close()


def exchange(browser: Any, broker: BrokerThread, url: str) -> str:
    """What MQTT.js in a fresh page gets from `url` (`broker`'s, told the page's origin): `got
    hi`, or how it failed."""
    bundle = DashboardSettings().node_modules / "mqtt" / "dist" / "mqtt.min.js"  # global `mqtt`
    if not bundle.exists():
        pytest.fail(f"{bundle} is missing: run 'npm ci' in dashboard/")
    context = browser.new_context()  # certificate errors count
    try:
        page = context.new_page()
        with blank_page_server() as port:  # a page of this machine's (the broker checks origins)
            broker.allow_origins(f"http://127.0.0.1:{port}")
            page.goto(f"http://127.0.0.1:{port}/")
        page.add_script_tag(path=str(bundle))
        return str(page.evaluate(EXCHANGE, url))
    finally:
        context.close()


def test_chromium_trusting_the_ca_speaks_mqtt_over_wss(browser: Any, trusted: Path) -> None:
    # This failed while amqtt asked clients for a certificate: Chromium closed the socket.
    with wss_broker(trusted) as running:
        for url in (running.ws_url, running.ws_url.replace("127.0.0.1", "localhost")):
            assert url.startswith("wss://")
            assert exchange(browser, running, url) == "got hi", url


def test_chromium_refuses_a_broker_its_ca_did_not_sign(browser: Any, tmp_path: Path) -> None:
    with wss_broker(tls_dir(tmp_path)) as running:
        assert exchange(browser, running, running.ws_url) == "closed"
