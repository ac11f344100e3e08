"""The VDA 5050 adapter's edge takes what the official schemas allow (issue 53): pure.

Messages are drawn from the official JSON schemas of 2.0.0 and 2.1.0 (`state`, `connection`,
`factsheet`, `visualization`; hypothesis-jsonschema over ../shared/vda5050/) and given to a
vehicle's core through the entry the shell uses (`VehicleCore.on_vehicle`), the header's
manufacturer, serial number and version the vehicle's own. Each is also broken once (a field
dropped, or given a value of another JSON type), `jsonschema` saying whether it still is valid.
Two cores take every message: one without the schemas (as the adapter runs by default: it checks
what it reads) and one holding what it receives and sends to them (`--schemas`).

- no message makes the core raise;
- a valid message is handled; the one refusal a valid message may get is a factsheet that tells
  no capacity above 0 kg (gridfleet's units carry something), with exactly that reason;
- an invalid message whose broken field the adapter reads (and, with the schemas, any invalid
  one) is refused on `errors` with its reason, and changes nothing;
- `visualization` is not read: whatever comes there is ignored, without a word.

How the drawing is kept to seconds: arrays hold at most two items, and hypothesis-jsonschema
draws no keys beside the schema's; unknown keys (of any JSON value) are added to every object of
the message here instead. The factsheet's parts the adapter does not read, which take seconds an
example to draw, are one fixed valid value each (`protocolLimits`, `protocolFeatures`,
`agvGeometry`), or absent (the optional `vehicleConfig`, `localizationParameters`). Every
message drawn is checked valid against the official schema before it is used.

The 2.0.0 factsheet schema as VDA published it defines its fields beside `properties` rather than
in it, so it holds a factsheet to nothing but having its required keys; its messages are drawn
from those definitions put in `properties` ("as meant", which 2.1.0's does), and a 2.0.0
factsheet the published schema lets through with a field of the wrong shape is refused (below).
"""

from __future__ import annotations

import json
import time
from enum import Enum
from functools import cache
from types import NoneType, UnionType
from typing import Any, Union, get_args, get_origin

import pytest
from hypothesis import event, given
from hypothesis import strategies as st
from hypothesis_jsonschema import from_schema
from jsonschema import Draft202012Validator
from pydantic import BaseModel

from gridfleet.grid import Cell, GridMap
from gridfleet.outbound import Outbound
from gridfleet.protocol import ErrorReport, Topics, decode
from gridfleet.robots.vda5050.config import VehicleConfig
from gridfleet.robots.vda5050.core import VehicleCore
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.inbound import VdaConnection, VdaFactsheet, VdaState
from gridfleet.robots.vda5050.virtual import VirtualSpec, VirtualVehicle
from gridfleet.robots.vda5050.wire import VERSIONS, Vehicle, Version

from support.schema_inputs import edge_settings
from support.vda import SCHEMAS, needs_schemas, official, state

pytestmark = needs_schemas

T0 = 1_795_000_000.0
TOPICS = Topics("t")
GRID = GridMap.from_rows(["....", "....", "...."], name="bay")
ERRORS = TOPICS.fleet("errors")
HEADER = ("headerId", "timestamp", "version", "manufacturer", "serialNumber")
KINDS = ("state", "connection", "factsheet", "visualization")
MODELS: dict[str, type[BaseModel]] = {
    "state": VdaState,
    "connection": VdaConnection,
    "factsheet": VdaFactsheet,
}
NO_CAPACITY = "vehicle agv1: refused: no maxLoadMass nor maxWeight: no capacity to go by"
UNREAD_FACTSHEET_PARTS = ("protocolLimits", "protocolFeatures", "agvGeometry")
OPTIONAL_UNREAD = ("vehicleConfig", "localizationParameters")
# Outside what the published 2.0.0 factsheet schema names as its own (its `properties`).
SCHEMA_KEYWORDS = {"$schema", "title", "description", "required", "subtopic", "type"}
SETTINGS = edge_settings(30)


# ---- the schemas ------------------------------------------------------------------------------


@cache
def published(version: str, kind: str) -> dict[str, Any]:
    """The official schema as VDA publishes it."""
    text = (SCHEMAS / version / f"{kind}.schema.json").read_text(encoding="utf-8")
    schema: dict[str, Any] = json.loads(text)
    return schema


