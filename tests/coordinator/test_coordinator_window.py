"""Released windows (coordinator/window.py, protocol.md §4.4): a unit on a free road is given the
next squares of its way and drives every step without waiting a round trip per square; a
follower gets its leader's square the step after the leader left; a stop, a pause, a halt order
and a lost coordinator cut a window to nothing. Every window is checked by the validator."""

from __future__ import annotations

import pytest

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.planning.unjam import Unjam
from gridfleet.coordinator.planning.validate import validate_windows
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import ControlUnit, Order, SetGoal
from gridfleet.robots.unit import UnitLogic

from support.coordinator_drive import (
    TOPICS,
    from_unit,
    make_core,
    meet,
    orders_in,
    reply_in,
    request,
)
from support.coordinator_fakes import Yard
from support.effects import header

ROAD = GridMap.from_rows(["............", "@@@@@@@@@@@.", "............"])


def fleet(
    window: int, starts: dict[str, Cell], grid: GridMap = ROAD
) -> tuple[CoordinatorCore, Yard]:
    """A core with `window` and units at `starts` (10 kg, 1 s steps), online and heard from."""
    core = make_core(grid, window=window)
    yard = Yard(grid, [UnitLogic(u, grid, c, 10.0, 1.0) for u, c in starts.items()])
    for u in starts:
        meet(core, yard.state(u), 10.0)
    return core, yard


def goal(core: CoordinatorCore, unit: str, target: Cell) -> None:
    req = SetGoal(
        header=header("t"), request_id=f"g-{unit}", reply_to="t", unit=unit, target=target
    )
    assert reply_in(request(core, "set_goal", req, 0.0)).accepted


def deliver(core: CoordinatorCore, yard: Yard, now: float) -> dict[str, Order]:
    """One coordinator step; every unit takes its order. The windows pass the validator."""
    orders = orders_in(core.step(now))
    for uid, order in orders.items():
        yard.units[uid].on_order(order, now)
    units = list(yard.units.values())
    problems = validate_windows(
        yard.world.grid, [u.position for u in units], [u.released for u in units], core.window
    )
    assert problems == [], problems
    return orders


def late_drive(core: CoordinatorCore, yard: Yard, unit: str, steps: range) -> list[int]:
    """The unit drives for `steps` (1 s apart); its state reaches the coordinator only every other
    step (a loaded broker). Its x after each of its steps."""
    xs = []
    for t in steps:
        yard.tick(unit, float(t))
        xs.append(yard.units[unit].position.x)
        if t % 2 == 0:
            from_unit(core, "state", unit, yard.state(unit), float(t))
        deliver(core, yard, float(t))
    return xs


def test_a_unit_whose_orders_come_late_grows_a_window_and_drives_on_consecutive_steps() -> None:
    core, yard = fleet(4, {"u": Cell(0, 0)})
    goal(core, "u", Cell(11, 2))
    assert deliver(core, yard, 1.0)["u"].released == [Cell(1, 0)]  # no window before it needs one
    xs = late_drive(core, yard, "u", range(2, 11))
    # It ran dry waiting for orders twice; its window grew, and it has driven every step since.
    assert xs == [1, 2, 2, 3, 4, 5, 6, 7, 8]
    order = deliver(core, yard, 11.0)["u"]
    assert order.released == [Cell(9, 0), Cell(10, 0), Cell(11, 0), Cell(11, 1)]  # grown to 4


def test_with_one_square_per_order_the_same_unit_keeps_waiting_for_its_states() -> None:
    core, yard = fleet(1, {"u": Cell(0, 0)})
    goal(core, "u", Cell(11, 2))
    assert deliver(core, yard, 1.0)["u"].released == [Cell(1, 0)]
    assert late_drive(core, yard, "u", range(2, 11)) == [1, 2, 2, 3, 3, 4, 4, 5, 5]


def test_a_unit_whose_states_come_in_time_is_released_one_square_at_a_time() -> None:
    core, yard = fleet(4, {"u": Cell(0, 0)})
    goal(core, "u", Cell(11, 2))
    for t in range(1, 8):
        assert len(deliver(core, yard, float(t))["u"].released) == 1
        yard.tick("u", t + 0.5)
        from_unit(core, "state", "u", yard.state("u"), t + 0.5)
    assert yard.units["u"].position == Cell(7, 0)


def windowed(starts: dict[str, Cell], goals: dict[str, Cell]) -> tuple[CoordinatorCore, Yard]:
    """Units at `starts` whose orders have come late until each has a window of 4 (the first
    unit's goal is far enough to need it), then heard in time again."""
    core, yard = fleet(4, starts)
    for unit, target in goals.items():
        goal(core, unit, target)
    for track in (core.orders.track(u) for u in starts):
        track.reach = 4  # as late_drive grows it; set here so the units start where placed
    return core, yard


