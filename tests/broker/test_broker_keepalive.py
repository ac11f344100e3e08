"""A client that falls silent is gone after 1.5 keep-alive periods, and its will is sent
(MQTT-3.1.2-24), on the embedded broker as on Mosquitto: the only way the fleet hears of a unit
whose link died without a FIN (a sleeping laptop, a Wi-Fi drop)."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from gridfleet.system.broker_thread import BrokerThread

from support.probe import MqttProbe

pytestmark = pytest.mark.every_broker  # the broker's keep-alive and will

KEEP_ALIVE_S = 2


def test_a_client_silent_for_one_and_a_half_keep_alives_is_gone_and_its_will_is_sent(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    watcher = probe_factory()
    watcher.subscribe(f"{root}/connection")
    silent = MqttProbe(broker.url).will(f"{root}/connection", b"broken", retain=True)
    silent.connect(keepalive=KEEP_ALIVE_S)
    try:
        fell_silent = time.monotonic()
        silent.fall_silent()
        # Before: amqtt 0.12.1 waited on the open link for good, the will never sent.
        will = watcher.wait(f"{root}/connection", lambda m: m.payload == b"broken", timeout=30)
        assert will.at - fell_silent >= KEEP_ALIVE_S, "gone before its keep-alive ran out"
    finally:
        silent.drop()
    # The broker keeps the will, retained, for whoever asks later.
    with MqttProbe(broker.url) as late:
        late.subscribe(f"{root}/connection")
        assert late.wait(f"{root}/connection").payload == b"broken"
