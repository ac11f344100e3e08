"""Message models of every JSON topic; each refuses bad values with an error naming the field."""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, StringConstraints

from gridfleet.protocol.constants import (
    ID_PATTERN,
    MAX_CHARGERS,
    MAX_COORD,
    MAX_ENERGY_UNITS,
    MAX_PCT_PER_S,
    MAX_PLACES,
    MAX_PLANNED,
    MAX_RELEASED,
    MAX_TEXT,
    MAX_ZONES,
    PROTOCOL_VERSION,
)
from gridfleet.squares import Cell

Id = Annotated[str, StringConstraints(pattern=ID_PATTERN)]
Text = Annotated[str, StringConstraints(max_length=MAX_TEXT)]
Coord = Annotated[int, Field(ge=0, le=MAX_COORD, strict=True)]


def _as_cell(value: tuple[int, int]) -> Cell:
    return Cell(value[0], value[1])


if TYPE_CHECKING:
    # What a field holds once validated: the checkers see the Cell that the code gets.
    Square = Cell
else:
    Square = Annotated[tuple[Coord, Coord], AfterValidator(_as_cell)]
"""A square as a JSON array [x, y]; decoded into a Cell."""

if TYPE_CHECKING:
    Where = Cell | str
else:
    Where = Square | Id
"""A square [x, y] or the name of a place on the map (protocol.md §5.10): the coordinator
resolves a name to its square."""


def _spoken_version(value: str) -> str:
    if value != PROTOCOL_VERSION:
        raise ValueError(f"protocol version {value[:32]!r} is not {PROTOCOL_VERSION!r}")
    return value


Version = Annotated[
    str, AfterValidator(_spoken_version), Field(json_schema_extra={"const": PROTOCOL_VERSION})
]
"""The one protocol version this code speaks (constants.PROTOCOL_VERSION); others are refused."""

Kg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Pct = Annotated[float, Field(ge=0, le=100, allow_inf_nan=False)]
"""A share of a full battery, 0 to 100."""
PositiveKg = Annotated[float, Field(gt=0, allow_inf_nan=False)]
DirectionLetter = Literal["N", "E", "S", "W", "-"]
SensorReading = Literal["free", "wall", "obstacle", "unit"]
UnitStatus = Literal["idle", "moving", "waiting", "stopped", "holding"]
JobState = Literal[
    "queued",
    "assigned",
    "to_pickup",
    "loaded",
    "to_dropoff",
    "done",
    "cancelled",
    "rejected",
    "failed",
]
FINAL_JOB_STATES: frozenset[str] = frozenset({"done", "cancelled", "rejected", "failed"})
# Why a job that is not final waits (protocol.md §5.3): the machine-readable half.
WaitCode = Literal[
    "fleet_stopped",
    "no_capable_unit",
    "no_unit_free",
    "unit_away",
    "unit_waiting",
    "unit_stuck",
    "unit_paused",
    "unit_out_of_service",
    "unit_charging",
    "battery_low",
    "zone_closed",  # its pickup or dropoff lies in a closed zone
    "unreachable",  # closed zones cut every way to its pickup or dropoff
]
# Why a request was refused, for machines (protocol.md §6): the HTTP API's status comes from it.
RefusalCode = Literal[
    "invalid",  # not allowed as asked (e.g. the fleet is stopped for this)
    "bad_square",  # off the map, a wall, or a charger's square
    "unknown_place",
    "unknown_job",
    "unknown_unit",
    "unknown_zone",
    "too_heavy",  # heavier than every unit can carry
    "unreachable",  # no unit able to carry it can reach it
    "zone_closed",  # a square of it lies in a closed zone
    "conflict",  # not in the state it must be (a finished job, a name taken)
    "queue_full",
    "too_many",  # the account has too many jobs not finished
    "forbidden",  # the account may not do this
]
PlaceKind = Literal["pickup", "dropoff", "charger", "parking"]
# An operator's control of one unit (protocol.md §6.4): paused keeps its job, out of service gives
# up a job not picked up yet and takes no new one.
UnitControlState = Literal["paused", "out_of_service"]
UnitCommand = Literal["pause", "resume", "out_of_service", "in_service", "charge"]


Side = Literal["N", "E", "S", "W"]


def _all_sides() -> list[Side]:
    return ["N", "E", "S", "W"]


# A map keyed by ids: its schema's patternProperties allow only ids as keys, as the model does.
ID_KEYS_ONLY: dict[str, Any] = {"additionalProperties": False}


