"""The embedded broker's subscription table under amqtt's broadcast: a subscribe mid-broadcast."""

from __future__ import annotations

from gridfleet.broker.routing import MAX_CACHED_TOPICS, Subscriptions


def test_the_broker_subscription_table_survives_a_subscribe_mid_broadcast() -> None:
    # What amqtt's broadcast does: iterate (awaiting the ACL check) while a client subscribes.
    table = Subscriptions({"a/#": []})
    for topic, _ in table.items():
        table[f"{topic}/new"] = []
    for topic in table:
        table.pop(topic)
    assert table == {}


def _matches(topic: str, a_filter: str) -> bool:
    """The filter rules the broker applies (amqtt's), for these tests: exact, `+` and `#`."""
    t, f = topic.split("/"), a_filter.split("/")
    if f[-1] == "#":
        return t[: len(f) - 1] == [x if x != "+" else t[i] for i, x in enumerate(f[:-1])]
    return len(t) == len(f) and all(x in ("+", y) for x, y in zip(f, t, strict=True))


def test_a_topic_reaches_the_filters_it_matches_in_the_order_they_were_subscribed() -> None:
    table = Subscriptions({"a/+/state": [], "b/#": [], "a/u1/state": [], "#": []})
    assert table.matching("a/u1/state", _matches) == ("a/+/state", "a/u1/state", "#")
    assert table.matching("b/x/y", _matches) == ("b/#", "#")
    assert table.matching("c", _matches) == ("#",)


def test_a_new_or_removed_filter_changes_what_a_topic_already_routed_reaches() -> None:
    table = Subscriptions({"a/+": []})
    assert table.matching("a/b", _matches) == ("a/+",)
    table["a/b"] = []  # as amqtt adds a filter
    assert table.matching("a/b", _matches) == ("a/+", "a/b")
    del table["a/+"]  # as amqtt drops a filter nobody holds any more
    assert table.matching("a/b", _matches) == ("a/b",)
    table.setdefault("#", [])
    assert table.matching("a/b", _matches) == ("a/b", "#")
    table.pop("a/b")
    assert table.matching("a/b", _matches) == ("#",)
    table.clear()
    assert table.matching("a/b", _matches) == ()


def test_a_session_joining_a_known_filter_needs_no_new_match() -> None:
    calls: list[tuple[str, str]] = []

    def counting(topic: str, a_filter: str) -> bool:
        calls.append((topic, a_filter))
        return _matches(topic, a_filter)

    table = Subscriptions({"a/+": []})
    table.matching("a/b", counting)
    table["a/+"].append(("session", 0))  # as amqtt adds a second subscriber to a filter
    table["a/+"] = table["a/+"]
    assert table.matching("a/b", counting) == ("a/+",)
    assert calls == [("a/b", "a/+")]  # looked up, not searched again


def test_a_client_inventing_topics_cannot_grow_the_table_s_memory_without_bound() -> None:
    table = Subscriptions({"a/#": [], "b/+": []})
    for n in range(MAX_CACHED_TOPICS + 10):
        table.matching(f"a/{n}", _matches)
    assert len(table._matching) <= MAX_CACHED_TOPICS
    assert table.matching("a/1", _matches) == ("a/#",)  # still right after starting afresh
