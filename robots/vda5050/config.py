"""The vehicles file: which VDA 5050 vehicles are which gridfleet units, on which map transform.

```toml
[maps.hall]               # one transform per vehicle map (frame.py)
origin = [0.0, 0.0]       # metres: where the centre of square (0, 0) lies on the vehicle's map
x_axis = [1, 0]           # along which a square's x grows there
y_axis = [0, -1]          # ... and its y (rows count down; VDA 5050's y is up)
square_m = 0.1

[[vehicles]]
unit = "agv1"             # the gridfleet unit id it becomes
manufacturer = "acme"
serial_number = "sn-7"
version = "2.0.0"         # or "2.1.0"
map = "hall"
capacity_kg = 20.0        # 2.0 vehicles; a 2.1 vehicle's factsheet says it
margin_m = 0.04           # its body beyond its reference point (states.py: it holds every square that reaches)
legacy_actions_key = true # vda-5050-lib 1.4.0: the instant actions under `instantActions` too
action_parameters = {stationType = "floor", loadType = "EPAL"}  # added to every pick and drop
client_id = "acme-sn-7"   # optional: its MQTT client id, bound to its vehicle account (no other may use it)
# optional: its battery's model (% of a full charge), the unit's factsheet `energy`; without it
# the factsheet says `energy: null` and the coordinator does not manage its energy
energy = { move_pct = 0.5, idle_pct_per_s = 0.01, charge_pct_per_s = 2.0 }
```

Every problem is refused in one line naming the file, the line and the key.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    ValidationError,
)
from pydantic_core import ErrorDetails

from gridfleet.config import CLIENT_ID, owner_of
from gridfleet.errors import ConfigError, GridfleetError, ProtocolError
from gridfleet.protocol import EnergyModel
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.wire import Vehicle, Version
from gridfleet.textfile import TomlFile

Metres = Annotated[StrictFloat | StrictInt, Field(allow_inf_nan=False)]
Axis = Annotated[list[StrictInt], Field(min_length=2, max_length=2)]
Pct = Annotated[StrictFloat | StrictInt, Field(ge=0, le=100, allow_inf_nan=False)]


class _Table(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)


class _MapTable(_Table):
    origin: Annotated[list[Metres], Field(min_length=2, max_length=2)] = [0.0, 0.0]
    x_axis: Axis = [1, 0]
    y_axis: Axis = [0, -1]
    square_m: Annotated[StrictFloat | StrictInt, Field(gt=0, allow_inf_nan=False)] = 0.1


class _EnergyTable(_Table):
    move_pct: Pct  # one square driven
    idle_pct_per_s: Pct  # a second standing
    charge_pct_per_s: Annotated[StrictFloat | StrictInt, Field(gt=0, le=100, allow_inf_nan=False)]


class _VehicleTable(_Table):
    unit: str
    manufacturer: str
    serial_number: str
    version: Version = "2.0.0"
    interface_name: str = "uagv"
    map: str
    capacity_kg: Annotated[StrictFloat | StrictInt, Field(gt=0, allow_inf_nan=False)] | None = None
    margin_m: Annotated[StrictFloat | StrictInt, Field(ge=0, allow_inf_nan=False)] = 0.0
    legacy_actions_key: bool = False
    # Extra parameters of every pick and drop (the vehicle's station and load types, say).
    action_parameters: dict[str, StrictStr | StrictFloat | StrictInt | StrictBool] = {}
    # The MQTT client id the vehicle connects with, if its vendor fixed one: bound to its account.
    client_id: str | None = None
    # Its battery's model, the unit's factsheet `energy`; absent: the fleet manages no energy.
    energy: _EnergyTable | None = None


class _VehiclesFile(_Table):
    maps: dict[str, _MapTable] = {}
    vehicles: list[_VehicleTable] = []


@dataclass(frozen=True)
class VehicleConfig:
    """One configured vehicle."""

    vehicle: Vehicle
    frame: Frame
    capacity_kg: float | None
    margin_m: float
    legacy_actions_key: bool
    action_parameters: Mapping[str, str | float | bool] = field(default_factory=dict)
    client_id: str | None = None  # bound to the vehicle's account (gridfleet/accounts.py)
    energy: EnergyModel | None = None  # its battery's model; None: the fleet manages no energy


def load_vehicles(path: str | Path) -> tuple[VehicleConfig, ...]:
    """The vehicles of a vehicles file; ConfigError in one line (file:line: problem)."""
    where = TomlFile(Path(path), "vehicles", ConfigError)
    try:
        shape = _VehiclesFile.model_validate(where.data)
    except ValidationError as exc:
        raise _shape_error(exc.errors()[0], where) from None
    frames: dict[str, Frame] = {}
    for name, table in shape.maps.items():
        try:
            frames[name] = Frame(
                name,
                (float(table.origin[0]), float(table.origin[1])),
                (table.x_axis[0], table.x_axis[1]),
                (table.y_axis[0], table.y_axis[1]),
                float(table.square_m),
            )
        except ConfigError as exc:
            raise where.error(where.key("x_axis"), str(exc)) from None
    configs: list[VehicleConfig] = []
    seen: dict[tuple[str, str, str], str] = {}
    for i, v in enumerate(shape.vehicles):
        line = where.table("vehicles", i)
        if v.map not in frames:
            raise where.error(line, f"vehicle {v.unit!r}: no [maps.{v.map}] table for its map")
        if any(c.vehicle.unit == v.unit for c in configs):
            raise where.error(line, f"vehicle {v.unit!r}: unit id used twice")
        wire_id = (v.interface_name, v.manufacturer, v.serial_number)
        if wire_id in seen:
            raise where.error(
                line, f"vehicle {v.unit!r}: the same vehicle as unit {seen[wire_id]!r}"
            )
        seen[wire_id] = v.unit
        try:
            vehicle = Vehicle(v.unit, v.manufacturer, v.serial_number, v.version, v.interface_name)
        except (ConfigError, ProtocolError) as exc:
            raise where.error(line, str(exc)) from None
        if v.version == "2.0.0" and v.capacity_kg is None:
            raise where.error(
                line,
                f"vehicle {v.unit!r}: a 2.0.0 vehicle needs capacity_kg (2.0 has no factsheet request)",
            )
        capacity = None if v.capacity_kg is None else float(v.capacity_kg)
        ours = sorted({"loadId", "weight"} & set(v.action_parameters))
        if ours:
            raise where.error(
                line, f"vehicle {v.unit!r}: action_parameters: {ours[0]} is the adapter's to set"
            )
        configs.append(
            VehicleConfig(
                vehicle,
                frames[v.map],
                capacity,
                float(v.margin_m),
                v.legacy_actions_key,
                dict(v.action_parameters),
                v.client_id,
                None
                if v.energy is None
                else EnergyModel(
                    move_pct=float(v.energy.move_pct),
                    idle_pct_per_s=float(v.energy.idle_pct_per_s),
                    charge_pct_per_s=float(v.energy.charge_pct_per_s),
                ),
            )
        )
    for i, c in enumerate(configs):
        problem = _client_id_problem(c, configs)
        if problem is not None:
            raise where.error(where.table("vehicles", i), f"vehicle {c.vehicle.unit!r}: {problem}")
    return tuple(configs)


def _client_id_problem(config: VehicleConfig, configs: Sequence[VehicleConfig]) -> str | None:
    """What is wrong with `config`'s client_id among the file's vehicles (None: nothing)."""
    client_id = config.client_id
    if client_id is None:
        return None
    if not CLIENT_ID.fullmatch(client_id):
        return f"client_id {client_id!r} is not 1-64 printable ASCII characters without spaces"
    twice = [c.vehicle.unit for c in configs if c is not config and c.client_id == client_id]
    if twice:
        return f"client_id {client_id!r} is vehicle {twice[0]!r}'s too"
    owner = owner_of(client_id, [c.vehicle.unit for c in configs])
    if owner is not None and owner != config.vehicle.unit:
        return f"client_id {client_id!r} belongs to vehicle {owner!r}'s account (its name)"
    return None


def _shape_error(error: ErrorDetails, where: TomlFile[ConfigError]) -> GridfleetError:
    """One line for the first thing wrong with the file's shape."""
    loc = [str(part) for part in error["loc"]]
    top = loc[0]
    if error["type"] == "extra_forbidden":
        if len(loc) == 1:
            return where.error(where.key(top), f"unknown key {top!r} (known: maps, vehicles)")
        line = where.table("vehicles", int(loc[1])) if top == "vehicles" else where.key(loc[-1])
        return where.error(line, f"{'.'.join(loc[:-1])}: unknown key {loc[-1]!r}")
    if top == "vehicles" and len(loc) >= 3:
        line = where.table("vehicles", int(loc[1]))
        key = ".".join(loc[2:4]) if loc[2] == "energy" else loc[2]  # energy.move_pct
        return where.error(line, f"vehicles #{int(loc[1]) + 1}: {key}: {_words(error)}")
    if top == "maps" and len(loc) >= 3:
        return where.error(where.key(loc[2]), f"maps.{loc[1]}: {loc[2]}: {_words(error)}")
    return where.error(where.key(top), f"{top}: {_words(error)}")


def _words(error: ErrorDetails) -> str:
    value: Any = error.get("input")
    if error["type"] == "missing":
        return "missing"
    if error["type"] == "model_type":
        return f"should be a table, got {value!r}"
    return f"{error['msg'].lower()}, got {value!r}"
