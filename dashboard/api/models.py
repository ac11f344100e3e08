"""The API's bodies and answers: small models around the protocol's own (gridfleet.protocol).

A request body reuses the protocol's field types (a square or a place name, a mass > 0, a
priority 0-100), strict about JSON's types as the protocol is: `"2.5"` is no mass, `true` no
priority. Answers carry the protocol's views unchanged (JobView, Place, Zone, UnitState, ...).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, StringConstraints

from gridfleet.protocol.constants import MAX_ESTOP_REASON, MAX_TEXT
from gridfleet.protocol.messages import (
    AuditEntry,
    ChargeEntry,
    CoordinatorStatus,
    Cursor,
    Factsheet,
    Id,
    JobHistoryEntry,
    JobState,
    JobView,
    Pct,
    Place,
    PositiveKg,
    RouteView,
    Square,
    Text,
    UnitCommand,
    UnitControlState,
    UnitEnergy,
    UnitState,
    UnitStatus,
    Where,
    Zone,
)

StrictKg = Annotated[PositiveKg, Field(strict=True)]
Priority = Annotated[int, Field(ge=0, le=100, strict=True)]
OneLine = Annotated[str, StringConstraints(max_length=MAX_ESTOP_REASON, pattern=r"^[^\r\n\x00]*$")]
ZoneReason = Annotated[str, StringConstraints(min_length=1, max_length=MAX_TEXT)]


class Body(BaseModel):
    """A request body: exactly its fields."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class JobRequest(Body):
    """A pick-and-deliver job: where from, where to (a square [x, y] or a place's name), how
    heavy, how urgent."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"pickup": "A1", "dropoff": "P1", "mass_kg": 2.5, "priority": 0},
                {"pickup": [1, 1], "dropoff": [8, 8], "mass_kg": 1.5},
            ]
        },
        # flask-openapi3: the request body's example in the document (and on the docs page).
        openapi_extra={"example": {"pickup": "A1", "dropoff": "P1", "mass_kg": 2.5}},  # type: ignore[typeddict-unknown-key]
    )

    pickup: Where
    dropoff: Where
    mass_kg: StrictKg
    priority: Priority = 0


class ZoneRequest(Body):
    """A zone to close: two opposite corners and why (shown to every operator)."""

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"first": [3, 3], "last": [4, 6], "reason": "cleaning"}]}
    )

    first: Square
    last: Square
    reason: ZoneReason


class ControlRequest(Body):
    """An operator's control of one unit (protocol.md §6.4)."""

    model_config = ConfigDict(json_schema_extra={"examples": [{"command": "pause"}]})

    command: UnitCommand


class StopRequest(Body):
    """Why the stop is engaged: one line, for everybody."""

    model_config = ConfigDict(json_schema_extra={"examples": [{"reason": "forklift in aisle 2"}]})

    reason: OneLine = "stopped over the API"


class Answer(BaseModel):
    """An answer of the API: exactly its fields."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class JobsPage(Answer):
    """A page of the jobs view's listing: the jobs not finished, then the latest finished."""

    jobs: list[JobView]
    next_cursor: str | None = Field(None, description="give it as `cursor` for the next page")
    counts: dict[JobState, int] = Field(default_factory=dict, description="every job, by state")


class UnitView(Answer):
    """One unit as the fleet's views show it."""

    id: Id
    connection: Literal["online", "offline", "broken"] | None = None
    status: UnitStatus | None = None
    position: Square | None = None
    job_id: Id | None = None
    battery_pct: Pct | None = None
    charging: bool = False
    control: UnitControlState | None = Field(None, description="an operator's control, if any")
    note: Text | None = Field(None, description="why the coordinator moves or holds it")
    state: UnitState | None = None
    factsheet: Factsheet | None = None
    route: RouteView | None = None
    energy: UnitEnergy | None = None


class UnitsList(Answer):
    """Every unit the fleet's views know, by id."""

    units: list[UnitView]


class PlacesList(Answer):
    """The map's named places (protocol.md §5.10)."""

    places: list[Place]


class ZonesList(Answer):
    """The zones closed now, in the order they were closed."""

    zones: list[Zone]


class Accepted(Answer):
    """The coordinator accepted the request; its words, if it said any."""

    accepted: bool = True
    reason: str | None = None
    job_id: Id | None = None


class StopSignal(Answer):
    """The latch or one press: engaged or released, by whom, why."""

    engaged: bool
    by: str
    reason: str


class StopState(Answer):
    """The emergency stop: the fleet is stopped while the latch or any press holds it."""

    engaged: bool
    latch: StopSignal | None = None
    presses: list[StopSignal] = Field(default_factory=list)
    coordinator_stopped: bool = Field(False, description="an online coordinator says so")
    message: str | None = Field(None, description="what the act did, as `gridfleet job` says")


class ZoneEvent(Answer):
    """A zone closed or opened (the data of an event `zone`)."""

    name: Id
    state: Literal["closed", "open"]
    zone: Zone | None = None


class HistoryPage(Answer):
    """A page of the job history, oldest first."""

    entries: list[JobHistoryEntry]
    next_cursor: Cursor | None = None


class ChargesPage(Answer):
    """A page of the charges' starts and ends, oldest first."""

    charges: list[ChargeEntry]
    next_cursor: Cursor | None = None


class AuditList(Answer):
    """A page of the audit trail, oldest first."""

    entries: list[AuditEntry]
    next_cursor: Cursor | None = None


class CoordinatorEvent(Answer):
    """The coordinator's status changed (the data of an event `coordinator`)."""

    status: CoordinatorStatus
