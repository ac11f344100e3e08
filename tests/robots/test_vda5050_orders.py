"""gridfleet's releases as VDA 5050 orders: valid against the official schemas of 2.0.0 and 2.1.0,
stitched as the specification requires, never releasing a square gridfleet did not release."""

from __future__ import annotations

import itertools
import json
import re
from pathlib import Path
from typing import Any

import pytest
from jsonschema import Draft202012Validator

from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol import Action
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.instant import instant_action
from gridfleet.robots.vda5050.orders import OrderStitcher, node_id
from gridfleet.robots.vda5050.wire import Headers, Vehicle, timestamp

SCHEMAS = Path(__file__).resolve().parents[3] / "shared" / "vda5050"
needs_schemas = pytest.mark.skipif(
    not SCHEMAS.exists(), reason="../shared/vda5050 not beside the checkout"
)
T0 = 1_795_000_000.0


def validator(version: str, topic: str) -> Draft202012Validator:
    schema = json.loads((SCHEMAS / version / f"{topic}.schema.json").read_text(encoding="utf-8"))
    return Draft202012Validator(schema)


def stitcher(version: str = "2.0.0") -> OrderStitcher:
    vehicle = Vehicle("agv1", "acme", "sn-7", version)  # type: ignore[arg-type]
    return OrderStitcher(Headers(vehicle), Frame("hall"), prefix="gf-ab12")


def base_of(order: dict[str, Any]) -> list[tuple[str, int]]:
    return [(n["nodeId"], n["sequenceId"]) for n in order["nodes"] if n["released"]]


@needs_schemas
@pytest.mark.parametrize("version", ["2.0.0", "2.1.0"])
def test_every_order_of_a_drive_is_valid_and_stitched(version: str) -> None:
    check = validator(version, "order")
    s = stitcher(version)
    pick = Action(kind="pick", job_id="job-1", square=Cell(3, 0), mass_kg=2.0)
    sent = [
        s.order(Cell(0, 0), [Cell(1, 0)], [Cell(2, 0), Cell(3, 0)], pick, T0),
        s.order(Cell(0, 0), [Cell(1, 0)], [Cell(2, 0), Cell(3, 0)], pick, T0 + 0.1),  # nothing new
        s.order(Cell(1, 0), [Cell(2, 0)], [Cell(3, 0)], pick, T0 + 0.2),
        s.order(Cell(2, 0), [Cell(3, 0)], [], pick, T0 + 0.3),
    ]
    assert sent[1] is None
    orders = [o for o in sent if o is not None]
    for order in orders:
        errors = sorted(check.iter_errors(order), key=str)
        assert errors == [], errors[0].message
        assert order["version"] == version
    assert [o["headerId"] for o in orders] == [0, 1, 2]
    assert {o["orderId"] for o in orders} == {"gf-ab12-1"}
    assert [o["orderUpdateId"] for o in orders] == [0, 1, 2]
    # Each update starts at the last base node sent before, and the base only grows.
    for before, after in itertools.pairwise(orders):
        assert after["nodes"][0]["nodeId"] == base_of(before)[-1][0]
        assert after["nodes"][0]["sequenceId"] == base_of(before)[-1][1]
    assert base_of(orders[0]) == [(node_id(Cell(0, 0)), 0), (node_id(Cell(1, 0)), 2)]
    assert base_of(orders[2]) == [(node_id(Cell(2, 0)), 4), (node_id(Cell(3, 0)), 6)]
    # Sequence ids: nodes even, edges odd, along the whole order; an edge is released with its end.
    for order in orders:
        seqs = sorted(
            [n["sequenceId"] for n in order["nodes"]] + [e["sequenceId"] for e in order["edges"]]
        )
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
        ends = {n["nodeId"]: n["released"] for n in order["nodes"]}
        assert all(e["released"] == ends[e["endNodeId"]] for e in order["edges"])
    # The pick is on the pickup's node, once it is there.
    assert orders[-1]["nodes"][-1]["actions"][0]["actionType"] == "pick"


def test_no_square_is_released_that_gridfleet_did_not_release() -> None:
    s = stitcher()
    first = s.order(Cell(0, 0), [], [Cell(1, 0), Cell(2, 0)], None, T0)  # a halt order, planned
    assert first is not None and base_of(first) == [(node_id(Cell(0, 0)), 0)]
    assert [n["released"] for n in first["nodes"]] == [True, False, False]
    assert s.base == (Cell(0, 0),)
    # gridfleet takes no released square back: a release that does not continue the base is a bug.
    s.order(Cell(0, 0), [Cell(1, 0)], [], None, T0 + 0.1)
    with pytest.raises(ValueError, match="does not continue the base"):
        s.order(Cell(0, 0), [Cell(0, 1)], [], None, T0 + 0.2)


def test_a_new_order_after_the_last_one_ended_starts_where_the_vehicle_stands() -> None:
    s = stitcher()
    s.order(Cell(0, 0), [Cell(1, 0)], [], None, T0)
    s.end()
    again = s.order(Cell(1, 0), [Cell(1, 1)], [], None, T0 + 1)
    assert again is not None
    assert (again["orderId"], again["orderUpdateId"]) == ("gf-ab12-2", 0)
    assert base_of(again) == [(node_id(Cell(1, 0)), 0), (node_id(Cell(1, 1)), 2)]


