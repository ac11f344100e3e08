"""Checks any broker with gridfleet's accounts must pass (the embedded amqtt and Mosquitto alike)."""

from __future__ import annotations

import pytest

from gridfleet.accounts import Accounts, VehicleLink
from gridfleet.config import with_credentials
from gridfleet.protocol import Topics

from support.probe import MqttProbe
from support.wait import wait_for

# Two VDA 5050 vehicles, as the accounts of these checks name them.
VEHICLES = (VehicleLink("agv1", "uagv/v2/acme/sn-1"), VehicleLink("agv2", "uagv/v2/acme/sn-2"))


def login(url: str, accounts: Accounts, name: str, password: str | None = None) -> str:
    """`url` logging in as account `name` (with `password` instead of its own, if given)."""
    account = accounts.get(name)
    return with_credentials(url, account.name, password or account.password)


def check_strangers_are_refused(url: str, accounts: Accounts, name: str) -> None:
    """Anonymous and wrong-password clients are refused; account `name` gets in."""
    for stranger in (url, login(url, accounts, name, "not the password")):
        with pytest.raises(AssertionError, match="Not authorized"):
            MqttProbe(stranger).connect(timeout=5)
    with MqttProbe(login(url, accounts, name)):
        pass


def check_a_unit_cannot_forge(url: str, accounts: Accounts, topics: Topics) -> None:
    """unit1's forged state (retained) and order for unit2, and a request only people may send,
    reach nobody, nor does a ghost unit without an account of its own (with accounts on, a unit
    exists only if its account does); unit1's own state does."""
    t = topics
    with (
        MqttProbe(login(url, accounts, "coordinator")) as coordinator,
        MqttProbe(login(url, accounts, "unit2")) as unit2,
        MqttProbe(login(url, accounts, "unit1")) as unit1,
    ):
        coordinator.subscribe(t.all_units("state"))
        coordinator.subscribe(t.all_units("factsheet"))
        coordinator.subscribe(t.all_requests)
        unit2.subscribe(t.unit("order", "unit2"))
        unit2.subscribe(t.unit("state", "unit1"))  # its marker, below
        ghost = b'{"forged": "a ghost unit"}'
        unit1.publish(t.unit("factsheet", "ghost"), ghost, retain=True)
        unit1.publish(t.unit("state", "ghost"), ghost, retain=True)
        unit1.publish(t.unit("state", "unit2"), b'{"forged": true}', retain=True)
        unit1.publish(t.unit("order", "unit2"), b'{"forged": true}')
        unit1.publish(t.request("clear_obstacles"), b'{"forged": "a cleared map"}')  # people only
        unit1.publish(t.request("job_history"), b'{"forged": "a page of the history"}')
        unit1.publish(t.request("remove_unit"), b'{"forged": "unit2 removed"}')  # people only
        unit1.publish(t.unit("state", "unit1"), b'{"own": true}', retain=True)
        # Its own state arrives, at each listener; published after the forgeries on the same
        # connection, and a broker keeps one client's messages in order for each subscriber, so
        # the forgeries had their chance at each of them.
        wait_for(lambda: coordinator.received(t.unit("state", "unit1")), what="unit1's own state")
        wait_for(lambda: unit2.received(t.unit("state", "unit1")), what="unit1's state at unit2")
        assert coordinator.received(t.unit("state", "unit2")) == []
        assert coordinator.received(t.unit("state", "ghost")) == []
        assert coordinator.received(t.unit("factsheet", "ghost")) == []
        assert unit2.received(t.unit("order", "unit2")) == []
        assert coordinator.received(t.request("clear_obstacles")) == []
        assert coordinator.received(t.request("job_history")) == []
        assert coordinator.received(t.request("remove_unit")) == []
    with MqttProbe(login(url, accounts, "coordinator")) as late:
        late.subscribe(t.all_units("state"))
        wait_for(lambda: late.received(t.unit("state", "unit1")), what="the retained own state")
        assert late.received(t.unit("state", "unit2")) == []  # no forged retained state either


