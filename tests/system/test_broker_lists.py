"""Broker lists (issue 56): `--broker A,B` is parsed item by item, one-shot clients take the first
broker that answers, and an Endpoint moves to the next broker when its own dies."""

from __future__ import annotations

import asyncio
import logging
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import unquote

import aiomqtt
import pytest

from gridfleet.bus import connect_first, reach_first
from gridfleet.config import (
    broker_login,
    broker_urls,
    parse_broker_url,
    parse_brokers,
    redacted,
    with_ca_file,
    with_credentials,
)
from gridfleet.endpoint import Backoff, Endpoint
from gridfleet.errors import ConfigError
from gridfleet.outbound import Outbound
from gridfleet.ports import free_port
from gridfleet.protocol import CoordinatorStatus, Topics, decode, encode
from gridfleet.system.broker_thread import BrokerThread

from support.cli import gridfleet
from support.effects import header
from support.output import Output
from support.probe import MqttProbe
from support.wait import async_wait_for, wait_for

# ---- parsing ------------------------------------------------------------------------------


def test_a_list_is_parsed_item_by_item_and_one_url_is_a_list_of_one() -> None:
    brokers = parse_brokers("mqtt://10.0.0.1:1883, mqtts://10.0.0.2 ,ws://10.0.0.3:9001/mqtt")
    assert [(b.scheme, b.host, b.port, b.transport) for b in brokers] == [
        ("mqtt", "10.0.0.1", 1883, "tcp"),
        ("mqtts", "10.0.0.2", 8883, "tcp"),
        ("ws", "10.0.0.3", 9001, "websockets"),
    ]
    assert broker_urls("mqtt://a:1, mqtt://b:2") == ["mqtt://a:1", "mqtt://b:2"]
    assert parse_brokers("mqtt://a:1") == (parse_broker_url("mqtt://a:1"),)
    assert broker_login("mqtt://op:pw@a:1,mqtt://op:pw@b:2") == "op"
    assert broker_login("mqtt://a:1,mqtt://b:2") is None


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("mqtt://a:1,,mqtt://b:2", "an empty item"),
        ("mqtt://a:1,", "an empty item"),
        (",mqtt://a:1", "an empty item"),
        ("mqtt://a:1,http://b:2", "'http://b:2': scheme must be"),
        ("mqtt://a:1,mqtt://b:99999", "'mqtt://b:99999'"),
        ("mqtt://a:1,mqtt://:2", "'mqtt://:2': no host"),
        ("mqtt://a:1,mqtt://b:2?cafile=/x", "'mqtt://b:2?cafile=/x': a CA file is for TLS"),
        ("mqtt://a:1,mqtt://A:1", "mqtt://a:1 is in it twice"),  # names are case-blind
        ("mqtt://a,mqtt://a:1883", "is in it twice"),  # the default port is the same port
        ("mqtt://u:p@a:1,mqtt://v:p@b:2", "every broker of a list logs in as one account"),
        ("mqtt://u:p@a:1,mqtt://b:2", "every broker of a list logs in as one account"),
    ],
)
def test_a_bad_list_is_refused_naming_what_is_wrong(text: str, says: str) -> None:
    with pytest.raises(ConfigError, match="broker") as refused:
        parse_brokers(text)
    assert says in str(refused.value)
    assert "\n" not in str(refused.value)


def test_one_url_where_one_is_wanted() -> None:
    with pytest.raises(ConfigError, match="one URL here, not a list"):
        parse_broker_url("mqtt://a:1,mqtt://b:2")


