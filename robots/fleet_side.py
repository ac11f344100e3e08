"""A unit's side of the fleet's protocol, pure: what every kind of unit says to the fleet.

A gridfleet unit (`robots/core.py`) and a VDA 5050 vehicle as a unit (`robots/vda5050/core.py`)
both speak it (as openTCS keeps it in `BasicVehicleCommAdapter`): `online`, `offline` and
`broken`, the factsheet, error reports on `errors`; the state when what it says changed, and every
`STATE_HEARTBEAT_STEPS` steps anyway (the heartbeat); the direction whenever it changed since it
was last sent on this connection. What a state says is each unit's own; here only when one is due
and how it goes out, as `Outbound`s.
"""

from __future__ import annotations

from typing import Literal, cast

from gridfleet.errors import ProtocolError
from gridfleet.grid import Direction
from gridfleet.outbound import Outbound, error_report
from gridfleet.protocol import (
    Connection,
    EnergyModel,
    Factsheet,
    HeaderStamper,
    Topics,
    UnitState,
    encode_direction,
)
from gridfleet.protocol.constants import DIRECTION_NONE, STATE_HEARTBEAT_STEPS
from gridfleet.protocol.messages import DirectionLetter, Side

Link = Literal["online", "offline", "broken"]
# What a state says but its header and step count; None while it has news to tell once.
Condition = tuple[object, ...] | None


def letter(direction: Direction | None) -> DirectionLetter:
    """The state's `direction`: the move's heading, or DIRECTION_NONE for none."""
    return cast(DirectionLetter, DIRECTION_NONE if direction is None else direction.value)


class FleetSide:
    """One unit's messages to the fleet: connection, factsheet, reports, state and direction."""

    def __init__(
        self,
        unit_id: str,
        topics: Topics,
        stamp: HeaderStamper,
        reporter: HeaderStamper | None = None,
    ) -> None:
        self.id = unit_id
        self.topics = topics
        self.stamp = stamp
        self.reporter = reporter or stamp  # who signs its reports on `errors`
        self._told: Condition = None  # what the last state said
        self._quiet = 0  # steps since the last state went out
        self._sent_direction: bytes | None = None  # what `direction` says on this connection

    def parse(self, topic: str) -> tuple[str, str | None] | None:
        """A topic's kind and unit, or None when it is none of the fleet's."""
        try:
            return self.topics.parse(topic)
        except ProtocolError:
            return None

    def connection(self, state: Link) -> Outbound:
        """The unit's `connection`: online, offline or broken."""
        message = Connection(header=self.stamp("connection"), state=state)
        return Outbound.of("connection", self.topics.unit("connection", self.id), message)

    def factsheet(
        self,
        *,
        capacity_kg: float,
        step_s: float,
        color: str,
        model: str,
        map_id: str,
        sensors: list[Side] | None = None,
        energy: EnergyModel | None = None,
    ) -> Outbound:
        """The unit's factsheet (every side's sensor unless `sensors` says otherwise).

        `energy`: its battery's model; None: it reports no energy.
        """
        factsheet = Factsheet(
            header=self.stamp("factsheet"),
            capacity_kg=capacity_kg,
            step_period_s=step_s,
            **({} if sensors is None else {"sensors": sensors}),
            color=color,
            model=model,
            map_id=map_id,
            energy=energy,
        )
        return Outbound.of("factsheet", self.topics.unit("factsheet", self.id), factsheet)

    def report(self, topic: str, reason: str) -> Outbound:
        """An error report on `errors` about a message on `topic`."""
        payload = error_report(self.reporter("errors"), topic, reason)
        return Outbound.of("errors", self.topics.fleet("errors"), payload)

    def new_connection(self) -> None:
        """A new connection (or session): the direction is said again."""
        self._sent_direction = None

    def due(self, condition: Condition) -> bool:
        """One step gone: whether a state must go out (what it says changed, or the heartbeat)."""
        self._quiet += 1
        return self._quiet >= STATE_HEARTBEAT_STEPS or condition != self._told

    def state(
        self, message: UnitState, condition: Condition, direction: Direction | None
    ) -> list[Outbound]:
        """The state (`condition`: what it says), then the direction when that changed."""
        self._told, self._quiet = condition, 0
        out = Outbound.of("state", self.topics.unit("state", self.id), message)
        return [out, *self.direction(direction)]

    def direction(self, direction: Direction | None) -> list[Outbound]:
        """The direction, when it changed since it was last sent on this connection."""
        payload = encode_direction(direction)
        if payload == self._sent_direction:
            return []
        self._sent_direction = payload
        return [Outbound.of("direction", self.topics.unit("direction", self.id), payload)]
