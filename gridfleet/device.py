"""`gridfleet device`: a virtual ESP32 in the terminal (four direction LEDs, an emergency-stop key).

The behaviour is gridfleet.device_logic.DeviceLogic (the same rules as the firmware); this module
is its MQTT shell (last will, reconnect with back-off) and the terminal front end.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import sys
import termios
import time
import tty
from collections.abc import Callable
from typing import TextIO

import aiomqtt

from gridfleet.bus import make_client
from gridfleet.cli import add_common
from gridfleet.device_logic import DeviceLogic, Refusal, render_plain, render_tty
from gridfleet.errors import ConfigError, ProtocolError
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
from gridfleet.tasks import cancel_and_wait, stop_on_signals

log = logging.getLogger("gridfleet.device")

BACKOFF_INITIAL_S = 0.5
BACKOFF_MAX_S = 10.0
STOP_WORDS = {"s", "stop", " "}


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


class Terminal:
    """Draws the LEDs (live line on a tty, one plain line per change otherwise) and reads keys."""

    def __init__(self, out: TextIO, inp: TextIO) -> None:
        self.out = out
        self.inp = inp
        self.tty_out = out.isatty()
        self.tty_in = inp.isatty()
        self._last = ""
        self._saved: list[object] | None = None
        self._buffer = b""

    def draw(self, logic: DeviceLogic) -> None:
        """Show the current state (plain mode prints only changes)."""
        if self.tty_out:
            blink_on = int(time.monotonic() * 4) % 2 == 0
            self.out.write("\r\x1b[2K" + render_tty(logic, blink_on))
            self.out.flush()
            return
        line = render_plain(logic)
        if line != self._last:
            self._last = line
            self.out.write(line + "\n")
            self.out.flush()

    def start_keys(
        self,
        loop: asyncio.AbstractEventLoop,
        on_stop: Callable[[], None],
        on_quit: Callable[[], None],
    ) -> None:
        """Call `on_stop` on space/`s` (tty) or a line `s`/`stop` (pipe); `on_quit` on `q`."""
        fd = self.inp.fileno()
        if self.tty_in:
            self._saved = termios.tcgetattr(fd)
            tty.setcbreak(fd)

        def readable() -> None:
            try:
                chunk = os.read(fd, 1024)
            except OSError:
                chunk = b""
            if not chunk:
                loop.remove_reader(fd)  # end of input: keep running until a signal
                return
            if self.tty_in:
                for ch in chunk.decode(errors="replace").lower():
                    if ch in (" ", "s"):
                        on_stop()
                    elif ch == "q":
                        on_quit()
                return
            self._buffer += chunk
            *lines, self._buffer = self._buffer.split(b"\n")
            for raw in lines:
                word = raw.decode(errors="replace").strip().lower()
                if word in STOP_WORDS or raw == b" ":
                    on_stop()
                elif word in ("q", "quit"):
                    on_quit()

        try:
            loop.add_reader(fd, readable)
        except OSError:
            # A regular file or /dev/null cannot be watched: it has no key presses to give.
            log.debug("stdin cannot be watched; the stop key is off (signals still stop)")

    def close(self, loop: asyncio.AbstractEventLoop) -> None:
        """Restore the terminal."""
        with contextlib.suppress(ValueError, OSError):
            loop.remove_reader(self.inp.fileno())
        if self._saved is not None:
            termios.tcsetattr(self.inp.fileno(), termios.TCSADRAIN, self._saved)  # type: ignore[arg-type]
        if self.tty_out:
            self.out.write("\n")
            self.out.flush()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet device`."""
    add_common(parser)
    parser.add_argument("--unit", required=True, help="the unit whose direction the LEDs show")
    parser.add_argument(
        "--device-id",
        default=None,
        help="this device's id (MQTT client id and <by> of its stop; default device-<unit>)",
    )
    parser.add_argument(
        "--retry",
        type=float,
        default=1.0,
        metavar="SECONDS",
        help="re-send an unconfirmed stop after this long (default 1.0)",
    )


async def _main(args: argparse.Namespace) -> int:
    loop = asyncio.get_running_loop()
    stop = stop_on_signals()
    term = Terminal(sys.stdout, sys.stdin)
    try:
        device = VirtualDevice(
            args.broker, args.unit, args.root, args.device_id, args.retry, on_change=term.draw
        )
    except ProtocolError as exc:
        raise ConfigError(str(exc)) from None
    term.start_keys(loop, device.press, stop.set)
    term.draw(device.logic)
    blinker: asyncio.Task[None] | None = None
    if term.tty_out:

        async def blink() -> None:
            while True:
                await asyncio.sleep(0.125)
                term.draw(device.logic)

        blinker = asyncio.create_task(blink())
    try:
        await device.run(stop)
    finally:
        if blinker is not None:
            blinker.cancel()
        term.close(loop)
    return 0


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet device`."""
    if args.retry <= 0:
        raise ConfigError("--retry must be greater than 0")
    return asyncio.run(_main(args))
