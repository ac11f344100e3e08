"""The virtual device's MQTT shell: it feeds DeviceLogic (the firmware's rules) and sends the stop."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable

import aiomqtt

from device.logic import DeviceLogic, Refusal
from gridfleet.bus import make_client
from gridfleet.protocol import (
    TOPICS,
    ErrorReport,
    HeaderStamper,
    Leds,
    Topics,
    encode,
    encode_device_connection,
)
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.tasks import cancel_and_wait

log = logging.getLogger("gridfleet.device")

BACKOFF_INITIAL_S = 0.5
BACKOFF_MAX_S = 10.0


class VirtualDevice:
    """The device's MQTT shell: connects with a last will, feeds DeviceLogic, sends the stop."""

    def __init__(
        self,
        url: str,
        unit: str,
        root: str = DEFAULT_ROOT,
        device_id: str | None = None,
        retry_s: float = 1.0,
        on_change: Callable[[DeviceLogic], None] | None = None,
    ) -> None:
        self.url = url
        self.logic = DeviceLogic(Topics(root), unit, device_id or f"device-{unit}", retry_s)
        self.on_change = on_change
        self.refused: list[Refusal] = []
        self._stamper = HeaderStamper(self.logic.device)
        self._wake: asyncio.Event | None = None

    @property
    def leds(self) -> Leds:
        """What the four LEDs show now."""
        return self.logic.leds

    @property
    def online(self) -> bool:
        """Whether it has a broker session."""
        return self.logic.online

    def press(self) -> None:
        """Press the stop key (call from the device's event loop)."""
        self.logic.press()
        self._changed()
        if self._wake is not None:
            self._wake.set()

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change(self.logic)

    async def run(self, stop: asyncio.Event) -> None:
        """Run until `stop` is set, reconnecting with back-off; says `offline` on the way out."""
        self._wake = asyncio.Event()
        backoff = BACKOFF_INITIAL_S
        while not stop.is_set():
            try:
                await self._session(stop)
                backoff = BACKOFF_INITIAL_S
            except aiomqtt.MqttError as exc:
                if stop.is_set():
                    break
                log.warning("broker %s: %s; retrying in %.1f s", self.url, exc, backoff)
                self.logic.disconnected()
                self._changed()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), backoff)
                backoff = min(backoff * 2, BACKOFF_MAX_S)
        self.logic.disconnected()
        self._changed()

    async def _session(self, stop: asyncio.Event) -> None:
        logic = self.logic
        spec = TOPICS["device_connection"]
        will = aiomqtt.Will(
            logic.connection_topic, encode_device_connection("broken"), spec.qos, spec.retained
        )
        async with make_client(self.url, logic.device, will=will) as client:
            await client.publish(
                logic.connection_topic,
                encode_device_connection("online"),
                qos=spec.qos,
                retain=spec.retained,
            )
            # Direction is high-rate: QoS 0, as protocol.md asks.
            await client.subscribe(logic.direction_topic, qos=0)
            await client.subscribe(logic.estop_topic, qos=TOPICS["estop"].qos)
            logic.connected()
            self._changed()
            reader = asyncio.create_task(self._read(client))
            stopper = asyncio.create_task(stop.wait())
            try:
                await self._send_loop(client, reader, stopper)
            finally:
                # cancel_and_wait: a single cancel() can be lost in Python 3.11 (see gridfleet.tasks).
                for task in (reader, stopper):
                    await cancel_and_wait(task)
            if reader.done() and not reader.cancelled() and reader.exception() is not None:
                raise reader.exception()  # type: ignore[misc]
            if stop.is_set():
                await client.publish(
                    logic.connection_topic,
                    encode_device_connection("offline"),
                    qos=spec.qos,
                    retain=spec.retained,
                )

    async def _send_loop(
        self, client: aiomqtt.Client, reader: asyncio.Task[None], stopper: asyncio.Task[bool]
    ) -> None:
        assert self._wake is not None
        estop = TOPICS["estop"]
        while not stopper.done() and not reader.done():
            now = time.monotonic()
            if self.logic.stop_due(now):
                await client.publish(
                    self.logic.estop_topic,
                    self.logic.stop_payload,
                    qos=estop.qos,
                    retain=estop.retained,
                )
                self.logic.stop_sent(now)
                # The screen shows the stop; a log line would be drawn across it.
                log.debug("emergency stop sent: %s", self.logic.stop_payload.decode())
            self._wake.clear()
            waker = asyncio.create_task(self._wake.wait())
            timeout = self.logic.next_stop_in(time.monotonic())
            await asyncio.wait(
                {reader, stopper, waker}, timeout=timeout, return_when=asyncio.FIRST_COMPLETED
            )
            waker.cancel()
        if reader.done() and not reader.cancelled() and reader.exception() is None:
            raise aiomqtt.MqttError("message stream ended")

    async def _read(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            payload = message.payload
            data = payload if isinstance(payload, bytes) else str(payload).encode()
            refusal = self.logic.on_message(message.topic.value, data)
            if refusal is None:
                self._changed()
                if self._wake is not None:
                    self._wake.set()  # our own stop may have come back
                continue
            self.refused.append(refusal)
            log.warning("ignored %s: %s", refusal.topic, refusal.reason)
            await self._report(client, refusal)

    async def _report(self, client: aiomqtt.Client, refusal: Refusal) -> None:
        try:
            report = ErrorReport(
                header=self._stamper("errors"),
                topic=refusal.topic[:256],
                reason=refusal.reason[:500],
            )
        except ValueError:
            return
        spec = TOPICS["errors"]
        await client.publish(
            self.logic.topics.fleet("errors"), encode(report), qos=spec.qos, retain=spec.retained
        )
