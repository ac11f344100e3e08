"""`gridfleet device`: a virtual ESP32 in the terminal (four direction LEDs, an emergency-stop key)."""

from __future__ import annotations

import argparse
import asyncio
import sys

from gridfleet.device.shell import DeviceShell
from gridfleet.device.terminal import Terminal
from gridfleet.errors import ConfigError, ProtocolError
from gridfleet.options import add_common, broker_url
from gridfleet.tasks import stop_on_signals


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
        device = DeviceShell(
            broker_url(args, args.device_id or f"device-{args.unit}"),
            args.unit,
            args.root,
            args.device_id,
            args.retry,
            on_change=term.draw,
        )
    except ProtocolError as exc:
        raise ConfigError(str(exc)) from None
    term.start_keys(loop, device.press, stop.set)
    term.draw(device.core)
    blinker: asyncio.Task[None] | None = None
    if term.tty_out:

        async def blink() -> None:
            while True:
                await asyncio.sleep(0.125)
                term.draw(device.core)

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