def test_credentials_ca_file_and_redaction_apply_to_each_item(tmp_path: Path) -> None:
    listed = with_credentials("mqtt://a:1,mqtt://old:pw@b:2", "unit1", "s3cret, pw")
    brokers = parse_brokers(listed)
    assert [(b.host, b.username, b.password) for b in brokers] == [
        ("a", "unit1", "s3cret, pw"),  # a comma in a password stays inside its item
        ("b", "unit1", "s3cret, pw"),
    ]
    shown = redacted(listed)
    assert "s3cret" not in unquote(shown)
    assert shown.count(":***@") == 2
    ca = tmp_path / "ca.pem"
    ca.write_text("not read here")
    trusted = parse_brokers(with_ca_file("mqtts://a:1,wss://b:2/mqtt", str(ca)))
    assert [b.ca_file for b in trusted] == [str(ca), str(ca)]
    # A list mixing TLS and plain brokers: the CA is the TLS ones'; a plain URL refuses one.
    mixed = parse_brokers(with_ca_file("mqtt://a:1,mqtts://b:2", str(ca)))
    assert [b.ca_file for b in mixed] == [None, str(ca)]
    with pytest.raises(ConfigError, match="a CA file is for TLS"):
        parse_brokers(with_ca_file("mqtt://a:1,mqtt://b:2", str(ca)))


# ---- connect_first ------------------------------------------------------------------------


@pytest.fixture
def two_brokers() -> Iterator[tuple[BrokerThread, BrokerThread]]:
    """Two embedded brokers of this test's own (the nodes of a make-believe cluster)."""
    with BrokerThread() as first, BrokerThread() as second:
        yield first, second


@pytest.fixture
def live() -> Iterator[BrokerThread]:
    """One embedded broker of this test's own."""
    with BrokerThread() as running:
        yield running


def dead() -> str:
    """A loopback broker URL nobody listens on."""
    return f"mqtt://127.0.0.1:{free_port()}"


async def test_connect_first_takes_the_first_that_answers_and_names_the_others(
    live: BrokerThread,
) -> None:
    gone, also_gone = dead(), dead()
    async with reach_first(f"{gone},{also_gone},{live.url}", "lists-test") as reached:
        await reached.client.publish("lists/x", b"here", qos=1)
        assert (reached.broker, reached.index, reached.count) == (live.url, 2, 3)
        assert reached.missed == (gone, also_gone)
        assert str(reached) == f"{live.url} (3 of 3; {gone}, {also_gone} did not answer)"
    async with reach_first(f"{live.url},{gone}", "lists-test") as reached:
        assert str(reached) == f"{live.url} (1 of 2)"  # the first answered: the rest not tried
    async with reach_first(live.url, "lists-test") as reached:
        assert str(reached) == live.url


async def test_connect_first_with_none_answering_names_each_and_no_password() -> None:
    gone, also_gone = dead(), dead()
    listed = with_credentials(f"{gone},{also_gone}", "op", "s3cret")
    with pytest.raises(aiomqtt.MqttError) as failed:
        async with connect_first(listed, "lists-test"):
            pass
    said = str(failed.value)
    assert said.startswith("no broker answered: ")
    assert f"mqtt://op@{gone[7:]}" in said and f"mqtt://op@{also_gone[7:]}" in said
    assert "s3cret" not in said
    # One URL: its own error, as before lists.
    with pytest.raises(aiomqtt.MqttError) as alone:
        async with connect_first(gone, "lists-test"):
            pass
    assert "no broker answered" not in str(alone.value)


async def test_connect_first_refuses_a_bad_list_before_connecting(live: BrokerThread) -> None:
    with pytest.raises(ConfigError, match="is in it twice"):
        async with connect_first(f"{live.url},{live.url}", "lists-test"):
            pass


# ---- the Endpoint on a list ---------------------------------------------------------------


def make(url: str, topics: Topics) -> Endpoint:
    """An endpoint that follows the stop topic and says it is online on a device's connection."""
    where = topics.device("device_connection", "d1")
    return Endpoint(
        url,
        "lists-endpoint",
        name="lists",
        subscriptions=lambda: [(topics.fleet("estop"), 1)],
        will=lambda: Outbound(where, b"broken", 1, True),
        online=lambda: Outbound(where, b"online", 1, True),
        offline=lambda: Outbound(where, b"offline", 1, True),
        backoff=Backoff(0.05, 0.2),
    )