def check_only_operators_write_the_latch(url: str, accounts: Accounts, topics: Topics) -> None:
    """A device or unit can press its own stop but not write the latch or another's press."""
    t = topics
    latch, own_press = t.fleet("estop"), t.device("device_stop", "device-unit1")
    with (
        MqttProbe(login(url, accounts, "coordinator")) as coordinator,
        MqttProbe(login(url, accounts, "device-unit1")) as device,
        MqttProbe(login(url, accounts, "unit1")) as unit1,
        MqttProbe(login(url, accounts, "operator")) as operator,
    ):
        for topic in (latch, t.all_units("stop"), t.all_devices("device_stop")):
            coordinator.subscribe(topic)
        coordinator.subscribe(t.unit("state", "unit1"))
        device.publish(latch, b"released|device-unit1|x", retain=True)
        unit1.publish(latch, b"released|unit1|x", retain=True)
        unit1.publish(t.unit("stop", "unit2"), b"engaged|unit2|forged", retain=True)
        # After its forgeries each forger sends what it may; a broker keeps one connection's
        # messages in order, so once those arrive the forgeries have been dealt with.
        device.publish(own_press, b"engaged|device-unit1|button", retain=True)
        unit1.publish(t.unit("state", "unit1"), b'{"marker": true}')
        coordinator.wait(own_press)
        coordinator.wait(t.unit("state", "unit1"))
        operator.publish(latch, b"released|operator|checked", retain=True)
        coordinator.wait(latch)
        assert [m.payload for m in coordinator.received(latch)] == [b"released|operator|checked"]
        assert coordinator.received(t.unit("stop", "unit2")) == []
        device.publish(own_press, b"", retain=True)  # tidy: no press left for the next check


def forged_wills(topics: Topics) -> list[tuple[str, str, bytes, bool]]:
    """(account, will topic, payload, retain) for wills outside each account's publish rules."""
    t = topics
    return [
        ("device-unit1", t.fleet("estop"), b"released|operator|a device's will", True),
        ("device-unit1", t.unit("connection", "unit2"), b"offline-by-device-will", True),
        ("unit1", t.fleet("estop"), b"released|operator|a unit's will", True),
        ("unit1", t.unit("connection", "unit2"), b"offline-by-unit1-will", True),
        ("unit1", t.unit("order", "unit2"), b'{"forged": "order by will"}', False),
    ]


def check_wills_obey_the_publish_rules(url: str, accounts: Accounts, topics: Topics) -> list[bool]:
    """A will its account could not publish is heard by nobody, live or retained; unit1's will on
    its own connection is heard. Returns, per forged will, whether the CONNECT was refused."""
    t = topics
    forged = forged_wills(t)
    payloads = {payload for *_, payload, _ in forged}
    watched = [t.fleet("estop"), t.all_units("connection")]
    refused = []
    with (
        MqttProbe(login(url, accounts, "coordinator")) as coordinator,
        MqttProbe(login(url, accounts, "unit2")) as unit2,
    ):
        for topic in watched:
            coordinator.subscribe(topic)
        unit2.subscribe(t.unit("order", "unit2"))
        for account, topic, payload, retain in forged:
            client = MqttProbe(login(url, accounts, account)).will(topic, payload, retain)
            try:
                client.connect(timeout=5)
            except AssertionError as exc:
                assert "Not authorized" in str(exc), exc
                refused.append(True)
                continue
            refused.append(False)
            client.drop()
        # The control, last: a will the account may publish is heard (so the others had time).
        own = t.unit("connection", "unit1")
        MqttProbe(login(url, accounts, "unit1")).will(own, b"unit1-own-will", True).connect().drop()
        wait_for(lambda: coordinator.received(own), what="unit1's own will")
        everything = [*coordinator.messages.values(), *unit2.messages.values()]
        heard = [m for ms in everything for m in ms if m.payload in payloads]
        assert heard == [], heard
    with MqttProbe(login(url, accounts, "operator")) as late:  # nothing forged was retained
        for topic in watched:
            late.subscribe(topic)
        wait_for(lambda: late.received(own), what="the retained own will")
        kept = [m for ms in late.messages.values() for m in ms if m.payload in payloads]
        assert kept == [], kept
    return refused


