"""Deeply nested JSON (valid, under the size limit) is refused cleanly, never an exception: at
the embedded broker's gate, in the coordinator's reading of requests, and over a real broker
with accounts (the embedded amqtt and Mosquitto)."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest

from gridfleet.accounts import Accounts, default_accounts
from gridfleet.alerts.core import AlertsCore
from gridfleet.alerts.settings import AlertSettings
from gridfleet.broker.gate import Gate
from gridfleet.grid import GridMap
from gridfleet.protocol import HeaderStamper, Topics
from gridfleet.protocol.constants import MAX_REQUEST_BYTES

from support.coordinator_drive import answered, make_core
from support.effects import header_json, published
from support.mosquitto import broker_with_accounts
from support.probe import MqttProbe
from support.security import login

ROOT = "deep"
T = Topics(ROOT)
GRID = GridMap.from_rows(["....", "....", "...."], name="yard")
DEPTH = 7000  # far beyond Python's recursion limit, and under MAX_REQUEST_BYTES


def deep(sender: str, request_id: str = "d-1") -> bytes:
    """A request naming `sender` and a reply address, with one field nested DEPTH levels."""
    head = {"header": header_json(sender, 0), "request_id": request_id, "reply_to": sender}
    text = json.dumps(head)[:-1] + ', "squares": ' + "[" * DEPTH + "]" * DEPTH + "}"
    assert len(text) <= MAX_REQUEST_BYTES
    return text.encode()


def test_the_gate_drops_a_request_nested_too_deep_to_read_its_sender() -> None:
    # As found: json.loads raised RecursionError (no ValueError) inside the broker's delivery.
    gate = Gate(default_accounts(["unit1"]), root=ROOT)
    for topic in (T.request("clear_obstacles"), T.fleet("errors"), T.request("audit")):
        refused = gate.refused_publish("operator", "operator-cli", topic, deep("coordinator"))
        assert refused is not None and "nested too deeply" in refused, topic


def test_the_coordinator_refuses_a_deeply_nested_request_in_words() -> None:
    core = make_core(GRID)
    topic = Topics("gridfleet").request("clear_obstacles")
    sent = published(core.on_message(topic, deep("operator-cli"), 0.0))
    errors = [p for t, p, _, _ in sent if t.endswith("/errors")]
    assert len(errors) == 1 and errors[0]["topic"] == topic
    assert "ClearObstacles" in errors[0]["reason"] and core.world.obstacles == set()


def test_the_coordinator_refuses_a_deeply_nested_audit_query_in_words() -> None:
    topics = Topics("gridfleet")
    out, effects = answered(make_core(GRID), topics.request("audit"), deep("operator-cli"))
    assert [o.topic for o in out] == [topics.fleet("errors")]
    assert effects.audit.entries == ()


def test_the_alerts_process_refuses_a_deeply_nested_acknowledgement_in_words() -> None:
    core = AlertsCore(T, AlertSettings(), HeaderStamper("alerts"), nonce="n", now=0.0)
    out = core.on_message(T.request("ack_alert"), deep("operator-cli"), 0.0)
    assert [o.topic for o in out.publish] == [T.fleet("errors")]


@pytest.fixture(scope="module")
def accounts() -> Accounts:
    return default_accounts(["unit1"])


@pytest.fixture(scope="module", params=["amqtt", "mosquitto"])
def broker_url(
    request: pytest.FixtureRequest, accounts: Accounts, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[str, bool]]:
    """(URL, whether it reads senders) of a broker with accounts: the embedded amqtt or Mosquitto."""
    directory = tmp_path_factory.mktemp("mosquitto")
    with broker_with_accounts(request.param, accounts, ROOT, directory) as running:
        yield running


@pytest.mark.every_broker
def test_a_deeply_nested_request_leaves_the_broker_and_the_senders_session_working(
    broker_url: tuple[str, bool], accounts: Accounts
) -> None:
    url, reads_senders = broker_url
    submit = T.request("submit_job")
    with (
        MqttProbe(login(url, accounts, "coordinator")) as coordinator,
        MqttProbe(login(url, accounts, "operator"), "operator-cli") as operator,
    ):
        coordinator.subscribe(submit)
        # As found: the embedded broker's handler of the operator's connection died on a
        # RecursionError and the link dropped (paho reconnected and sent the next one).
        drops: list[object] = []
        operator.client.on_disconnect = lambda c, u, flags, rc, p: drops.append(rc)
        nested = [deep("coordinator", "forged"), deep("operator-cli", "own")]
        for payload in nested:
            operator.publish(submit, payload)
        marker = json.dumps({"header": header_json("operator-cli", 1), "request_id": "after"})
        operator.publish(submit, marker.encode())  # same connection, after: the others had theirs
        coordinator.wait(submit, lambda m: m.payload == marker.encode())
        got = [m.payload for m in coordinator.received(submit)]
        # The embedded broker's gate cannot read a sender in them: dropped, forged or not.
        # Mosquitto reads no payload: they pass, and the coordinator refuses them in words.
        assert got == ([] if reads_senders else nested) + [marker.encode()]
        assert drops == []
