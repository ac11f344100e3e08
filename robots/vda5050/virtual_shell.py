"""A virtual VDA 5050 vehicle on a broker: its own MQTT session (last will: CONNECTIONBROKEN)."""

from __future__ import annotations

import asyncio
import json
import logging
import time
import uuid
from collections.abc import Sequence
from typing import Any, Literal

from gridfleet.endpoint import Endpoint
from gridfleet.outbound import Outbound
from gridfleet.robots.vda5050.virtual import Message, VirtualSpec, VirtualVehicle
from gridfleet.robots.vda5050.wire import Vehicle
from gridfleet.tasks import cancel_and_wait

log = logging.getLogger("gridfleet.vda5050.virtual")


class VirtualVehicleShell:
    """Runs one virtual vehicle: orders and instant actions in, its messages out at QoS 0."""

    def __init__(
        self, vehicle: Vehicle, spec: VirtualSpec, broker_url: str, *, tick_s: float = 0.05
    ) -> None:
        self.core = VirtualVehicle(vehicle, spec)
        self.vehicle = vehicle
        self.tick_s = tick_s
        self.received: list[Message] = []  # every order and instant action
        self.sent: list[Message] = []  # every message it published, as sent
        self.endpoint = Endpoint(
            broker_url,
            f"vda-{vehicle.serial_number}-{uuid.uuid4().hex[:6]}",
            name=f"vehicle {vehicle.serial_number}",
            subscriptions=lambda: [
                (vehicle.topic("order"), 0),
                (vehicle.topic("instantActions"), 0),
            ],
            will=lambda: self._connection("CONNECTIONBROKEN"),
            online=lambda: self._connection("ONLINE"),
            offline=lambda: self._connection("OFFLINE"),
        )
        self.ready = self.endpoint.online  # set while connected and subscribed

    def _connection(self, state: Literal["ONLINE", "OFFLINE", "CONNECTIONBROKEN"]) -> Outbound:
        message = self.core.connection(state, time.time())
        self.sent.append(("connection", message))
        return Outbound(self.vehicle.topic("connection"), _json(message), 1, True)

    async def run(self, shutdown: asyncio.Event) -> None:
        """Drive and report until `shutdown` is set (then OFFLINE) or `kill()` (the will)."""
        ticker = asyncio.create_task(self._ticks(shutdown))
        try:
            await self.endpoint.run(shutdown, self._handle, on_connect=self._connected)
        finally:
            await cancel_and_wait(ticker)

    async def _connected(self) -> None:
        await self._send([("state", self.core.state(time.time()))])

    async def _handle(self, topic: str, payload: bytes) -> None:
        try:
            message = json.loads(payload)
        except (UnicodeDecodeError, json.JSONDecodeError):
            log.warning("%s: not JSON on %s", self.endpoint.name, topic)
            return
        now = time.time()
        if topic == self.vehicle.topic("order"):
            self.received.append(("order", message))
            await self._send(self.core.on_order(message, now))
        elif topic == self.vehicle.topic("instantActions"):
            self.received.append(("instantActions", message))
            await self._send(self.core.on_instant_actions(message, now))

    async def _ticks(self, shutdown: asyncio.Event) -> None:
        while not shutdown.is_set() and not self.endpoint.killed:
            await asyncio.sleep(self.tick_s)
            if self.endpoint.connected:
                await self._send(self.core.advance(time.time(), self.tick_s))

    async def _send(self, messages: Sequence[Message]) -> None:
        for name, message in messages:
            self.sent.append((name, message))
            await self.endpoint.publish(
                Outbound(self.vehicle.topic(name), _json(message), 0, False)
            )

    def kill(self) -> None:
        """Die as a vehicle losing power: no OFFLINE; the broker sends the will."""
        self.endpoint.kill()


def _json(message: dict[str, Any]) -> bytes:
    return json.dumps(message, separators=(",", ":")).encode()
