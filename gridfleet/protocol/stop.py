"""The fleet's emergency stop as one reader sees it: the operators' latch and every source's press.

protocol.md §5.1: the fleet is stopped while `fleet/estop` (the latch) says engaged or any unit's
or device's own `stop` topic holds a press. A press can only engage; operators release on the
latch, and the coordinator then clears the presses. A broker ACL sees topics, not payloads: this
split is what keeps a unit or device from releasing a stop.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gridfleet.protocol.constants import SUBSCRIBE_QOS
from gridfleet.protocol.device import EstopSignal, decode_estop, decode_press
from gridfleet.protocol.topics import Topics

LATCH = "estop"
PRESS_KINDS = ("stop", "device_stop")  # units/<unit>/stop, devices/<device>/stop
STOP_KINDS = (LATCH, *PRESS_KINDS)


def stop_filters(topics: Topics) -> list[tuple[str, int]]:
    """The filters that carry the stop (the latch and every press), with their subscription QoS."""
    return [
        (topics.fleet(LATCH), SUBSCRIBE_QOS),
        (topics.all_units("stop"), SUBSCRIBE_QOS),
        (topics.all_devices("device_stop"), SUBSCRIBE_QOS),
    ]


@dataclass
class StopView:
    """The latch and the held presses; `apply` one message at a time."""

    latch: EstopSignal | None = None  # the last valid signal on fleet/estop
    presses: dict[str, EstopSignal] = field(default_factory=dict)  # press topic -> its press

    @property
    def engaged(self) -> bool:
        """Whether the fleet is stopped."""
        return self.latch_engaged or bool(self.presses)

    @property
    def latch_engaged(self) -> bool:
        """Whether the latch itself says engaged."""
        return self.latch is not None and self.latch.engaged

    @property
    def cause(self) -> EstopSignal | None:
        """What holds the fleet: the engaged latch, else the oldest press; None when released."""
        if self.latch_engaged:
            return self.latch
        return next(iter(self.presses.values()), None)

    def apply(
        self, kind: str, source: str | None, topic: str, payload: bytes
    ) -> EstopSignal | None:
        """Read one message on a stop topic (kind and source as Topics.parse gives them).

        Returns the signal read (None: a press was cleared); a bad payload raises ProtocolError
        and changes nothing — above all it never releases.
        """
        if kind == LATCH:
            self.latch = decode_estop(payload)
            return self.latch
        assert kind in PRESS_KINDS and source is not None, f"{kind} is not a stop topic"
        press = decode_press(payload, source)
        if press is None:
            self.presses.pop(topic, None)
        else:
            self.presses[topic] = press
        return press

    def release_presses(self) -> list[str]:
        """Forget every held press (an operator released the latch); the topics to clear."""
        held = list(self.presses)
        self.presses.clear()
        return held
