"""The unit's pure core: order rules, LEDs, emergency stop, holding, actions, standalone routing."""

from __future__ import annotations

from datetime import UTC, datetime

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol import Action, Header, Order
from gridfleet.robots.unit import UnitLogic
from gridfleet.robots.world import WorldSim

E, S = Direction.E, Direction.S
START = Cell(0, 1)
HEADER = Header(seq=0, timestamp=datetime(2026, 11, 21, tzinfo=UTC), sender="coordinator")


def order(
    oid: str,
    update: int,
    released: list[tuple[int, int]],
    action: Action | None = None,
    planned: list[tuple[int, int]] | None = None,
) -> Order:
    return Order(
        header=HEADER,
        order_id=oid,
        update_id=update,
        released=released,
        planned=planned or [],
        action=action,
    )


def setup(
    rows: tuple[str, ...] = (".....", ".....", "....."),
    start: Cell = START,
    capacity: float = 5.0,
) -> tuple[WorldSim, UnitLogic]:
    grid = GridMap.from_rows(rows)
    world = WorldSim(grid, (), {"u1": start})
    return world, UnitLogic("u1", grid, start, capacity, 0.1)


def step_in(world: WorldSim, logic: UnitLogic, now: float = 0.0) -> Direction | None:
    """One step of `logic` with `world` as its sensors and its wheels; the move made, if any."""
    uid = logic.unit_id
    return logic.tick(lambda: world.sense(uid), lambda d: world.move(uid, d), now)


def run(world: WorldSim, logic: UnitLogic, steps: int, now: float = 0.0) -> list[Cell]:
    positions = []
    for _ in range(steps):
        step_in(world, logic, now)
        positions.append(logic.position)
    return positions


def test_unit_drives_its_released_squares_and_no_further() -> None:
    world, u = setup()
    taken = u.on_order(order("o1", 1, [(1, 1), (2, 1)], planned=[(3, 1), (4, 1)]), 0.0)
    assert taken.result == "accepted"
    assert u.direction is E
    assert run(world, u, 5)[-1] == Cell(2, 1)
    assert world.positions["u1"] == Cell(2, 1) and world.moves["u1"] == 2
    assert u.released == [] and u.status == "idle" and u.direction is None


def test_state_and_leds_agree_when_an_order_arrives_or_goes_between_steps() -> None:
    world, u = setup()
    assert u.status == "idle"
    u.on_order(order("o1", 1, [(1, 1)]), 0.0)
    assert (u.direction, u.status) == (E, "waiting")  # LEDs lit: not idle
    u.on_order(order("o2", 1, []), 0.0)  # the coordinator takes the release back
    assert (u.direction, u.status) == (None, "idle")
    step_in(world, u, 0.0)
    assert u.position == START and u.status == "idle"


def test_leds_show_exactly_the_intended_move_before_it_is_made() -> None:
    world, u = setup()
    u.on_order(order("o1", 1, [(1, 1), (1, 2), (2, 2)]), 0.0)
    for _ in range(5):
        shown, leds = u.direction, u.leds()
        before = u.position
        step_in(world, u, 0.0)
        made = before.direction_to(u.position)
        if made is not None:
            assert made is shown
            assert [k for k, v in leds.model_dump().items() if v] == [made.value]
    assert u.position == Cell(2, 2) and u.leds().model_dump() == dict.fromkeys("NESW", False)


def test_stale_and_repeated_orders_change_nothing_and_new_ids_replace() -> None:
    _, u = setup()
    assert u.on_order(order("o1", 2, [(1, 1)]), 0.0).result == "accepted"
    assert u.on_order(order("o1", 2, [(0, 0)]), 0.0).result == "stale"
    assert u.on_order(order("o1", 1, [(0, 2)]), 0.0).result == "stale"
    assert u.released == [Cell(1, 1)] and u.order_update_id == 2
    assert u.on_order(order("o2", 1, [(0, 2)]), 0.0).result == "accepted"
    assert u.released == [Cell(0, 2)] and u.order_id == "o2"


