"""`gridfleet bench flood`'s instruments: MQTT clients (requesters, the fleet's watch, the jobs
view's counter) and a sampler of the coordinator's metrics. Each paho client reads in a thread of
its own and notes arrival times there; the bench's main thread reads what they noted."""

from __future__ import annotations

import json
import math
import threading
import time
import urllib.request
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion
from prometheus_client.parser import text_string_to_metric_families

from gridfleet.accounts import Account
from gridfleet.config import parse_broker_url
from gridfleet.errors import ConfigError, ProtocolError
from gridfleet.outbound import Outbound
from gridfleet.protocol import CancelJob, HeaderStamper, SubmitJob, Topics
from gridfleet.protocol.messages import FINAL_JOB_STATES
from gridfleet.squares import Cell

RETRY_S = 2.0  # as the operator's clients: re-sent after 2 s, doubling up to 10 s
RETRY_MOST_S = 10.0


class Client:
    """A paho client logged in as `account`, subscribed to `subscriptions`, reading in a thread."""

    def __init__(
        self,
        url: str,
        account: Account,
        client_id: str,
        subscriptions: list[tuple[str, int]],
        inflight: int = 20,
    ) -> None:
        broker = parse_broker_url(url)
        self.client_id = client_id
        self.subscriptions = subscriptions
        self.ready = threading.Event()
        self.refused: str | None = None
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id)
        self.client.username_pw_set(account.name, account.password)
        self.client.on_connect = self._connected
        self.client.on_subscribe = lambda c, u, mid, codes, p: self.ready.set()
        self.client.on_message = self._message
        self.client.on_publish = self._acked
        self.client.max_inflight_messages_set(inflight)  # 0: as many as it can write
        self.client.connect(broker.host, broker.port, keepalive=30)
        self.client.loop_start()

    def _connected(self, client: mqtt.Client, u: object, f: object, rc: Any, p: object) -> None:
        if rc.is_failure:
            self.refused = str(rc)
            return
        if self.subscriptions:
            client.subscribe(self.subscriptions)
        else:
            self.ready.set()

    def _acked(self, client: mqtt.Client, userdata: object, mid: int, rc: Any, p: object) -> None:
        """A PUBACK (in the client's thread)."""

    def wait_ready(self, timeout: float = 30.0) -> None:
        """ConfigError when not connected and subscribed within `timeout`."""
        if not self.ready.wait(timeout):
            why = self.refused or "no answer"
            raise ConfigError(f"{self.client_id} could not log in and subscribe: {why}")

    def _message(self, client: mqtt.Client, userdata: object, message: mqtt.MQTTMessage) -> None:
        self.on_message(message.topic, bytes(message.payload), time.monotonic())

    def on_message(self, topic: str, payload: bytes, at: float) -> None:
        """One message, as it arrived (in the client's thread)."""

    def close(self) -> None:
        """Disconnect and stop the client's thread."""
        self.client.disconnect()
        self.client.loop_stop()


@dataclass
class Asked:
    """One request: when it was first sent and when, and how, it was answered."""

    kind: str
    sent: float  # time.monotonic() of its first send
    out: Outbound
    retry: bool
    answered: float | None = None
    accepted: bool | None = None
    reason: str | None = None
    tries: int = 1
    next_try: float = math.inf
    pause: float = RETRY_S

    @property
    def answer_ms(self) -> float | None:
        """From its first send to its answer (None: not answered)."""
        return None if self.answered is None else (self.answered - self.sent) * 1000


