"""The coordinator's world model learns obstacles from reports and from every state's sensors."""

from __future__ import annotations

import pytest

from gridfleet.coordinator.jobs import Job
from gridfleet.coordinator.world import DEAF_AFTER_S, World
from gridfleet.errors import ProtocolError
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import HeaderStamper, Leds, Sensors, UnitState

from support.coordinator_drive import make_core, meet, orders_in

ROWS = ["....", ".@..", "...."]


def state(position: Cell, sensors: dict[str, str], reported: list[Cell]) -> UnitState:
    return UnitState(
        header=HeaderStamper("u")("state"),
        step=1,
        position=position,
        direction="-",
        status="idle",
        leds=Leds(),
        sensors=Sensors(**{"N": "free", "E": "free", "S": "free", "W": "free", **sensors}),  # type: ignore[arg-type]
        obstacles=reported,
    )


def test_an_obstacle_seen_by_a_sensor_is_learnt_without_a_report() -> None:
    world = World(GridMap.from_rows(ROWS))
    # A restarted coordinator never saw the one-time report: the sensors still show it.
    new = world.on_state("u", state(Cell(2, 0), {"S": "obstacle"}, []), 0.0)
    assert new == [Cell(2, 1)]
    assert not world.grid.is_free(Cell(2, 1))
    assert world.on_state("u", state(Cell(2, 0), {"S": "obstacle"}, [Cell(2, 1)]), 1.0) == []


def test_walls_units_and_off_map_readings_are_not_obstacles() -> None:
    world = World(GridMap.from_rows(ROWS))
    world.on_state("v", state(Cell(0, 0), {}, []), 0.0)
    # From [1, 0]: N is off the map, W is where unit v stands.
    new = world.on_state("u", state(Cell(1, 0), {"N": "obstacle", "W": "obstacle"}, []), 0.0)
    assert new == []
    later = state(Cell(0, 1), {"E": "obstacle", "N": "obstacle"}, []).model_copy(update={"step": 3})
    new = world.on_state("u", later, 1.0)  # two squares on, two steps later
    assert new == []  # from [0, 1]: E [1, 1] is a wall on the map, N [0, 0] holds unit v
    assert world.obstacles == set()


def test_a_restarted_coordinator_adopts_a_job_a_unit_reports_carrying() -> None:
    # The store still had the job waiting (the unit picked it up just before the restart).
    job = Job(
        id="j", pickup=Cell(0, 0), dropoff=Cell(3, 2), mass_kg=4.0, state="to_pickup", unit="u"
    )
    core = make_core(GridMap.from_rows(ROWS), jobs=[job])
    assert job.state == "queued"  # re-queued on restart
    assert [j.id for j in core.restored().persist] == ["j"]
    carrying = state(Cell(0, 0), {}, []).model_copy(update={"job_id": "j", "load_kg": 4.0})
    meet(core, carrying, capacity_kg=5)
    core.step(1.0)
    assert (job.state, job.unit) == ("loaded", "u")
    assert orders_in(core.step(2.0))["u"].target == Cell(3, 2)  # on to the dropoff


def test_a_unit_whose_states_come_late_is_not_lost_but_one_that_stops_is() -> None:
    world = World(GridMap.from_rows(ROWS), step_period_s=0.05)  # timeout: max(0.5, 5 x 0.05)
    here = state(Cell(0, 0), {}, [])
    t = 0.0
    world.on_state("u", here, t)
    for _ in range(20):  # an overloaded broker: states every 0.3 s, not every 0.05 s
        t += 0.3
        world.on_state("u", here, t)
    assert "u" in world.roll_call(t + 1.0)  # silent 1 s: late, not lost (5 x ~0.3 s)
    assert "u" not in world.roll_call(t + 2.0)  # silent 2 s: lost


def test_one_long_silence_does_not_stretch_the_timeout() -> None:
    world = World(GridMap.from_rows(ROWS), step_period_s=0.05)
    here = state(Cell(0, 0), {}, [])
    for i in range(10):
        world.on_state("u", here, i * 0.05)
    world.on_state("u", here, 60.0)  # back after a minute away
    assert world.stale_after_s(world.units["u"]) < 1.0


