"""The I/O shell of one unit: pumps messages between its endpoint and its core, and steps it.

Every decision is the core's (`robots/core.py`); the session (last will, reconnecting with back-off,
the goodbye) is the endpoint's. What is left here: the clock, the step loop that reads the unit's
sensors from the world and applies its move, and sending what the core returns in its order.
"""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import Callable, Sequence

from gridfleet.endpoint import Backoff, Endpoint
from gridfleet.outbound import Outbound
from gridfleet.protocol import Topics
from gridfleet.robots.core import UnitCore
from gridfleet.robots.unit import UnitLogic
from gridfleet.robots.world import SimulatedWorld
from gridfleet.tasks import cancel_and_wait


class UnitShell:
    """Runs one simulated unit: its MQTT endpoint, its core, and its steps in the world."""

    def __init__(
        self,
        logic: UnitLogic,
        world: SimulatedWorld,
        broker_url: str,
        topics: Topics,
        *,
        color: str = "#607d8b",
        watch_remote: bool = False,
        reconnect_s: float = 0.1,
        max_reconnect_s: float = 5.0,
        on_step: Callable[[UnitLogic], None] | None = None,
        model: str = "gridfleet-sim",
        phase_s: float = 0.0,
    ) -> None:
        self.core = UnitCore(logic, topics, color=color, model=model)
        # Where in the step period this unit steps: a unit has a clock of its own, so the units
        # of one process do not all step (and publish) in the same instant.
        self.phase_s = phase_s
        self.on_step = on_step  # after each step, e.g. to save where the unit stands
        self.world = world
        self.id = logic.unit_id
        # One client id per shell: two processes started with the same unit never kick each other.
        self.endpoint = Endpoint(
            broker_url,
            f"{self.id}-{uuid.uuid4().hex[:8]}",
            name=self.id,
            subscriptions=lambda: self.core.subscriptions(watch_peers=watch_remote),
            will=self.core.will,
            offline=self.core.offline,
            backoff=Backoff(reconnect_s, max_reconnect_s),
            component="unit",
            report=self.core.side.report,  # a failed handler, told on `errors`
        )

    @property
    def logic(self) -> UnitLogic:
        """The unit's pure state machine."""
        return self.core.logic

    @property
    def online(self) -> asyncio.Event:
        """Set while connected and announced."""
        return self.endpoint.online

    @property
    def connects(self) -> int:
        """How many times it has connected (tests watch reconnects)."""
        return self.endpoint.connects

    @property
    def killed(self) -> bool:
        """Set by `kill()`: gone for good, as a unit that lost power."""
        return self.endpoint.killed

    def _now(self) -> float:
        return asyncio.get_running_loop().time()

    async def run(self, shutdown: asyncio.Event) -> None:
        """Step and stay connected until `stop` is set; then say "offline" and disconnect."""
        self.core.start(self._now())
        ticker = asyncio.create_task(self._ticks(shutdown), name=f"{self.id}-ticks")
        try:
            await self.endpoint.run(
                shutdown,
                self._handle,
                on_connect=self._connected,
                on_disconnect=lambda why: self.core.on_disconnect(self._now()),
            )
        finally:
            await cancel_and_wait(ticker)

    async def _connected(self) -> None:
        await self._send(self.core.on_connect(self._now()))

    async def _handle(self, topic: str, payload: bytes) -> None:
        retained = self.endpoint.retained  # of this message: read before anything awaits
        seen = self.core.peer_position(topic, payload)
        if seen is not None:
            self.world.observe(*seen)
            return
        await self._send(self.core.on_message(topic, payload, self._now(), retained=retained))

    async def _ticks(self, shutdown: asyncio.Event) -> None:
        step_s = self.logic.step_s
        due = self._now() + self.phase_s
        while not shutdown.is_set() and not self.killed:
            due += step_s
            delay = due - self._now()
            if delay < -step_s:  # fell far behind (e.g. a long pause): do not catch up in a burst
                due = self._now()
            elif delay > 0:
                await asyncio.sleep(delay)
            if shutdown.is_set() or self.killed:
                return
            await self._send(self.tick())

    def tick(self) -> list[Outbound]:
        """One step: sense, decide, move in the world (atomically: nothing awaits in between)."""
        with self.world.turn():  # and no unit of another process steps meanwhile
            outs = self.core.tick(
                lambda: self.world.sense(self.id),
                lambda d: self.world.move(self.id, d),
                self._now(),
            )
        if self.on_step is not None:
            self.on_step(self.logic)
        return outs

    async def _send(self, outs: Sequence[Outbound]) -> None:
        """Publish what the core returned, in its order; dropped while disconnected."""
        # The step loop and message handlers both publish. Each send is a task and asyncio starts
        # tasks in the order they were made; paho queues a message in that first, synchronous
        # part of the publish, so states and directions leave in the order the core took them
        # (and it took them before any await: a step cannot overtake the state that showed its
        # move). Nothing waits for an acknowledgement while holding anything: a publish stuck on
        # a dropped connection must not hold back the states sent on the next one.
        sends = [asyncio.ensure_future(self.endpoint.publish(out)) for out in outs]
        if sends:
            await asyncio.gather(*sends)

    def drop_connection(self) -> None:
        """Cut the TCP connection without a DISCONNECT, as a pulled cable would (for tests)."""
        self.endpoint.drop()

    def kill(self) -> None:
        """Die abruptly, as a unit losing power (for tests): no "offline", no reconnect, no steps.

        The connection is cut without a DISCONNECT, so the broker publishes the last will
        ("broken"); the unit stays where it is in the world.
        """
        self.endpoint.kill()