class Requester(Client):
    """Sends requests (QoS 1, reply_to set, each its own id) and notes their answers."""

    def __init__(
        self, url: str, account: Account, client_id: str, topics: Topics, inflight: int = 20
    ) -> None:
        self.topics = topics
        self.stamp = HeaderStamper(client_id)
        self.asked: dict[str, Asked] = {}
        self.answered = 0
        self.acked = 0  # PUBACKs of this client's requests
        self.last_ack = 0.0
        self._session = f"{time.time_ns() % 10**9:x}"
        self._count = 0
        self._lock = threading.Lock()
        super().__init__(url, account, client_id, [(topics.reply(client_id), 1)], inflight)

    def _acked(self, client: mqtt.Client, userdata: object, mid: int, rc: Any, p: object) -> None:
        self.acked += 1
        self.last_ack = time.monotonic()

    def _next_id(self) -> str:
        self._count += 1
        return f"{self.client_id}-{self._session}-{self._count}"[-64:]

    def submit(
        self,
        pickup: Cell,
        dropoff: Cell,
        mass_kg: float,
        job_id: str | None = None,
        retry: bool = False,
    ) -> Asked:
        """Send a submit_job."""
        request = SubmitJob(
            header=self.stamp("submit_job"),
            request_id=self._next_id(),
            reply_to=self.client_id,
            pickup=pickup,
            dropoff=dropoff,
            mass_kg=mass_kg,
            priority=0,
            job_id=job_id,
        )
        return self._send("submit_job", request.request_id, request, retry)

    def cancel(self, job_id: str, retry: bool = False) -> Asked:
        """Send a cancel_job."""
        request = CancelJob(
            header=self.stamp("cancel_job"),
            request_id=self._next_id(),
            reply_to=self.client_id,
            job_id=job_id,
        )
        return self._send("cancel_job", request.request_id, request, retry)

    def _send(self, kind: str, rid: str, request: SubmitJob | CancelJob, retry: bool) -> Asked:
        out = Outbound.of(kind, self.topics.request(kind), request)
        now = time.monotonic()
        asked = Asked(kind, now, out, retry, next_try=now + RETRY_S if retry else math.inf)
        with self._lock:
            self.asked[rid] = asked
        self.client.publish(out.topic, out.payload, qos=1)
        return asked

    def resend_due(self, now: float) -> None:
        """Send again, the same, each retried request unanswered past its time (backing off)."""
        with self._lock:
            due = [a for a in self.asked.values() if a.answered is None and a.next_try <= now]
        for asked in due:
            asked.tries += 1
            asked.pause = min(2 * asked.pause, RETRY_MOST_S)
            asked.next_try = now + asked.pause
            self.client.publish(asked.out.topic, asked.out.payload, qos=1)

    def on_message(self, topic: str, payload: bytes, at: float) -> None:
        """A reply: the first answer to a request of ours is noted."""
        try:
            reply = json.loads(payload)
            asked = self.asked.get(str(reply["request_id"]))
        except (ValueError, KeyError, TypeError):
            return
        if asked is None or asked.answered is not None:
            return
        asked.answered = at
        asked.accepted = bool(reply.get("accepted"))
        asked.reason = reply.get("reason")
        self.answered += 1

    def pending(self, now: float, within_s: float) -> int:
        """Requests unanswered, sent within the last `within_s` seconds."""
        with self._lock:
            return sum(
                1 for a in self.asked.values() if a.answered is None and now - a.sent < within_s
            )

    def engage(self, latch: str, engaged: bool, reason: str) -> None:
        """Engage or release the fleet's latch as this client (retained, QoS 1)."""
        word = "engaged" if engaged else "released"
        self.client.publish(latch, f"{word}|{self.client_id}|{reason}".encode(), qos=1, retain=True)


@dataclass
class Shown:
    """Which units have shown the stop condition awaited since `since`, and when."""

    want: bool
    since: datetime
    at: dict[str, float] = field(default_factory=dict)  # unit -> time.monotonic() of arrival


