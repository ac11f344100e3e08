"""Real units for coordinator tests, stepped by the test: `Yard` without a broker, `FakeFleet` over MQTT.

Each unit is the real unit core (`robots.unit.UnitLogic`; over MQTT a `gridfleet.robots.shell.UnitShell`
each, with its `UnitCore` and `Endpoint`, last will included) on a ground-truth world
(`robots.world.WorldSim`: walls, hidden obstacles, refused and counted bad moves). Only the stepping
is the test's own: every unit steps once per fleet step, in a random order, so units act
asynchronously, and a test can count, pause or kill them.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
from collections.abc import Iterable

from gridfleet.grid import Cell, GridMap
from gridfleet.outbound import Outbound
from gridfleet.protocol import HeaderStamper, Topics, UnitState
from gridfleet.robots.shell import UnitShell
from gridfleet.robots.unit import UnitLogic
from gridfleet.robots.world import WorldSim
from gridfleet.tasks import cancel_and_wait

# A 10 x 10 room with a few walls: the pure-core tests' shared playground.
ROOM_ROWS = [
    "..........",
    "..........",
    "..@@......",
    "..@.......",
    "......@...",
    "......@...",
    "..........",
    "...@@.....",
    "..........",
    "..........",
]

# (pickup, dropoff, mass) on maps/playfield.map (units of 2, 5, 10 and 20 kg): every square is
# free (walls and hidden obstacles avoided); three jobs only unit4 (20 kg) can carry, two only
# unit3 or unit4.
PLAYFIELD_JOBS = [
    (Cell(1, 1), Cell(8, 8), 1.5),
    (Cell(8, 1), Cell(1, 8), 4.0),
    (Cell(5, 0), Cell(5, 9), 8.0),
    (Cell(0, 5), Cell(9, 5), 15.0),
    (Cell(3, 3), Cell(7, 0), 1.0),
    (Cell(9, 2), Cell(0, 2), 3.0),
    (Cell(4, 8), Cell(4, 1), 12.0),
    (Cell(1, 6), Cell(8, 3), 6.0),
    (Cell(7, 7), Cell(2, 0), 0.5),
    (Cell(0, 1), Cell(9, 8), 9.5),
    (Cell(6, 6), Cell(3, 9), 18.0),
    (Cell(8, 9), Cell(1, 4), 2.0),
]


class Yard:
    """Units on a ground-truth world, without a broker: the test delivers orders and states."""

    def __init__(
        self,
        grid: GridMap,
        units: Iterable[UnitLogic],
        hidden: Iterable[Cell] = (),
        *,
        sensors_see_units: bool = True,
    ) -> None:
        self.units = {u.unit_id: u for u in units}
        self.world = WorldSim(
            grid,
            hidden,
            {uid: u.position for uid, u in self.units.items()},
            sensors_see_units=sensors_see_units,
        )
        self._stamps = {uid: HeaderStamper(uid) for uid in self.units}

    def tick(self, unit_id: str, now: float) -> None:
        """One step of one unit: it senses, decides and makes its move in the world."""
        w = self.world
        self.units[unit_id].tick(lambda: w.sense(unit_id), lambda d: w.move(unit_id, d), now)

    def state(self, unit_id: str) -> UnitState:
        """The unit's state message now (obstacles and errors in it are reported once)."""
        return self.units[unit_id].report(self._stamps[unit_id]("state"))


class FakeFleet:
    """Units over MQTT, stepped by `step_once`/`run` in a random order instead of by their clocks.

    Each unit is a `gridfleet.robots.shell.UnitShell`: its core, its endpoint (client id, last will,
    offline, back-off) and its `tick` are the product's. Only `UnitShell.run` is not used, since
    it also starts the unit's own step loop; the session it runs is wired here the same way, with
    sends that are never awaited (see `_send`).
    """

    def __init__(
        self,
        broker: str,
        root: str,
        grid: GridMap,
        units: list[UnitLogic],
        hidden: set[Cell] | None = None,
        seed: int = 0,
    ) -> None:
        self.broker = broker
        self.topics = Topics(root)
        self.yard = Yard(grid, units, hidden or ())
        self.units = self.yard.units
        self.world = self.yard.world
        self.rng = random.Random(seed)
        self.steps = 0
        self.shells: dict[str, UnitShell] = {}  # the running units
        self._tasks: dict[str, asyncio.Task[None]] = {}
        self._sending: list[asyncio.Future[bool]] = []

    @property
    def collisions(self) -> int:
        """Collisions the world counted (vertex, swap, into a wall or obstacle)."""
        return self.world.collisions

    def _now(self) -> float:
        return asyncio.get_running_loop().time()

    def start(self, unit_id: str) -> None:
        """Start the MQTT session of one unit (a new runner: a restart after `kill`)."""
        runner = UnitShell(
            self.units[unit_id],
            self.world,
            self.broker,
            self.topics,
            reconnect_s=0.05,
            max_reconnect_s=0.5,
        )
        self.shells[unit_id] = runner
        core = runner.core
        core.start(self._now())

        async def handle(topic: str, payload: bytes) -> None:
            self._send(unit_id, core.on_message(topic, payload, self._now()))

        async def connected() -> None:
            self._send(unit_id, core.on_connect(self._now()))

        self._tasks[unit_id] = asyncio.create_task(
            runner.endpoint.run(
                asyncio.Event(),
                handle,
                on_connect=connected,
                on_disconnect=lambda _: core.on_disconnect(self._now()),
            )
        )

    async def start_all(self) -> None:
        """Start every unit and wait until all are connected."""
        for uid in self.units:
            self.start(uid)
        await asyncio.gather(*(r.online.wait() for r in self.shells.values()))

    async def kill(self, unit_id: str) -> None:
        """The unit dies where it stands: no `offline`, no more steps; the broker has its will."""
        self.shells.pop(unit_id).kill()
        await cancel_and_wait(self._tasks.pop(unit_id))

    async def step_once(self) -> None:
        """Every running unit takes one step, in random order, then publishes what it says."""
        alive = list(self.shells)
        self.rng.shuffle(alive)
        said = [(uid, self.shells[uid].tick()) for uid in alive]
        self.steps += 1
        for uid, outs in said:
            self._send(uid, outs)

    def _send(self, unit_id: str, outs: list[Outbound]) -> None:
        # In order, one task a message, as UnitShell._send; but not awaited, so a send stuck on
        # a cut connection never holds back the step of the other units.
        runner = self.shells.get(unit_id)
        if runner is not None:
            self._sending = [s for s in self._sending if not s.done()]
            self._sending += [asyncio.ensure_future(runner.endpoint.publish(out)) for out in outs]

    async def run(self, shutdown: asyncio.Event, step_s: float) -> None:
        """Step until `stop` is set."""
        while not shutdown.is_set():
            await self.step_once()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(shutdown.wait(), step_s)

    async def close(self) -> None:
        """End every unit's session (as a kill: these are test units, gone with the test)."""
        for uid in list(self._tasks):
            await self.kill(uid)
        for sending in self._sending:
            sending.cancel()
        await asyncio.gather(*self._sending, return_exceptions=True)
