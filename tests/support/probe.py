"""A paho MQTT client for tests: records every message it sees and waits for the ones it needs."""

from __future__ import annotations

import contextlib
import ssl
import threading
import time
import uuid
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from gridfleet.config import owned_client_id, parse_brokers
from gridfleet.protocol import Topics

from support.wait import wait_for


@dataclass(frozen=True)
class Seen:
    """A message as the probe received it."""

    topic: str
    payload: bytes
    retain: bool
    qos: int
    at: float = 0.0  # time.monotonic() when it arrived


class MqttProbe:
    """Connects, subscribes, records messages by topic; publish and wait helpers for tests."""

    def __init__(self, url: str, client_id: str | None = None) -> None:
        broker = parse_brokers(url)[0]  # a cluster's list: a probe speaks to its first
        self.client = mqtt.Client(
            CallbackAPIVersion.VERSION2,
            # An explicit id is used as given (tests of who may use which id).
            client_id=client_id
            or owned_client_id(broker.username, f"probe-{uuid.uuid4().hex[:8]}"),
            transport=broker.transport,  # type: ignore[arg-type]
        )
        if broker.websocket:
            self.client.ws_set_options(path=broker.path)
        if broker.tls:  # verifies the broker's certificate and name, as the product's clients do
            self.client.tls_set_context(ssl.create_default_context(cafile=broker.ca_file))
        if broker.username is not None:
            self.client.username_pw_set(broker.username, broker.password)
        self.refused: object | None = None  # the CONNACK's reason when the broker said no
        self._batch: list[mqtt.MQTTMessageInfo] | None = None  # publishes not waited for yet
        self._broker = broker
        self._lock = threading.Lock()
        self.messages: defaultdict[str, list[Seen]] = defaultdict(list)
        self._connected = threading.Event()
        self._answered = threading.Event()  # a CONNACK came, yes or no, or the link closed
        self._subacks: set[int] = set()
        self.client.on_message = self._on_message
        self.client.on_connect = self._on_connect
        # Closed before any CONNACK (a websocket refused for its origin): no answer will come.
        self.client.on_disconnect = lambda c, u, flags, rc, p: self._answered.set()
        self.client.on_subscribe = lambda c, u, mid, rcs, p: self._subacks.add(mid)

    def _on_connect(
        self, client: object, userdata: object, flags: object, rc: Any, p: object
    ) -> None:
        if rc.is_failure:
            self.refused = rc
        else:
            self._connected.set()
        self._answered.set()

    def _on_message(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        with self._lock:
            self.messages[msg.topic].append(
                Seen(msg.topic, bytes(msg.payload), msg.retain, msg.qos, time.monotonic())
            )

    def connect(self, timeout: float = 10.0, keepalive: int = 60) -> MqttProbe:
        """Connect and start paho's network thread (once: see below)."""
        # A second connect() makes paho drop the live socket and open another: a SUBSCRIBE sent
        # meanwhile is lost without a SUBACK (2 in 30 tries here; amqtt logs "No data to decode
        # MQTT packet fixed header"). That was the late-client test's rare timeout.
        if self._connected.is_set():
            raise AssertionError("MqttProbe.connect() called twice (`with` connects by itself)")
        self.client.connect(self._broker.host, self._broker.port, keepalive=keepalive)
        self.client.loop_start()
        if not (self._answered.wait(timeout) and self._connected.is_set()):
            self.client.loop_stop()
            why = f": refused ({self.refused})" if self.refused is not None else ""
            raise AssertionError(f"probe could not connect to {self._broker}{why}")
        return self

    def subscribe(self, topic: str, qos: int = 1, timeout: float = 30.0) -> None:
        """Subscribe and wait for the broker's SUBACK."""
        # Generous: amqtt reads a client's next SUBSCRIBE only once it has replayed the retained
        # messages of the one before, each replay waiting up to 5 s for its PUBACK; on a machine
        # shared with other test workers a SUBACK came later than a 10 s bound (a CI run).
        _, mid = self.client.subscribe(topic, qos)
        wait_for(lambda: mid in self._subacks, timeout, what=f"SUBACK for {topic}")

    def publish(
        self,
        topic: str,
        payload: bytes | str,
        qos: int = 1,
        retain: bool = False,
        timeout: float = 10.0,
    ) -> None:
        """Publish and wait until paho has handed it to the broker (in a `batch`: at its end)."""
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        if self._batch is not None:
            self._batch.append(info)
            return
        info.wait_for_publish(timeout)

    @contextlib.contextmanager
    def batch(self, timeout: float = 60.0) -> Iterator[None]:
        """Publishes inside go out back to back; all of them are waited for when the block ends."""
        self._batch = []
        try:
            yield
        finally:
            pending, self._batch = self._batch, None
            for info in pending:
                info.wait_for_publish(timeout)

    def received(self, topic: str) -> list[Seen]:
        """Messages seen so far on `topic`."""
        with self._lock:
            return list(self.messages.get(topic, []))

    def wait(
        self, topic: str, match: Callable[[Seen], bool] = lambda m: True, timeout: float = 10.0
    ) -> Seen:
        """The first message on `topic` for which `match` holds (waits for it to arrive)."""

        def find() -> Seen | None:
            return next((m for m in self.received(topic) if match(m)), None)

        found = wait_for(find, timeout, what=f"a matching message on {topic}")
        assert found is not None
        return found

    def will(self, topic: str, payload: bytes, retain: bool = False, qos: int = 1) -> MqttProbe:
        """Set the last will the next connect() registers; returns self."""
        self.client.will_set(topic, payload, qos=qos, retain=retain)
        return self

    def drop(self) -> None:
        """Lose the link without a DISCONNECT: the broker then sends the will (if it took one)."""
        self.client.loop_stop()
        sock = self.client.socket()
        if sock is not None:
            sock.close()

    def fall_silent(self) -> None:
        """Send nothing more, not even a ping, on a link left open: as a host whose link died
        without a FIN looks to the broker."""
        self.client.loop_stop()

    def close(self) -> None:
        """Disconnect cleanly."""
        self.client.disconnect()
        self.client.loop_stop()

    def __enter__(self) -> MqttProbe:
        return self.connect()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def login_refused(url: str) -> bool:
    """Whether the broker refuses a CONNECT with `url`'s login now (any other failure raises)."""
    try:
        with MqttProbe(url):
            return False
    except AssertionError as exc:
        assert "Not authorized" in str(exc), exc
        return True


def retained_latch(url: str, topics: Topics) -> bytes | None:
    """The retained latch a client connecting to `url` now reads (None: nothing retained)."""
    with MqttProbe(url) as probe:
        probe.subscribe(topics.fleet("estop"))
        marker = f"{topics.root}/marker"
        probe.subscribe(marker)
        probe.publish(marker, b"m")  # comes back after any retained latch
        probe.wait(marker)
        seen = probe.received(topics.fleet("estop"))
        return seen[-1].payload if seen else None
