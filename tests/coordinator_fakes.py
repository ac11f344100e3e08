"""A tiny test-only unit that follows protocol.md §4 (not the real robots/ units), and its fleet.

`FakeUnit` is pure (orders in, states out); `FakeFleet` runs several over MQTT, each with its own
client and last will, stepping in a random order so that units act asynchronously.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
from dataclasses import dataclass, field

import aiomqtt

from gridfleet.bus import make_client
from gridfleet.errors import ProtocolError
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import (
    Action,
    Connection,
    Factsheet,
    HeaderStamper,
    Leds,
    Order,
    Sensors,
    Topics,
    UnitState,
    decode,
    decode_estop,
    encode,
)
from gridfleet.protocol.messages import UnitError

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


@dataclass
class FakeUnit:
    """One unit: drives released squares only when free, does pick/drop actions."""

    id: str
    position: Cell
    capacity_kg: float
    step_s: float = 0.02
    step: int = 0
    order_id: str | None = None
    update_id: int = 0
    released: list[Cell] = field(default_factory=list)
    action: Action | None = None
    job_id: str | None = None
    load_kg: float = 0.0
    estop: bool = False
    status: str = "idle"
    wait_reason: str | None = None
    new_obstacles: list[Cell] = field(default_factory=list)
    known_obstacles: set[Cell] = field(default_factory=set)
    errors: list[UnitError] = field(default_factory=list)
    done_actions: set[tuple[str, str]] = field(default_factory=set)

    def on_order(self, order: Order, grid: GridMap) -> None:
        """Accept, ignore (stale) or refuse an order as protocol.md §4.4 says."""
        if order.order_id == self.order_id and order.update_id <= self.update_id:
            return
        here = self.position
        for sq in order.released:
            c = Cell(sq[0], sq[1])
            if c.manhattan(here) != 1 or not grid.is_free(c):
                self.errors.append(UnitError(code="bad_order", message=f"bad square {list(c)}"))
                return
            here = c
        self.order_id = order.order_id
        self.update_id = order.update_id
        self.released = [Cell(s[0], s[1]) for s in order.released]
        self.action = order.action

    def tick(self, occupied: set[Cell], hidden: set[Cell]) -> None:
        """One step: move one released square if the sensor sees it free, then act."""
        self.step += 1
        self.wait_reason = None
        if self.estop:
            self.status = "stopped"
            return
        if self.released:
            nxt = self.released[0]
            if nxt in hidden:
                if nxt not in self.known_obstacles:
                    self.known_obstacles.add(nxt)
                    self.new_obstacles.append(nxt)
                self.status, self.wait_reason = "waiting", "obstacle ahead"
                return
            if nxt in occupied:
                self.status, self.wait_reason = "waiting", "unit ahead"
                return
            self.position = nxt
            self.released.pop(0)
            self.status = "moving"
        else:
            self.status = "idle"
        a = self.action
        if a is not None and not self.released and Cell(*a.square) == self.position:
            key = (a.kind, a.job_id)
            if key in self.done_actions:
                return
            if a.kind == "pick":
                if self.load_kg + a.mass_kg > self.capacity_kg:
                    self.errors.append(UnitError(code="over_capacity", message="too heavy"))
                    return
                self.job_id, self.load_kg = a.job_id, self.load_kg + a.mass_kg
            elif self.job_id == a.job_id:
                self.job_id, self.load_kg = None, 0.0
            self.done_actions.add(key)

    def state(self, stamp: HeaderStamper) -> UnitState:
        """The state message of this step (reports obstacles and errors once)."""
        direction = "-"
        if self.released and not self.estop:
            d = self.position.direction_to(self.released[0])
            direction = d.value if d else "-"
        msg = UnitState(
            header=stamp("state"),
            step=self.step,
            position=self.position,
            direction=direction,  # type: ignore[arg-type]
            status=self.status,  # type: ignore[arg-type]
            wait_reason=self.wait_reason,
            job_id=self.job_id,
            load_kg=self.load_kg,
            leds=Leds(),
            sensors=Sensors(N="free", E="free", S="free", W="free"),
            obstacles=self.new_obstacles[:4],  # type: ignore[arg-type]
            order_id=self.order_id,
            order_update_id=self.update_id,
            released=list(self.released),  # type: ignore[arg-type]
            estop=self.estop,
            errors=self.errors[:16],
        )
        self.new_obstacles = self.new_obstacles[4:]
        self.errors = []
        return msg


class FakeFleet:
    """Runs FakeUnits over MQTT; `positions_log` records every step for collision checks."""

    def __init__(
        self,
        broker: str,
        root: str,
        grid: GridMap,
        units: list[FakeUnit],
        hidden: set[Cell] | None = None,
        seed: int = 0,
    ) -> None:
        self.broker = broker
        self.topics = Topics(root)
        self.grid = grid
        self.units = {u.id: u for u in units}
        self.hidden = hidden or set()
        self.rng = random.Random(seed)
        self.collisions = 0
        self.steps = 0
        self.positions_log: list[dict[str, Cell]] = []
        self._tasks: dict[str, asyncio.Task[None]] = {}
        self._stops: dict[str, asyncio.Event] = {}
        self._clients: dict[str, aiomqtt.Client] = {}
        self._stamps = {u.id: HeaderStamper(u.id) for u in units}
        self._ready: dict[str, asyncio.Event] = {}
        self._sending: dict[str, asyncio.Task[None]] = {}

    def start(self, unit_id: str) -> None:
        """Start (or restart) the MQTT client of one unit."""
        self._stops[unit_id] = asyncio.Event()
        self._ready[unit_id] = asyncio.Event()
        self._tasks[unit_id] = asyncio.create_task(self._client_task(unit_id))

    async def start_all(self) -> None:
        """Start every unit and wait until all are connected."""
        for uid in self.units:
            self.start(uid)
        await asyncio.gather(*(e.wait() for e in self._ready.values()))

    async def kill(self, unit_id: str) -> None:
        """The unit vanishes silently (no offline message; amqtt sends no will)."""
        self._stops[unit_id].set()
        task = self._tasks.pop(unit_id)
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
            await task
        self._clients.pop(unit_id, None)

    async def _client_task(self, unit_id: str) -> None:
        u = self.units[unit_id]
        t = self.topics
        will = aiomqtt.Will(
            t.unit("connection", unit_id),
            encode(Connection(header=self._stamps[unit_id]("connection"), state="broken")),
            qos=1,
            retain=True,
        )
        async with make_client(self.broker, f"fake-{unit_id}", will=will) as client:
            await client.subscribe(t.unit("order", unit_id), qos=1)
            await client.subscribe(t.fleet("estop"), qos=1)
            stamp = self._stamps[unit_id]
            await client.publish(
                t.unit("connection", unit_id),
                encode(Connection(header=stamp("connection"), state="online")),
                qos=1,
                retain=True,
            )
            await client.publish(
                t.unit("factsheet", unit_id),
                encode(
                    Factsheet(
                        header=stamp("factsheet"), capacity_kg=u.capacity_kg, step_period_s=u.step_s
                    )
                ),
                qos=1,
                retain=True,
            )
            await client.publish(
                t.unit("state", unit_id), encode(u.state(stamp)), qos=0, retain=True
            )
            self._clients[unit_id] = client
            self._ready[unit_id].set()
            async for message in client.messages:
                raw = message.payload
                data = raw if isinstance(raw, bytes | bytearray) else str(raw).encode()
                try:
                    kind, _ = t.parse(str(message.topic))
                    if kind == "order":
                        u.on_order(decode(Order, bytes(data)), self.grid)
                    elif kind == "estop":
                        u.estop = decode_estop(bytes(data)).engaged
                except ProtocolError:
                    continue

    async def step_once(self) -> None:
        """Every connected unit takes one step, in random order, and publishes its state."""
        alive = [uid for uid in self.units if uid in self._clients]
        self.rng.shuffle(alive)
        for uid in alive:
            u = self.units[uid]
            occupied = {o.position for o in self.units.values() if o.id != uid}
            u.tick(occupied, self.hidden)
        positions = [u.position for u in self.units.values()]
        if len(set(positions)) != len(positions):
            self.collisions += 1
        self.positions_log.append({u.id: u.position for u in self.units.values()})
        self.steps += 1
        for uid in alive:
            client = self._clients.get(uid)
            sending = self._sending.get(uid)
            if client is None or (sending is not None and not sending.done()):
                continue  # its link is stuck (e.g. killed mid-send): it misses this state
            # Each unit sends on its own, as real units do: a send stuck on a cut connection
            # (aiomqtt gives up only after 10 s) must not silence the others.
            payload = encode(self.units[uid].state(self._stamps[uid]))
            self._sending[uid] = asyncio.create_task(self._send_state(client, uid, payload))

    async def _send_state(self, client: aiomqtt.Client, uid: str, payload: bytes) -> None:
        with contextlib.suppress(aiomqtt.MqttError):
            await client.publish(self.topics.unit("state", uid), payload, qos=0, retain=True)

    async def run(self, stop: asyncio.Event, step_s: float) -> None:
        """Step until `stop` is set."""
        while not stop.is_set():
            await self.step_once()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), step_s)

    async def close(self) -> None:
        """Stop every unit's client."""
        for uid in list(self._tasks):
            await self.kill(uid)
        for sending in self._sending.values():
            sending.cancel()
        await asyncio.gather(*self._sending.values(), return_exceptions=True)
