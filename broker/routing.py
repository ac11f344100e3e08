"""The embedded broker's subscription table: the filters a topic matches, looked up once per topic."""

# amqtt 0.12.1 matches every published topic against every filter of the table, one by one, and
# formats a debug line for each filter that does not match (whether debug is on or not). A fleet
# has a filter per unit (its order topic) and publishes thousands of messages a second: that
# search was a fifth of the broker's time (py-spy, 100 units). A fleet's topics are few and
# repeat, so the filters each one matches are kept until the table's filters change.

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any

# Topics whose matches are kept; past that (a client inventing topics) the table starts afresh.
MAX_CACHED_TOPICS = 16384

Sessions = list[tuple[Any, int]]  # (amqtt session, subscription QoS), in subscription order


class Subscriptions(dict[str, Sessions]):
    """amqtt's subscription table (filter -> sessions), iterated over a snapshot."""

    # amqtt 0.12.1's broadcast awaits the ACL check while iterating this table: a client
    # subscribing to a new filter meanwhile raised "dictionary changed size during iteration"
    # and the message reached nobody further (seen in `gridfleet up --accounts` at start-up).

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._matching: dict[str, tuple[str, ...]] = {}

    def matching(self, topic: str, matches: Callable[[str, str], bool]) -> tuple[str, ...]:
        """The filters `topic` matches, in the table's order (`matches(topic, filter)` decides)."""
        found = self._matching.get(topic)
        if found is None:
            if len(self._matching) >= MAX_CACHED_TOPICS:
                self._matching.clear()
            found = tuple(f for f in super().__iter__() if matches(topic, f))
            self._matching[topic] = found
        return found

    def items(self) -> list[tuple[str, Sessions]]:  # type: ignore[override]
        return list(super().items())

    def __iter__(self) -> Iterator[str]:
        return iter(list(super().__iter__()))

    # Every change to the set of filters forgets what was matched. The sessions' lists are read
    # when a message is routed, so a session joining or leaving a filter needs nothing here.

    def __setitem__(self, key: str, value: Sessions) -> None:
        if key not in self:
            self._matching.clear()
        super().__setitem__(key, value)

    def __delitem__(self, key: str) -> None:
        super().__delitem__(key)
        self._matching.clear()

    def pop(self, key: str, *default: Any) -> Any:
        self._matching.clear()
        return super().pop(key, *default)

    def popitem(self) -> tuple[str, Sessions]:
        self._matching.clear()
        return super().popitem()

    def clear(self) -> None:
        self._matching.clear()
        super().clear()

    def setdefault(self, key: str, default: Sessions | None = None) -> Sessions:
        if key not in self:
            self._matching.clear()
        return super().setdefault(key, [] if default is None else default)

    def update(self, *args: Any, **kwargs: Any) -> None:
        self._matching.clear()
        super().update(*args, **kwargs)

    def __ior__(self, other: Iterable[Any]) -> Subscriptions:  # type: ignore[override,misc]
        self.update(other)
        return self