async def test_an_endpoint_given_a_dead_broker_first_gets_on_the_live_one(
    live: BrokerThread, topics: Topics, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gridfleet.endpoint")
    gone = dead()
    endpoint = make(f"{gone},{live.url}", topics)
    assert endpoint.brokers == f"one of {gone}, {live.url}"  # for start-up lines
    received: list[tuple[str, bytes]] = []

    async def handle(topic: str, payload: bytes) -> None:
        received.append((topic, payload))

    stop = asyncio.Event()
    task = asyncio.create_task(endpoint.run(stop, handle))
    try:
        await async_wait_for(lambda: endpoint.online.is_set() or task.done(), what="online")
        assert endpoint.where == live.url
        with MqttProbe(live.url) as probe:
            probe.publish(topics.fleet("estop"), b"engaged|probe|x")
        await async_wait_for(lambda: received, what="the stop, on the live broker")
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)
    assert f"lists: on broker {live.url}" in caplog.messages


async def test_an_endpoint_moves_to_the_next_broker_when_its_own_stops(
    two_brokers: tuple[BrokerThread, BrokerThread], topics: Topics
) -> None:
    first, second = two_brokers
    endpoint = make(f"{first.url},{second.url}", topics)
    received: list[tuple[str, bytes]] = []
    lost: list[str] = []

    async def handle(topic: str, payload: bytes) -> None:
        received.append((topic, payload))

    connection = topics.device("device_connection", "d1")
    on_second = MqttProbe(second.url).connect()
    on_second.subscribe(connection)
    stop = asyncio.Event()
    task = asyncio.create_task(endpoint.run(stop, handle, on_disconnect=lost.append))
    try:
        await async_wait_for(lambda: endpoint.online.is_set() or task.done(), what="online")
        assert endpoint.where == first.url  # the list's order
        await asyncio.to_thread(first.stop)
        await async_wait_for(
            lambda: endpoint.connects == 2 and endpoint.online.is_set(),
            20,
            what="online on the second broker",
        )
        assert endpoint.where == second.url
        assert lost, "the lost session was reported"
        await asyncio.to_thread(on_second.wait, connection, lambda m: m.payload == b"online")
        on_second.publish(topics.fleet("estop"), b"released|probe|x")
        await async_wait_for(
            lambda: (topics.fleet("estop"), b"released|probe|x") in received,
            what="a message on the second broker (subscribed again there)",
        )
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)
        on_second.close()


# ---- the commands -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (
            ["status", "--once", "--broker", "mqtt://127.0.0.1:1,mqtt://127.0.0.1:1"],
            "gridfleet status: error: broker list 'mqtt://127.0.0.1:1,mqtt://127.0.0.1:1': "
            "mqtt://127.0.0.1:1 is in it twice",
        ),
        (
            ["job", "list", "--broker", "mqtt://127.0.0.1:1,,mqtt://127.0.0.1:2"],
            "gridfleet job: error: broker list 'mqtt://127.0.0.1:1,,mqtt://127.0.0.1:2': an "
            "empty item (two commas, or one at an end)",
        ),
        (
            ["coordinator", "--map", "playfield", "--broker", "mqtt://127.0.0.1:1,http://h:2"],
            "gridfleet coordinator: error: broker URL 'http://h:2': scheme must be mqtt://, "
            "mqtts://, ws:// or wss://",
        ),
        (
            ["robots", "--scenario", "playfield", "--broker", "mqtt://127.0.0.1:1,mqtt://h:99999"],
            "gridfleet robots: error: broker URL 'mqtt://h:99999': Port out of range 0-65535",
        ),
        (
            ["alerts", "--list", "--broker", "mqtt://a:x@127.0.0.1:1,mqtt://b:y@127.0.0.1:2"],
            "gridfleet alerts: error: broker list 'mqtt://a:***@127.0.0.1:1,mqtt://b:***@"
            "127.0.0.1:2': every broker of a list logs in as one account",
        ),
        (
            ["device", "--unit", "unit1", "--broker", "mqtt://127.0.0.1:1,mqtt://127.0.0.1:1/"],
            "gridfleet device: error: broker list 'mqtt://127.0.0.1:1,mqtt://127.0.0.1:1/': "
            "mqtt://127.0.0.1:1 is in it twice",
        ),
        (
            ["up", "--broker", "mqtt://127.0.0.1:1", "--broker-ws", "ws://h:2,mqtt://h:3"],
            "gridfleet up: error: --broker-ws mqtt://h:3: the page needs a websocket URL, ws:// "
            "or wss://",
        ),
        (
            ["up", "--broker", "mqtt://127.0.0.1:1,", "--broker-ws", "ws://h:2"],
            "gridfleet up: error: broker list 'mqtt://127.0.0.1:1,': an empty item (two "
            "commas, or one at an end)",
        ),
        (
            ["bench", "soak", "--broker", "mqtt://127.0.0.1:1,mqtt://127.0.0.1:2"],
            "gridfleet bench: error: --broker mqtt://127.0.0.1:1,mqtt://127.0.0.1:2: one "
            "broker, not a list (the soak's proxy stands in front of one)",
        ),
    ],
)
def test_a_bad_broker_list_is_one_line_and_exit_2(argv: list[str], says: str) -> None:
    out = gridfleet(*argv)
    assert (out.returncode, out.stdout) == (2, ""), out.stderr
    assert out.stderr.splitlines() == [says]


