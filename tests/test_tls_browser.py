"""MQTT.js in real Chromium over wss to the embedded broker with TLS (the dashboard's path)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from broker.certs import make_tls, write_tls
from broker.embedded import BrokerSettings
from dashboard.settings import DashboardSettings
from system.broker_thread import BrokerThread

pytestmark = pytest.mark.browser

# Subscribe, publish, and resolve with what came back (or with why the connection ended).
EXCHANGE = """url => new Promise(done => {
    const client = mqtt.connect(url, {clientId: 'tls-page', reconnectPeriod: 0});
    client.on('connect', () => client.subscribe('tls/page', () => client.publish('tls/page', 'hi')));
    client.on('message', (topic, payload) => { done('got ' + payload); client.end(); });
    client.on('error', error => done('error ' + error.message));
    client.on('close', () => done('closed'));
})"""


@pytest.fixture(scope="module")
def wss_broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[BrokerThread]:
    """The embedded broker with TLS, its websocket listener on a free port."""
    tls = tmp_path_factory.mktemp("tls")
    write_tls(make_tls(), tls)
    settings = BrokerSettings(
        port=0, ws_port=0, tls_cert=tls / "server.pem", tls_key=tls / "server.key"
    )
    with BrokerThread(settings) as running:
        yield running


def test_chromium_speaks_mqtt_over_wss(chromium: Any, wss_broker: BrokerThread) -> None:
    bundle = DashboardSettings().node_modules / "mqtt" / "dist" / "mqtt.min.js"  # global `mqtt`
    if not bundle.exists():
        pytest.fail(f"{bundle} is missing: run 'npm ci' in dashboard/")
    # The page trusts no local CA (a browser has only its own store): certificate errors are
    # ignored here, so what is tested is that the broker's handshake suits a browser at all. It
    # did not while amqtt asked clients for a certificate: Chromium closed the socket.
    context = chromium.new_context(ignore_https_errors=True)
    try:
        page = context.new_page()
        page.set_content("<html><body></body></html>")
        page.add_script_tag(path=str(bundle))
        assert wss_broker.ws_url.startswith("wss://")
        assert page.evaluate(EXCHANGE, wss_broker.ws_url) == "got hi"
    finally:
        context.close()