@cache
def as_meant(version: str, kind: str) -> dict[str, Any]:
    """The official schema, its field definitions in `properties` (only 2.0.0's factsheet has
    them beside it)."""
    schema = published(version, kind)
    if "properties" in schema:
        return schema
    kept = {k: v for k, v in schema.items() if k in SCHEMA_KEYWORDS}
    return {**kept, "properties": {k: v for k, v in schema.items() if k not in SCHEMA_KEYWORDS}}


def _tightened(node: Any) -> Any:
    """`node` with arrays of at most two items and no keys beside an object's properties."""
    if isinstance(node, list):
        return [_tightened(n) for n in node]
    if not isinstance(node, dict):
        return node
    out = {k: _tightened(v) for k, v in node.items()}
    if out.get("type") == "array":
        out["maxItems"] = min(out.get("maxItems", 2), 2)
    if out.get("type") == "object" and "additionalProperties" not in out:
        out["additionalProperties"] = False
    return out


@cache
def drawable(version: str, kind: str) -> dict[str, Any]:
    """What the messages are drawn from: the schema as meant, tightened, a factsheet's unread
    parts fixed (each valid: the virtual vehicle's)."""
    schema = _tightened(as_meant(version, kind))
    if kind == "factsheet":
        sheet = VirtualVehicle(
            Vehicle("v", "acme", "sn-7", "2.1.0"), VirtualSpec((0, 0), "hall")
        ).factsheet(T0)
        props = dict(schema["properties"])
        props.update({part: {"const": sheet[part]} for part in UNREAD_FACTSHEET_PARTS})
        for part in OPTIONAL_UNREAD:
            props.pop(part, None)
        schema = {**schema, "properties": props}
    return schema


@cache
def drawn_from(version: str, kind: str) -> st.SearchStrategy[Any]:
    """hypothesis-jsonschema's strategy for `drawable(version, kind)`, made once."""
    return from_schema(drawable(version, kind))


@cache
def validator(version: str, kind: str, meant: bool = True) -> Draft202012Validator:
    """The judge of validity: the schema as meant (or as published)."""
    return Draft202012Validator(as_meant(version, kind) if meant else published(version, kind))


# ---- drawing ----------------------------------------------------------------------------------

SCALARS = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=8)
)
JSON_VALUES = st.recursive(
    SCALARS,
    lambda inner: (
        st.lists(inner, max_size=2) | st.dictionaries(st.text(max_size=4), inner, max_size=2)
    ),
    max_leaves=4,
)


def with_unknown_keys(draw: st.DrawFn, message: Any, schema: dict[str, Any]) -> Any:
    """`message` with keys its schema does not name added to each of its objects."""
    if isinstance(message, list) and isinstance(schema.get("items"), dict):
        return [with_unknown_keys(draw, item, schema["items"]) for item in message]
    if not (isinstance(message, dict) and "properties" in schema):
        return message
    props = schema["properties"]
    out = {k: with_unknown_keys(draw, v, props.get(k, {})) for k, v in message.items()}
    unknown = st.text(min_size=1, max_size=12).filter(lambda key: key not in props)
    out.update(draw(st.dictionaries(unknown, JSON_VALUES, max_size=2)))
    return out


@st.composite
def messages(draw: st.DrawFn, version: Version, kind: str) -> dict[str, Any]:
    """A message of `kind`, valid against `version`'s schema, from the test's vehicle."""
    drawn = draw(drawn_from(version, kind))
    message = with_unknown_keys(draw, drawn, as_meant(version, kind))
    message.update(manufacturer="acme", serialNumber="sn-7", version=version)
    return message


Path = tuple[str | int, ...]
OTHER_VALUES: tuple[object, ...] = (None, True, 0, 0.5, "x", [], {})


def _json_type(value: object) -> str:
    return "number" if type(value) in (int, float) else type(value).__name__