class Model(BaseModel):
    """Base of every message: immutable, strict about unknown fields."""

    model_config = ConfigDict(frozen=True, extra="forbid", populate_by_name=True, defer_build=True)


class Header(Model):
    """Carried by every JSON message: who sent it, when, and its place in the topic's sequence."""

    version: Version = PROTOCOL_VERSION
    seq: Annotated[int, Field(ge=0, strict=True)]
    timestamp: datetime
    sender: Id


class Message(Model):
    """A JSON message with its header."""

    # Whether its fields that are null are left out on the wire (absent reads as null).
    omits_nulls: ClassVar[bool] = False

    header: Header


class Connection(Message):
    """`units/<id>/connection`: whether a unit is online; its last will says "broken"."""

    state: Literal["online", "offline", "broken"]


class EnergyModel(Model):
    """What a unit's battery does (protocol.md §4.2): the coordinator plans its charges by it."""

    move_pct: Annotated[float, Field(ge=0, le=100, allow_inf_nan=False)]  # one move (one square)
    # A second standing, a second on a charger: up to MAX_PCT_PER_S, for a simulation run faster
    # than life states its rates per second of the run (robots/battery.py).
    idle_pct_per_s: Annotated[float, Field(ge=0, le=MAX_PCT_PER_S, allow_inf_nan=False)]
    charge_pct_per_s: Annotated[float, Field(gt=0, le=MAX_PCT_PER_S, allow_inf_nan=False)]


class Factsheet(Message):
    """`units/<id>/factsheet`: what a unit can do, read by allocation and the dashboard."""

    capacity_kg: PositiveKg
    step_period_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)]
    sensors: list[Side] = Field(default_factory=_all_sides)
    color: Annotated[str, StringConstraints(pattern=r"^#[0-9a-fA-F]{6}$")] = "#607d8b"
    model: Annotated[str, StringConstraints(max_length=64)] = "gridfleet-sim"
    # The map the unit drives on (GridMap.map_id); a coordinator on another map ignores the unit.
    map_id: Annotated[str, StringConstraints(pattern=r"^[0-9a-f]{12}$")] | None = None
    # Its battery's model; null: it does not report energy (it never runs down, as far as the
    # coordinator knows).
    energy: EnergyModel | None = None


class VehicleCondition(Message):
    """`units/<id>/vehicle`: what a VDA 5050 vehicle says of itself (its battery, its own errors)."""

    battery_pct: Annotated[float, Field(ge=0, le=100, allow_inf_nan=False)] | None = None
    charging: bool = False
    errors: Annotated[list[Text], Field(max_length=8)] = Field(default_factory=list)


class Leds(Model):
    """The four direction LEDs; exactly one is lit before a move, all when emergency-stopped."""

    N: bool = False
    E: bool = False
    S: bool = False
    W: bool = False


class Sensors(Model):
    """What the four distance sensors see in the neighbouring squares."""

    N: SensorReading
    E: SensorReading
    S: SensorReading
    W: SensorReading


class UnitError(Model):
    """An error a unit reports in its state (e.g. a refused order)."""

    code: Annotated[str, StringConstraints(pattern=r"^[a-z_]{1,40}$")]
    message: Text


class UnitState(Message):
    """`units/<id>/state`: a unit's pose and condition, sent on change and at least every 3 steps."""

    step: Annotated[int, Field(ge=0, strict=True)]
    position: Square
    direction: DirectionLetter
    status: UnitStatus
    wait_reason: Text | None = None
    mode: Literal["coordinated", "standalone"] = "coordinated"
    job_id: Id | None = None
    load_kg: Kg = 0.0
    leds: Leds
    sensors: Sensors
    obstacles: Annotated[list[Square], Field(max_length=4)] = Field(default_factory=list)
    order_id: Annotated[str, StringConstraints(max_length=128)] | None = None
    order_update_id: Annotated[int, Field(ge=0, strict=True)] = 0
    released: Annotated[list[Square], Field(max_length=MAX_RELEASED)] = Field(default_factory=list)
    goal: Square | None = None
    estop: bool = False
    errors: Annotated[list[UnitError], Field(max_length=16)] = Field(default_factory=list)
    battery_pct: Pct | None = None  # its charge; null: it does not report energy
    charging: bool = False  # on a charger, charging