def check_a_device_cannot_take_the_coordinators_connection(
    url: str, accounts: Accounts, topics: Topics
) -> bool:
    """device-unit1 connecting with the coordinator's or unit2's client id does not cut them off.

    Returns whether the broker refused those connections (the embedded broker does)."""
    t = topics
    with (
        MqttProbe(login(url, accounts, "coordinator"), "coordinator") as coordinator,
        MqttProbe(login(url, accounts, "unit2"), "unit2") as unit2,
    ):
        coordinator.subscribe(t.fleet("estop"))
        unit2.subscribe(t.unit("order", "unit2"))
        refused = True
        for taken in ("coordinator", "unit2", "unit2-3fa2c1d0"):
            thief = MqttProbe(login(url, accounts, "device-unit1"), taken)
            try:
                thief.connect(timeout=5)
            except AssertionError as exc:
                assert "Not authorized" in str(exc), exc
                continue
            refused = False
            thief.close()
        # Both still connected and subscribed: each hears what it is sent.
        with MqttProbe(login(url, accounts, "operator")) as operator:
            operator.publish(t.fleet("estop"), b"released|operator|still there", retain=False)
        with MqttProbe(login(url, accounts, "coordinator"), "coordinator-2") as other:
            other.publish(t.unit("order", "unit2"), b'{"still": "there"}')
        coordinator.wait(t.fleet("estop"), lambda m: m.payload.endswith(b"still there"))
        unit2.wait(t.unit("order", "unit2"), lambda m: b"still" in m.payload)
    return refused


def check_a_vehicle_cannot_forge(url: str, accounts: Accounts, topics: Topics) -> None:
    """A vehicle's account reaches only its own VDA 5050 topics: an order or instant action for
    another vehicle (or for itself: only the adapter orders), another vehicle's state, a
    gridfleet unit's state or the latch reach nobody; its own state does. The adapter's account
    orders its vehicles but cannot speak for a unit that is not one of them."""
    t = topics
    agv1, agv2 = VEHICLES
    with (
        MqttProbe(login(url, accounts, "vda5050")) as adapter,
        MqttProbe(login(url, accounts, "agv2")) as vehicle2,
        MqttProbe(login(url, accounts, "agv1")) as vehicle1,
        MqttProbe(login(url, accounts, "coordinator")) as coordinator,
    ):
        adapter.subscribe(f"{agv2.topic}/state")
        adapter.subscribe(f"{agv1.topic}/state")  # its marker, below
        vehicle2.subscribe(f"{agv2.topic}/order")
        vehicle2.subscribe(f"{agv2.topic}/instantActions")
        vehicle1.subscribe(f"{agv1.topic}/order")
        coordinator.subscribe(t.all_units("state"))
        coordinator.subscribe(t.fleet("estop"))
        forged = b'{"forged": true}'
        vehicle1.publish(f"{agv2.topic}/order", forged)
        vehicle1.publish(f"{agv2.topic}/instantActions", forged)
        vehicle1.publish(f"{agv1.topic}/order", forged)
        vehicle1.publish(f"{agv2.topic}/state", forged, retain=True)
        vehicle1.publish(t.unit("state", "agv1"), forged, retain=True)
        vehicle1.publish(t.fleet("estop"), b"released|agv1|forged", retain=True)
        by_adapter = b'{"forged by": "vda5050"}'
        adapter.publish(t.unit("state", "unit1"), by_adapter, retain=True)  # not one of its units
        adapter.publish(t.unit("state", "agv2"), b'{"adapter": true}')  # one of them
        vehicle1.publish(f"{agv1.topic}/state", b'{"own": true}')
        # The marker, published after the forgeries on the same connection: a broker keeps one
        # client's messages in order for each subscriber, so the forgeries had their chance.
        wait_for(lambda: adapter.received(f"{agv1.topic}/state"), what="agv1's own state")
        wait_for(lambda: coordinator.received(t.unit("state", "agv2")), what="the adapter's")
        assert adapter.received(f"{agv2.topic}/state") == []
        assert vehicle2.received(f"{agv2.topic}/order") == []
        assert vehicle2.received(f"{agv2.topic}/instantActions") == []
        assert vehicle1.received(f"{agv1.topic}/order") == []
        assert coordinator.received(t.unit("state", "agv1")) == []
        # (unit1's own state may be retained there by another check on this broker)
        assert by_adapter not in [m.payload for m in coordinator.received(t.unit("state", "unit1"))]
        latch = [m.payload for m in coordinator.received(t.fleet("estop"))]
        assert b"released|agv1|forged" not in latch  # (a latch retained before may be there)
        adapter.publish(f"{agv2.topic}/order", b'{"adapter order": true}')
        wait_for(lambda: vehicle2.received(f"{agv2.topic}/order"), what="the adapter's order")