@st.composite
def broken(
    draw: st.DrawFn, kind: str, message: dict[str, Any]
) -> tuple[dict[str, Any], Path, bool, object]:
    """`message` with one field dropped or given a value of another JSON type: (the message,
    where, whether dropped, the new value); one the adapter reads half of the time."""
    paths: list[tuple[Path, object]] = []

    def walk(node: object, path: Path) -> None:
        items = (
            node.items()
            if isinstance(node, dict)
            else enumerate(node)
            if isinstance(node, list)
            else ()
        )
        for key, value in items:
            paths.append(((*path, key), value))
            walk(value, (*path, key))

    walk(message, ())
    read = [(path, old) for path, old in paths if read_by_adapter(kind, path, False, old)]
    path, old = draw(st.sampled_from(read if read and draw(st.booleans()) else paths))
    dropped = isinstance(path[-1], str) and draw(st.booleans())
    value = (
        None
        if dropped
        else draw(st.sampled_from([v for v in OTHER_VALUES if _json_type(v) != _json_type(old)]))
    )
    copy = json.loads(json.dumps(message))
    parent = copy
    for key in path[:-1]:
        parent = parent[key]
    if dropped:
        del parent[path[-1]]
    else:
        parent[path[-1]] = value
    return copy, path, dropped, value


def _unwrapped(annotation: Any) -> Any:
    """`X` of `X | None`."""
    if get_origin(annotation) in (Union, UnionType):
        rest = [a for a in get_args(annotation) if a is not NoneType]
        return rest[0] if len(rest) == 1 else annotation
    return annotation


def read_by_adapter(kind: str, path: Path, dropped: bool, value: object) -> bool:
    """Whether the field broken at `path` is one the adapter reads (its inbound model has it)
    and the break is one it must refuse: a field it requires dropped, or a value of another
    type (but null where it takes the field's absence)."""
    annotation: Any = MODELS.get(kind)
    if annotation is None:
        return False
    field = None
    for key in path:
        annotation = _unwrapped(annotation)
        if isinstance(key, str):
            if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
                return False
            field = annotation.model_fields.get(key)
            if field is None:
                return False
            annotation = field.annotation
        else:
            if get_origin(annotation) is not list:
                return False
            (annotation,) = get_args(annotation)
            field = None
    if annotation is Any:
        return False
    if dropped:
        return field is not None and field.is_required()
    return not (value is None and field is not None and not field.is_required())


# ---- the cores --------------------------------------------------------------------------------


def online_core(version: Version, held: bool) -> VehicleCore:
    """A vehicle's core, its unit on line at square (0, 0); `held`: with the official schemas."""
    config = VehicleConfig(
        Vehicle("agv1", "acme", "sn-7", version), Frame("hall"), 20.0, 0.0, False
    )
    schemas = official() if held else None
    c = VehicleCore(
        config,
        GRID,
        TOPICS,
        run_id="r1",
        check=None if schemas is None else lambda topic, m: schemas.check(version, topic, m),
    )
    header = {k: v for k, v in state(version).items() if k in HEADER}
    connection = {**header, "connectionState": "ONLINE"}
    c.on_vehicle("connection", json.dumps(connection).encode(), T0)
    c.on_vehicle("state", json.dumps(state(version)).encode(), T0)
    assert c.announced and c.square == Cell(0, 0)
    return c