def test_a_follower_gets_the_leaders_square_the_step_after_the_leader_left() -> None:
    starts = {"lead": Cell(1, 0), "next": Cell(0, 0)}
    core, yard = windowed(starts, {"lead": Cell(11, 2), "next": Cell(10, 0)})
    orders = deliver(core, yard, 1.0)
    assert orders["lead"].released == [Cell(2, 0), Cell(3, 0), Cell(4, 0), Cell(5, 0)]
    assert orders["next"].released == []  # its way starts where the leader still stands
    yard.tick("lead", 1.5)
    yard.tick("next", 1.5)
    from_unit(core, "state", "lead", yard.state("lead"), 1.5)  # it left [1, 0]
    from_unit(core, "state", "next", yard.state("next"), 1.5)
    orders = deliver(core, yard, 2.0)
    # [1, 0] at once; not [2, 0], where the leader stands now.
    assert orders["next"].released == [Cell(1, 0)]


def test_while_a_way_out_of_a_livelock_is_due_no_window_goes_beyond_the_next_square(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The search out of a livelock starts from a still fleet; with windows some unit was nearly
    # always still driving, and one simulate run in 342 went round in circles to its step limit.
    core, yard = windowed({"u": Cell(0, 0)}, {"u": Cell(11, 2)})
    monkeypatch.setattr(Unjam, "busy", property(lambda self: True))
    assert deliver(core, yard, 1.0)["u"].released == [Cell(1, 0)]
    yard.tick("u", 1.5)
    from_unit(core, "state", "u", yard.state("u"), 1.5)
    assert deliver(core, yard, 2.0)["u"].released == [Cell(2, 0)]
    monkeypatch.undo()  # the way out found and followed: windows grow again once needed
    late_drive(core, yard, "u", range(3, 9))
    assert len(deliver(core, yard, 9.0)["u"].released) > 1


def test_the_stop_cuts_every_window_to_nothing() -> None:
    core, yard = windowed({"u": Cell(0, 0)}, {"u": Cell(11, 2)})
    deliver(core, yard, 1.0)
    unit = yard.units["u"]
    assert len(unit.released) == 4
    halts = orders_in(core.on_message(TOPICS.fleet("estop"), b"engaged|op|test", 1.2))
    assert halts["u"].released == []
    unit.on_order(halts["u"], 1.2)
    assert unit.released == []
    assert deliver(core, yard, 2.0)["u"].released == []  # and nothing while it holds


def test_a_pause_cuts_the_window_to_nothing_and_resume_gives_one_again() -> None:
    core, yard = windowed({"u": Cell(0, 0)}, {"u": Cell(11, 2)})
    deliver(core, yard, 1.0)
    unit = yard.units["u"]

    def control(command: str) -> None:
        req = ControlUnit(
            header=header("t"), request_id=command, reply_to="t", unit="u", command=command
        )
        assert reply_in(request(core, "control_unit", req, 1.5)).accepted

    control("pause")
    assert deliver(core, yard, 2.0)["u"].released == []
    assert unit.released == [] and unit.position == Cell(0, 0)
    from_unit(core, "state", "u", yard.state("u"), 2.5)
    control("resume")
    assert len(deliver(core, yard, 3.0)["u"].released) == 4


def test_an_obstacle_found_in_a_window_gets_a_halt_order_that_cuts_it() -> None:
    grid = GridMap.from_rows(["............", "............"])
    core = make_core(grid, window=4)
    yard = Yard(grid, [UnitLogic("u", grid, Cell(0, 0), 10.0, 1.0)], hidden={Cell(3, 0)})
    meet(core, yard.state("u"), 10.0)
    goal(core, "u", Cell(8, 0))
    core.orders.track("u").reach = 4
    assert deliver(core, yard, 1.0)["u"].released == [
        Cell(1, 0),
        Cell(2, 0),
        Cell(3, 0),
        Cell(4, 0),
    ]
    yard.tick("u", 1.5)
    yard.tick("u", 1.7)  # at [2, 0]: it senses the obstacle at [3, 0] and waits
    from_unit(core, "state", "u", yard.state("u"), 1.8)
    unit = yard.units["u"]
    assert unit.position == Cell(2, 0)
    order = deliver(core, yard, 2.0)["u"]
    assert Cell(3, 0) not in order.released  # cut at once: the halt order, or a way round
    assert unit.released == order.released


def test_a_unit_that_loses_the_coordinator_drops_its_window_and_holds() -> None:
    core, yard = windowed({"u": Cell(0, 0)}, {"u": Cell(11, 2)})
    deliver(core, yard, 1.0)
    unit = yard.units["u"]
    # No order comes any more: it drives on what it was given, until its hold time (3 step
    # periods of 1 s) has passed without an order; then it holds and drops the rest.
    for t in (1.5, 2.5, 3.5, 4.5):
        yard.tick("u", t)
    assert unit.released == [] and yard.state("u").status == "holding"
    assert unit.position.x < 4