class Action(Model):
    """What a unit does when it stands on `square` under an order: pick up or drop a job's item."""

    kind: Literal["pick", "drop"]
    job_id: Id
    square: Square
    mass_kg: PositiveKg


class Order(Message):
    """`units/<id>/order`: squares released to a unit, the planned rest, and an action."""

    order_id: Annotated[str, StringConstraints(min_length=1, max_length=128)]
    update_id: Annotated[int, Field(ge=1, strict=True)]
    step: Annotated[int, Field(ge=0, strict=True)] = 0
    released: Annotated[list[Square], Field(max_length=MAX_RELEASED)]
    planned: Annotated[list[Square], Field(max_length=MAX_PLANNED)] = Field(default_factory=list)
    target: Square | None = None
    action: Action | None = None
    # The charger square where it charges once it stands there with nothing left to drive;
    # null: it does not charge (a unit charging stops).
    charge: Square | None = None


class Goal(Message):
    """`units/<id>/goal`: a target for a unit that plans for itself (standalone mode); null clears."""

    target: Square | None


class Charger(Model):
    """A charger on the map: its square and its name."""

    name: Id
    square: Square


class Place(Model):
    """A named square of the map and what may happen there (protocol.md §5.10)."""

    name: Id
    square: Square
    kinds: Annotated[list[PlaceKind], Field(min_length=1, max_length=4)]


class FleetMap(Message):
    """`fleet/map`: the static map, its chargers and places, and the obstacles units found."""

    name: Annotated[str, StringConstraints(max_length=128)]
    width: Annotated[int, Field(ge=1, le=MAX_COORD + 1, strict=True)]
    height: Annotated[int, Field(ge=1, le=MAX_COORD + 1, strict=True)]
    rows: list[Annotated[str, StringConstraints(pattern=r"^[.@]+$")]]
    obstacles: list[Square] = Field(default_factory=list)
    chargers: Annotated[list[Charger], Field(max_length=MAX_CHARGERS)] = Field(default_factory=list)
    places: Annotated[list[Place], Field(max_length=MAX_PLACES)] = Field(default_factory=list)


# ---- energy (coordinator/energy.py: protocol.md §5.9) -------------------------------------------

EnergyPlan = Literal["to_charger", "queued", "charging", "stranded"]
AvailableFrom = Literal["sufficient", "full"]


class Thresholds(Model):
    """The coordinator's charge thresholds, openTCS's four (protocol.md §5.9)."""

    critical_pct: Pct  # at or below: no job, to a charger at once
    good_pct: Pct  # below, and idle: to a charger
    sufficient_pct: Pct  # a charging unit takes jobs again from here (when `available_from`)
    full_pct: Pct  # a charging unit with nothing to do charges up to here
    available_from: AvailableFrom = "sufficient"


class ChargerView(Model):
    """A charger as the energy view shows it: who is on it (or on the way) and who waits."""

    name: Id
    square: Square
    unit: Id | None = None  # the unit it is given to: charging there, or on its way
    queue: Annotated[list[Id], Field(max_length=MAX_ENERGY_UNITS)] = Field(default_factory=list)


class UnitEnergy(Model):
    """What the energy policy does with one unit, when it does anything."""

    plan: EnergyPlan
    charger: Id | None = None  # the charger it goes to or charges at
    reason: Text | None = None  # in words, e.g. "charging: 62 % of 80 %"


class EnergyView(Message):
    """`fleet/energy`: the thresholds, the chargers and the units the energy policy moves."""

    thresholds: Thresholds
    chargers: Annotated[list[ChargerView], Field(max_length=MAX_CHARGERS)] = Field(
        default_factory=list
    )
    units: Annotated[
        dict[Id, UnitEnergy], Field(max_length=MAX_ENERGY_UNITS, json_schema_extra=ID_KEYS_ONLY)
    ] = Field(
        default_factory=dict
    )  # only units the policy sends to, holds at or queues for a charger, or cannot help


class JobView(Model):
    """One job as the queue view shows it."""

    id: Id
    pickup: Square
    dropoff: Square
    mass_kg: PositiveKg
    priority: Annotated[int, Field(ge=0, le=100, strict=True)] = 0
    state: JobState
    unit: Id | None = None
    reason: Text | None = None
    submitted_by: Id | None = None
    created_step: Annotated[int, Field(ge=0, strict=True)] = 0
    done_step: Annotated[int, Field(ge=0, strict=True)] | None = None
    wait: WaitCode | None = None
    wait_reason: Text | None = None
    pickup_place: Id | None = None  # the place its pickup was named by, if it was
    dropoff_place: Id | None = None


