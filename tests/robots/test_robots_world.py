"""The world simulation: sensors on ASCII grids in all four directions, and the collision counter."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol.messages import SensorReading
from gridfleet.robots.world import WorldSim

N, E, S, W = Direction.N, Direction.E, Direction.S, Direction.W


def world_of(*rows: str) -> WorldSim:
    """A world from ASCII rows: `@` fixed obstacle, `H` hidden obstacle, letters a-z units."""
    static = ["".join("@" if ch == "@" else "." for ch in row) for row in rows]
    hidden = [Cell(x, y) for y, row in enumerate(rows) for x, ch in enumerate(row) if ch == "H"]
    units = {
        ch: Cell(x, y) for y, row in enumerate(rows) for x, ch in enumerate(row) if ch.islower()
    }
    return WorldSim(GridMap.from_rows(static), hidden, units)


SENSOR_CASES: list[tuple[tuple[str, ...], dict[Direction, SensorReading]]] = [
    (("a",), {N: "wall", E: "wall", S: "wall", W: "wall"}),  # off the map on every side
    ((".@.", "HaH", ".b."), {N: "obstacle", E: "obstacle", S: "unit", W: "obstacle"}),
    ((".b.", "@a.", ".H."), {N: "unit", E: "free", S: "obstacle", W: "obstacle"}),
    (("...", ".ab", "..."), {N: "free", E: "unit", S: "free", W: "free"}),
    (("...", "ba.", "..."), {N: "free", E: "free", S: "free", W: "unit"}),
    (("a..", "...", "..."), {N: "wall", E: "free", S: "free", W: "wall"}),
    (("...", "...", "..a"), {N: "free", E: "wall", S: "wall", W: "free"}),
    ((".H.", "@a@", ".@."), {N: "obstacle", E: "obstacle", S: "obstacle", W: "obstacle"}),
]


@pytest.mark.parametrize(
    ("rows", "expected"), SENSOR_CASES, ids=lambda v: "|".join(v) if isinstance(v, tuple) else ""
)
def test_sensors_see_walls_obstacles_and_units(
    rows: tuple[str, ...], expected: dict[Direction, SensorReading]
) -> None:
    assert world_of(*rows).sense("a") == expected


def test_a_unit_never_sees_itself_and_others_see_it() -> None:
    w = world_of("ab")
    assert w.sense("a")[E] == "unit" and w.sense("b")[W] == "unit"
    assert w.square(Cell(0, 0), exclude="a") == "free"


def test_move_is_atomic_and_counted() -> None:
    w = world_of("a..", "...")
    assert w.move("a", E) and w.move("a", S)
    assert w.positions["a"] == Cell(1, 1) and w.moves["a"] == 2
    assert (w.collisions, w.prevented) == (0, 0)


@pytest.mark.parametrize(
    ("rows", "direction"),
    [(("ab",), E), (("a@",), E), (("aH",), E), (("a",), N), (("a",), W), (("b", "a"), N)],
)
def test_move_into_blocked_square_is_refused_and_counted_as_prevented(
    rows: tuple[str, ...], direction: Direction
) -> None:
    w = world_of(*rows)
    before = dict(w.positions)
    assert not w.move("a", direction)
    assert w.positions == before and w.moves["a"] == 0
    assert (w.prevented, w.collisions) == (1, 0)


def test_collision_counter_sees_a_vertex_collision() -> None:
    w = world_of("a.b")
    assert w.force_move({"a": E, "b": W}) == 1
    assert [c.kind for c in w.log] == ["vertex"]
    assert w.log[0].units == ("a", "b") and w.log[0].square == Cell(1, 0)


def test_collision_counter_sees_a_unit_driving_into_a_standing_one() -> None:
    w = world_of("ab")
    assert w.force_move({"a": E}) == 1 and w.log[0].kind == "vertex"


def test_collision_counter_sees_a_swap() -> None:
    w = world_of("ab")
    assert w.force_move({"a": E, "b": W}) == 1
    assert [c.kind for c in w.log] == ["swap"]


@pytest.mark.parametrize(
    ("rows", "direction", "kind"),
    [(("a",), N, "wall"), (("a",), E, "wall"), (("a@",), E, "obstacle"), (("aH",), E, "obstacle")],
)
def test_collision_counter_sees_driving_into_walls_and_obstacles(
    rows: tuple[str, ...], direction: Direction, kind: str
) -> None:
    w = world_of(*rows)
    assert w.force_move({"a": direction}) == 1
    assert w.log[0].kind == kind and w.collisions == 1


def test_following_moves_are_not_collisions() -> None:
    w = world_of("ab.")
    assert w.force_move({"a": E, "b": E}) == 0
    assert w.positions == {"a": Cell(1, 0), "b": Cell(2, 0)}


def test_remote_units_are_placed_from_their_state() -> None:
    w = world_of("a..")
    w.place("z", Cell(1, 0))
    assert w.sense("a")[E] == "unit" and "z" in w.remote
    w.place("z", Cell(2, 0))
    assert w.sense("a")[E] == "free"


Action = tuple[str, str, int, int]  # (kind, unit, x or direction index, y)


@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["move", "force", "place", "remove"]),
            st.sampled_from(["a", "b", "c", "r"]),
            st.integers(0, 3),
            st.integers(0, 2),
        ),
        max_size=40,
    )
)
def test_sensors_always_agree_with_where_the_units_are(actions: list[Action]) -> None:
    # The world keeps an index of who stands where; whatever happens, sensors must read the
    # same as a scan of every unit's square would.
    world = world_of("a...", "..b.", "c..@")
    for kind, unit, a, b in actions:
        if kind == "place":
            world.place(unit, Cell(a, b))
        elif kind == "remove" and unit == "r":
            world.remove(unit)
        elif unit in world.positions and kind == "move":
            world.move(unit, list(Direction)[a])
        elif unit in world.positions and kind == "force":
            world.force_move({unit: list(Direction)[a]})
    for y in range(-1, 4):
        for x in range(-1, 5):
            cell = Cell(x, y)
            for asking in [None, *world.positions]:
                scan = any(c == cell and u != asking for u, c in world.positions.items())
                assert (world.square(cell, exclude=asking) == "unit") == (
                    scan and world.grid.is_free(cell) and cell not in world.hidden
                )


def test_units_seen_through_their_state_are_placed_but_units_simulated_here_stay_the_truth() -> (
    None
):
    world = world_of("a...", "....")
    world.observe("r", Cell(2, 0))
    world.observe("a", Cell(3, 1))  # a stale or foreign report about a unit simulated here
    assert world.positions == {"a": Cell(0, 0), "r": Cell(2, 0)} and world.remote == {"r"}
    world.observe("r", Cell(2, 1))
    assert world.position("r") == Cell(2, 1) and world.sense("a")[E] == "free"
