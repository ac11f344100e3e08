"""The ESP32 device's behaviour as a pure core: direction and estop in, LEDs out, a key press out.

The same rules as firmware/esp32_unit/src/ (protocol.md 4.6, 5.1, 5.6): the LED of the unit's
direction is lit, none for `-`; all four when the emergency stop is engaged (or a press is still
being sent), which wins over everything; none while offline. A press is pending until the device
sees its own `engaged|<device>|button` come back from the broker, and is re-sent after every
reconnect and every `retry_s` until then. No sockets, no clock: callers pass `now`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from gridfleet.errors import ProtocolError
from gridfleet.grid import Direction
from gridfleet.protocol import (
    TOPICS,
    EstopSignal,
    Leds,
    Topics,
    decode_direction,
    decode_estop,
    encode_estop,
    validate_id,
)

Pattern = Literal["direction", "stop", "offline"]
ARROWS = {"N": "↑", "E": "→", "S": "↓", "W": "←"}


@dataclass(frozen=True)
class Refusal:
    """A message the device ignored, and why (for the `errors` topic)."""

    topic: str
    reason: str


class DeviceLogic:
    """What the device shows and sends, driven by MQTT messages, key presses and time."""

    def __init__(self, topics: Topics, unit: str, device: str, retry_s: float = 1.0) -> None:
        self.topics = topics
        self.unit = validate_id(unit, "unit id")
        self.device = validate_id(device, "device id")
        self.retry_s = retry_s
        self.direction_topic = topics.unit("direction", unit)
        self.estop_topic = topics.fleet("estop")
        self.connection_topic = topics.device("device_connection", device)
        self.stop_payload = encode_estop(EstopSignal(True, device, "button"))
        self.direction: Direction | None = None
        self.estop: EstopSignal | None = None
        self.online = False
        self.pending_stop = False
        self._sent_this_session = False
        self._last_sent = 0.0

    # -- what comes in ---------------------------------------------------------------------------

    def on_message(self, topic: str, payload: bytes) -> Refusal | None:
        """Apply one received message; a bad or unexpected one changes nothing and is returned."""
        try:
            kind, ident = self.topics.parse(topic)
        except ProtocolError as exc:
            return Refusal(topic, str(exc))
        try:
            if kind == "direction" and ident == self.unit:
                if len(payload) > TOPICS["direction"].max_bytes:
                    raise ProtocolError(f"direction: payload of {len(payload)} bytes is too long")
                self.direction = decode_direction(payload)
                return None
            if kind == "estop":
                signal = decode_estop(payload)
                self.estop = signal
                if signal.engaged and payload == self.stop_payload:
                    self.pending_stop = False
                return None
        except ProtocolError as exc:
            return Refusal(topic, str(exc))
        return Refusal(topic, f"device {self.device} does not expect messages on {kind}")

    def press(self) -> None:
        """The stop key: engage the emergency stop (a second press while pending is the same)."""
        self.pending_stop = True

    def connected(self) -> None:
        """A new broker session: a pending stop is sent at once."""
        self.online = True
        self._sent_this_session = False

    def disconnected(self) -> None:
        """The broker is gone: show offline; direction is stale until the retained one returns."""
        self.online = False
        self._sent_this_session = False

    # -- what goes out ---------------------------------------------------------------------------

    def stop_due(self, now: float) -> bool:
        """Whether to publish the stop now (only meaningful while connected)."""
        if not self.pending_stop or not self.online:
            return False
        return not self._sent_this_session or now - self._last_sent >= self.retry_s

    def stop_sent(self, now: float) -> None:
        """The stop was handed to the broker at `now`."""
        self._sent_this_session = True
        self._last_sent = now

    def next_stop_in(self, now: float) -> float | None:
        """Seconds until the stop is due again, None when nothing is pending."""
        if not self.pending_stop or not self.online:
            return None
        if not self._sent_this_session:
            return 0.0
        return max(0.0, self._last_sent + self.retry_s - now)

    @property
    def estop_engaged(self) -> bool:
        """Whether the retained emergency stop says `engaged`."""
        return self.estop is not None and self.estop.engaged

    @property
    def pattern(self) -> Pattern:
        """Which pattern the LEDs show: the stop wins, then offline, then the direction."""
        if self.estop_engaged or self.pending_stop:
            return "stop"
        if not self.online:
            return "offline"
        return "direction"

    @property
    def leds(self) -> Leds:
        """The four LEDs (stop: all four, as in UnitState.leds; offline: none)."""
        pattern = self.pattern
        if pattern == "stop":
            return Leds(N=True, E=True, S=True, W=True)
        if pattern == "offline" or self.direction is None:
            return Leds()
        return Leds(**{self.direction.value: True})


def render_plain(logic: DeviceLogic) -> str:
    """One line for logs and pipes: `leds=.#.. direction=E estop=released link=online`."""
    leds = logic.leds
    lit = "".join("#" if getattr(leds, side) else "." for side in "NESW")
    direction = "-" if logic.direction is None else logic.direction.value
    estop = "engaged" if logic.estop_engaged else "released" if logic.estop else "unknown"
    pending = " stop=pending" if logic.pending_stop else ""
    link = "online" if logic.online else "offline"
    return f"leds={lit} direction={direction} estop={estop} link={link}{pending}"


def render_tty(logic: DeviceLogic, blink_on: bool) -> str:
    """The live terminal line: the four arrows, the lit one highlighted; stop blinks all in red."""
    leds = logic.leds
    cells = []
    for side in "NESW":
        arrow = ARROWS[side]
        if logic.pattern == "stop":
            cells.append(f"\x1b[1;41;97m {arrow} \x1b[0m" if blink_on else f" {arrow} ")
        elif getattr(leds, side):
            cells.append(f"\x1b[1;42;30m {arrow} \x1b[0m")
        else:
            cells.append(f"\x1b[2m {arrow} \x1b[0m")
    status = {
        "stop": "EMERGENCY STOP" + (" (sending)" if logic.pending_stop else ""),
        "offline": "offline: connecting",
        "direction": f"unit {logic.unit}",
    }[logic.pattern]
    return "".join(cells) + f"  {status}  [space/s: stop, q: quit]"