def test_bad_orders_are_refused_and_change_nothing() -> None:
    _, u = setup(rows=(".....", ".@...", "....."))
    u.on_order(order("o1", 1, [(0, 0)]), 0.0)
    bad = [
        order("o2", 1, [(2, 1)]),  # not adjacent to the unit
        order("o2", 1, [(0, 2), (1, 0)]),  # not contiguous
        order("o2", 1, [(1, 1)]),  # into a wall
        order("o2", 1, [(0, 2), (0, 3)]),  # off the map
        order("o1", 2, [(0, 0)], Action(kind="pick", job_id="j", square=(9, 9), mass_kg=1)),
    ]
    for o in bad:
        assert u.on_order(o, 0.0).result == "refused"
        assert u.released == [Cell(0, 0)] and (u.order_id, u.order_update_id) == ("o1", 1)
    assert [e.code for e in u.errors] == ["bad_order"] * len(bad)
    state = u.report(HEADER)
    assert len(state.errors) == len(bad) and u.errors == []


def test_an_order_planned_from_an_older_state_follows_on_from_where_the_unit_stands() -> None:
    world, u = setup()
    u.on_order(order("o1", 1, [(1, 1)]), 0.0)
    run(world, u, 2)
    assert u.position == Cell(1, 1)
    assert u.on_order(order("o1", 2, [(1, 1), (2, 1)]), 0.0).result == "accepted"
    assert u.released == [Cell(2, 1)]


def test_unit_waits_for_a_released_square_its_sensor_sees_occupied() -> None:
    world, u = setup()
    world.place("other", Cell(1, 1))
    u.on_order(order("o1", 1, [(1, 1)]), 0.0)
    run(world, u, 4)
    assert u.position == Cell(0, 1) and u.status == "waiting"
    assert u.wait_reason is not None and "another unit" in u.wait_reason
    assert (world.collisions, world.prevented) == (0, 0)
    world.remove("other")
    run(world, u, 3)
    assert u.position == Cell(1, 1)


def test_emergency_stop_halts_at_once_and_lights_every_led_until_released() -> None:
    world, u = setup()
    u.on_order(order("o1", 1, [(1, 1), (2, 1), (3, 1)]), 0.0)
    run(world, u, 2)
    at = u.position
    u.on_estop(True, 0.0)
    assert u.status == "stopped" and u.leds().model_dump() == dict.fromkeys("NESW", True)
    u.on_order(order("o1", 2, [(at.x + 1, 1)]), 0.0)
    assert run(world, u, 5) == [at] * 5 and u.status == "stopped"
    u.on_estop(False, 0.0)
    u.on_order(order("o1", 3, [(at.x + 1, 1)]), 0.0)
    assert run(world, u, 2)[-1] == Cell(at.x + 1, 1)


def test_unit_without_orders_holds_and_resumes_with_the_next_order() -> None:
    world, u = setup()
    u.on_order(order("o1", 1, [(1, 1), (2, 1)]), 0.0)
    late = u.hold_timeout_s + 0.01
    assert run(world, u, 3, now=late) == [Cell(0, 1)] * 3
    assert u.status == "holding" and u.released == []
    u.on_coordinator(1.0)
    assert u.hold_timeout_s == 3.0
    u.on_order(order("o1", 2, [(1, 1)]), late)
    assert run(world, u, 2, now=late)[-1] == Cell(1, 1)


def test_unit_that_lost_the_broker_holds_still() -> None:
    world, u = setup()
    u.on_order(order("o1", 1, [(1, 1), (2, 1)]), 0.0)
    u.on_disconnect(0.0)
    assert run(world, u, 3) == [Cell(0, 1)] * 3 and u.status == "holding"


def test_pick_and_drop_at_the_action_square_and_over_capacity_refused() -> None:
    world, u = setup(capacity=2.0)
    u.on_order(
        order("o1", 1, [(1, 1)], Action(kind="pick", job_id="j1", square=(1, 1), mass_kg=1.5)), 0.0
    )
    run(world, u, 3)
    assert (u.job_id, u.load_kg) == ("j1", 1.5)
    u.on_order(
        order("o1", 2, [], Action(kind="pick", job_id="j1", square=(1, 1), mass_kg=1.5)), 0.0
    )
    run(world, u, 2)
    assert (u.job_id, u.load_kg) == ("j1", 1.5)  # repeating an action changes nothing
    u.on_order(
        order("o2", 1, [(2, 1)], Action(kind="drop", job_id="j1", square=(2, 1), mass_kg=1.5)), 0.0
    )
    run(world, u, 3)
    assert (u.job_id, u.load_kg, u.position) == (None, 0.0, Cell(2, 1))
    u.on_order(
        order("o3", 1, [], Action(kind="pick", job_id="j2", square=(2, 1), mass_kg=3.0)), 0.0
    )
    run(world, u, 2)
    assert u.job_id is None and [e.code for e in u.errors] == ["over_capacity"]


