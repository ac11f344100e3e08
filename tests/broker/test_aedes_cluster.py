"""The aedes cluster (three instances on one Redis, broker/aedes/launcher.mjs) as gridfleet runs on
it: messages and retained ones cross instances, QoS 1 queues wait in Redis, an instance killed
comes back on its ports, the accounts are enforced, and a dead instance's wills come late."""

from __future__ import annotations

import json
import stat
import time
from collections.abc import Iterator
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from gridfleet.accounts import Account, Accounts, default_accounts, new_password, write_accounts
from gridfleet.broker.aedes import ITERATIONS, password_hash
from gridfleet.config import parse_broker_url
from gridfleet.protocol import Topics

from support.aedes import AedesCluster, aedes_with_accounts, own_processes_gone
from support.cli import gridfleet
from support.probe import MqttProbe
from support.security import (
    VEHICLES,
    check_a_bridge_carries_only_the_halls_topics,
    check_a_unit_cannot_forge,
    check_a_vehicle_cannot_forge,
    check_only_operators_write_the_latch,
    check_strangers_are_refused,
    check_wills_obey_the_publish_rules,
)
from support.wait import wait_for

# Three instances and a Redis per module, killed and restarted: make test, not test-fast.
pytestmark = pytest.mark.slow

T = Topics("aedes")


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[AedesCluster]:
    """Three anonymous instances on one Redis, for the tests that do not kill one."""
    with AedesCluster(tmp_path_factory.mktemp("aedes")) as running:
        yield running


@pytest.fixture
def own_cluster(tmp_path: Path) -> Iterator[AedesCluster]:
    """A cluster of this test's own, for tests that kill an instance."""
    with AedesCluster(tmp_path / "aedes") as running:
        yield running


def test_the_url_list_begins_at_the_next_instance_on_each_read(cluster: AedesCluster) -> None:
    first, second, third, fourth = (cluster.url.split(",") for _ in range(4))
    assert sorted(first) == sorted(cluster.node_urls) and len(set(first)) == 3
    assert [first[0], second[0], third[0]] == [first[0], first[1], first[2]]
    assert fourth == first
    assert cluster.ws_url.split(",")[0] != cluster.ws_url.split(",")[0]


def test_a_message_on_one_instance_reaches_subscribers_on_the_others(
    cluster: AedesCluster,
) -> None:
    node0, node1, node2 = cluster.node_urls
    topic = f"{T.prefix}/cross"
    with MqttProbe(node1) as one, MqttProbe(node2) as two, MqttProbe(node0) as writer:
        one.subscribe(topic)
        two.subscribe(topic)
        writer.publish(topic, b"from node 0", qos=0)
        assert one.wait(topic).payload == b"from node 0"
        assert two.wait(topic).payload == b"from node 0"


def test_a_page_on_websockets_hears_an_instance_it_is_not_on(cluster: AedesCluster) -> None:
    topic = f"{T.prefix}/ws"
    with MqttProbe(cluster.node_ws_urls[2]) as page, MqttProbe(cluster.node_urls[0]) as writer:
        page.subscribe(topic)
        writer.publish(topic, b"to the page")
        assert page.wait(topic).payload == b"to the page"


def test_retained_messages_are_shared_by_every_instance(cluster: AedesCluster) -> None:
    # Unlike RabbitMQ's node-local store (rabbitmq-server #8096): one Redis holds them.
    topic = f"{T.prefix}/fleet/estop"
    with MqttProbe(cluster.node_urls[0]) as writer:
        writer.publish(topic, b"engaged|operator|x", retain=True)
    for url in cluster.node_urls:
        with MqttProbe(url) as late:
            late.subscribe(topic)
            seen = late.wait(topic)
            assert (seen.payload, seen.retain) == (b"engaged|operator|x", True)
    with MqttProbe(cluster.node_urls[2]) as writer:  # replaced from another instance
        writer.publish(topic, b"released|operator|y", retain=True)
    with MqttProbe(cluster.node_urls[0]) as late:
        late.subscribe(topic)
        assert late.wait(topic).payload == b"released|operator|y"


def test_a_retained_message_is_not_overtaken_and_lost_behind_a_plain_one(
    cluster: AedesCluster,
) -> None:
    # aedes numbers messages as they start and subscribers drop one numbered below the last they
    # had; a retained one, stored in Redis first, was overtaken by the plain one sent after it
    # and lost (2 to 6 rounds in 20 before the launcher published one at a time; aedes #994).
    for n in range(20):
        topic = f"{T.prefix}/order{n}"
        with MqttProbe(cluster.node_urls[0]) as listener, MqttProbe(cluster.node_urls[1]) as sender:
            listener.subscribe(f"{topic}/#")
            sender.publish(f"{topic}/a", b"retained", retain=True)
            sender.publish(f"{topic}/b", b"plain")
            sender.publish(f"{topic}/c", b"retained", retain=True)
            listener.wait(f"{topic}/c")
            assert sorted(listener.messages) == [f"{topic}/{k}" for k in "abc"], n