def test_status_says_which_broker_it_reached(live: BrokerThread, root: str) -> None:
    gone = dead()
    brokers = f"{gone},{live.url}"
    where = f"{live.url} (2 of 2; {gone} did not answer)"
    out = gridfleet("status", "--once", "--broker", brokers, "--root", root, "--timeout", "1")
    assert (out.returncode, out.stdout) == (2, "")
    assert out.stderr.splitlines()[-1] == (
        f"gridfleet status: error: nothing from the coordinator on {where} under root {root!r} "
        "within 1 s: is it running?"
    )
    status = CoordinatorStatus(header=header("coordinator"), state="online", step=3)
    with MqttProbe(live.url) as probe:
        probe.publish(Topics(root).fleet("coordinator"), encode(status), retain=True)
    out = gridfleet("status", "--once", "--broker", brokers, "--root", root)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == f"broker: {where}"
    assert lines[1] == "stop: clear"


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
def test_a_coordinator_on_a_list_keeps_working_when_its_broker_stops(
    two_brokers: tuple[BrokerThread, BrokerThread], root: str, tmp_path: Path
) -> None:
    first, second = two_brokers
    brokers = f"{first.url},{second.url}"
    topics = Topics(root)
    online = topics.fleet("coordinator")

    def says_online(probe: MqttProbe) -> bool:
        seen = probe.received(online)
        return bool(seen) and decode(CoordinatorStatus, seen[-1].payload).state == "online"

    with MqttProbe(first.url) as on_first, MqttProbe(second.url) as on_second:
        on_first.subscribe(online)
        on_second.subscribe(online)
        argv = ["coordinator", "--broker", brokers, "--map", "playfield", "--root", root]
        argv += ["--db", str(tmp_path / "jobs.db"), "--step", "0.1"]
        coordinator = subprocess.Popen(
            [sys.executable, "-m", "gridfleet", *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        log = Output(coordinator)
        try:
            wait_for(lambda: says_online(on_first), 30, what="the coordinator on the first")
            # Its session's start is over (a broker gone during it is noticed only when a
            # publish of it times out, not at once).
            log.wait("coordinator online at", 30)
            assert not on_second.received(online)  # one broker at a time
            first.stop()
            wait_for(lambda: says_online(on_second), 20, what="the coordinator on the second")
            # It reads its requests there: a job submitted to the list (the first refuses at
            # once) is answered.
            job = ["job", "submit", "--pickup", "1,8", "--dropoff", "8,8", "--mass", "1"]
            out = gridfleet(*job, "--broker", brokers, "--root", root, "--timeout", "20")
            assert out.returncode == 0, out.stderr
            assert out.stdout.startswith("accepted: job "), out.stdout
        finally:
            coordinator.terminate()
            coordinator.wait(timeout=20)
            log.wait_closed()
    assert f"coordinator: on broker {second.url}" in log.text, log.text[-2000:]
