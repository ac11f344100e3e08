"""Hostile clients: oversized packets, subscribers that do not read, strangers reusing a client id."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from gridfleet.accounts import Accounts, default_accounts
from gridfleet.broker.amqtt_broker import GridfleetBroker, make_broker
from gridfleet.broker.embedded import BrokerSettings
from gridfleet.broker.limits import MAX_PACKET_BYTES, Limits
from gridfleet.config import parse_broker_url
from gridfleet.protocol import Topics
from gridfleet.protocol.constants import MAX_VIEW_BYTES
from gridfleet.system.broker_thread import BrokerThread

from support.mosquitto import mosquitto_with_accounts
from support.probe import MqttProbe
from support.security import login
from support.wait import wait_for

ROOT = "lim"
T = Topics(ROOT)

# The embedded broker's own limits (its Mosquitto counterparts start a Mosquitto of their own).
pytestmark = pytest.mark.amqtt_only


class Client:
    """A bare paho client with no network thread: it reads and writes only while the test polls."""

    def __init__(self, url: str, client_id: str, clean_session: bool = True) -> None:
        broker = parse_broker_url(url)
        self.client = mqtt.Client(
            CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=clean_session
        )
        if broker.username is not None:
            self.client.username_pw_set(broker.username, broker.password)
        self.answer: Any = None  # the CONNACK's reason code
        self.disconnected = False
        self.acked: set[int] = set()
        self.messages: list[bytes] = []
        self.client.on_connect = lambda c, u, f, rc, p: setattr(self, "answer", rc)
        self.client.on_disconnect = lambda c, u, f, rc, p: setattr(self, "disconnected", True)
        self.client.on_subscribe = lambda c, u, mid, rcs, p: self.acked.add(mid)
        self.client.on_message = lambda c, u, m: self.messages.append(m.payload)
        self.client.connect(broker.host, broker.port)
        self.poll_until(lambda: self.answer is not None, what=f"CONNACK for {client_id}")

    def poll_until(self, predicate: Callable[[], object], what: str) -> None:
        """Let paho read and write until `predicate` holds (10 s at most)."""

        def step() -> object:
            self.client.loop(0.01)
            return predicate()

        wait_for(step, 10, interval=0, what=what)

    def subscribe(self, topic: str, qos: int) -> None:
        """Subscribe and wait for the SUBACK."""
        _, mid = self.client.subscribe(topic, qos)
        self.poll_until(lambda: mid in self.acked, what=f"SUBACK for {topic}")

    def close(self) -> None:
        """Disconnect (if still connected) and close the socket."""
        if self.client.is_connected():
            self.client.disconnect()
            self.client.loop(0.01)
        if self.client.socket() is not None:
            self.client.socket().close()


def watch_disconnects(probe: MqttProbe) -> threading.Event:
    """An event set when `probe` loses its connection."""
    lost = threading.Event()
    probe.client.on_disconnect = lambda c, u, f, rc, p: lost.set()
    return lost


# ---- payload size, on the broker gridfleet runs (default limits) --------------------------------


def test_the_largest_view_the_protocol_allows_passes_and_is_retained(
    broker: BrokerThread, probe_factory: Callable[..., MqttProbe], root: str
) -> None:
    topic = Topics(root).fleet("map")
    view = b"v" * MAX_VIEW_BYTES
    live = probe_factory()
    live.subscribe(topic)
    probe_factory().publish(topic, view, retain=True)
    assert live.wait(topic).payload == view
    late = probe_factory()
    late.subscribe(topic)
    assert late.wait(topic).payload == view


def test_a_bigger_packet_disconnects_its_sender_and_reaches_nobody(
    broker: BrokerThread, probe_factory: Callable[..., MqttProbe], root: str
) -> None:
    topic = Topics(root).fleet("map")
    live = probe_factory()
    live.subscribe(f"{root}/#")
    sender = Client(broker.url, "too-big")
    sender.client.publish(topic, b"x" * MAX_PACKET_BYTES, qos=0, retain=True)
    sender.poll_until(lambda: sender.disconnected, what="the oversized packet's sender dropped")
    sender.close()
    # The broker carries on for everyone else; the oversized message was neither sent nor kept.
    other = probe_factory()
    other.publish(topic, b"small")
    other.publish(f"{root}/marker", b"m", retain=True)
    assert live.wait(topic).payload == b"small"
    assert [m.payload for m in live.received(topic)] == [b"small"]
    late = probe_factory()
    late.subscribe(f"{root}/#")
    late.wait(f"{root}/marker")  # retained messages come in the order they were kept
    assert late.received(topic) == []


def test_a_message_the_broker_cannot_route_is_dropped_and_the_next_ones_still_go(
    broker: BrokerThread,
    probe_factory: Callable[..., MqttProbe],
    root: str,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The broker routes messages one after another in one loop (broker/amqtt_broker.py): a
    # failure on one (a bug, a plugin raising) must not end the loop, or nobody hears anything.
    matches = GridfleetBroker._matches

    def failing(self: GridfleetBroker, topic: str, a_filter: str) -> bool:
        if topic.endswith("/unroutable"):
            raise RuntimeError("a routing bug")
        return bool(matches(self, topic, a_filter))

    monkeypatch.setattr(GridfleetBroker, "_matches", failing)
    live = probe_factory()
    live.subscribe(f"{root}/#")
    sender = probe_factory()
    sender.publish(f"{root}/unroutable", b"lost")
    sender.publish(f"{root}/after", b"delivered")
    assert live.wait(f"{root}/after").payload == b"delivered"
    assert live.received(f"{root}/unroutable") == []


def test_a_burst_of_mixed_qos_reaches_a_subscriber_whole_and_in_order_per_qos(
    broker: BrokerThread, probe_factory: Callable[..., MqttProbe], root: str
) -> None:
    # The broker writes a turn's QoS 0 messages to a socket together, while QoS 1 ones, and QoS 0
    # ones behind them, take the queued way: each QoS must still arrive in the order sent
    # (MQTT-4.6.0-6; across QoS levels amqtt keeps no order, nor must it).
    topic = f"{root}/burst"
    reader = probe_factory()
    reader.subscribe(topic, qos=1)
    sender = Client(broker.url, "burst")
    count = 300
    qos_of = {n: 1 if n % 7 == 3 else 0 for n in range(count)}
    for n in range(count):  # paho only queues them: they leave in one go at the next poll
        sender.client.publish(topic, n.to_bytes(2, "big"), qos=qos_of[n])
    sender.poll_until(lambda: len(reader.received(topic)) == count, what="the whole burst")
    got = [int.from_bytes(m.payload, "big") for m in reader.received(topic)]
    for qos in (0, 1):
        assert [n for n in got if qos_of[n] == qos] == [n for n in range(count) if qos_of[n] == qos]
    sender.close()


def test_the_packet_limit_is_a_broker_setting() -> None:
    settings = BrokerSettings(port=0, ws_port=None, max_packet_bytes=4096)
    with BrokerThread(settings) as small, MqttProbe(small.url) as live:
        live.subscribe(f"{ROOT}/#")
        sender = Client(small.url, "over-4k")
        sender.client.publish(f"{ROOT}/big", b"x" * 5000, qos=0)
        sender.poll_until(lambda: sender.disconnected, what="the 5000-byte packet's sender")
        sender.close()
        with MqttProbe(small.url) as other:
            other.publish(f"{ROOT}/fits", b"y" * 3000)
            live.wait(f"{ROOT}/fits")
        assert live.received(f"{ROOT}/big") == []


# ---- a subscriber that does not read ------------------------------------------------------------


class LimitedBroker:
    """A GridfleetBroker with small limits in a thread of its own, on a free loopback port."""

    def __init__(self, **limits: int) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._thread.start()
        config = BrokerSettings(port=0, ws_port=None).amqtt_config()
        self.broker = self._run(self._start(config, limits))
        self.url = f"mqtt://127.0.0.1:{self.broker.bound_port()}"

    async def _start(self, config: dict[str, Any], limits: dict[str, int]) -> GridfleetBroker:
        broker = make_broker(config, limits=Limits(**limits))
        await broker.start()
        return broker

    def _run(self, coro: Any) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(10)

    def stop(self) -> None:
        """Shut the broker down and end its thread."""
        self._run(self.broker.shutdown())
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        self._loop.close()


QUEUED_MESSAGES, QUEUED_BYTES = 16, 768 * 1024


@pytest.fixture
def limited() -> Iterator[LimitedBroker]:
    running = LimitedBroker(max_queued_messages=QUEUED_MESSAGES, max_queued_bytes=QUEUED_BYTES)
    yield running
    running.stop()


# QoS 1: deliveries wait for slow's PUBACK, and 16 small ones fill its queue. QoS 0: the kernel's
# socket buffers fill first, then 12 big ones fill the queue's bytes.
@pytest.mark.parametrize(("qos", "chunk"), [(0, 64 * 1024), (1, 16 * 1024)])
def test_a_subscriber_that_does_not_read_costs_a_bounded_queue_and_blocks_nobody(
    limited: LimitedBroker, qos: int, chunk: int
) -> None:
    topic = "load/x"
    slow = Client(limited.url, "slow")
    slow.subscribe(topic, qos)  # from now on nobody reads slow's socket until it polls again
    reader = MqttProbe(limited.url).connect()
    reader.subscribe(topic, qos=0)
    publisher = MqttProbe(limited.url).connect()
    sent = 0

    def publish() -> None:
        # Each once the reader has the one before: a reader starved of a core on a loaded
        # machine must not fall a queue behind (the broker would rightly drop for it too).
        nonlocal sent
        wait_for(lambda: len(reader.received(topic)) == sent, what=f"message {sent} at the reader")
        publisher.publish(topic, sent.to_bytes(4, "big") + bytes(chunk - 4), qos=0)
        sent += 1

    def dropping() -> bool:
        publish()
        backlog = limited.broker.backlog("slow")
        return backlog is not None and backlog.dropped > 0

    wait_for(dropping, 30, interval=0, what="the broker dropping messages for slow")
    for _ in range(50):
        publish()
    # A subscriber that reads got every message, in order. (Each message is queued for, or
    # dropped for, slow before it goes to the reader.)
    wait_for(lambda: len(reader.received(topic)) == sent, what="every message at the reader")
    assert [int.from_bytes(m.payload[:4], "big") for m in reader.received(topic)] == list(
        range(sent)
    )
    backlog = limited.broker.backlog("slow")
    assert backlog is not None and backlog.dropped >= 50
    assert backlog.messages <= QUEUED_MESSAGES and backlog.bytes <= QUEUED_BYTES, backlog
    assert backlog.messages == QUEUED_MESSAGES or backlog.bytes + chunk > QUEUED_BYTES, backlog
    # slow reads again: its queue drains, and new messages reach it.
    slow.poll_until(lambda: _backlog_messages(limited, "slow") == 0, what="slow's queue draining")
    publisher.publish(topic, b"after", qos=0)
    slow.poll_until(lambda: b"after" in slow.messages, what="a new message at slow")
    for client in (slow, reader, publisher):
        client.close()


def _backlog_messages(limited: LimitedBroker, client_id: str) -> int | None:
    backlog = limited.broker.backlog(client_id)
    return None if backlog is None else backlog.messages


# ---- client-id takeover --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def accounts() -> Accounts:
    return default_accounts(["unit1"])


@pytest.fixture(scope="module")
def secured(accounts: Accounts) -> Iterator[BrokerThread]:
    settings = BrokerSettings(port=0, ws_port=None, accounts=accounts, root=ROOT)
    with BrokerThread(settings) as running:
        yield running


@pytest.mark.parametrize("clean_session", [True, False])
def test_a_wrong_password_cannot_take_the_coordinators_client_id(
    secured: BrokerThread, accounts: Accounts, clean_session: bool
) -> None:
    state = T.unit("state", "unit1")
    with MqttProbe(login(secured.url, accounts, "coordinator"), "coordinator") as coordinator:
        lost = watch_disconnects(coordinator)
        coordinator.subscribe(T.all_units("state"))
        for url in (login(secured.url, accounts, "coordinator", "wrong"), secured.url):
            stranger = Client(url, "coordinator", clean_session)
            stranger.close()
            assert stranger.answer.is_failure and "authorized" in str(stranger.answer)
        with MqttProbe(login(secured.url, accounts, "unit1")) as unit1:
            unit1.publish(state, b'{"still": "listening"}')
        assert coordinator.wait(state).payload == b'{"still": "listening"}'
        assert not lost.is_set()


def test_the_right_password_still_takes_the_client_id_over(
    secured: BrokerThread, accounts: Accounts
) -> None:
    state = T.unit("state", "unit1")
    own = login(secured.url, accounts, "coordinator")
    first = Client(own, "coordinator")
    first.subscribe(T.all_units("state"), 1)
    with MqttProbe(own, "coordinator") as second:
        # MQTT-3.1.4-2: the connection taken over is closed.
        first.poll_until(lambda: first.disconnected, what="the first connection closed")
        second.subscribe(T.all_units("state"))
        with MqttProbe(login(secured.url, accounts, "unit1")) as unit1:
            unit1.publish(state, b'{"to": "the new one"}')
        assert second.wait(state).payload == b'{"to": "the new one"}'
    first.close()
    assert first.messages == []


# ---- Mosquitto with the recommended configuration -------------------------------------------------


@pytest.fixture(scope="module")
def mosquitto(accounts: Accounts, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """Mosquitto on a free loopback port, configured by mosquitto_conf; its URL."""
    with mosquitto_with_accounts(accounts, T, tmp_path_factory.mktemp("mosquitto")) as url:
        yield url


def test_mosquitto_with_the_recommended_lines_refuses_an_oversized_packet(
    mosquitto: str, accounts: Accounts
) -> None:
    topic = T.fleet("map")
    with MqttProbe(login(mosquitto, accounts, "dashboard")) as dashboard:
        dashboard.subscribe(topic)
        sender = Client(login(mosquitto, accounts, "coordinator"), "coordinator")
        sender.client.publish(topic, b"x" * MAX_PACKET_BYTES, qos=0)
        sender.poll_until(lambda: sender.disconnected, what="the oversized packet's sender dropped")
        sender.close()
        with MqttProbe(login(mosquitto, accounts, "coordinator")) as coordinator:
            coordinator.publish(topic, b"v" * MAX_VIEW_BYTES)
        assert len(dashboard.wait(topic).payload) == MAX_VIEW_BYTES
        assert len(dashboard.received(topic)) == 1