class Session:
    """A paho client with a persistent session (clean_session false) and a fixed client id."""

    def __init__(self, url: str, client_id: str) -> None:
        broker = parse_broker_url(url)
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id,
                                  clean_session=False)  # fmt: skip
        self.got: list[bytes] = []
        self.session_present: list[bool] = []
        self.client.on_message = lambda c, u, m: self.got.append(bytes(m.payload))
        self.client.on_connect = lambda c, u, flags, rc, p: self.session_present.append(
            bool(flags.session_present)
        )
        self.client.connect(broker.host, broker.port, keepalive=30)
        self.client.loop_start()
        wait_for(lambda: self.session_present, 10, what=f"{client_id} connected")

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def test_a_qos1_message_waits_in_redis_for_a_session_that_comes_back_elsewhere(
    cluster: AedesCluster,
) -> None:
    topic = f"{T.prefix}/units/unit1/order"
    away = Session(cluster.node_urls[1], "aedes-test-unit1")
    result, _ = away.client.subscribe(topic, qos=1)
    assert result == mqtt.MQTT_ERR_SUCCESS
    wait_for(lambda: away.client.want_write() is False, 5)
    with MqttProbe(cluster.node_urls[1]) as marker:  # its SUBACK came: the subscription is kept
        marker.subscribe(topic)
        with MqttProbe(cluster.node_urls[0]) as writer:
            writer.publish(topic, b"before", qos=1)
        marker.wait(topic)
    wait_for(lambda: away.got == [b"before"], what="the order live")
    away.close()
    with MqttProbe(cluster.node_urls[0]) as writer:
        writer.publish(topic, b"while away", qos=1)
    back = Session(cluster.node_urls[2], "aedes-test-unit1")
    try:
        assert back.session_present == [True]
        wait_for(lambda: back.got == [b"while away"], what="the queued order on another node")
    finally:
        back.close()


def test_an_instance_killed_comes_back_on_its_ports_with_the_clusters_state(
    own_cluster: AedesCluster,
) -> None:
    node0, node1, node2 = own_cluster.node_urls
    topic, retained = f"{T.prefix}/kill", f"{T.prefix}/kept"
    with MqttProbe(node1) as writer:
        writer.publish(retained, b"kept in redis", retain=True)
    with MqttProbe(node2) as listener:
        listener.subscribe(topic)
        own_cluster.kill_node(1)
        assert own_cluster.pids[:2] != [] and len(own_cluster.pids) == 3  # two instances, Redis
        with MqttProbe(node0) as writer:  # the survivors carry on
            writer.publish(topic, b"while node 1 is dead")
        assert listener.wait(topic).payload == b"while node 1 is dead"
        with pytest.raises(ConnectionRefusedError):
            MqttProbe(node1).connect(timeout=2)
        own_cluster.start_node(1)
        with MqttProbe(node1) as back:
            back.subscribe(retained)
            assert back.wait(retained).payload == b"kept in redis"
            back.publish(topic, b"from node 1 again")
        listener.wait(topic, lambda m: m.payload == b"from node 1 again")


def test_a_paused_instance_answers_again_when_resumed(own_cluster: AedesCluster) -> None:
    topic = f"{T.prefix}/pause"
    with MqttProbe(own_cluster.node_urls[0]) as listener:
        listener.subscribe(topic)
        own_cluster.pause_node(0)
        with MqttProbe(own_cluster.node_urls[1]) as writer:
            writer.publish(topic, b"while paused")
        assert listener.received(topic) == []  # its instance cannot send it now
        own_cluster.resume_node(0)
        assert listener.wait(topic).payload == b"while paused"


def will_client(url: str, topic: str, payload: bytes, client_id: str) -> mqtt.Client:
    """A connected paho client on `url` with a retained will on `topic`."""
    broker = parse_broker_url(url)
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id)
    client.will_set(topic, payload, qos=1, retain=True)
    connected: list[bool] = []
    client.on_connect = lambda c, u, flags, rc, p: connected.append(not rc.is_failure)
    client.connect(broker.host, broker.port, keepalive=30)
    client.loop_start()
    wait_for(lambda: connected == [True], 10, what=f"{client_id} connected")
    return client


def test_the_wills_of_a_killed_instance_come_from_a_survivor_heartbeats_later(
    own_cluster: AedesCluster,
) -> None:
    # aedes: every 4 heartbeats each survivor publishes the stored wills of instances silent for
    # 3, so 3 to 7 heartbeats (1 s here; 60 s by default: 3 to 7 minutes) after the death.
    topic = T.unit("connection", "unit9")
    dying = will_client(own_cluster.node_urls[0], topic, b"offline-by-will", "aedes-will-unit9")
    try:
        with MqttProbe(own_cluster.node_urls[1]) as listener:
            listener.subscribe(topic)
            killed = time.monotonic()
            own_cluster.kill_node(0)
            heard = listener.wait(topic, timeout=30)
            delay = heard.at - killed
            beat = own_cluster.heartbeat_ms / 1000
            print(f"will of a killed instance after {delay:.1f} s (heartbeat {beat} s)")
            assert heard.payload == b"offline-by-will"
            assert 2 * beat <= delay <= 8 * beat + 2, delay
        with MqttProbe(own_cluster.node_urls[2]) as late:  # retained, in Redis
            late.subscribe(topic)
            assert late.wait(topic).payload == b"offline-by-will"
    finally:
        dying.loop_stop()


