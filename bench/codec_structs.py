"""msgspec Structs for a unit's state and an order, with the protocol's constraints as msgspec
spells them: what `gridfleet bench codec` times msgspec's validated reading with. A bench's copy
of two messages, not the protocol's (gridfleet.protocol.messages is that)."""

import re
from datetime import datetime
from typing import Annotated, Literal

import msgspec

from gridfleet.protocol.constants import (
    ID_PATTERN,
    MAX_COORD,
    MAX_PLANNED,
    MAX_RELEASED,
    MAX_TEXT,
    PROTOCOL_VERSION,
)

SPOKEN_VERSION = f"^{re.escape(PROTOCOL_VERSION)}$"  # the protocol's own, not a copy of its number

coord = Annotated[int, msgspec.Meta(ge=0, le=MAX_COORD)]
square = tuple[coord, coord]
ident = Annotated[str, msgspec.Meta(pattern=ID_PATTERN)]
count = Annotated[int, msgspec.Meta(ge=0)]
reading = Literal["free", "wall", "obstacle", "unit"]


class Header(msgspec.Struct, forbid_unknown_fields=True):
    version: Annotated[str, msgspec.Meta(pattern=SPOKEN_VERSION)]
    seq: count
    timestamp: datetime
    sender: ident


class Leds(msgspec.Struct, forbid_unknown_fields=True):
    N: bool = False
    E: bool = False
    S: bool = False
    W: bool = False


class Sensors(msgspec.Struct, forbid_unknown_fields=True):
    N: reading
    E: reading
    S: reading
    W: reading


class State(msgspec.Struct, forbid_unknown_fields=True):
    header: Header
    step: count
    position: square
    direction: Literal["N", "E", "S", "W", "-"]
    status: Literal["idle", "moving", "waiting", "stopped", "holding"]
    leds: Leds
    sensors: Sensors
    wait_reason: Annotated[str, msgspec.Meta(max_length=MAX_TEXT)] | None = None
    mode: Literal["coordinated", "standalone"] = "coordinated"
    job_id: ident | None = None
    load_kg: Annotated[float, msgspec.Meta(ge=0)] = 0.0
    obstacles: Annotated[list[square], msgspec.Meta(max_length=4)] = []
    order_id: Annotated[str, msgspec.Meta(max_length=128)] | None = None
    order_update_id: count = 0
    released: Annotated[list[square], msgspec.Meta(max_length=MAX_RELEASED)] = []
    goal: square | None = None
    estop: bool = False
    errors: list[dict[str, str]] = []
    battery_pct: Annotated[float, msgspec.Meta(ge=0, le=100)] | None = None
    charging: bool = False


class Action(msgspec.Struct, forbid_unknown_fields=True):
    kind: Literal["pick", "drop"]
    job_id: ident
    square: square
    mass_kg: Annotated[float, msgspec.Meta(gt=0)]


class Order(msgspec.Struct, forbid_unknown_fields=True):
    header: Header
    order_id: Annotated[str, msgspec.Meta(min_length=1, max_length=128)]
    update_id: Annotated[int, msgspec.Meta(ge=1)]
    released: Annotated[list[square], msgspec.Meta(max_length=MAX_RELEASED)]
    step: count = 0
    planned: Annotated[list[square], msgspec.Meta(max_length=MAX_PLANNED)] = []
    target: square | None = None
    action: Action | None = None
    charge: square | None = None


STRUCTS: dict[str, type[msgspec.Struct]] = {"UnitState": State, "Order": Order}
