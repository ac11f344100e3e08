"""The embedded broker carries retained messages between real clients: paho, mosquitto, websockets."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import shutil
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
import websockets

from gridfleet.broker import cli as broker_cli
from gridfleet.broker import embedded
from gridfleet.broker.embedded import BrokerSettings, load_settings
from gridfleet.bus import make_client
from gridfleet.errors import ConfigError
from gridfleet.system.broker_thread import BrokerThread

from support.probe import MqttProbe
from support.wait import WaitTimeout, async_wait_for, wait_for

pytestmark = pytest.mark.every_broker  # about what a broker does

needs_mosquitto = pytest.mark.skipif(
    not shutil.which("mosquitto_pub"),
    reason="mosquitto-clients not installed (.ci/run installs it)",
)


def test_paho_clients_exchange_a_retained_message(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    topic = f"{root}/retained"
    probe_factory().publish(topic, b"kept", retain=True)
    late = probe_factory()
    late.subscribe(topic)
    seen = late.wait(topic)
    assert (seen.payload, seen.retain) == (b"kept", True)


def test_websocket_client_sees_what_a_tcp_client_retained(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    topic = f"{root}/ws"
    probe_factory().publish(topic, b"over tcp", retain=True)
    ws = probe_factory(broker.ws_url)
    ws.subscribe(topic)
    assert ws.wait(topic).payload == b"over tcp"
    ws.publish(f"{topic}/back", b"over ws", retain=True)
    tcp = probe_factory()
    tcp.subscribe(f"{topic}/back")
    assert tcp.wait(f"{topic}/back").payload == b"over ws"


@needs_mosquitto
def test_mosquitto_clients_exchange_a_retained_message_with_paho(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    host, port = "127.0.0.1", str(broker.port)
    subprocess.run(
        [
            "mosquitto_pub",
            "-h",
            host,
            "-p",
            port,
            "-t",
            f"{root}/from-mosq",
            "-m",
            "hello from mosquitto_pub",
            "-r",
            "-q",
            "1",
        ],
        check=True,
        timeout=10,
    )
    paho = probe_factory()
    paho.subscribe(f"{root}/from-mosq")
    assert paho.wait(f"{root}/from-mosq").payload == b"hello from mosquitto_pub"

    paho.publish(f"{root}/from-paho", b"hello from paho", retain=True)
    out = subprocess.run(
        [
            "mosquitto_sub",
            "-h",
            host,
            "-p",
            port,
            "-t",
            f"{root}/from-paho",
            "-C",
            "1",
            "-W",
            "10",
            "-v",
        ],
        check=True,
        timeout=15,
        capture_output=True,
        text=True,
    )
    assert out.stdout.strip() == f"{root}/from-paho hello from paho"


def test_late_client_sees_every_retained_topic_at_once(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    writer = probe_factory()
    for i in range(20):
        writer.publish(f"{root}/units/u{i}/state", f"s{i}".encode(), retain=True)

    def a_late_client_sees_all() -> bool:
        """A client subscribing now is given all 20 at once (within a second)."""
        late = probe_factory()
        late.subscribe(f"{root}/units/+/state")
        every = [f"{root}/units/u{i}/state" for i in range(20)]
        try:
            wait_for(lambda: all(late.received(t) for t in every), 1.0)
        except WaitTimeout:
            return False
        return True

    # On aedes' cluster the store is shared, but a retained message may reach it a moment after
    # its PUBACK: a client on another instance that subscribed at once missed the last ones (once
    # in two runs of the cluster lane), and one a moment later has them all. A single broker
    # gives them to the first.
    wait_for(a_late_client_sees_all, 10, what="a late client given every retained topic")


def test_broker_restarts_on_the_same_ports(fresh_broker: BrokerThread) -> None:
    port, ws_port = fresh_broker.port, fresh_broker.ws_port
    fresh_broker.restart()
    assert (fresh_broker.port, fresh_broker.ws_port) == (port, ws_port)
    with MqttProbe(fresh_broker.url) as probe:
        probe.subscribe("x/y")


def test_cli_broker_starts_prints_its_urls_and_stops_cleanly(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "gridfleet", "broker", "--port", "0", "--ws-port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        match = re.search(r"listening on (mqtt://\S+) and (ws://\S+)", line)
        assert match, line
        with MqttProbe(match.group(1)) as tcp, MqttProbe(match.group(2)) as ws:
            tcp.publish("cli/t", b"1", retain=True)
            ws.subscribe("cli/t")
            assert ws.wait("cli/t").payload == b"1"
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=15)
    assert proc.returncode == 0, err
    assert "Traceback" not in err


def test_settings_come_from_a_config_file(tmp_path: Path) -> None:
    path = tmp_path / "broker.toml"
    path.write_text('[broker]\nport = 1999\nws_port = 9999\nhost = "127.0.0.1"\n')
    assert load_settings(path) == BrokerSettings(port=1999, ws_port=9999)
    path.write_text("[broker]\nmax_packet_bytes = 65536\nmax_queued_messages = 50\n")
    limited = load_settings(path)
    assert (limited.max_packet_bytes, limited.max_queued_messages) == (65536, 50)


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("[broker]\nport = 'x'\n", "broker setting 'port' must be int"),
        ("[broker]\nport = true\n", "broker setting 'port' must be int"),
        ("[broker]\nhost = 127\n", "broker setting 'host' must be str"),
        ("broker = 3\n", r"\[broker\] must be a table"),
        ("[broker]\nprot = 1\n", "unknown broker setting 'prot'"),
        ("[broker]\nport = 70000\n", "outside 0..65535"),
        ("[broker]\nmax_queued_messages = 0\n", "max_queued_messages 0 must be at least 1"),
        ("[broker\n", "cannot read broker config"),
    ],
)
def test_bad_config_files_are_refused(tmp_path: Path, text: str, problem: str) -> None:
    path = tmp_path / "broker.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=problem):
        load_settings(path)


def test_a_taken_port_is_a_clear_error(broker: BrokerThread) -> None:
    taken = BrokerThread(BrokerSettings(port=broker.port, ws_port=None))
    with pytest.raises(ConfigError, match="cannot listen"):
        taken.start()


def test_a_new_client_gets_only_the_retained_messages_it_subscribed_to(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    # amqtt 0.12.1 replays every filter's retained messages to each new client; ours must not.
    probe_factory().publish(f"{root}/a", b"for a", retain=True)
    probe_factory().publish(f"{root}/b", b"for b", retain=True)
    first = probe_factory()
    first.subscribe(f"{root}/a")
    first.wait(f"{root}/a")
    second = probe_factory()
    second.subscribe(f"{root}/b")
    second.wait(f"{root}/b")
    # The retained message of b arrived after SUBACK; a leak of a would have come before it.
    assert second.received(f"{root}/a") == []
    assert len(second.received(f"{root}/b")) == 1


def test_a_busy_port_is_one_line_and_exit_2(broker: BrokerThread) -> None:
    # The session broker holds its port: a second broker on it must say so, not dump a traceback.
    out = subprocess.run(
        [sys.executable, "-m", "gridfleet", "broker", "--port", str(broker.port), "--no-ws"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip().count("\n") == 0 and "Traceback" not in out.stderr + out.stdout
    assert f"cannot listen on 127.0.0.1 port {broker.port}" in out.stderr


async def test_a_broker_whose_shutdown_hangs_still_stops_within_its_bound(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # amqtt drains its whole broadcast queue on shutdown; after an overload that outlasted the
    # supervisor's 15 s wait after SIGTERM (the chaos soak saw it).
    monkeypatch.setattr(embedded, "SHUTDOWN_S", 0.2)
    broker = embedded.EmbeddedBroker(BrokerSettings(port=0, ws_port=None))
    await broker.start()
    real_shutdown = broker._broker.shutdown

    async def draining_for_ever() -> None:
        await asyncio.Event().wait()

    broker._broker.shutdown = draining_for_ever
    try:
        await asyncio.wait_for(broker.stop(), 5)
        assert broker.abandoned
        assert "stopped without draining" in caplog.text
    finally:
        await real_shutdown()


async def test_a_shutdown_that_ignores_its_cancel_still_lets_the_ports_go(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # asyncio.wait_for waits for the cancelled shutdown to end: one that never ends held the stop
    # (and its ports) for good, so a restart on the same port failed.
    monkeypatch.setattr(embedded, "SHUTDOWN_S", 0.2)
    broker = embedded.EmbeddedBroker(BrokerSettings(port=0, ws_port=None))
    await broker.start()
    port = broker.port
    release = asyncio.Event()

    async def deaf_to_cancel() -> None:
        while not release.is_set():
            with contextlib.suppress(asyncio.CancelledError):
                await release.wait()

    inner, broker._broker.shutdown = broker._broker, deaf_to_cancel
    try:
        await asyncio.wait_for(broker.stop(), 5)
        assert broker.abandoned and "not done after 0.2 s" in caplog.text
        again = embedded.EmbeddedBroker(BrokerSettings(port=port or 0, ws_port=None))
        await again.start()  # the port was let go
        await again.stop()
    finally:
        release.set()
        del inner.shutdown
        await inner.shutdown()


async def test_a_connection_whose_reader_lost_its_cancel_does_not_hold_up_the_shutdown() -> None:
    # Python 3.11's wait_for can lose a cancel that comes as a packet does; amqtt's handler.stop()
    # then waited for its reader loop for good. Here the cancel is lost every time.
    broker = embedded.EmbeddedBroker(BrokerSettings(port=0, ws_port=None))
    await broker.start()
    reader, writer = await asyncio.open_connection("127.0.0.1", broker.port)
    connect = b"\x00\x04MQTT\x04\x02\x00\x3c" + b"\x00\x04deaf"  # clean session, keep-alive 60
    writer.write(_mqtt_packet(0x10, connect))
    assert (await asyncio.wait_for(reader.readexactly(4), 5))[:2] == b"\x20\x02"  # CONNACK
    amqtt = broker._broker
    ((_, handler),) = amqtt._sessions.values()
    handler._reader_task.cancel = lambda *_: False
    try:
        await asyncio.wait_for(broker.stop(), 4)
        assert not broker.abandoned  # amqtt's own shutdown ended, within its bound
        assert await asyncio.wait_for(reader.read(), 5) == b""  # and the client was let go
    finally:
        writer.close()


def _mqtt_packet(kind: int, body: bytes) -> bytes:
    return bytes([kind, len(body)]) + body  # bodies here are under 128 bytes


async def test_a_browser_tab_closing_mid_stream_leaves_the_log_quiet(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # Reloading the dashboard closes its websocket (1001, going away) while messages are on
    # their way to it: amqtt logged an "Unhandled exception" and tracebacks of failed tasks.
    caplog.set_level(logging.WARNING)
    async with embedded.EmbeddedBroker(BrokerSettings(port=0, ws_port=0)) as broker:
        publisher = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="publisher")
        publisher.connect("127.0.0.1", broker.port)
        publisher.loop_start()
        # A last reader, whose copy of a final marker says everything before it went out: a
        # broker stopped with messages still queued says so ("N messages not broadcasted").
        drained = threading.Event()
        reader = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="reader")
        reader.on_message = lambda c, u, m: drained.set() if m.topic == "x/end" else None
        subscribed = threading.Event()
        reader.on_subscribe = lambda c, u, mid, codes, p: subscribed.set()
        reader.connect("127.0.0.1", broker.port)
        reader.subscribe("x/#")
        reader.loop_start()
        try:
            assert await asyncio.to_thread(subscribed.wait, 30), "no SUBACK for the reader"
            for tab in range(3):
                page = await websockets.connect(broker.ws_url, subprotocols=["mqtt"])
                client_id = f"page-{tab}".encode()
                connect = b"\x00\x04MQTT\x04\x02\x00\x3c" + len(client_id).to_bytes(2, "big")
                await page.send(_mqtt_packet(0x10, connect + client_id))
                await page.recv()  # CONNACK
                await page.send(_mqtt_packet(0x82, b"\x00\x01\x00\x03x/#\x00"))
                await page.recv()  # SUBACK
                for _ in range(200):
                    publisher.publish("x/y", b"z" * 100)
                await page.close(code=1001)  # the tab goes away with messages on their way
                for _ in range(200):
                    publisher.publish("x/y", b"z" * 100)
            publisher.publish("x/end", b"")
            assert await asyncio.to_thread(drained.wait, 30), "the marker never came"
        finally:
            for client in (publisher, reader):
                client.loop_stop()
                client.disconnect()
    noisy = [r.getMessage() for r in caplog.records if r.name.startswith("amqtt")]
    assert noisy == []


def test_subscribing_and_unsubscribing_change_where_an_already_routed_topic_goes(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    # The embedded broker remembers which filters a topic matched: a filter added or dropped
    # after the topic was first routed must still count (broker/routing.py).
    topic, marker = f"{root}/units/u1/state", f"{root}/marker"
    early, late, sender = probe_factory(), probe_factory(), probe_factory()
    early.subscribe(f"{root}/units/+/state")
    early.subscribe(marker)
    sender.publish(topic, b"1")
    early.wait(topic, lambda m: m.payload == b"1")
    late.subscribe(f"{root}/#")
    sender.publish(topic, b"2")
    late.wait(topic, lambda m: m.payload == b"2")
    unsubscribed = threading.Event()
    early.client.on_unsubscribe = lambda *_: unsubscribed.set()
    early.client.unsubscribe(f"{root}/units/+/state")
    assert unsubscribed.wait(10), "no UNSUBACK"
    sender.publish(topic, b"3")
    sender.publish(marker, b"after 3")
    early.wait(marker)  # the same publisher's messages keep their order: 3 came before this
    late.wait(marker)
    assert [m.payload for m in early.received(topic)] == [b"1", b"2"]
    assert [m.payload for m in late.received(topic)] == [b"2", b"3"]


async def test_the_broker_process_ends_even_when_a_task_ignores_its_cancel() -> None:
    # In the network soak a broker that had logged "broker stopped" still ran 15 s after SIGTERM
    # (asyncio.run waits for every task it cancels; a reader can lose its cancel, see above):
    # `gridfleet broker` gives the leftovers a bound, then ends the process anyway.
    release = asyncio.Event()

    async def deaf_to_cancel() -> None:
        while not release.is_set():
            with contextlib.suppress(asyncio.CancelledError):
                await release.wait()

    deaf = asyncio.create_task(deaf_to_cancel())
    polite = asyncio.create_task(asyncio.Event().wait())
    await asyncio.sleep(0)  # both running
    try:
        assert not await asyncio.wait_for(broker_cli._leftovers_ended({deaf, polite}, 0.2), 5)
        assert polite.cancelled()
    finally:
        release.set()
        await deaf
    assert await broker_cli._leftovers_ended({deaf, polite}, 0.2)  # all ended: the loop may close


@pytest.mark.parametrize("cleaned_first", ["its-own", "another-ended-one"])
async def test_a_client_back_under_its_id_keeps_its_subscriptions_while_the_old_one_is_cleaned_up(
    cleaned_first: str,
) -> None:
    # amqtt's session monitor cleans up ended sessions by client id, awaiting each: a unit back
    # under its id meanwhile lost what it had just subscribed to (connected, but deaf to the
    # emergency stop), or its new connection (CI: an operator never heard the fleet's map).
    async with embedded.EmbeddedBroker(BrokerSettings(port=0, ws_port=None)) as broker:
        amqtt = broker._broker
        held, go_on = asyncio.Event(), asyncio.Event()
        cleaned: list[str] = []
        stop_handler, cleanup = amqtt._stop_handler, amqtt._cleanup_session

        async def held_up(handler: Any) -> None:
            # The monitor stopping an ended session's handler, held up while the unit returns.
            if handler.session.transitions.state == "disconnected":
                held.set()
                await go_on.wait()
            await stop_handler(handler)

        async def watched(client_id: str) -> None:
            await cleanup(client_id)
            cleaned.append(client_id)

        amqtt._stop_handler, amqtt._cleanup_session = held_up, watched
        if cleaned_first == "another-ended-one":
            async with make_client(broker.url, "earlier"):
                pass
        async with make_client(broker.url, "unit1"):
            pass  # the unit's link ends; its session waits for the monitor
        await asyncio.wait_for(held.wait(), 10)
        async with make_client(broker.url, "unit1") as unit, make_client(broker.url, "op") as op:
            await unit.subscribe("t/fleet/estop", qos=1)
            go_on.set()
            await async_wait_for(lambda: "unit1" in cleaned, what="the monitor's pass")
            await op.publish("t/fleet/estop", b"engaged", qos=1)
            async with asyncio.timeout(10):
                message = await anext(aiter(unit.messages))
            assert message.payload == b"engaged"
