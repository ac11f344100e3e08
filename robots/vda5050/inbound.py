"""What a VDA 5050 vehicle sends, checked at the edge: every field the fleet reads, typed.

Each message is read against the fields the adapter uses (and the header every VDA 5050 message
carries); anything else is the vehicle's business and passes. A message that is not JSON, lacks a
field, has one of the wrong type, or claims another vehicle or version is refused with one line
saying what, and changes nothing. (The tests, and `--schemas` at run time, also hold every message
to the official JSON schema of its version.)

Whatever the official schemas of 2.0.0 and 2.1.0 allow is taken (tests/robots/
test_vda5050_schema_edges.py): a field is required here only where the schema requires it too,
a number only bounded where the schema bounds it (what makes no sense physically, a negative
deviation, is read in states.py), and an integer may come as `3.0` (JSON Schema's integers).
Refused although the schemas allow them: numbers beyond a double's range (`1e400`) and a
message over MAX_VDA_BYTES.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Annotated, Any, Literal, TypeVar

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError

from gridfleet.errors import ProtocolError
from gridfleet.robots.vda5050.wire import Vehicle

MAX_VDA_BYTES = 256 * 1024  # a state of a long order is a few kB; far beyond that is no state

Number = Annotated[float, Field(allow_inf_nan=False)]


def _integral(value: object) -> object:
    """JSON Schema's integer: `3.0` is one (JSON has one kind of number); left as it is else."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


# Any integer, however signed: the schemas bound none of those it is used for.
Integer = Annotated[int, BeforeValidator(_integral), Field(strict=True)]


class _Part(BaseModel):
    model_config = ConfigDict(extra="allow", strict=True, frozen=True, defer_build=True)


class _Sender(_Part):
    version: str
    manufacturer: str
    serialNumber: str


class _Header(_Sender):
    headerId: Integer  # required by the schemas; the adapter reads neither it nor the timestamp
    timestamp: str


class VdaConnection(_Header):
    """`connection`: whether the vehicle is on line."""

    connectionState: Literal["ONLINE", "OFFLINE", "CONNECTIONBROKEN"]


class _Position(_Part):
    x: Number
    y: Number
    theta: Number
    mapId: str
    positionInitialized: bool
    deviationRange: Number = 0.0  # absent: a position that is exact (states.py reads a sign)


class _Reference(_Part):
    referenceKey: str
    referenceValue: str


class _Error(_Part):
    errorType: str
    errorLevel: Literal["WARNING", "FATAL"]
    errorDescription: str | None = None
    errorReferences: list[_Reference] = Field(default_factory=list)

    def about(self, key: str) -> str | None:
        """The value of its reference `key` (e.g. the `orderId` it is about), if it has one."""
        return next((r.referenceValue for r in self.errorReferences if r.referenceKey == key), None)


class _ActionState(_Part):
    actionId: str
    actionStatus: Literal["WAITING", "INITIALIZING", "RUNNING", "PAUSED", "FINISHED", "FAILED"]
    resultDescription: str | None = None  # absent: the action's outcome is told by its status


class _Battery(_Part):
    batteryCharge: Number
    charging: bool = False  # required by the schemas; absent, not charging


class _Safety(_Part):
    eStop: Literal["AUTOACK", "MANUAL", "REMOTE", "NONE"]
    fieldViolation: bool


class _NodeState(_Part):
    nodeId: str
    sequenceId: Integer
    released: bool


class VdaState(_Header):
    """`state`: the fields the fleet reads."""

    orderId: str
    orderUpdateId: Integer
    lastNodeId: str
    lastNodeSequenceId: Integer
    nodeStates: list[_NodeState]
    edgeStates: list[Any]
    agvPosition: _Position | None = None  # absent: where it stands is unknown (no square)
    driving: bool
    paused: bool | None = None  # absent: not paused
    operatingMode: str
    errors: list[_Error]
    actionStates: list[_ActionState]
    batteryState: _Battery
    safetyState: _Safety
    # `loads` is not read (each load's `weight` is optional): the unit carries its job's mass
    # from the vehicle's pick to its drop (core.py), whatever the vehicle says of its loads.


class _LoadSet(_Part):
    maxWeight: Number | None = None  # absent (or not above 0): this set tells no capacity
    # So spelt in 2.0.0's schema (2.1.0's knows no such key): a number there reads as maxWeight.
    maxWeigth: Any = None


class _LoadSpecification(_Part):
    loadSets: list[_LoadSet] = Field(default_factory=list)  # absent: none tells a capacity


class _TypeSpecification(_Part):
    maxLoadMass: Annotated[Number, Field(ge=0)]


class VdaFactsheet(_Sender):
    """`factsheet`: what the vehicle carries (its header's id and time are optional here)."""

    typeSpecification: _TypeSpecification
    loadSpecification: _LoadSpecification

    @property
    def capacity_kg(self) -> float | None:
        """The heaviest load it takes: `maxLoadMass`, else its load sets' largest `maxWeight`."""
        if self.typeSpecification.maxLoadMass > 0:
            return self.typeSpecification.maxLoadMass
        weights: list[float] = []
        for load_set in self.loadSpecification.loadSets:
            weight = load_set.maxWeight if load_set.maxWeight is not None else load_set.maxWeigth
            if type(weight) in (int, float) and math.isfinite(weight) and weight > 0:
                weights.append(float(weight))
        return max(weights) if weights else None


M = TypeVar("M", bound=_Sender)


def read_vda(
    model: type[M], payload: bytes, vehicle: Vehicle, schema: Callable[[Any], None] | None = None
) -> M:
    """`payload` as `model`, from `vehicle`; ProtocolError in one line when it is not.

    `schema`, when given, holds the whole message to the official schema first (it raises
    ProtocolError naming the first problem).
    """
    if len(payload) > MAX_VDA_BYTES:
        raise ProtocolError(f"{len(payload)} bytes: more than {MAX_VDA_BYTES}")
    try:
        data = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ProtocolError(f"not JSON: {exc}") from None
    if schema is not None:
        schema(data)
    try:
        message = model.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(part) for part in first["loc"]) or "message"
        # Not pydantic's "valid dictionary or instance of _Part": JSON has objects.
        what = "should be an object" if first["type"] == "model_type" else first["msg"].lower()
        raise ProtocolError(f"{where}: {what}") from None
    if (message.manufacturer, message.serialNumber) != (
        vehicle.manufacturer,
        vehicle.serial_number,
    ):
        raise ProtocolError(
            f"from {message.manufacturer}/{message.serialNumber} on "
            f"{vehicle.manufacturer}/{vehicle.serial_number}'s topic"
        )
    if message.version.split(".")[0] != vehicle.version.split(".")[0]:
        raise ProtocolError(f"version {message.version!r} on a {vehicle.version} vehicle's topic")
    return message


def as_dict(message: BaseModel) -> dict[str, Any]:
    """A validated message as the plain JSON data it came as."""
    return message.model_dump(mode="json", exclude_none=False)
