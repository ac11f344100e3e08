"""The embedded broker's subscription table under amqtt's broadcast: a subscribe mid-broadcast."""

from __future__ import annotations

from broker.amqtt_broker import _Subscriptions


def test_the_broker_subscription_table_survives_a_subscribe_mid_broadcast() -> None:
    # What amqtt's broadcast does: iterate (awaiting the ACL check) while a client subscribes.
    table = _Subscriptions({"a/#": []})
    for topic, _ in table.items():
        table[f"{topic}/new"] = []
    for topic in table:
        table.pop(topic)
    assert table == {}
