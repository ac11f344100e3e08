"""The system bench's listener: messages by topic kind, state latency, and who shows the stop.

`gridfleet.monitor.FleetMonitor` keeps the latest view of the fleet but neither the arrival time
of a state nor counts by kind, which are what the bench measures; hence this small listener.
"""

from __future__ import annotations

import asyncio
import time
from collections import Counter
from dataclasses import dataclass
from datetime import UTC, datetime

import aiomqtt

from gridfleet.errors import ProtocolError
from gridfleet.protocol import TOPICS, Routes, Topics, UnitState, decode


@dataclass(frozen=True)
class Shown:
    """When one unit's state first showed the awaited stop condition."""

    seen: float  # time.monotonic() at arrival here
    stamped: datetime  # the unit's header timestamp (when it made the state)


class BenchMonitor:
    """Subscribes to `<root>/v1/#` at QoS 0; counts, times states, and watches stop engagements."""

    def __init__(self, client: aiomqtt.Client, topics: Topics, units: int) -> None:
        self.client = client
        self.topics = topics
        self.units = units
        self.by_kind: Counter[str] = Counter()
        self.step = 0
        self.retained_topics: set[str] = set()  # cleared at the end on an external broker
        self.measuring = False
        self.latencies: list[float] = []  # seconds from a state's header timestamp to arrival
        self._want: bool | None = None  # the estop value awaited on every unit's state
        self._since: datetime = datetime.now(UTC)
        self.shown: dict[str, Shown] = {}
        self.all_shown = asyncio.Event()

    @property
    def messages(self) -> int:
        """Every message seen so far."""
        return sum(self.by_kind.values())

    async def start(self) -> None:
        """Subscribe to everything under the root."""
        await self.client.subscribe(f"{self.topics.prefix}/#", qos=0)

    def expect(self, estop: bool) -> None:
        """Start watching for every unit's state to show `estop` (engaged and stopped, or not)."""
        self._want = estop
        self._since = datetime.now(UTC)
        self.shown = {}
        self.all_shown.clear()

    async def listen(self) -> None:
        """Consume messages until the client disconnects."""
        async for message in self.client.messages:
            topic = str(message.topic)
            try:
                kind, unit = self.topics.parse(topic)
            except ProtocolError:
                self.by_kind["other"] += 1
                continue
            self.by_kind[kind] += 1
            spec = TOPICS.get(kind)
            if spec is not None and spec.retained:
                self.retained_topics.add(topic)
            payload = (
                bytes(message.payload) if isinstance(message.payload, bytes | bytearray) else b""
            )
            try:
                if kind == "state" and unit is not None:
                    self._on_state(unit, decode(UnitState, payload))
                elif kind == "routes":
                    routes = decode(Routes, payload, TOPICS["routes"].max_bytes)
                    self.step = max(self.step, routes.step)
            except ProtocolError:
                self.by_kind["bad"] += 1

    def _on_state(self, unit: str, state: UnitState) -> None:
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
