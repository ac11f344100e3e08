"""A VDA 5050 vehicle's state read for the fleet: the squares it holds while it moves between
two, its own stop, its errors and mode; the fixtures are valid against the official schemas."""

from __future__ import annotations

import json

import pytest
from jsonschema import Draft202012Validator

from gridfleet.grid import Cell
from gridfleet.robots.vda5050.frame import Frame
from gridfleet.robots.vda5050.states import read_state, reported_square

from support.vda import SCHEMAS, state

FRAME = Frame("hall")  # 0.1 m squares, square (0, 0) at the origin, y up


@pytest.mark.skipif(not SCHEMAS.exists(), reason="../shared/vda5050 not beside the checkout")
@pytest.mark.parametrize("version", ["2.0.0", "2.1.0"])
def test_the_fixture_is_a_valid_state(version: str) -> None:
    schema = json.loads((SCHEMAS / version / "state.schema.json").read_text(encoding="utf-8"))
    errors = list(Draft202012Validator(schema).iter_errors(state(version)))
    assert errors == [], errors[0].message


def test_a_vehicle_driving_to_the_next_square_holds_the_one_behind_until_it_is_off_it() -> None:
    base = [Cell(0, 0), Cell(1, 0), Cell(2, 0)]
    body = 0.04  # beyond its reference point, within a 0.1 m square
    reported: list[Cell | None] = []
    square: Cell | None = Cell(0, 0)
    for x in (0.0, 0.03, 0.05, 0.07, 0.085, 0.1, 0.13, 0.16, 0.2):
        pose = {"x": x, "y": 0.0, "theta": 0.0, "mapId": "hall", "positionInitialized": True}
        view = read_state(state(agvPosition=pose, driving=True), FRAME, body)
        square = reported_square(square, view.under, base)
        reported.append(square)
    # (0, 0) until its body is off it (x ≥ 0.09), (1, 0) until x ≥ 0.19: never a square early.
    assert reported == [Cell(0, 0)] * 5 + [Cell(1, 0)] * 3 + [Cell(2, 0)]


def test_a_lost_state_gives_up_no_square_and_a_jump_is_followed_along_the_base() -> None:
    base = [Cell(0, 0), Cell(1, 0), Cell(2, 0), Cell(3, 0)]
    # States lost in between (QoS 0, a 30 s interval): the next one shows it two squares on.
    assert reported_square(Cell(0, 0), frozenset({Cell(2, 0)}), base) == Cell(2, 0)
    # Between two squares of its base, off the one it had: the first one ahead of it.
    assert reported_square(Cell(0, 0), frozenset({Cell(2, 0), Cell(3, 0)}), base) == Cell(2, 0)
    # Somewhere it was not sent, on two squares: no square to report (it holds, the adapter says so).
    assert reported_square(Cell(0, 0), frozenset({Cell(5, 5), Cell(5, 6)}), base) is None
    assert reported_square(None, frozenset({Cell(5, 5)}), []) == Cell(5, 5)


def test_the_deviation_of_its_position_widens_what_it_holds() -> None:
    pose = {"x": 0.0, "y": 0.0, "theta": 0.0, "mapId": "hall", "positionInitialized": True}
    sure = read_state(state(agvPosition=pose), FRAME, 0.0)
    unsure = read_state(state(agvPosition={**pose, "deviationRange": 0.06}), FRAME, 0.0)
    assert sure.under == {Cell(0, 0)}
    assert unsure.under == {Cell(x, y) for x in (-1, 0, 1) for y in (-1, 0, 1)}


def test_an_uninitialised_or_foreign_map_position_is_no_square() -> None:
    pose = {"x": 0.0, "y": 0.0, "theta": 0.0, "mapId": "hall", "positionInitialized": False}
    assert read_state(state(agvPosition=pose), FRAME, 0.0).under == frozenset()
    other = {**pose, "positionInitialized": True, "mapId": "yard"}
    assert read_state(state(agvPosition=other), FRAME, 0.0).under == frozenset()
    no_pose = state()
    del no_pose["agvPosition"]
    assert read_state(no_pose, FRAME, 0.0).under == frozenset()


def test_its_own_stop_its_errors_and_its_mode_decide_whether_it_can_drive() -> None:
    well = read_state(state(), FRAME, 0.0)
    assert well.can_drive and well.battery_pct == 81.5 and well.last_node == ("sq-0-0", 0)
    pressed = read_state(state(safetyState={"eStop": "MANUAL", "fieldViolation": False}), FRAME, 0)
    assert pressed.estop and not pressed.can_drive
    fatal = {"errorType": "driveError", "errorLevel": "FATAL", "errorDescription": "motor hot"}
    warning = {"errorType": "lowBattery", "errorLevel": "WARNING"}
    broken = read_state(state(errors=[fatal, warning]), FRAME, 0.0)
    assert broken.fatal == ("driveError: motor hot",) and broken.warnings == ("lowBattery",)
    assert not broken.can_drive
    assert not read_state(state(operatingMode="MANUAL"), FRAME, 0.0).can_drive
    loaded = read_state(
        state(
            loads=[{"loadId": "job-1", "weight": 2.5}],
            actionStates=[
                {"actionId": "pick-job-1", "actionStatus": "FINISHED"},
                {"actionId": "drop-job-0", "actionStatus": "FAILED"},
                {"actionId": "drop-job-1", "actionStatus": "WAITING"},
            ],
        ),
        FRAME,
        0.0,
    )
    assert (loaded.finished, loaded.failed) == ({"pick-job-1"}, {"drop-job-0"})


@pytest.mark.parametrize(
    "loads",
    [[{"loadId": "pick-hA"}], [{"loadId": "pick-hA", "weight": None}], [{}]],
    ids=["no-weight", "weight-null", "nothing-named"],
)
def test_a_load_the_schemas_allow_without_a_weight_is_read_as_any_other_state(
    loads: list[dict[str, object]],
) -> None:
    # Found by a vehicle written from the spec (issue 53): the schemas' load requires no field,
    # and such a vehicle reports `{"loadId": …}` alone once it has picked; every state it sent
    # after that raised TypeError in here and was dropped. The adapter reads no load now: the
    # unit carries its job's mass from its pick to its drop (test_vda5050_core.py).
    unloaded = read_state(state(), FRAME, 0.0)
    assert read_state(state(loads=loads), FRAME, 0.0) == unloaded
    mixed = read_state(state(loads=[*loads, {"loadId": "b", "weight": 4.0}]), FRAME, 0.0)
    assert mixed == unloaded and mixed.can_drive