class FleetWatch(Client):
    """Every unit's state, the routes' step and the coordinator's status, as they arrive."""

    def __init__(
        self, url: str, account: Account, client_id: str, topics: Topics, units: set[str]
    ) -> None:
        self.topics = topics
        self.units = units
        self.states_seen: set[str] = set()
        self.planned: set[str] = set()
        self.coordinator_online = False
        self.steps: list[tuple[float, int]] = []  # (arrival, step) of each routes view
        self.shown: Shown | None = None
        self.all_shown = threading.Event()
        subscriptions = [
            (topics.all_units("state"), 0),
            (topics.fleet("routes"), 0),
            (topics.fleet("coordinator"), 1),
        ]
        super().__init__(url, account, client_id, subscriptions)

    def expect(self, estop: bool) -> Shown:
        """Watch for every unit's state made from now on to show `estop` (and, engaged, stopped)."""
        self.all_shown.clear()
        self.shown = Shown(estop, datetime.now(UTC))
        return self.shown

    def on_message(self, topic: str, payload: bytes, at: float) -> None:
        """Note what the message says."""
        try:
            kind, unit = self.topics.parse(topic)
            data = json.loads(payload)
        except (ProtocolError, ValueError):
            return
        if kind == "state" and unit is not None:
            self.states_seen.add(unit)
            shown = self.shown
            if shown is None or unit in shown.at or not isinstance(data, dict):
                return
            stamped = datetime.fromisoformat(str(data["header"]["timestamp"]))
            estop = bool(data.get("estop"))
            stopped = not shown.want or data.get("status") == "stopped"
            if stamped >= shown.since and estop == shown.want and stopped:
                shown.at[unit] = at
                if len(shown.at) >= len(self.units):
                    self.all_shown.set()
        elif kind == "routes" and isinstance(data, dict):
            self.planned = set(data.get("routes", {}))
            self.steps.append((at, int(data.get("step", 0))))
        elif kind == "coordinator" and isinstance(data, dict):
            self.coordinator_online = data.get("state") == "online"


class ViewCount(Client):
    """Counts the `fleet/jobs` views one subscriber receives, and their bytes."""

    def __init__(self, url: str, account: Account, client_id: str, topics: Topics) -> None:
        self.count = 0
        self.bytes = 0
        self.largest = 0
        super().__init__(url, account, client_id, [(topics.fleet("jobs"), 1)])

    def on_message(self, topic: str, payload: bytes, at: float) -> None:
        """Count it."""
        self.count += 1
        self.bytes += len(payload)
        self.largest = max(self.largest, len(payload))


@dataclass(frozen=True)
class Sample:
    """One scrape of the coordinator's metrics."""

    at: float  # time.monotonic() when the answer came
    took_s: float  # how long the scrape took
    steps: float
    achieved_s: float | None
    active_jobs: float
    done: float


class MetricsSampler:
    """Scrapes the coordinator's `/metrics` every second in a thread of its own."""

    def __init__(self, port: int, period_s: float = 1.0) -> None:
        self.url = f"http://127.0.0.1:{port}/metrics"
        self.period_s = period_s
        self.samples: list[Sample] = []
        self.failures = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="metrics", daemon=True)

    def start(self) -> None:
        """Start scraping."""
        self._thread.start()

    def stop(self) -> None:
        """Stop scraping (waits for the scrape under way)."""
        self._stop.set()
        self._thread.join(15)

    def scrape(self) -> Sample:
        """One scrape now (raises OSError or ValueError when it fails)."""
        began = time.monotonic()
        with urllib.request.urlopen(self.url, timeout=10) as answer:  # loopback
            text = answer.read().decode()
        values: dict[str, float] = {}
        active = 0.0
        for family in text_string_to_metric_families(text):
            for s in family.samples:
                if s.name == "gridfleet_jobs" and s.labels.get("state") not in FINAL_JOB_STATES:
                    active += s.value
                else:
                    values.setdefault(s.name, s.value)
        now = time.monotonic()
        return Sample(
            at=now,
            took_s=now - began,
            steps=values.get("gridfleet_steps_total", 0.0),
            achieved_s=values.get("gridfleet_step_achieved_seconds"),
            active_jobs=active,
            done=values.get("gridfleet_jobs_done_total", 0.0),
        )

    def _run(self) -> None:
        while not self._stop.is_set():
            began = time.monotonic()
            try:
                self.samples.append(self.scrape())
            except (OSError, ValueError):
                self.failures += 1
            self._stop.wait(max(0.0, began + self.period_s - time.monotonic()))

    def latest(self) -> Sample | None:
        """The latest sample, if any."""
        return self.samples[-1] if self.samples else None
