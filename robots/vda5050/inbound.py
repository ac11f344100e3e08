"""What a VDA 5050 vehicle sends, checked at the edge: every field the fleet reads, typed.

Each message is read against the fields the adapter uses (and the header every VDA 5050 message
carries); anything else is the vehicle's business and passes. A message that is not JSON, lacks a
field, has one of the wrong type, or claims another vehicle or version is refused with one line
saying what, and changes nothing. (The tests, and `--schemas` at run time, also hold every message
to the official JSON schema of its version.)
"""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from gridfleet.errors import ProtocolError
from gridfleet.robots.vda5050.wire import Vehicle

MAX_VDA_BYTES = 256 * 1024  # a state of a long order is a few kB; far beyond that is no state

Number = Annotated[float, Field(allow_inf_nan=False)]


class _Part(BaseModel):
    model_config = ConfigDict(extra="allow", strict=True, frozen=True, defer_build=True)


class _Header(_Part):
    headerId: Annotated[int, Field(ge=0, strict=True)]
    timestamp: str
    version: str
    manufacturer: str
    serialNumber: str


class VdaConnection(_Header):
    """`connection`: whether the vehicle is on line."""

    connectionState: Literal["ONLINE", "OFFLINE", "CONNECTIONBROKEN"]


class _Position(_Part):
    x: Number
    y: Number
    theta: Number
    mapId: str
    positionInitialized: bool
    deviationRange: Annotated[Number, Field(ge=0)] = 0.0


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
    actionType: str | None = None


class _Load(_Part):
    weight: Annotated[Number, Field(ge=0)] | None = None


class _Battery(_Part):
    batteryCharge: Number
    charging: bool = False


class _Safety(_Part):
    eStop: Literal["AUTOACK", "MANUAL", "REMOTE", "NONE"]
    fieldViolation: bool


class _NodeState(_Part):
    nodeId: str
    sequenceId: Annotated[int, Field(ge=0, strict=True)]
    released: bool


class VdaState(_Header):
    """`state`: the fields the fleet reads."""

    orderId: str
    orderUpdateId: Annotated[int, Field(ge=0, strict=True)]
    lastNodeId: str
    lastNodeSequenceId: Annotated[int, Field(ge=0, strict=True)]
    nodeStates: list[_NodeState]
    edgeStates: list[Any]
    agvPosition: _Position | None = None
    driving: bool
    paused: bool | None = None
    operatingMode: str
    errors: list[_Error]
    actionStates: list[_ActionState]
    loads: list[_Load] = Field(default_factory=list)
    batteryState: _Battery
    safetyState: _Safety


class _LoadSet(_Part):
    maxWeight: Annotated[Number, Field(gt=0)] | None = None


class _LoadSpecification(_Part):
    loadSets: list[_LoadSet] = Field(default_factory=list)


class _PhysicalParameters(_Part):
    speedMax: Annotated[Number, Field(gt=0)]


class _TypeSpecification(_Part):
    maxLoadMass: Annotated[Number, Field(ge=0)]


class VdaFactsheet(_Header):
    """`factsheet` (2.1): what the vehicle carries and how fast it drives."""

    typeSpecification: _TypeSpecification
    physicalParameters: _PhysicalParameters
    loadSpecification: _LoadSpecification

    @property
    def capacity_kg(self) -> float | None:
        """The heaviest load it takes: `maxLoadMass`, else its load sets' largest `maxWeight`."""
        if self.typeSpecification.maxLoadMass > 0:
            return self.typeSpecification.maxLoadMass
        weights = [s.maxWeight for s in self.loadSpecification.loadSets if s.maxWeight is not None]
        return max(weights) if weights else None


M = TypeVar("M", bound=_Header)


def read_vda(model: type[M], payload: bytes, vehicle: Vehicle) -> M:
    """`payload` as `model`, from `vehicle`; ProtocolError in one line when it is not."""
    if len(payload) > MAX_VDA_BYTES:
        raise ProtocolError(f"{len(payload)} bytes: more than {MAX_VDA_BYTES}")
    try:
        data = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ProtocolError(f"not JSON: {exc}") from None
    try:
        message = model.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(part) for part in first["loc"]) or "message"
        raise ProtocolError(f"{where}: {first['msg'].lower()}") from None
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
