"""The ESP32 device's behaviour as a pure core: direction and estop in, LEDs out, a key press out.

The same rules as firmware/esp32_unit/src/ (protocol.md 4.6, 5.1, 5.6): the LED of the unit's
direction is lit, none for `-`; all four when the emergency stop is engaged, or this device's press
is held or still being sent, which wins over everything; none while offline. The button presses
on the device's own `devices/<device>/stop` (it cannot release: only operators do, on
`fleet/estop`). A press is pending until the device sees its own `engaged|<device>|button` come
back on that topic, and is re-sent after every reconnect and every `retry_s` until then. No
sockets, no clock: callers pass `now`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from gridfleet.errors import ProtocolError
from gridfleet.outbound import Outbound, error_report
from gridfleet.protocol import (
    SUBSCRIBE_QOS,
    TOPICS,
    DeviceConnection,
    EstopSignal,
    HeaderStamper,
    Leds,
    Topics,
    decode_direction,
    decode_estop,
    decode_press,
    encode_device_connection,
    encode_estop,
    validate_id,
)
from gridfleet.squares import Direction

Pattern = Literal["direction", "stop", "offline"]


@dataclass(frozen=True)
class Refusal:
    """A message the device ignored, and why (for the `errors` topic)."""

    topic: str
    reason: str


class DeviceCore:
    """What the device shows and sends, driven by MQTT messages, key presses and time."""

    def __init__(
        self,
        topics: Topics,
        unit: str,
        device: str,
        retry_s: float = 1.0,
        stamp: HeaderStamper | None = None,
    ) -> None:
        self.topics = topics
        self.unit = validate_id(unit, "unit id")
        self.device = validate_id(device, "device id")
        self.retry_s = retry_s
        self.direction_topic = topics.unit("direction", unit)
        self.estop_topic = topics.fleet("estop")  # the latch: the fleet's stop, shown
        self.press_topic = topics.device("device_stop", device)  # where the button presses
        self.connection_topic = topics.device("device_connection", device)
        self.stop_payload = encode_estop(EstopSignal(True, device, "button"))
        self.direction: Direction | None = None
        self.estop: EstopSignal | None = None
        self.pressed = False  # the broker holds this device's press (until an operator releases)
        self.online = False
        self.pending_stop = False
        self._sent_this_session = False
        self._last_sent = 0.0
        self.refused: list[Refusal] = []
        self._stamp = stamp or HeaderStamper(self.device)

    # -- the session -----------------------------------------------------------------------------

    def subscriptions(self) -> list[tuple[str, int]]:
        """What the device follows (its unit's direction, the stop, its press), with the QoS."""
        return [
            (self.direction_topic, SUBSCRIBE_QOS),
            (self.estop_topic, SUBSCRIBE_QOS),
            (self.press_topic, SUBSCRIBE_QOS),
        ]

    def connection(self, state: DeviceConnection) -> Outbound:
        """The device's retained connection message (`broken` is its last will)."""
        payload = encode_device_connection(state)
        return Outbound.of("device_connection", self.connection_topic, payload)

    def receive(self, topic: str, payload: bytes) -> list[Outbound]:
        """Apply one received message; a refused one is kept and reported on `errors`."""
        refusal = self.on_message(topic, payload)
        if refusal is None:
            return []
        self.refused.append(refusal)
        return [self.report(refusal.topic, refusal.reason)]

    def report(self, topic: str, reason: str) -> Outbound:
        """A report on `errors` about a message on `topic`."""
        payload = error_report(self._stamp("errors"), topic, reason)
        return Outbound.of("errors", self.topics.fleet("errors"), payload)

    def due(self, now: float) -> list[Outbound]:
        """What to publish at `now`: the pending stop, at once on a new session, then every retry."""
        if not self.stop_due(now):
            return []
        self.stop_sent(now)
        return [Outbound.of("device_stop", self.press_topic, self.stop_payload)]

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
                self.estop = decode_estop(payload)
                return None
            if kind == "device_stop" and ident == self.device:
                # The broker has the press: sent, held until an operator's release clears it.
                self.pressed = decode_press(payload, self.device) is not None
                if self.pressed:
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
        # Read afresh on the next session: a press cleared meanwhile (an operator's release) is
        # not replayed, and one still held is.
        self.pressed = False

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
        if self.estop_engaged or self.pressed or self.pending_stop:
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
