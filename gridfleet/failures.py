"""A handler's failures told on `errors` without flooding it, in words anyone may read (pure).

When a component's handler raises on a message (a bug), the fleet hears of it on `errors`: the
topic, and `internal error in <component>: <ExceptionClass> while handling a message on this
topic`, never the exception's text or its traceback (those stay in the component's log). A storm
of failures is told, per topic, at once for the first and then at most once every `every_s`,
each report counting the failures since the one before (`internal error in <component>: 12
failures (the latest TypeError) while handling messages on this topic`), and a component tells at
most `burst` reports at once, `per_s` a second after (under the embedded broker's own limit of a
client's reports, protocol.md §10). What is not told at once is told when its time comes (`due`).
`parse_failure` reads a report back: the coordinator counts them (`gridfleet_handler_failures`)
and the alerts process raises `handler_failures` on them.
"""

from __future__ import annotations

import re
from collections import OrderedDict
from dataclasses import dataclass

PREFIX = "internal error in "
EVERY_S = 1.0  # a topic's failures are told at most once a second (the first one at once)
BURST = 10  # reports a component may tell at once (on as many topics)
PER_S = 2.0  # and then a second
MAX_TOPICS = 256  # topics remembered (the oldest told first out)
# What one report may add to the count read back: a second's failures of a busy topic are far
# fewer; a report claiming more (anyone who may write on `errors` can) adds no more than this.
MAX_COUNT = 10_000
# The kinds of component that tell their failures: a metric's label takes one of these.
COMPONENTS = ("coordinator", "unit", "vda5050", "device", "alerts")
OTHER = "other"
_REPORT = re.compile(
    r"internal error in (?P<component>[a-z0-9_]+): (?:(?P<count>\d{1,9}) failures \(the latest "
    r"(?P<latest>[A-Za-z_][\w.]*)\)|(?P<one>[A-Za-z_][\w.]*)) while handling"
)


def failure_reason(component: str, error: str, count: int = 1) -> str:
    """The reason of a report: `count` failures of `component`, the latest raising `error`."""
    if count == 1:
        return f"{PREFIX}{component}: {error} while handling a message on this topic"
    return (
        f"{PREFIX}{component}: {count} failures (the latest {error}) while handling messages "
        "on this topic"
    )


@dataclass(frozen=True)
class Failure:
    """What a report on `errors` says of a handler's failures."""

    component: str  # one of COMPONENTS, or OTHER
    count: int  # failures it tells of (1, or those since the topic's last report)
    error: str  # the class of the latest exception


def parse_failure(reason: str) -> Failure | None:
    """The failures a report's reason tells of; None for any other report (a refusal)."""
    found = _REPORT.match(reason)
    if found is None:
        return None
    component = found["component"] if found["component"] in COMPONENTS else OTHER
    if found["count"] is not None:
        return Failure(component, min(MAX_COUNT, max(1, int(found["count"]))), found["latest"])
    return Failure(component, 1, found["one"])


@dataclass
class _Topic:
    told_at: float | None = None  # when a report on it last went out
    untold: int = 0  # failures since
    latest: str = ""  # the class of the latest


class FailureReports:
    """Which failures to tell now, and which later: `failed`, then `due` when `next_due` comes."""

    def __init__(
        self,
        component: str,
        *,
        every_s: float = EVERY_S,
        burst: int = BURST,
        per_s: float = PER_S,
        max_topics: int = MAX_TOPICS,
    ) -> None:
        self.component = component
        self.every_s = every_s
        self.burst = burst
        self.per_s = per_s
        self.max_topics = max_topics
        self.failures = 0  # every failure, told or not
        self._topics: OrderedDict[str, _Topic] = OrderedDict()
        self._tokens = float(burst)
        self._tokens_at: float | None = None

    def failed(self, topic: str, error: str, now: float) -> str | None:
        """A handler raised `error` (its class name) on `topic`: the reason to tell now, or None
        (counted, and told by `due` when its time comes)."""
        self.failures += 1
        entry = self._topics.get(topic)
        if entry is None:
            entry = self._topics[topic] = _Topic()
            self._forget_old()
        entry.untold += 1
        entry.latest = error
        return self._tell(entry, now)

    def due(self, now: float) -> list[tuple[str, str]]:
        """(topic, reason) of the failures not told yet whose time has come."""
        told = []
        for topic, entry in list(self._topics.items()):
            if entry.untold:
                reason = self._tell(entry, now)
                if reason is not None:
                    told.append((topic, reason))
        return told

    def next_due(self, now: float) -> float | None:
        """When `due` next has something to tell (None: nothing waits)."""
        waiting = [
            now if e.told_at is None else e.told_at + self.every_s
            for e in self._topics.values()
            if e.untold
        ]
        if not waiting:
            return None
        refill = 0.0 if self._refilled(now) >= 1 else (1 - self._refilled(now)) / self.per_s
        return max(min(waiting), now + refill)

    def _tell(self, entry: _Topic, now: float) -> str | None:
        if entry.told_at is not None and now - entry.told_at < self.every_s:
            return None
        tokens = self._refilled(now)
        if tokens < 1:
            return None
        self._tokens, self._tokens_at = tokens - 1, now
        reason = failure_reason(self.component, entry.latest, entry.untold)
        entry.told_at, entry.untold = now, 0
        return reason

    def _refilled(self, now: float) -> float:
        if self._tokens_at is None:
            return self._tokens
        return min(float(self.burst), self._tokens + (now - self._tokens_at) * self.per_s)

    def _forget_old(self) -> None:
        """At most `max_topics` remembered: the oldest with nothing untold go first."""
        for topic in [t for t, e in self._topics.items() if not e.untold]:
            if len(self._topics) <= self.max_topics:
                return
            del self._topics[topic]
        while len(self._topics) > self.max_topics:
            self._topics.popitem(last=False)  # all untold: the oldest is dropped, still counted