def check_a_bridge_carries_only_the_halls_topics(
    url: str, accounts: Accounts, topics: Topics, bridge: str
) -> None:
    """A hall's bridge account (on the central broker) says only what a hall's units and devices
    may say, and reads only what the hall needs: the latch, an order, a request or a fleet view
    it writes reaches nobody; requests and fleet views never reach it; a state and a goal do."""
    t = topics
    with (
        MqttProbe(login(url, accounts, "coordinator")) as coordinator,
        MqttProbe(login(url, accounts, "operator")) as operator,
        MqttProbe(login(url, accounts, bridge)) as hall,
    ):
        for topic in (t.fleet("estop"), t.all_units("order"), t.all_requests, t.fleet("jobs")):
            coordinator.subscribe(topic)
        coordinator.subscribe(t.fleet("coordinator"))
        coordinator.subscribe(t.unit("state", "unit1"))  # its marker, below
        hall.subscribe(t.all_requests)
        hall.subscribe(t.fleet("jobs"))
        hall.subscribe(t.unit("goal", "unit1"))  # the operator's marker, below
        hall.publish(t.fleet("estop"), b"released|hall|forged", retain=True)
        hall.publish(t.unit("order", "unit1"), b'{"forged": "an order"}')
        hall.publish(t.request("cancel_job"), b'{"forged": "a request"}')
        hall.publish(t.fleet("jobs"), b'{"forged": "a queue"}', retain=True)
        hall.publish(t.fleet("coordinator"), b'{"forged": "a coordinator"}', retain=True)
        hall.publish(t.unit("state", "unit1"), b'{"carried": true}')
        operator.publish(t.request("cancel_job"), b'{"for the coordinator": true}')
        operator.publish(t.unit("goal", "unit1"), b'{"carried": true}')
        # Each marker comes after the messages before it on its connection (a broker keeps one
        # client's messages in order for each subscriber): the others had their chance.
        wait_for(lambda: coordinator.received(t.unit("state", "unit1")), what="the hall's state")
        wait_for(lambda: hall.received(t.unit("goal", "unit1")), what="the operator's goal")
        wait_for(lambda: coordinator.received(t.request("cancel_job")), what="the request")
        assert b"released|hall|forged" not in [
            m.payload for m in coordinator.received(t.fleet("estop"))
        ]
        assert coordinator.received(t.unit("order", "unit1")) == []
        assert [m.payload for m in coordinator.received(t.request("cancel_job"))] == [
            b'{"for the coordinator": true}'
        ]
        assert coordinator.received(t.fleet("jobs")) == []
        assert b'{"forged": "a coordinator"}' not in [
            m.payload for m in coordinator.received(t.fleet("coordinator"))
        ]
        assert hall.received(t.request("cancel_job")) == [] and hall.received(t.fleet("jobs")) == []