FINISHED_LISTED = 20  # the queue view's latest finished jobs
CHART_MINUTES = 10  # the queue view's jobs done per minute


class JobsView(Message):
    """`fleet/jobs`: the jobs not finished, the latest finished ones, and counts of all."""

    omits_nulls: ClassVar[bool] = True  # a queued job's null unit, reason, ...: a third of it

    jobs: list[JobView]  # every job not finished, in submission order
    finished: Annotated[list[JobView], Field(max_length=FINISHED_LISTED)] = Field(
        default_factory=list
    )  # the latest finished jobs, newest first
    counts: dict[JobState, int] = Field(default_factory=dict)  # every job ever, by state
    done_per_minute: Annotated[list[Annotated[int, Field(ge=0)]], Field(max_length=60)] = Field(
        default_factory=list
    )  # jobs done in each of the last minutes of coordinator steps, the current one last

    def listed(self) -> list[JobView]:
        """Every job the view lists: those not finished, then the latest finished."""
        return [*self.jobs, *self.finished]


class RouteView(Model):
    """One unit's route as planned: released squares, the planned rest, and the target."""

    released: list[Square] = Field(default_factory=list)
    planned: list[Square] = Field(default_factory=list)
    target: Square | None = None
    control: UnitControlState | None = None  # an operator's control of the unit, if any
    note: Text | None = None  # why the coordinator moves or holds it, e.g. leaving a closed zone


class Routes(Message):
    """`fleet/routes`: every unit's route, for display."""

    step: Annotated[int, Field(ge=0, strict=True)]
    routes: Annotated[dict[Id, RouteView], Field(json_schema_extra=ID_KEYS_ONLY)]


class Zone(Model):
    """A closed zone: a rectangle no unit is sent into, who closed it, when and why."""

    name: Id
    first: Square  # its corner of least x and y
    last: Square  # its corner of greatest x and y
    reason: Text
    closed_by: Id | None = None  # the account that closed it (the request's sender)
    closed_at: datetime


class ZonesView(Message):
    """`fleet/zones`: the zones closed now, in the order they were closed."""

    zones: Annotated[list[Zone], Field(max_length=MAX_ZONES)] = Field(default_factory=list)


EventKind = Literal["job", "unit", "stop", "refusal", "zone"]
MAX_EVENTS = 100  # the events view keeps the latest this many


class EventEntry(Model):
    """One thing that happened, in plain words, and the job or unit it concerns."""

    at: datetime
    kind: EventKind
    text: Text
    job: Id | None = None
    unit: Id | None = None


class EventsView(Message):
    """`fleet/events`: the coordinator's recent history, oldest first, at most MAX_EVENTS."""

    events: Annotated[list[EventEntry], Field(max_length=MAX_EVENTS)]


class Request(Message):
    """Common fields of an operator request: an id to match the reply, and where to reply."""

    request_id: Annotated[str, StringConstraints(min_length=1, max_length=64)]
    reply_to: Id | None = None  # client id: the reply goes to replies/<reply_to>


class SubmitJob(Request):
    """`requests/submit_job`: queue a pick-and-deliver job (its squares, or places by name)."""

    pickup: Where
    dropoff: Where
    mass_kg: PositiveKg
    priority: Annotated[int, Field(ge=0, le=100, strict=True)] = 0
    job_id: Id | None = None


class CancelJob(Request):
    """`requests/cancel_job`: delete a queued job or abort an active one."""

    job_id: Id


class SetGoal(Request):
    """`requests/set_goal`: send one unit to a square (null target clears the goal)."""

    unit: Id
    target: Square | None


class ControlUnit(Request):
    """`requests/control_unit`: pause or resume one unit, take it out of service or back."""

    unit: Id
    command: UnitCommand


class ClearObstacles(Request):
    """`requests/clear_obstacles`: discovered obstacles an operator knows are gone (null: all)."""

    squares: Annotated[list[Square], Field(min_length=1, max_length=1024)] | None


class RemoveUnit(Request):
    """`requests/remove_unit`: a lost unit an operator knows is off the floor, forgotten for good."""

    unit: Id
    reason: Text | None = None  # why, in words, for the audit and the events


