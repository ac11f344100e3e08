"""The system bench's listener: messages by topic kind, state latency, and who shows the stop."""

from __future__ import annotations

import asyncio
import time
from collections import Counter
from dataclasses import dataclass
from datetime import UTC, datetime

import aiomqtt

from gridfleet.console.monitor import FleetMonitor
from gridfleet.errors import ProtocolError
from gridfleet.protocol import TOPICS, Topics, UnitState


@dataclass(frozen=True)
class Shown:
    """When one unit's state first showed the awaited stop condition."""

    seen: float  # time.monotonic() at arrival here
    stamped: datetime  # the unit's header timestamp (when it made the state)


class BenchMonitor(FleetMonitor):
    """A FleetMonitor that also counts by kind, times states, and watches stop engagements.

    It decodes only states and routes: the jobs and map views are not measured, and decoding
    them would load the process being measured.
    """

    def __init__(self, client: aiomqtt.Client, topics: Topics, units: int) -> None:
        super().__init__(client, topics)
        self.units = units
        self.by_kind: Counter[str] = Counter()
        self.retained_topics: set[str] = set()  # cleared at the end on an external broker
        self.measuring = False
        self.latencies: list[float] = []  # seconds from a state's header timestamp to arrival
        self._want: bool | None = None  # the estop value awaited on every unit's state
        self._since: datetime = datetime.now(UTC)
        self.shown: dict[str, Shown] = {}
        self.all_shown = asyncio.Event()

    def expect(self, estop: bool) -> None:
        """Start watching for every unit's state to show `estop` (engaged and stopped, or not)."""
        self._want = estop
        self._since = datetime.now(UTC)
        self.shown = {}
        self.all_shown.clear()

    def seen(self, kind: str, unit: str | None, topic: str, payload: bytes) -> bool:
        """Count the message by kind; decode it only when it is a state or the routes."""
        self.by_kind[kind] += 1
        spec = TOPICS.get(kind)
        if spec is not None and spec.retained:
            self.retained_topics.add(topic)
        return kind in ("state", "routes") and super().seen(kind, unit, topic, payload)

    def bad(self, topic: str, kind: str | None, exc: ProtocolError) -> None:
        """Counted, not logged: `other` for a topic outside the protocol, else `bad`."""
        self.by_kind["other" if kind is None else "bad"] += 1

    def on_state(self, unit: str, state: UnitState) -> None:
        """Time the state, and note whether it shows the stop condition awaited."""
        now = datetime.now(UTC)
        if self.measuring:
            self.latencies.append((now - state.header.timestamp).total_seconds())
        want = self._want
        if want is None or unit in self.shown or state.header.timestamp < self._since:
            return
        if state.estop == want and (not want or state.status == "stopped"):
            self.shown[unit] = Shown(time.monotonic(), state.header.timestamp)
            if len(self.shown) >= self.units:
                self.all_shown.set()