def test_a_unit_cannot_claim_a_queued_job_it_was_never_given_or_cannot_carry() -> None:
    # As found: a 2 kg unit named a queued 15 kg job in its state, "picked it up" across the
    # map and "delivered" it.
    heavy = Job(id="heavy", pickup=Cell(3, 2), dropoff=Cell(3, 0), mass_kg=15.0)
    mine = Job(id="mine", pickup=Cell(0, 0), dropoff=Cell(3, 2), mass_kg=15.0)
    mine.state, mine.unit = "to_pickup", "u"  # given to u, which then could not carry it
    core = make_core(GridMap.from_rows(ROWS), jobs=[heavy, mine])
    big = state(Cell(3, 0), {}, []).model_copy(update={"header": HeaderStamper("big")("state")})
    meet(core, big, capacity_kg=20.0)  # so the heavy jobs stay queued, not rejected
    for job_id in ("heavy", "mine"):
        claim = state(Cell(0, 0), {}, []).model_copy(update={"job_id": job_id, "load_kg": 2.0})
        meet(core, claim, capacity_kg=2.0)
        core.step(1.0)
        job = core.jobs.jobs[job_id]
        assert job.unit != "u", (job_id, job.state)  # big may have it now, never u


def test_a_gap_in_everything_heard_is_the_coordinators_own_not_its_units() -> None:
    world = World(GridMap.from_rows(ROWS), step_period_s=0.1)  # loss timeout 0.5 s
    here = state(Cell(0, 0), {}, [])
    world.on_state("gone", here, 0.0)
    world.on_state("late", state(Cell(3, 0), {}, []), 0.0)
    world.heard(0.0)
    world.roll_call(1.0)  # both lost at 1 s
    world.heard(4.0)  # something else heard: 3 s of absence so far
    assert world.away_s(world.units["gone"], 4.0) == 3.0
    # Nothing heard from 4 s to 30 s: not counted, however long it lasted.
    assert world.away_s(world.units["gone"], 30.0) == 3.0
    world.heard(30.0)
    assert world.away_s(world.units["gone"], 31.0) == 3.0
    world.heard(32.0)
    assert world.away_s(world.units["gone"], 32.0) == 5.0
    # A gap up to DEAF_AFTER_S is only a quiet fleet: it counts.
    world.heard(32.0 + DEAF_AFTER_S)
    assert world.away_s(world.units["gone"], 32.0 + DEAF_AFTER_S) == 5.0 + DEAF_AFTER_S


def test_a_unit_lost_while_the_coordinator_heard_nothing_counts_from_when_it_hears() -> None:
    world = World(GridMap.from_rows(ROWS), step_period_s=0.1)
    world.on_state("u", state(Cell(0, 0), {}, []), 0.0)
    world.heard(0.0)
    world.roll_call(20.0)  # its own link down since 0 s: the unit is lost, as far as it knows
    world.heard(40.0)
    assert world.units["u"].lost_since == 40.0
    assert world.away_s(world.units["u"], 40.0) == 0.0


def test_a_unit_back_from_a_silence_may_stand_on_a_square_released_to_it_not_elsewhere() -> None:
    # As found by the cluster soak: the coordinator's broker died, it missed a unit's states while
    # the unit drove on through its released squares, and then refused it for good (3 squares
    # from where it was last seen). Those squares were kept for it: it may be on any of them.
    world = World(GridMap.from_rows(["." * 10, "." * 10]), step_period_s=0.1)

    def at(x: int, y: int = 0, released: tuple[Cell, ...] = ()) -> UnitState:
        return state(Cell(x, y), {}, []).model_copy(update={"released": list(released)})

    world.on_state("u", at(0, released=(Cell(1, 0), Cell(2, 0))), 0.0)
    world.roll_call(5.0)  # silent for seconds: lost
    ordered = frozenset({Cell(3, 0)})  # released by an order it had not acknowledged yet
    with pytest.raises(ProtocolError, match="a unit rejoins where it left"):
        world.on_state("u", at(3, 1), 5.0, reserved=ordered)  # 4 squares off, not released
    world.on_state("u", at(3), 5.0, reserved=ordered)
    assert world.units["u"].position == Cell(3, 0)
    world.on_state("u", at(3, released=tuple(Cell(x, 0) for x in range(4, 8))), 5.1)
    world.roll_call(10.0)
    world.on_state("u", at(7), 10.0)  # its own last state's released square, 4 squares on
    assert world.units["u"].position == Cell(7, 0)