class CloseZone(Request):
    """`requests/close_zone`: close a rectangle of squares, with a reason (protocol.md §5.11)."""

    name: Id
    first: Square  # one corner
    last: Square  # the opposite corner
    reason: Annotated[str, StringConstraints(min_length=1, max_length=MAX_TEXT)]


class OpenZone(Request):
    """`requests/open_zone`: open a closed zone again."""

    name: Id


class Reply(Message):
    """`replies/<client>`: the answer to one request."""

    request_id: Annotated[str, StringConstraints(min_length=1, max_length=64)]
    accepted: bool
    reason: Text | None = None
    job_id: Id | None = None
    code: RefusalCode | None = None  # why it was refused, for machines; null when accepted


class ErrorReport(Message):
    """`errors`: a component refused a message; says which topic and why."""

    topic: Annotated[str, StringConstraints(max_length=256)]
    reason: Text
    request_id: Annotated[str, StringConstraints(max_length=64)] | None = None


class CoordinatorStatus(Message):
    """`coordinator/status`: whether the coordinator runs; its last will says "broken"."""

    state: Literal["online", "offline", "broken"]
    step: Annotated[int, Field(ge=0, strict=True)] = 0
    step_period_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 1.0
    estop: bool = False
    version: Annotated[str, StringConstraints(max_length=32)] = "0"
    # The mean time one step actually took over the last few seconds (None until measured): on
    # a loaded machine or broker it is longer than `step_period_s`.
    achieved_step_s: Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False)] | None = None


# ---- alerts (the alerts process, `gridfleet alerts`: protocol.md §5.8, §6.7) ------------------

AlertRule = Literal[
    "unit_lost",
    "unit_stuck",
    "job_queued",
    "estop",
    "step_rate_low",
    "coordinator_down",
    "broker_down",
    "handler_failures",
    "battery_low",
    "battery_critical",
    "cannot_reach_charger",
    "zone_wait",  # a job waits on a closed zone too long
]
AlertSeverity = Literal["warning", "critical"]
CLEARED_ALERTS_LISTED = 20  # the alerts view's latest cleared alerts
# Alerts in force at once: one per rule and subject, and the subjects are units and open jobs
# (MAX_OPEN_JOBS), so a view of them all stays well inside MAX_VIEW_BYTES.
MAX_ACTIVE_ALERTS = 20000


class AlertEntry(Model):
    """One alert: a rule's condition about a subject, raised, maybe cleared and acknowledged."""

    id: Id  # stable for the alert's life: the key an acknowledgement names
    rule: AlertRule
    subject: Id | None = None  # the unit or job it concerns; null for the fleet as a whole
    severity: AlertSeverity
    text: Text
    raised_at: datetime
    cleared_at: datetime | None = None
    acked_by: Id | None = None  # the broker account that acknowledged it
    acked_at: datetime | None = None


class AlertsView(Message):
    """`fleet/alerts`: the alerts in force, oldest first, and the latest cleared, newest first."""

    active: Annotated[list[AlertEntry], Field(max_length=MAX_ACTIVE_ALERTS)]
    cleared: Annotated[list[AlertEntry], Field(max_length=CLEARED_ALERTS_LISTED)] = Field(
        default_factory=list
    )


class AckAlert(Request):
    """`requests/ack_alert`: a person has seen an alert (active or cleared) and takes it on."""

    alert_id: Id


# ---- the audit trail (coordinator/audit.py: protocol.md §6.8, §6.9) ----------------------------

AuditAct = Literal[
    "stop_engage",
    "stop_release",
    "submit_job",
    "cancel_job",
    "set_goal",
    "clear_goal",
    "pause",
    "resume",
    "out_of_service",
    "in_service",
    "charge",
    "clear_obstacles",
    "remove_unit",
    "close_zone",
    "open_zone",
    "login",
    "logout",
    "login_failed",
]
AuditOutcome = Literal["accepted", "refused"]
LoginEvent = Literal["login", "logout", "login_failed"]
MAX_AUDIT_PAGE = 500  # entries one audit reply carries at most
# Where the next page of a stored record goes on (the last entry's row): opaque to clients.
Cursor = Annotated[str, StringConstraints(pattern=r"^[0-9]{1,19}$")]


class AuditEntry(Model):
    """One operator act: who (the account), when, what, and whether it was carried out."""

    at: datetime
    actor: Id | None  # the account; with `verified` false, only what the client claimed
    verified: bool  # the broker (or the dashboard's login) vouched for `actor`
    via: Id | None = None  # the client id that sent it (the header's sender, the latch's `by`)
    act: AuditAct
    target: Annotated[str, StringConstraints(max_length=200)] | None = None  # job, unit, squares
    detail: Text | None = None
    outcome: AuditOutcome
    reason: Text | None = None  # why it was refused


