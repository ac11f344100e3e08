"""A three-node RabbitMQ 3.10 cluster (tests/support/rabbitmq.py) with gridfleet's accounts: what
crosses nodes, what stays on one (retained messages: rabbitmq-server #8096), what the accounts
refuse, and a node killed and back. Each assertion is what RabbitMQ 3.10.8 was seen to do."""

from __future__ import annotations

import base64
import contextlib
import hashlib
import json
import re
import stat
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from gridfleet.accounts import Accounts, default_accounts, write_accounts
from gridfleet.broker.rabbitmq import filter_regex, filters_regex, password_hash, routing_words
from gridfleet.protocol import Topics

from support.cli import gridfleet
from support.probe import MqttProbe
from support.rabbitmq import SBIN, RabbitCluster, rabbitmq_with_accounts
from support.security import login
from support.wait import wait_for

pytestmark = [
    pytest.mark.skipif(not (SBIN / "rabbitmq-server").exists(), reason="no rabbitmq-server 3.10.8"),
    # Each cluster takes 20-30 s to form on two shared cores; a node killed, ~10 s to come back.
    pytest.mark.timeout(240),
    pytest.mark.slow,  # clusters that form in tens of seconds: make test, not test-fast
]

T = Topics("rmq")
# How long a message that would cross would take at most, to say it did not (generous: 2 cores).
SETTLE_S = 3.0


def test_password_hashes_are_rabbitmqs_sha256_format() -> None:
    made = base64.b64decode(password_hash("correct horse", salt=b"salt"))
    assert made[:4] == b"salt" and made[4:] == hashlib.sha256(b"salt" + b"correct horse").digest()
    assert password_hash("correct horse") != password_hash("correct horse")  # salted


def test_filters_become_routing_key_patterns_as_the_mqtt_plugin_maps_topics() -> None:
    assert routing_words("a/b.c") == ["a", "b", "c"]  # 3.10: '.' separates words too
    assert filter_regex("a/+/c") == r"a\.[^.#]*\.c"
    assert filter_regex("a/#") == r"a(?:\..*)?"
    assert filters_regex([]) == "^(?!)"
    pattern = re.compile(filters_regex(["rmq/v1/units/+/state", "rmq/v1/fleet/#"]))
    assert pattern.match("rmq.v1.units.unit1.state") and pattern.match("rmq.v1.units.*.state")
    assert pattern.match("rmq.v1.fleet") and pattern.match("rmq.v1.fleet.estop")
    assert not pattern.match("rmq.v1.units.#")  # a wider subscription is not a narrower one
    assert not pattern.match("rmq.v1.units.unit1.order")


@pytest.fixture(scope="module")
def accounts() -> Accounts:
    return default_accounts(["unit1", "unit2"])


