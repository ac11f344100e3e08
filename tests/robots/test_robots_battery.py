"""A unit's battery: the pure model, and the unit's core draining, charging and running empty."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime

import pytest

from gridfleet.energy import BatterySpec
from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol import Header, Order
from gridfleet.protocol.messages import EnergyModel
from gridfleet.robots.battery import Battery
from gridfleet.robots.unit import BATTERY_EMPTY, UnitLogic
from gridfleet.robots.world import WorldSim

HEADER = Header(seq=0, timestamp=datetime(2026, 11, 21, tzinfo=UTC), sender="coordinator")
ROWS = (".....", ".....", ".....")
START = Cell(0, 1)
CHARGER = Cell(0, 1)  # the unit starts on it
NOT_A_CHARGER = Cell(1, 1)
STEP_S = 0.1
# Per step of 0.1 s: a move costs 1.0 %, standing 0.01 %, charging adds 1.0 %.
MODEL = EnergyModel(move_pct=1.0, idle_pct_per_s=0.1, charge_pct_per_s=10.0)


def order(
    update: int, released: Sequence[tuple[int, int]] = (), charge: Cell | None = None
) -> Order:
    return Order(
        header=HEADER,
        order_id="o1",
        update_id=update,
        released=list(released),
        charge=charge,
    )


def setup(start_pct: float = 50.0, start: Cell = START) -> tuple[WorldSim, UnitLogic]:
    grid = GridMap.from_rows(ROWS)
    world = WorldSim(grid, (), {"u1": start})
    unit = UnitLogic(
        "u1",
        grid,
        start,
        5.0,
        STEP_S,
        battery=Battery(MODEL, start_pct),
        chargers=frozenset({CHARGER}),
    )
    return world, unit


def step(world: WorldSim, unit: UnitLogic, now: float = 0.0) -> Direction | None:
    return unit.tick(lambda: world.sense("u1"), lambda d: world.move("u1", d), now)


def pct(unit: UnitLogic) -> float:
    assert unit.battery is not None
    return unit.battery.pct


# ---- the model ----------------------------------------------------------------------------------


def test_a_move_costs_move_pct_standing_costs_by_the_step_period_and_charging_adds() -> None:
    b = Battery(MODEL, 50.0)
    b.step(moved=True, charging=False, step_s=STEP_S)
    assert b.pct == pytest.approx(49.0)
    b.step(moved=False, charging=False, step_s=STEP_S)
    assert b.pct == pytest.approx(48.99)
    b.step(moved=False, charging=True, step_s=STEP_S)
    assert b.pct == pytest.approx(49.99)  # no idle drain while charging
    b.step(moved=False, charging=False, step_s=0.5)  # the unit's step period, not wall time
    assert b.pct == pytest.approx(49.94)


def test_the_charge_stays_within_0_and_100_and_the_run_is_remembered() -> None:
    b = Battery(MODEL, 99.5)
    b.step(moved=False, charging=True, step_s=STEP_S)
    assert b.pct == 100.0 and b.shown_pct == 100.0
    b.step(moved=False, charging=True, step_s=STEP_S)
    assert (b.pct, b.charges, b.charging_steps) == (100.0, 1, 2)  # one spell of two steps
    b = Battery(MODEL, 1.5)
    b.step(moved=True, charging=False, step_s=STEP_S)
    assert b.pct == pytest.approx(0.5) and not b.empty and not b.reached_empty
    b.step(moved=True, charging=False, step_s=STEP_S)
    assert b.pct == 0.0 and b.empty and b.reached_empty
    b.step(moved=False, charging=True, step_s=STEP_S)
    b.step(moved=False, charging=False, step_s=STEP_S)
    b.step(moved=False, charging=True, step_s=STEP_S)
    assert b.charges == 2 and b.charging_steps == 2  # two spells
    assert b.lowest_pct == 0.0 and b.reached_empty and not b.empty


def test_what_the_state_shows_and_when_it_counts_as_empty() -> None:
    b = Battery(MODEL, 42.349)
    assert (b.shown_pct, b.whole_pct) == (42.3, 42)
    assert Battery(MODEL, 0.04).empty and Battery(MODEL, 0.04).shown_pct == 0.0
    assert not Battery(MODEL, 0.06).empty  # shown as 0.1: it can still move
    with pytest.raises(ValueError, match="start_pct 101"):
        Battery(MODEL, 101.0)


def test_a_scenarios_battery_becomes_the_model_and_the_start() -> None:
    b = Battery.from_spec(BatterySpec(start_pct=40.0, move_pct=0.25))
    assert b.pct == 40.0 and b.lowest_pct == 40.0
    assert b.model == EnergyModel(move_pct=0.25, idle_pct_per_s=0.01, charge_pct_per_s=2.0)


# ---- the unit -----------------------------------------------------------------------------------


def test_a_unit_drains_per_move_and_per_step_standing() -> None:
    world, u = setup()
    assert u.on_order(order(1, [(1, 1), (2, 1)]), 0.0).result == "accepted"
    moves = [step(world, u) for _ in range(4)]  # its LEDs showed E at once: it moves at once
    assert moves == [Direction.E, Direction.E, None, None]
    assert pct(u) == pytest.approx(50.0 - 2 * 1.0 - 2 * 0.01)
    assert world.moves["u1"] == 2


def test_a_unit_without_a_battery_never_runs_down_and_reports_no_energy() -> None:
    grid = GridMap.from_rows(ROWS)
    u = UnitLogic("u1", grid, START, 5.0, STEP_S, chargers=frozenset({CHARGER}))
    u.on_order(order(1, charge=CHARGER), 0.0)
    state = u.report(HEADER)
    assert (u.battery, u.charging, state.battery_pct, state.charging) == (None, False, None, False)


def test_it_charges_on_its_orders_charger_with_nothing_left_to_drive() -> None:
    world, u = setup(50.0)
    u.on_order(order(1, charge=CHARGER), 0.0)
    assert u.charging
    for _ in range(3):
        step(world, u)
    assert pct(u) == pytest.approx(53.0)
    state = u.report(HEADER)
    assert (state.battery_pct, state.charging, state.errors) == (53.0, True, [])
    assert u.battery is not None and u.battery.charges == 1


def test_it_charges_only_once_it_stands_on_the_charger_and_has_driven_every_square() -> None:
    world, u = setup(50.0, start=Cell(2, 1))
    u.on_order(order(1, [(1, 1), (0, 1)], charge=CHARGER), 0.0)
    seen = []
    for _ in range(5):  # moves, moves (onto the charger), charges, charges, charges
        step(world, u)
        seen.append(u.charging)
    assert u.position == CHARGER
    assert seen == [False, True, True, True, True]
    # The move onto the charger was a move: charging began with the step after it.
    assert pct(u) == pytest.approx(50.0 - 2 * 1.0 + 3 * 1.0)


def test_an_order_with_no_charge_or_another_square_stops_the_charge_at_once() -> None:
    world, u = setup(50.0)
    u.on_order(order(1, charge=CHARGER), 0.0)
    step(world, u)
    u.on_order(order(2, charge=CHARGER), 0.0)  # a heartbeat order repeats it: charging on
    assert u.charging
    u.on_order(order(3), 0.0)
    assert not u.charging and not u.report(HEADER).charging
    step(world, u)
    assert pct(u) == pytest.approx(51.0 - 0.01)
    u.on_order(order(4, charge=CHARGER), 0.0)
    assert u.charging
    u.on_order(order(5, [(1, 1)], charge=CHARGER), 0.0)  # released squares left: not here
    assert not u.charging
    assert u.battery is not None and u.battery.charges == 1


def test_ordered_to_charge_where_no_charger_is_it_says_so_once_and_does_not_charge() -> None:
    world, u = setup(50.0, start=NOT_A_CHARGER)
    u.on_order(order(1, charge=NOT_A_CHARGER), 0.0)
    assert not u.charging
    errors = u.report(HEADER).errors
    assert [(e.code, e.message) for e in errors] == [
        ("no_charger", "ordered to charge on [1, 1], which is no charger")
    ]
    u.on_order(order(2, charge=NOT_A_CHARGER), 0.0)  # the same again: not told again
    step(world, u)
    assert u.report(HEADER).errors == []
    assert pct(u) == pytest.approx(49.99)
    u.on_order(order(3), 0.0)
    u.on_order(order(4, charge=NOT_A_CHARGER), 0.0)  # ordered anew after a change: told anew
    assert [e.code for e in u.report(HEADER).errors] == ["no_charger"]


def test_at_0_pct_it_cannot_move_says_why_and_can_still_charge() -> None:
    world, u = setup(0.0)
    u.on_order(order(1, [(1, 1)]), 0.0)
    for _ in range(3):
        assert step(world, u) is None
    assert (u.position, u.status, u.wait_reason, u.direction) == (
        START,
        "waiting",
        BATTERY_EMPTY,
        None,
    )
    assert not any(u.leds().model_dump().values())  # no LED shows a move it cannot make
    u.on_order(order(2), 0.0)  # nothing to do: idle, still saying why it stays
    step(world, u)
    assert (u.status, u.wait_reason) == ("idle", BATTERY_EMPTY)
    u.on_order(order(3, charge=CHARGER), 0.0)
    step(world, u)
    assert pct(u) == pytest.approx(1.0) and u.report(HEADER).battery_pct == 1.0
    u.on_order(order(4, [(1, 1)]), 0.0)
    moves = [step(world, u) for _ in range(2)]
    assert moves == [Direction.E, None] and pct(u) == 0.0
    assert u.battery is not None and u.battery.reached_empty


def test_a_move_that_empties_the_battery_is_its_last() -> None:
    world, u = setup(1.5)
    u.on_order(order(1, [(1, 1), (2, 1), (3, 1)]), 0.0)
    moves = [step(world, u) for _ in range(5)]
    assert moves == [Direction.E, Direction.E, None, None, None]
    assert pct(u) == 0.0 and u.position == Cell(2, 1) and u.wait_reason == BATTERY_EMPTY


def test_the_emergency_stop_stops_the_charge_and_the_release_resumes_it() -> None:
    world, u = setup(50.0)
    u.on_order(order(1, charge=CHARGER), 0.0)
    u.on_estop(True, 0.0)
    assert not u.charging
    step(world, u)
    assert pct(u) == pytest.approx(49.99)
    u.on_estop(False, 0.0)
    assert u.charging  # the order still names the charger (the coordinator's next one says)


def test_standing_without_orders_drains_it_by_the_step_period() -> None:
    world, u = setup(50.0)
    for _ in range(10):
        step(world, u, now=0.0)
    assert pct(u) == pytest.approx(50.0 - 10 * 0.01)


def test_a_simulated_battery_lives_a_second_a_step_whatever_the_step_period() -> None:
    spec = BatterySpec(start_pct=50.0, move_pct=1.0, idle_pct_per_s=0.5, charge_pct_per_s=2.0)
    for step_s in (0.02, 0.25, 1.0):
        b = Battery.from_spec(spec, simulated_step_s=step_s)
        # The factsheet states the rates per second of the run: a faster run, faster rates.
        assert b.model.charge_pct_per_s == pytest.approx(2.0 / step_s)
        assert b.model.idle_pct_per_s == pytest.approx(0.5 / step_s)
        b.step(moved=False, charging=True, step_s=step_s)
        assert b.pct == pytest.approx(52.0)  # a second on a charger, at any step period
        b.step(moved=False, charging=False, step_s=step_s)
        assert b.pct == pytest.approx(51.5)  # a second standing
        b.step(moved=True, charging=False, step_s=step_s)
        assert b.pct == pytest.approx(50.5)  # a move costs what it costs
    real = Battery.from_spec(spec)  # a Webots unit's: real time, the rates as written
    assert real.model.charge_pct_per_s == 2.0
    real.step(moved=False, charging=True, step_s=0.25)
    assert real.pct == pytest.approx(50.5)
