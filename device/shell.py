"""The virtual device's MQTT shell: pumps messages between the broker and DeviceCore."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable

from gridfleet.bus import KEEP_ALIVE_S
from gridfleet.device.core import DeviceCore, Refusal
from gridfleet.endpoint import Backoff, Endpoint
from gridfleet.outbound import Outbound
from gridfleet.protocol import Leds, Topics
from gridfleet.protocol.constants import DEFAULT_ROOT

log = logging.getLogger("gridfleet.device")

BACKOFF = Backoff(first=0.5, most=10.0)
# A press whose acknowledgement is late is not given up on before the broker would give up on
# the device (1.5 keep-alives, then its will): a link that hangs for longer than the usual 10 s
# delivers the press by TCP's retransmission once it is back, and a copy sent over a new session
# meanwhile would arrive too. Past the broker's keep-alive the old connection is refused, and the
# press goes once over the next session.
PRESS_ACK_S = 1.5 * KEEP_ALIVE_S + 5.0


class DeviceShell:
    """Connects as the device (last will `broken`), feeds DeviceCore and sends what it says."""

    def __init__(
        self,
        url: str,
        unit: str,
        root: str = DEFAULT_ROOT,
        device_id: str | None = None,
        retry_s: float = 1.0,
        on_change: Callable[[DeviceCore], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        core = DeviceCore(Topics(root), unit, device_id or f"device-{unit}", retry_s)
        self.core = core
        self.endpoint = Endpoint(
            url,
            Topics(root).client_id(core.device),  # per root: fleets may share a broker
            name=f"device {core.device}",
            subscriptions=core.subscriptions,
            will=lambda: core.connection("broken"),
            online=lambda: core.connection("online"),
            offline=lambda: core.connection("offline"),
            backoff=BACKOFF,
            ack_s=PRESS_ACK_S,
            component="device",
            report=core.report,  # a failed handler, told on `errors`
        )
        self.on_change = on_change
        self.clock = clock
        self._wake: asyncio.Event | None = None

    @property
    def leds(self) -> Leds:
        """What the four LEDs show now."""
        return self.core.leds

    @property
    def online(self) -> bool:
        """Whether it has a broker session."""
        return self.core.online

    @property
    def refused(self) -> list[Refusal]:
        """Messages it ignored, with the reason each was reported under."""
        return self.core.refused

    def press(self) -> None:
        """Press the stop key (call from the device's event loop)."""
        self.core.press()
        self._changed()

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change(self.core)
        if self._wake is not None:
            self._wake.set()  # a press, or our own stop come back: the send loop looks again

    async def run(self, shutdown: asyncio.Event) -> None:
        """Run until `stop` is set, reconnecting with back-off; says `offline` on the way out."""
        self._wake = asyncio.Event()
        await self.endpoint.run(
            shutdown,
            self._receive,
            on_connect=self._connected,
            on_disconnect=self._disconnected,
            during=self._send_loop,
        )
        self.core.disconnected()
        self._changed()

    async def _connected(self) -> None:
        self.core.connected()
        self._changed()

    def _disconnected(self, why: str) -> None:
        self.core.disconnected()
        self._changed()

    async def _receive(self, topic: str, payload: bytes) -> None:
        out = self.core.receive(topic, payload)
        if out:
            log.warning("ignored a message on %s (reported on errors)", topic)
        self._changed()
        await self._send(out)

    async def _send_loop(self, shutdown: asyncio.Event) -> None:
        assert self._wake is not None
        while not shutdown.is_set():
            self._wake.clear()
            # The screen shows the stop; a log line would be drawn across it.
            for message in self.core.due(self.clock()):
                if await self.endpoint.publish(message):
                    # The broker has it: a re-send waits `retry_s` from its acknowledgement, not
                    # from the hand-over (after a stall the acknowledgement comes late, and the
                    # press's echo, which confirms it, right after: re-sent before, it arrived
                    # twice in a CI run).
                    self.core.stop_sent(self.clock())
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), self.core.next_stop_in(self.clock()))

    async def _send(self, messages: list[Outbound]) -> None:
        for message in messages:
            await self.endpoint.publish(message)