def contents(value: object) -> object:
    """What a core holds, as plain data to compare (its header stamps' counters left out)."""
    if value is None or isinstance(value, str | int | float | bool):
        return value
    if isinstance(value, Enum | type):
        return repr(value)
    if isinstance(value, dict):
        return {repr(k): contents(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [contents(v) for v in value]
    if isinstance(value, set | frozenset):
        return sorted(repr(v) for v in value)
    if type(value).__name__ == "HeaderStamper":
        return "stamps"
    if hasattr(value, "__dict__"):
        return {k: contents(v) for k, v in vars(value).items()}
    return repr(value)


def refusals(outs: list[Outbound]) -> list[str]:
    """The reasons of the reports on `errors` among `outs`."""
    return [decode(ErrorReport, o.payload).reason for o in outs if o.topic == ERRORS]


def capacity_told(sheet: dict[str, Any]) -> float | None:
    """The capacity a factsheet tells: maxLoadMass above 0, else its load sets' largest
    maxWeight above 0 (2.0.0's schema spells it maxWeigth), else none."""
    if sheet["typeSpecification"]["maxLoadMass"] > 0:
        return float(sheet["typeSpecification"]["maxLoadMass"])
    weights = []
    for load_set in sheet["loadSpecification"].get("loadSets", []):
        weight = load_set.get("maxWeight", load_set.get("maxWeigth"))
        if type(weight) in (int, float) and weight > 0:
            weights.append(float(weight))
    return max(weights, default=None)


def assert_handled(
    c: VehicleCore, kind: str, message: dict[str, Any], outs: list[Outbound]
) -> None:
    """A valid message was taken for what it says."""
    if kind == "factsheet" and capacity_told(message) is None:
        assert refusals(outs) == [NO_CAPACITY]
        assert c.capacity_kg == 20.0
        return
    assert refusals(outs) == []
    if kind == "state":
        assert c.view is not None
        assert c.view.last_node == (message["lastNodeId"], message["lastNodeSequenceId"])
        assert c.view.driving is message["driving"]
    elif kind == "connection":
        assert c.link == message["connectionState"]
    elif kind == "factsheet":
        assert c.capacity_kg == capacity_told(message)


def assert_refused(c: VehicleCore, before: object, outs: list[Outbound]) -> None:
    """A message refused with its reason, and nothing else changed."""
    (reason,) = refusals(outs)
    assert reason.startswith("vehicle agv1: refused: ") and len(reason) > 24, reason
    assert len(outs) == 1
    assert contents(c) == before


CASES = [(v, k) for v in VERSIONS for k in KINDS]


@pytest.mark.parametrize(("version", "kind"), CASES, ids=[f"{v}-{k}" for v, k in CASES])
@SETTINGS
@given(data=st.data())
def test_what_the_schema_allows_is_handled_and_what_it_does_not_is_refused(
    version: Version, kind: str, data: st.DataObject
) -> None:
    message = data.draw(messages(version, kind), label="valid")
    assert validator(version, kind, meant=False).is_valid(message)
    assert validator(version, kind).is_valid(message), next(
        validator(version, kind).iter_errors(message)
    ).message
    mutant, path, dropped, value = data.draw(broken(kind, message), label="broken")
    mutant_valid = validator(version, kind).is_valid(mutant)
    published_valid = validator(version, kind, meant=False).is_valid(mutant)
    read = read_by_adapter(kind, path, dropped, value)
    event("broken: " + ("still valid" if mutant_valid else "read" if read else "unread"))
    for held in (False, True):
        for each, valid in ((message, True), (mutant, mutant_valid)):
            c = online_core(version, held)
            before = contents(c)
            outs = c.on_vehicle(kind, json.dumps(each).encode(), T0 + 1)  # never raises
            if kind == "visualization":
                assert outs == [] and contents(c) == before  # not read: ignored
            elif valid:
                assert_handled(c, kind, each, outs)
            elif read or (held and not published_valid):
                assert_refused(c, before, outs)


# ---- the values at the ends of what the schemas allow -----------------------------------------


def position(**changes: Any) -> dict[str, Any]:
    pose = {"x": 0.0, "y": 0.0, "theta": 0.0, "mapId": "hall", "positionInitialized": True}
    return {**pose, **changes}


@pytest.mark.parametrize(
    "far",
    [
        position(x=1e308),
        position(y=-1.7976931348623157e308),
        position(x=-1e300, y=1e300),
        position(x=5e-324),
    ],
    ids=["x-1e308", "y-max-double", "far-corner", "smallest"],
)
def test_a_position_anywhere_a_double_reaches_is_read_as_off_the_map_or_on_it(
    far: dict[str, Any],
) -> None:
    # x = 1e308 once overflowed to infinity turned into squares: OverflowError in the adapter.
    c = online_core("2.1.0", held=True)
    outs = c.on_vehicle("state", json.dumps(state("2.1.0", agvPosition=far)).encode(), T0)
    assert refusals(outs) == []
    if far["x"] == 5e-324:
        assert c.view is not None and c.view.under == {Cell(0, 0)}
    else:
        assert c.view is not None and c.view.under == frozenset()
        sent = [json.loads(o.payload) for o in outs if o.topic.endswith("instantActions")]
        assert [a["actionType"] for m in sent for a in m["actions"]] == ["startPause"]


@pytest.mark.parametrize("doubt", [1e6, 1e308])
def test_a_deviation_wider_than_the_map_holds_the_map_and_costs_no_more(doubt: float) -> None:
    # deviationRange has no bound in the schemas: 1e6 m once made a range of 2e7 squares a
    # side to walk through (the adapter hung on one state).
    c = online_core("2.0.0", held=True)
    message = state("2.0.0", agvPosition=position(deviationRange=doubt))
    started = time.monotonic()
    outs = c.on_vehicle("state", json.dumps(message).encode(), T0)
    # No speed claim (microseconds here): a hang's guard, generous for a loaded machine.
    assert time.monotonic() - started < 10.0
    assert refusals(outs) == [] and c.view is not None
    assert c.view.under == {Cell(x, y) for x in range(GRID.width) for y in range(GRID.height)}
    assert c.square == Cell(0, 0)  # it may still be on its square: it keeps it


def test_a_negative_deviation_is_read_by_its_size() -> None:
    # A deviation is a distance: the schemas bound it by nothing, and a sign says nothing more.
    c, d = online_core("2.1.0", held=True), online_core("2.1.0", held=True)
    east = {"x": 0.05, "deviationRange": 0.06}
    c.on_vehicle("state", json.dumps(state("2.1.0", agvPosition=position(**east))).encode(), T0)
    west = {**east, "deviationRange": -0.06}
    d.on_vehicle("state", json.dumps(state("2.1.0", agvPosition=position(**west))).encode(), T0)
    assert c.view is not None and d.view is not None
    assert d.view.under == c.view.under == {Cell(0, 0), Cell(1, 0), Cell(0, 1), Cell(1, 1)}


def test_integers_may_come_as_json_numbers_with_a_zero_fraction_and_of_any_sign() -> None:
    c = online_core("2.0.0", held=True)
    message = state("2.0.0", headerId=-7, orderUpdateId=3.0, lastNodeSequenceId=2.0)
    assert validator("2.0.0", "state").is_valid(message)  # JSON Schema: 3.0 is an integer
    outs = c.on_vehicle("state", json.dumps(message).encode(), T0)
    assert refusals(outs) == [] and c.view is not None and c.view.last_node == ("sq-0-0", 2)
    half = state("2.0.0", orderUpdateId=0.5)
    before = contents(c)
    outs = c.on_vehicle("state", json.dumps(half).encode(), T0)
    assert_refused(c, before, outs)


def test_a_number_beyond_a_double_is_refused_in_words() -> None:
    # Valid JSON and valid to the schemas, but no double holds it (Python reads it as infinity):
    # no vehicle measures that; refused, as said in docs/vda5050.md.
    c = online_core("2.1.0", held=False)
    text = json.dumps(state("2.1.0", agvPosition=position())).replace('"x": 0.0', '"x": 1e400')
    before = contents(c)
    outs = c.on_vehicle("state", text.encode(), T0)
    assert_refused(c, before, outs)
    assert refusals(outs) == [
        "vehicle agv1: refused: agvPosition.x: input should be a finite number"
    ]


def _factsheet(version: Version, **changes: Any) -> dict[str, Any]:
    sheet = VirtualVehicle(Vehicle("agv1", "acme", "sn-7", version), VirtualSpec((0, 0), "hall"))
    return {**sheet.factsheet(T0), **changes}


@pytest.mark.parametrize("version", VERSIONS)
def test_a_factsheet_without_header_id_and_time_and_with_any_speed_is_read(
    version: Version,
) -> None:
    # The factsheet schemas require neither headerId nor timestamp; speedMax is bounded by none.
    c = online_core(version, held=False)
    sheet = _factsheet(
        version, physicalParameters={**_factsheet(version)["physicalParameters"], "speedMax": 0}
    )
    del sheet["headerId"], sheet["timestamp"]
    sheet["typeSpecification"] = {**sheet["typeSpecification"], "maxLoadMass": 0}
    spelt = "maxWeigth" if version == "2.0.0" else "maxWeight"
    sheet["loadSpecification"] = {
        "loadSets": [
            {"setName": "crate", "loadType": "crate", spelt: 12.5},
            {"setName": "none", "loadType": "crate", spelt: -1.0},
        ]
    }
    assert refusals(c.on_vehicle("factsheet", json.dumps(sheet).encode(), T0)) == []
    assert c.capacity_kg == 12.5


def test_a_2_0_factsheet_of_the_wrong_shape_its_published_schema_lets_through_is_refused() -> None:
    sheet = _factsheet("2.0.0", typeSpecification=5)
    assert validator("2.0.0", "factsheet", meant=False).is_valid(sheet)
    assert not validator("2.0.0", "factsheet").is_valid(sheet)
    c = online_core("2.0.0", held=True)
    before = contents(c)
    outs = c.on_vehicle("factsheet", json.dumps(sheet).encode(), T0)
    assert_refused(c, before, outs)
    assert refusals(outs) == ["vehicle agv1: refused: typeSpecification: should be an object"]