def test_squares_are_placed_on_the_vehicles_map_by_its_transform() -> None:
    frame = Frame("hall", origin=(2.0, 5.0), x_axis=(1, 0), y_axis=(0, -1), square_m=0.5)
    assert frame.position(Cell(0, 0)) == (2.0, 5.0)
    assert frame.position(Cell(2, 3)) == (3.0, 3.5)
    assert frame.heading(Cell(0, 0), Cell(1, 0)) == 0.0
    assert frame.heading(Cell(0, 0), Cell(0, 1)) == pytest.approx(-1.570796, abs=1e-6)
    # A move along -x is pi, within the schemas' bound of 3.14159265359 (rounded, it was not).
    assert 3.14159 < frame.heading(Cell(1, 0), Cell(0, 0)) <= 3.14159265359
    # At a square's centre a vehicle stands on it; on a boundary it holds both; with a body or
    # doubt about its position beyond the point, every square that reaches.
    assert frame.squares_under(3.0, 3.5) == {Cell(2, 3)}
    assert frame.squares_under(3.1, 3.5) == {Cell(2, 3)}
    assert frame.squares_under(3.25, 3.5) == {Cell(2, 3), Cell(3, 3)}
    assert frame.squares_under(3.25, 3.25) == {Cell(2, 3), Cell(3, 3), Cell(2, 4), Cell(3, 4)}
    assert frame.squares_under(3.1, 3.5, margin_m=0.25) == {Cell(2, 3), Cell(3, 3)}
    assert frame.squares_under(3.0, 3.5, margin_m=0.3) == {
        Cell(x, y) for x in (1, 2, 3) for y in (2, 3, 4)
    }


@pytest.mark.parametrize(
    ("kwargs", "problem"),
    [
        ({"x_axis": (1, 1)}, "must each be one of"),
        ({"x_axis": (1, 0), "y_axis": (-1, 0)}, "at right angles"),
        ({"square_m": 0.0}, "positive number of metres"),
    ],
)
def test_a_bad_transform_is_refused_in_words(kwargs: dict[str, Any], problem: str) -> None:
    with pytest.raises(ConfigError, match=problem):
        Frame("hall", **kwargs)


def test_a_vehicles_topics_and_its_refusals() -> None:
    v = Vehicle("agv1", "acme", "sn-7", "2.1.0")
    assert v.topic("order") == "uagv/v2/acme/sn-7/order"
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z", timestamp(T0))
    with pytest.raises(ConfigError, match="cannot be a topic level"):
        Vehicle("agv1", "acme/x", "sn-7")
    with pytest.raises(ConfigError, match=r"version '1\.1\.0'"):
        Vehicle("agv1", "acme", "sn-7", "1.1.0")  # type: ignore[arg-type]


@needs_schemas
@pytest.mark.parametrize("version", ["2.0.0", "2.1.0"])
@pytest.mark.parametrize("legacy", [False, True])
def test_instant_actions_are_valid_with_or_without_the_legacy_key(
    version: str, legacy: bool
) -> None:
    check = validator(version, "instantActions")
    vehicle = Vehicle("agv1", "acme", "sn-7", version)  # type: ignore[arg-type]
    headers = Headers(vehicle)
    kinds = ["startPause", "stopPause", "cancelOrder", "startCharging", "stopCharging"] + (
        ["factsheetRequest"] if version == "2.1.0" else []
    )
    for n, kind in enumerate(kinds):
        message = instant_action(headers, kind, f"a-{n}", T0, legacy_actions_key=legacy)  # type: ignore[arg-type]
        errors = list(check.iter_errors(message))
        assert errors == [], errors[0].message
        assert message["actions"][0]["actionType"] == kind and message["headerId"] == n
        # vda-5050-lib 1.4.0 reads the 1.1 key: the same list there too, only when asked.
        assert ("instantActions" in message) == legacy
        if legacy:
            assert message["instantActions"] == message["actions"]


def test_a_2_0_vehicle_gets_no_factsheet_request() -> None:
    headers = Headers(Vehicle("agv1", "acme", "sn-7", "2.0.0"))
    with pytest.raises(ConfigError, match=r"2\.0\.0 has no factsheetRequest"):
        instant_action(headers, "factsheetRequest", "f-1", T0)


def _actions_on_released_nodes(orders: list[dict[str, Any] | None]) -> list[tuple[str, str]]:
    return [
        (n["nodeId"], a["actionId"])
        for o in orders
        if o is not None
        for n in o["nodes"]
        if n["released"]
        for a in n["actions"]
    ]


def test_an_action_the_vehicle_has_is_not_sent_again_on_the_stitching_node() -> None:
    # As a CI run found: the base ended on the dropoff with its drop; an update changed only the
    # horizon, the next changed it back, and the stitching node carried the drop again: a second
    # action with the same id, which vda-5050-lib 1.4.0 runs after the first until it crashes.
    s = stitcher()
    drop = Action(kind="drop", job_id="crate", square=Cell(9, 8), mass_kg=2.5)
    sent = [
        s.order(Cell(8, 8), [Cell(9, 8)], [], drop, T0),
        s.order(Cell(8, 8), [Cell(9, 8)], [Cell(9, 7)], drop, T0 + 0.1),
        s.order(Cell(8, 8), [Cell(9, 8)], [], drop, T0 + 0.2),
    ]
    assert all(o is not None for o in sent)
    assert _actions_on_released_nodes(sent) == [(node_id(Cell(9, 8)), "drop-crate")]


def test_an_action_given_once_its_square_is_in_the_base_goes_on_the_stitching_node_once() -> None:
    s = stitcher()
    drop = Action(kind="drop", job_id="crate", square=Cell(9, 8), mass_kg=2.5)
    sent = [
        s.order(Cell(8, 8), [Cell(9, 8)], [], None, T0),
        s.order(Cell(8, 8), [Cell(9, 8)], [], drop, T0 + 0.1),  # the action comes later
        s.order(Cell(8, 8), [Cell(9, 8)], [Cell(9, 7)], drop, T0 + 0.2),
    ]
    given = _actions_on_released_nodes(sent)
    assert len(given) == 1 and given[0][0] == node_id(Cell(9, 8))