class AuditQuery(Request):
    """`requests/audit`: a page of the audit trail, oldest first (operators only)."""

    since: datetime
    until: datetime | None = None  # null: now
    actor: Id | None = None  # only this account's acts
    limit: Annotated[int, Field(ge=1, le=MAX_AUDIT_PAGE, strict=True)] = 100
    cursor: Cursor | None = None  # the previous page's `next_cursor`


class Page(Message):
    """The answer to a query of a stored record (audit, job history): a page, or why not."""

    request_id: Annotated[str, StringConstraints(min_length=1, max_length=64)]
    accepted: bool
    reason: Text | None = None
    next_cursor: Cursor | None = None  # null: this was the last page


class AuditPage(Page):
    """`audit/replies/<client>`: the answer to an AuditQuery: a page of entries, or why not."""

    entries: Annotated[list[AuditEntry], Field(max_length=MAX_AUDIT_PAGE)] = Field(
        default_factory=list
    )


class AuditLogin(Request):
    """`requests/audit_login`: the dashboard tells the audit of a login, logout or failed login."""

    event: LoginEvent
    user: Id | None  # the account logged in or out; for a failed login the name tried (if an id)
    address: Annotated[str, StringConstraints(max_length=64)] | None = None  # the person's
    reason: Text | None = None  # why a login failed


class BrokerRevoke(Message):
    """`broker/revoke`: the dashboard takes a page session's broker password back (its logout).

    Read by the embedded broker alone, which passes it to nobody (protocol.md §10).
    """

    sid: Annotated[str, StringConstraints(pattern=r"^[A-Za-z0-9_-]{1,64}$")]  # the session's id
    expires: Annotated[int, Field(ge=0, strict=True)]  # its end, unix seconds: forgotten after


# ---- the job history (coordinator/history.py: protocol.md §6.10) -------------------------------

MAX_HISTORY_PAGE = 1000  # entries one history reply carries at most


class JobHistoryEntry(Model):
    """One change in a job's life: its state, unit or reason for waiting, and when."""

    at: datetime
    job: Id
    state: JobState
    unit: Id | None = None  # the unit it is assigned to (or was, when it ended)
    wait: WaitCode | None = None  # why it waits, while queued or under way
    reason: Text | None = None  # why it waits, or why it ended as it did, in words
    since_submitted_s: Annotated[float, Field(ge=0, allow_inf_nan=False)]
    pickup: Square
    dropoff: Square
    mass_kg: PositiveKg
    priority: Annotated[int, Field(ge=0, le=100, strict=True)] = 0
    submitted_by: Id | None = None
    pickup_place: Id | None = None  # the place its pickup was named by, if it was
    dropoff_place: Id | None = None


ChargeEvent = Literal["started", "ended"]


class ChargeEntry(Model):
    """A charge started or ended: which unit, at which charger, its battery then, and why."""

    at: datetime
    unit: Id
    charger: Id
    event: ChargeEvent
    battery_pct: Pct
    reason: Text | None = None  # why it started or ended, in words


class JobHistoryQuery(Request):
    """`requests/job_history`: a page of the job history (or of the charges), oldest first."""

    kind: Literal["jobs", "charges"] = "jobs"  # charges: the charges' starts and ends instead
    since: datetime
    until: datetime | None = None  # null: now
    unit: Id | None = None  # only changes of jobs while this unit had them
    job_id: Id | None = None  # only this job's changes
    state: JobState | None = None  # only changes into this state
    limit: Annotated[int, Field(ge=1, le=MAX_HISTORY_PAGE, strict=True)] = 200
    cursor: Cursor | None = None  # the previous page's `next_cursor`


class JobHistoryPage(Page):
    """`history/replies/<client>`: the answer to a JobHistoryQuery: a page of entries, or why not."""

    entries: Annotated[list[JobHistoryEntry], Field(max_length=MAX_HISTORY_PAGE)] = Field(
        default_factory=list
    )
    # The answer to a query of kind "charges" (its `entries` are then empty).
    charges: Annotated[list[ChargeEntry], Field(max_length=MAX_HISTORY_PAGE)] = Field(
        default_factory=list
    )
