"""The embedded broker's metrics: `gridfleet broker --metrics PORT` as a user runs it, scraped while
clients connect, publish, retain, and one subscriber stops reading."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from gridfleet.config import parse_broker_url

from support.probe import MqttProbe
from support.scrape import Scrape, get, parse
from support.wait import wait_for

pytestmark = pytest.mark.amqtt_only  # about the embedded broker itself
BROKER = (sys.executable, "-m", "gridfleet", "broker", "--port", "0", "--no-ws")
# The broker's backlog per client: small, so that a subscriber that does not read fills it.
QUEUED = 16


class BrokerProcess:
    """`gridfleet broker` on free ports with its metrics; the URLs it printed."""

    def __init__(self, folder: Path, *flags: str) -> None:
        config = folder / "broker.toml"
        config.write_text(f"[broker]\nmax_queued_messages = {QUEUED}\n", encoding="utf-8")
        self.out = folder / "broker.out"
        with self.out.open("w") as out:
            self.process = subprocess.Popen(
                [*BROKER, "--config", str(config), *flags],
                stdout=out,
                stderr=subprocess.STDOUT,
                text=True,
            )
        said = wait_for(self._said, timeout=30, what="the broker's addresses")
        assert said is not None
        self.mqtt_url, self.metrics_url = said

    def _said(self) -> tuple[str, str] | None:
        text = self.out.read_text()
        if self.process.poll() is not None:
            raise AssertionError(f"the broker exited: {text}")
        mqtt_url = re.search(r"listening on (mqtt://\S+)", text)
        metrics_url = re.search(r"metrics on (http://\S+)", text)
        return (mqtt_url[1], metrics_url[1]) if mqtt_url and metrics_url else None

    def scrape(self) -> Scrape:
        """Its metrics now."""
        status, body = get(self.metrics_url)
        assert status == 200, body
        return parse(body)

    def stop(self) -> int:
        """SIGTERM, as a supervisor stops it; its exit status (killed: -9)."""
        self.process.terminate()
        try:
            return self.process.wait(30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(10)
            return -9


@pytest.fixture
def broker_process(tmp_path: Path) -> Iterator[BrokerProcess]:
    """The broker with its metrics on a free loopback port; stopped after the test."""
    running = BrokerProcess(tmp_path, "--metrics", "0")
    yield running
    assert running.stop() == 0  # its metrics server does not hold up a clean exit


def not_reading(url: str, topic: str) -> mqtt.Client:
    """A client subscribed to `topic` at QoS 1 that never reads again (nor acknowledges)."""
    where = parse_broker_url(url)
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="slow")
    acked: list[int] = []
    client.on_subscribe = lambda c, u, mid, rcs, p: acked.append(mid)
    client.connect(where.host, where.port)
    _, mid = client.subscribe(topic, 1)

    def step() -> bool:
        client.loop(0.01)
        return mid in acked

    wait_for(step, timeout=10, interval=0, what="the slow client's SUBACK")
    return client


def test_the_broker_counts_clients_messages_retained_queued_and_dropped(
    broker_process: BrokerProcess,
) -> None:
    b = broker_process
    s = b.scrape()
    assert s.types["gridfleet_broker_clients"] == "gauge"
    assert s.types["gridfleet_broker_messages_dropped"] == "counter"
    assert s.value("gridfleet_broker_clients") == 0
    assert s.value("gridfleet_broker_messages_received_total") == 0
    assert s.labels_of("gridfleet_broker_refused_total", "what") == {
        "connect",
        "websocket",
        "publish",
    }

    slow = not_reading(b.mqtt_url, "m/x")
    reader = MqttProbe(b.mqtt_url).connect()
    reader.subscribe("m/x", qos=0)
    publisher = MqttProbe(b.mqtt_url).connect()
    publisher.publish("m/kept", b"kept", retain=True)
    sent = 3 * QUEUED
    began = time.monotonic()
    with publisher.batch():
        for n in range(sent):
            publisher.publish("m/x", str(n).encode(), qos=0)
    wait_for(lambda: len(reader.received("m/x")) == sent, what="every message at the reader")

    s = b.scrape()
    assert s.value("gridfleet_broker_clients") == 3
    assert s.value("gridfleet_broker_sessions") == 3
    assert s.value("gridfleet_broker_retained_messages") == 1
    assert s.value("gridfleet_broker_messages_received_total") == sent + 1
    assert s.value("gridfleet_broker_messages_delivered_total") == 2 * sent
    # slow holds a full backlog (its PUBACKs never come); the rest of its copies were dropped.
    # (amqtt gives a copy up after 5 s without its PUBACK: the backlog empties then.)
    if time.monotonic() - began < 4:
        assert s.value("gridfleet_broker_queued_messages") == QUEUED
        assert s.value("gridfleet_broker_queued_bytes") > 0
    assert s.value("gridfleet_broker_messages_dropped_total") == sent - QUEUED
    assert s.total("gridfleet_broker_refused_total") == 0
    sock = slow.socket()
    if sock is not None:
        sock.close()
    for probe in (reader, publisher):
        probe.close()


def test_the_brokers_metrics_flags_answer_mistakes_in_one_line() -> None:
    done = subprocess.run(
        [*BROKER, "--metrics", "9100", "--metrics-listen", "0.0.0.0"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0].startswith("gridfleet broker: error: serving metrics on 0.0.0.0 lets anyone")