def test_a_will_of_a_killed_instance_comes_even_when_its_client_is_back_elsewhere(
    own_cluster: AedesCluster,
) -> None:
    # What a unit that failed over sees: its old will, stored in Redis under the dead instance,
    # is published by a survivor seconds after the unit said it was back (aedes does not drop a
    # will whose client id has connected again).
    topic = T.unit("connection", "unit8")
    first = will_client(own_cluster.node_urls[0], topic, b"offline", "aedes-will-unit8")
    own_cluster.kill_node(0)
    first.loop_stop()
    again = will_client(own_cluster.node_urls[1], topic, b"offline", "aedes-will-unit8")
    try:
        again.publish(topic, b"online", qos=1, retain=True).wait_for_publish(10)
        with MqttProbe(own_cluster.node_urls[2]) as listener:
            listener.subscribe(topic)
            listener.wait(topic, lambda m: m.payload == b"online")
            late = listener.wait(topic, lambda m: m.payload == b"offline", timeout=30)
            assert late.payload == b"offline"  # the stale will, over the live client's word
    finally:
        again.disconnect()
        again.loop_stop()


def test_every_process_of_a_cluster_ends_with_it(tmp_path: Path) -> None:
    with AedesCluster(tmp_path / "aedes") as running:
        pids = running.pids
        assert len(pids) == 4
        running.pause_node(2)  # even a stopped one
    assert own_processes_gone(pids)


# The accounts, enforced by the launcher's hooks on every instance.


@pytest.fixture(scope="module")
def accounts() -> Accounts:
    hall = Account("hall1", new_password(), "bridge")
    return default_accounts(["unit1", "unit2"], VEHICLES).with_account(hall)


@pytest.fixture(scope="module")
def guarded(accounts: Accounts, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A cluster with the file 'gridfleet accounts aedes' writes: its URL list (no login)."""
    with aedes_with_accounts(accounts, T, tmp_path_factory.mktemp("aedes-accounts")) as running:
        yield running.url


def test_strangers_and_wrong_passwords_are_refused(guarded: str, accounts: Accounts) -> None:
    check_strangers_are_refused(guarded, accounts, "operator")


def test_a_unit_cannot_forge_another_unit_or_an_order(guarded: str, accounts: Accounts) -> None:
    check_a_unit_cannot_forge(guarded, accounts, T)


def test_a_device_or_unit_cannot_write_the_latch(guarded: str, accounts: Accounts) -> None:
    check_only_operators_write_the_latch(guarded, accounts, T)


def test_a_will_outside_the_accounts_rules_is_heard_by_nobody(
    guarded: str, accounts: Accounts
) -> None:
    # The launcher drops such a will at the CONNECT, before aedes stores it in Redis.
    assert not any(check_wills_obey_the_publish_rules(guarded, accounts, T))


def test_a_vehicle_cannot_forge_orders_states_or_the_latch(
    guarded: str, accounts: Accounts
) -> None:
    check_a_vehicle_cannot_forge(guarded, accounts, T)


def test_a_halls_bridge_carries_only_what_a_hall_may_say_and_read(
    guarded: str, accounts: Accounts
) -> None:
    check_a_bridge_carries_only_the_halls_topics(guarded, accounts, T, "hall1")


def test_the_command_writes_hashes_and_filters_never_a_password(tmp_path: Path) -> None:
    accounts_file, out = tmp_path / "accounts.toml", tmp_path / "aedes"
    accounts = default_accounts(["unit1"])
    write_accounts(accounts, accounts_file)
    done = gridfleet("accounts", "aedes", str(out), "--file", str(accounts_file), "--root", "lab")
    assert done.returncode == 0, done.stderr
    written = out / "aedes-accounts.json"
    assert f"wrote {written.resolve()}" in done.stdout and "launcher.mjs" in done.stdout
    assert stat.S_IMODE(written.stat().st_mode) == 0o600
    text = written.read_text()
    assert not any(a.password in text for a in accounts.accounts.values())
    users = json.loads(text)["users"]
    unit1 = users["unit1"]
    assert unit1["hash"]["algorithm"] == "pbkdf2-sha512"
    assert unit1["hash"]["iterations"] == ITERATIONS
    assert "lab/v1/units/unit1/connection" in unit1["publish"]
    assert "lab/v1/fleet/estop" not in unit1["publish"]
    assert "lab/v1/fleet/estop" in users["coordinator"]["publish"]


def test_password_hashes_are_salted() -> None:
    made = password_hash("correct horse", salt=b"\x00" * 16)
    assert made["salt"] == "A" * 22 + "=="
    assert password_hash("correct horse")["digest"] != password_hash("correct horse")["digest"]
