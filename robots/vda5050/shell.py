"""The VDA 5050 adapter's I/O shell: one MQTT endpoint for all its vehicles, a clock, nothing else.

Every decision is a vehicle core's (core.py). Here: one session on the broker (the adapter's own
account), following each vehicle's VDA 5050 topics and each unit's fleet topics, handing every
message to the core it concerns, and stepping the cores' clock for their heartbeats.

One endpoint has one last will, and a unit's is `connection: broken`: the adapter cannot leave one
per vehicle. If the adapter dies, its units' states stop and the coordinator counts them lost
after its silence timeout (protocol.md §8), as it does any unit that vanishes without a will.
"""

from __future__ import annotations

import asyncio
import logging
import time
import uuid
from collections.abc import Sequence

from gridfleet.config import broker_login, owned_client_id
from gridfleet.endpoint import Backoff, Endpoint
from gridfleet.errors import ProtocolError
from gridfleet.grid import GridMap
from gridfleet.outbound import Outbound
from gridfleet.protocol import SUBSCRIBE_QOS, TOPICS, HeaderStamper, Routes, Topics, decode
from gridfleet.protocol.stop import STOP_KINDS
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.core import Check, VehicleCore
from gridfleet.robots.vda5050.schemas import Schemas
from gridfleet.robots.vda5050.wire import VdaTopic
from gridfleet.tasks import cancel_and_wait

log = logging.getLogger("gridfleet.vda5050")
VEHICLE_TOPICS: tuple[VdaTopic, ...] = ("state", "connection", "factsheet")


class AdapterShell:
    """Runs the vehicles of a vehicles file as gridfleet units on one broker."""

    def __init__(
        self,
        vehicles: Sequence[VehicleConfig],
        grid: GridMap,
        broker_url: str,
        topics: Topics,
        *,
        step_s: float = 0.5,
        schemas: Schemas | None = None,
        reconnect_s: float = 0.1,
        max_reconnect_s: float = 5.0,
    ) -> None:
        run_id = uuid.uuid4().hex[:6]  # order ids are new in every run of the adapter
        self.topics = topics
        self.step_s = step_s
        client_id = f"vda5050-{run_id}"
        # Its reports on `errors` are signed with its own client id, as the broker sees it (one
        # its account owns: a vehicle's unit id is that vehicle's account's, not the adapter's).
        reporter = HeaderStamper(owned_client_id(broker_login(broker_url), client_id))
        self.cores = [
            VehicleCore(
                config,
                grid,
                topics,
                run_id=run_id,
                step_s=step_s,
                reporter=reporter,
                check=_checker(schemas, config) if schemas is not None else None,
            )
            for config in vehicles
        ]
        self._by_vda = {
            core.vehicle.topic(name): (core, name) for core in self.cores for name in VEHICLE_TOPICS
        }
        self._by_unit = {core.id: core for core in self.cores}
        self.endpoint = Endpoint(
            broker_url,
            client_id,
            name="vda5050",
            subscriptions=self.subscriptions,
            backoff=Backoff(reconnect_s, max_reconnect_s),
            component="vda5050",
            report=self._report,  # a failed handler, told on `errors`
        )
        self.ready = self.endpoint.online  # set while connected and subscribed

    def subscriptions(self) -> list[tuple[str, int]]:
        """Every vehicle's topics and every unit's, once each, and the operators' controls."""
        seen: dict[str, int] = {self.topics.fleet("routes"): SUBSCRIBE_QOS}
        for core in self.cores:
            for topic, qos in (*core.vehicle_subscriptions(), *core.fleet_subscriptions()):
                seen[topic] = max(qos, seen.get(topic, 0))
        return list(seen.items())

    def _now(self) -> float:
        return time.time()  # VDA 5050's headers carry the time of day

    async def run(self, shutdown: asyncio.Event) -> None:
        """Carry the vehicles until `shutdown` is set; then their units say `offline`."""
        ticker = asyncio.create_task(self._ticks(shutdown), name="vda5050-ticks")
        try:
            await self.endpoint.run(
                shutdown,
                self._handle,
                on_disconnect=lambda why: self._lost_broker(),
                on_stop=self._goodbye,
            )
        finally:
            await cancel_and_wait(ticker)

    def _lost_broker(self) -> None:
        for core in self.cores:
            core.on_broker_lost()

    async def _goodbye(self) -> None:
        await self._send([out for core in self.cores for out in core.offline()])

    async def _handle(self, topic: str, payload: bytes) -> None:
        retained = self.endpoint.retained  # of this message: read before anything awaits
        now = self._now()
        found = self._by_vda.get(topic)
        if found is not None:
            core, name = found
            try:
                outs = core.on_vehicle(name, payload, now)
            except Exception as exc:  # the unit shows it; the endpoint reports it on `errors`
                await self._send(core.on_failure(name, type(exc).__name__))
                raise
            await self._send(outs)
            return
        try:
            kind, who = self.topics.parse(topic)
        except ProtocolError:
            return
        if kind in STOP_KINDS:
            await self._send([o for core in self.cores for o in core.on_fleet(topic, payload, now)])
        elif kind == "routes":
            await self._send(self._controls(payload, now))
        elif kind == "coordinator":  # a new session is told again who every unit is
            outs = [
                o for c in self.cores for o in c.on_fleet(topic, payload, now, retained=retained)
            ]
            await self._send(outs)
        elif who in self._by_unit:
            await self._send(self._by_unit[who].on_fleet(topic, payload, now))

    def _report(self, topic: str, reason: str) -> Outbound:
        """A report on `errors` about `topic`, made by the unit it concerns (else the first),
        signed by the adapter."""
        found = self._by_vda.get(topic)
        core = found[0] if found is not None else None
        if core is None:
            try:
                core = self._by_unit.get(self.topics.parse(topic)[1] or "")
            except ProtocolError:
                core = None
        return (core or self.cores[0]).side.report(topic, reason)

    def _controls(self, payload: bytes, now: float) -> list[Outbound]:
        """Operators' controls of the units, from the coordinator's routes (read once for all)."""
        if not payload:
            return []  # cleared
        try:
            routes = decode(Routes, payload, TOPICS["routes"].max_bytes).routes
        except ProtocolError as exc:
            log.warning("vda5050: ignored a bad routes message: %s", exc)
            return []
        outs: list[Outbound] = []
        for core in self.cores:
            route = routes.get(core.id)
            outs += core.on_control(None if route is None else route.control, now)
        return outs

    async def _ticks(self, shutdown: asyncio.Event) -> None:
        due = time.monotonic()
        while not shutdown.is_set():
            due += self.step_s
            delay = due - time.monotonic()
            if delay < -self.step_s:
                due = time.monotonic()  # fell far behind: no burst of catching up
            elif delay > 0:
                await asyncio.sleep(delay)
            now = self._now()
            await self._send([out for core in self.cores for out in core.tick(now)])

    async def _send(self, outs: Sequence[Outbound]) -> None:
        """Publish in the cores' order (each send is queued before the next is made)."""
        sends = [asyncio.ensure_future(self.endpoint.publish(out)) for out in outs]
        if sends:
            await asyncio.gather(*sends)


def _checker(schemas: Schemas, config: VehicleConfig) -> Check:
    """Hold what goes to this vehicle to its version's official schema."""
    version = config.vehicle.version
    return lambda topic, message: schemas.check(version, topic, message)