def test_hidden_obstacle_is_reported_once_and_units_never() -> None:
    grid = GridMap.from_rows(["....", "....", "...."])
    world = WorldSim(grid, [Cell(2, 1)], {"u1": Cell(0, 1), "u2": Cell(0, 0)})
    u = UnitLogic("u1", grid, Cell(0, 1), 5.0, 0.1)
    u.on_order(order("o1", 1, [(1, 1), (2, 1), (3, 1)]), 0.0)
    reported = []
    for _ in range(5):
        step_in(world, u, 0.0)
        reported += u.report(HEADER).obstacles
    assert reported == [Cell(2, 1)]
    assert u.position == Cell(1, 1) and u.wait_reason and "obstacle" in u.wait_reason
    assert world.collisions == 0


def test_fixed_obstacles_of_the_map_are_not_reported() -> None:
    world, u = setup(rows=(".@...", ".....", "....."), start=Cell(1, 1))
    step_in(world, u, 0.0)
    assert u.sensors[Direction.N] == "obstacle" and u.report(HEADER).obstacles == []


def test_standalone_units_head_on_in_a_corridor_give_way_and_both_arrive() -> None:
    grid = GridMap.from_rows([".......", ".......", "@@@.@@@"])
    world = WorldSim(grid, (), {"a": Cell(0, 0), "b": Cell(6, 0)})
    units = [
        UnitLogic("a", grid, Cell(0, 0), 1.0, 0.1, mode="standalone", goal=Cell(6, 0)),
        UnitLogic("b", grid, Cell(6, 0), 1.0, 0.1, mode="standalone", goal=Cell(0, 0)),
    ]
    for _ in range(60):
        for u in units:
            step_in(world, u)
        if all(u.position == u.goal for u in units):
            break
    assert [u.position for u in units] == [Cell(6, 0), Cell(0, 0)]
    assert world.collisions == 0


def test_standalone_unit_replans_around_a_hidden_obstacle() -> None:
    grid = GridMap.from_rows([".....", ".....", "....."])
    world = WorldSim(grid, [Cell(2, 1)], {"a": Cell(0, 1)})
    u = UnitLogic("a", grid, Cell(0, 1), 1.0, 0.1, mode="standalone", goal=Cell(4, 1))
    for _ in range(20):
        step_in(world, u)
    assert u.position == Cell(4, 1) and Cell(2, 1) in u.known_obstacles
    assert world.collisions == 0 and world.moves["a"] == 6


def test_standalone_goal_on_a_wall_is_refused() -> None:
    grid = GridMap.from_rows(["..@"])
    u = UnitLogic("a", grid, Cell(0, 0), 1.0, 0.1, mode="standalone")
    assert u.on_goal(Cell(2, 0), 0.0).result == "refused"
    assert u.on_goal(Cell(5, 0), 0.0).result == "refused"
    assert u.goal is None and [e.code for e in u.errors] == ["bad_goal", "bad_goal"]
    assert u.on_goal(Cell(1, 0), 0.0).result == "accepted" and u.goal == Cell(1, 0)


def test_standalone_units_swap_ends_of_a_corridor_through_its_only_bay() -> None:
    grid = GridMap.from_rows(["@@@@.@@@@", ".........", "@@@@@@@@@"])
    for a_id, b_id in (("west", "east"), ("unit1", "unit2"), ("a", "b"), ("x", "y")):
        world = WorldSim(grid, (), {a_id: Cell(0, 1), b_id: Cell(8, 1)})
        units = [
            UnitLogic(a_id, grid, Cell(0, 1), 1.0, 0.1, mode="standalone", goal=Cell(8, 1)),
            UnitLogic(b_id, grid, Cell(8, 1), 1.0, 0.1, mode="standalone", goal=Cell(0, 1)),
        ]
        for _ in range(400):
            for u in units:
                step_in(world, u)
            if all(u.position == u.goal for u in units):
                break
        assert [u.position for u in units] == [Cell(8, 1), Cell(0, 1)], (a_id, b_id)
        assert world.collisions == 0