@pytest.fixture(scope="module")
def cluster(
    accounts: Accounts, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[RabbitCluster]:
    """Three nodes with the definitions 'gridfleet accounts rabbitmq' writes."""
    with rabbitmq_with_accounts(accounts, T, tmp_path_factory.mktemp("rabbitmq")) as running:
        yield running


def _as(cluster: RabbitCluster, node: int, accounts: Accounts, name: str) -> MqttProbe:
    """A probe (not connected yet: `with` connects it) logging in on `node` as `name`."""
    return MqttProbe(login(cluster.node_urls[node], accounts, name))


def test_the_three_nodes_form_one_cluster(cluster: RabbitCluster) -> None:
    status = cluster.ctl(1, "cluster_status")
    for name in cluster.names:
        assert name in status.split("Running Nodes", 1)[1].split("Versions", 1)[0]


def test_a_message_on_node0_reaches_subscribers_on_node1_and_node2_at_qos1(
    cluster: RabbitCluster, accounts: Accounts
) -> None:
    with (
        _as(cluster, 1, accounts, "unit1") as on1,
        _as(cluster, 2, accounts, "unit2") as on2,
        _as(cluster, 0, accounts, "coordinator") as coordinator,
    ):
        on1.subscribe(T.fleet("coordinator"))
        on2.subscribe(T.fleet("coordinator"))
        coordinator.publish(T.fleet("coordinator"), b'{"n": 1}', qos=1)
        for probe in (on1, on2):
            seen = probe.wait(T.fleet("coordinator"))
            assert seen.payload == b'{"n": 1}' and seen.qos == 1


def test_strangers_and_wrong_passwords_are_refused(
    cluster: RabbitCluster, accounts: Accounts
) -> None:
    # RabbitMQ answers both with CONNACK 4 (bad user name or password), not 5 as Mosquitto.
    url = cluster.node_urls[0]
    for stranger in (url, login(url, accounts, "unit1", "not the password")):
        with pytest.raises(AssertionError, match="Bad user name or password"):
            MqttProbe(stranger).connect(timeout=5)
    with pytest.raises(AssertionError, match="Bad user name or password"):
        MqttProbe(url.replace("mqtt://", "mqtt://guest:guest@")).connect(timeout=5)  # no guest
    with _as(cluster, 0, accounts, "unit1"):
        pass


def test_a_unit_cannot_write_the_latch_and_is_disconnected_for_trying(
    cluster: RabbitCluster, accounts: Accounts
) -> None:
    with _as(cluster, 1, accounts, "coordinator") as coordinator:
        coordinator.subscribe(T.fleet("estop"))
        coordinator.subscribe(T.all_units("stop"))
        forger = _as(cluster, 0, accounts, "unit1").connect()
        try:
            forger.client.publish(T.fleet("estop"), b'{"forged": true}', qos=1, retain=True)
            # 3.10 closes the connection of a PUBLISH its topic permissions refuse.
            wait_for(lambda: not forger.client.is_connected(), SETTLE_S, what="forger dropped")
        finally:
            forger.close()
        with _as(cluster, 0, accounts, "unit1") as unit1:  # its own press it may send
            unit1.publish(T.unit("stop", "unit1"), b'{"pressed": true}')
            coordinator.wait(T.unit("stop", "unit1"))
        assert coordinator.received(T.fleet("estop")) == []


def test_a_unit_cannot_subscribe_to_another_units_order(
    cluster: RabbitCluster, accounts: Accounts
) -> None:
    with (
        _as(cluster, 2, accounts, "unit1") as spy,
        _as(cluster, 0, accounts, "coordinator") as coordinator,
    ):
        _, refused = spy.client.subscribe(T.unit("order", "unit2"), 1)
        _, own = spy.client.subscribe(T.unit("order", "unit1"), 1)  # allowed, on the same link
        coordinator.publish(T.unit("order", "unit2"), b'{"order": "for unit2"}')
        coordinator.publish(T.unit("order", "unit1"), b'{"order": "for unit1"}')
        # 3.10 answers a refused SUBSCRIBE with no SUBACK, and its channel to the broker's core
        # is gone: the connection stays open but hears nothing more, not even what it may.
        with contextlib.suppress(AssertionError):
            spy.wait(T.unit("order", "unit1"), timeout=SETTLE_S)
        assert refused not in spy._subacks and own not in spy._subacks
        assert spy.received(T.unit("order", "unit2")) == []
        assert spy.received(T.unit("order", "unit1")) == []
    with _as(cluster, 2, accounts, "unit1") as unit1:  # a new connection hears its own orders
        unit1.subscribe(T.unit("order", "unit1"))


def test_retained_messages_stay_on_the_node_they_were_published_through(
    cluster: RabbitCluster, accounts: Accounts
) -> None:
    """rabbitmq-server #8096: each node keeps its own retained store (3.10: DETS on its disk)."""
    latch = T.fleet("estop")
    with _as(cluster, 0, accounts, "operator") as operator:
        operator.publish(latch, b'{"latched": true}', retain=True)

    def late_latch(node: int, topic: str = latch, name: str = "coordinator") -> list[bytes]:
        """What a subscriber to `topic` that joins on `node` now is given of the latch."""
        with _as(cluster, node, accounts, name) as late:
            late.subscribe(topic)
            # One that comes, comes within this; one that does not, gets this long.
            with contextlib.suppress(AssertionError):
                late.wait(latch, timeout=SETTLE_S)
            return [m.payload for m in late.received(latch)]

    assert late_latch(0) == [b'{"latched": true}']  # the node it was published through
    assert late_latch(1) == []  # the others never heard of it
    assert late_latch(2) == []
    # A wildcard subscription gets no retained message even on that node (3.10's store is
    # looked up by exact topic only).
    assert late_latch(0, f"{T.prefix}/fleet/+", "operator") == []


def test_a_node_killed_comes_back_on_its_data_and_the_others_carry_on(
    cluster: RabbitCluster, accounts: Accounts
) -> None:
    latch = T.fleet("estop")
    with _as(cluster, 0, accounts, "operator") as operator:
        operator.publish(latch, b'{"latched": "before the kill"}', retain=True)
    # Node 0 writes its retained store to its disk every 2 s (DETS, 3.10's default
    # retained_message_store_dets_sync_interval): what changed since is lost with a SIGKILL.
    store = next((cluster.directory / "node0" / "mnesia").glob("*/mqtt_retained_*.dets"))
    wait_for(
        lambda: b"before the kill" in store.read_bytes(), 10, what="the latch on node 0's disk"
    )
    cluster.kill_node(0)
    assert len(cluster.pids) == 3  # two nodes and the epmd
    with (
        _as(cluster, 2, accounts, "unit1") as on2,
        _as(cluster, 1, accounts, "coordinator") as on1,
    ):
        on2.subscribe(T.fleet("coordinator"))
        on1.publish(T.fleet("coordinator"), b'{"while": "node0 is dead"}')
        on2.wait(T.fleet("coordinator"))
    cluster.start_node(0)
    with _as(cluster, 0, accounts, "coordinator") as back:
        back.subscribe(latch)  # its retained store outlived the SIGKILL (on its disk)
        assert back.wait(latch).payload == b'{"latched": "before the kill"}'


def _takes(cluster: RabbitCluster, node: int, accounts: Accounts, client_id: str, qos: int) -> bool:
    """Whether `client_id`, a clean session as the coordinator, connects on `node` and is granted
    every unit's state at `qos` (3.10 closes the connection when it cannot: no SUBACK)."""
    probe = MqttProbe(login(cluster.node_urls[node], accounts, "coordinator"), client_id=client_id)
    try:
        probe.connect()
        probe.subscribe(T.all_units("state"), qos=qos, timeout=5)
        return True
    except AssertionError:  # refused, or closed before its SUBACK (WaitTimeout is one too)
        return False
    finally:
        probe.close()


@contextlib.contextmanager
def _publishing_qos1(url: str, topic: str) -> Iterator[None]:
    """QoS 1 messages on `topic` every 10 ms while inside (a unit's states; its link may drop)."""
    feeder = MqttProbe(url)
    feeder.connect()
    done = threading.Event()

    def feed() -> None:
        while not done.wait(0.01):  # a rate, not a synchronisation
            feeder.client.publish(topic, b"{}", qos=1)

    thread = threading.Thread(target=feed, name="qos1-feeder", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join(5)
        feeder.close()


def test_a_clean_sessions_qos1_subscription_pins_its_client_id_to_a_dead_node_qos0_does_not(
    cluster: RabbitCluster, accounts: Accounts
) -> None:
    """Why every gridfleet subscription is QoS 0 (protocol.md §2): RabbitMQ 3.10 keeps a clean
    session's QoS 1 subscription in a durable queue on the client's node; killed with QoS 1
    messages under way, that queue keeps its client id off the survivors until the node is back."""
    with _publishing_qos1(login(cluster.node_urls[1], accounts, "unit1"), T.unit("state", "unit1")):
        watchers = {}
        for qos in (0, 1):
            watcher = MqttProbe(
                login(cluster.node_urls[0], accounts, "coordinator"), client_id=f"pinned-at-{qos}"
            )
            watcher.connect()
            watcher.subscribe(T.all_units("state"), qos=qos)
            watchers[qos] = watcher
        for watcher in watchers.values():  # deliveries under way to each when node 0 dies
            watcher.wait(T.unit("state", "unit1"), timeout=10)
        cluster.kill_node(0)
        for watcher in watchers.values():
            watcher.close()
        wait_for(lambda: _takes(cluster, 1, accounts, "pinned-at-0", 0), 20, what="QoS 0 on node 1")
        for _ in range(3):  # ~15 s: not a moment's election, a queue whose home is dead
            assert not _takes(cluster, 1, accounts, "pinned-at-1", 1)
    cluster.start_node(0)
    wait_for(lambda: _takes(cluster, 1, accounts, "pinned-at-1", 1), 60, what="its queue's home")


def _beams_under(directory: Path) -> list[str]:
    """Erlang VMs or port mappers whose command or environment names `directory`."""
    found = []
    listing = subprocess.run(["ps", "-eo", "pid=,comm="], capture_output=True, text=True).stdout
    for line in listing.splitlines():
        pid, _, name = line.strip().partition(" ")
        if not name.startswith(("beam", "epmd", "erl_child")):
            continue
        try:
            env = Path(f"/proc/{pid}/environ").read_bytes()
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z" and str(directory).encode() in env:
            found.append(f"{pid} {name}")
    return found


def test_a_plain_cluster_takes_anyone_and_leaves_no_process(tmp_path: Path) -> None:
    """The suite's kind (GRIDFLEET_TEST_BROKER=rabbitmq): anonymous, rotating URL lists."""
    cluster = RabbitCluster(tmp_path)
    with cluster:
        assert len(cluster.pids) == 4
        first, second = cluster.url, cluster.url
        assert first.split(",")[1:] + first.split(",")[:1] == second.split(",")
        with MqttProbe(cluster.node_urls[2]) as sub, MqttProbe(cluster.node_urls[0]) as pub:
            sub.subscribe("plain/x")
            pub.publish("plain/x", b"hello")
            sub.wait("plain/x")
        cluster.pause_node(1)
        cluster.resume_node(1)
        assert _beams_under(tmp_path)
    assert cluster.pids == []
    wait_for(lambda: not _beams_under(tmp_path), 10, what="every process of the cluster gone")


def test_the_command_writes_private_definitions_and_a_config_that_loads_them(
    tmp_path: Path,
) -> None:
    accounts_file = tmp_path / "accounts.toml"
    write_accounts(default_accounts(["unit1"]), accounts_file)
    out = tmp_path / "rabbit"
    done = gridfleet(
        "accounts", "rabbitmq", str(out), "--file", str(accounts_file), "--root", "lab"
    )
    assert done.returncode == 0, done.stderr
    assert "mqtt.allow_anonymous false" in done.stdout
    conf = (out / "rabbitmq.conf").read_text()
    assert f"definitions.local.path = {out.resolve() / 'definitions.json'}" in conf
    assert "listeners.tcp = none" in conf and "mqtt.allow_anonymous = false" in conf
    assert stat.S_IMODE((out / "definitions.json").stat().st_mode) == 0o600
    loaded = json.loads((out / "definitions.json").read_text())
    unit1 = next(p for p in loaded["topic_permissions"] if p["user"] == "unit1")
    assert unit1["exchange"] == "amq.topic" and r"lab\.v1\.units\.unit1\.state" in unit1["write"]
    assert all("password" not in u for u in loaded["users"])  # hashes only
