"""Checks any broker with gridfleet's accounts must pass (the embedded amqtt and Mosquitto alike)."""

from __future__ import annotations

import pytest

from gridfleet.accounts import Accounts
from gridfleet.config import with_credentials
from gridfleet.protocol import Topics

from support.probe import MqttProbe
from support.wait import wait_for


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
    """unit1's forged state (retained) and order for unit2 reach nobody, nor does a ghost unit
    without an account of its own (with accounts on, a unit exists only if its account does);
    unit1's own state does."""
    t = topics
    with (
        MqttProbe(login(url, accounts, "coordinator")) as coordinator,
        MqttProbe(login(url, accounts, "unit2")) as unit2,
        MqttProbe(login(url, accounts, "unit1")) as unit1,
    ):
        coordinator.subscribe(t.all_units("state"))
        coordinator.subscribe(t.all_units("factsheet"))
        unit2.subscribe(t.unit("order", "unit2"))
        ghost = b'{"forged": "a ghost unit"}'
        unit1.publish(t.unit("factsheet", "ghost"), ghost, retain=True)
        unit1.publish(t.unit("state", "ghost"), ghost, retain=True)
        unit1.publish(t.unit("state", "unit2"), b'{"forged": true}', retain=True)
        unit1.publish(t.unit("order", "unit2"), b'{"forged": true}')
        unit1.publish(t.unit("state", "unit1"), b'{"own": true}', retain=True)
        # Its own state arrives; published after the forgeries, so they had their chance.
        wait_for(lambda: coordinator.received(t.unit("state", "unit1")), what="unit1's own state")
        assert coordinator.received(t.unit("state", "unit2")) == []
        assert coordinator.received(t.unit("state", "ghost")) == []
        assert coordinator.received(t.unit("factsheet", "ghost")) == []
        assert unit2.received(t.unit("order", "unit2")) == []
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
        device.publish(latch, b"released|device-unit1|x", retain=True)
        unit1.publish(latch, b"released|unit1|x", retain=True)
        unit1.publish(t.unit("stop", "unit2"), b"engaged|unit2|forged", retain=True)
        device.publish(own_press, b"engaged|device-unit1|button", retain=True)
        operator.publish(latch, b"released|operator|checked", retain=True)
        # The operator's release arrives; published last, so the forgeries had their chance.
        wait_for(lambda: coordinator.received(latch), what="the operator's release")
        assert [m.payload for m in coordinator.received(latch)] == [b"released|operator|checked"]
        assert coordinator.received(t.unit("stop", "unit2")) == []
        wait_for(lambda: coordinator.received(own_press), what="the device's own press")
        device.publish(own_press, b"", retain=True)  # tidy: no press left for the next check
