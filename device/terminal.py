"""The virtual device's terminal front end: draws the four LEDs and reads the stop key."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import termios
import time
import tty
from collections.abc import Callable
from typing import TextIO

from gridfleet.device.core import DeviceCore

log = logging.getLogger("gridfleet.device")

STOP_WORDS = {"s", "stop", " "}
ARROWS = {"N": "↑", "E": "→", "S": "↓", "W": "←"}


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

    def draw(self, core: DeviceCore) -> None:
        """Show the current state (plain mode prints only changes)."""
        if self.tty_out:
            blink_on = int(time.monotonic() * 4) % 2 == 0
            self.out.write("\r\x1b[2K" + render_tty(core, blink_on))
            self.out.flush()
            return
        line = render_plain(core)
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


def render_plain(core: DeviceCore) -> str:
    """One line for logs and pipes: `leds=.#.. direction=E estop=released link=online`."""
    leds = core.leds
    lit = "".join("#" if getattr(leds, side) else "." for side in "NESW")
    direction = "-" if core.direction is None else core.direction.value
    engaged = core.estop_engaged or core.pressed  # the fleet is stopped by either
    estop = "engaged" if engaged else "released" if core.estop else "unknown"
    pending = " stop=pending" if core.pending_stop else ""
    link = "online" if core.online else "offline"
    return f"leds={lit} direction={direction} estop={estop} link={link}{pending}"


def render_tty(core: DeviceCore, blink_on: bool) -> str:
    """The live terminal line: the four arrows, the lit one highlighted; stop blinks all in red."""
    leds = core.leds
    cells = []
    for side in "NESW":
        arrow = ARROWS[side]
        if core.pattern == "stop":
            cells.append(f"\x1b[1;41;97m {arrow} \x1b[0m" if blink_on else f" {arrow} ")
        elif getattr(leds, side):
            cells.append(f"\x1b[1;42;30m {arrow} \x1b[0m")
        else:
            cells.append(f"\x1b[2m {arrow} \x1b[0m")
    status = {
        "stop": "EMERGENCY STOP" + (" (sending)" if core.pending_stop else ""),
        "offline": "offline: connecting",
        "direction": f"unit {core.unit}",
    }[core.pattern]
    return "".join(cells) + f"  {status}  [space/s: stop, q: quit]"
