"""Allocation: capacity always holds, nearer capable units are preferred, impossible jobs named."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from gridfleet.coordinator.allocation import (
    JobRequest,
    UnitSlot,
    allocate,
    capacity_reason,
    feasible,
)
from gridfleet.grid import Cell, GridMap
from gridfleet.paths import DistanceFieldCache

from support.coordinator_fakes import ROOM_ROWS

ROOM = GridMap.from_rows(ROOM_ROWS)
CACHE = DistanceFieldCache(ROOM)
FREE = ROOM.free_cells()

cells = st.sampled_from(FREE)
masses = st.floats(min_value=0.1, max_value=30, allow_nan=False)


@st.composite
def fleets(draw: st.DrawFn) -> tuple[list[UnitSlot], list[JobRequest]]:
    n_units = draw(st.integers(1, 6))
    spots = draw(st.lists(cells, min_size=n_units, max_size=n_units, unique=True))
    units = [
        UnitSlot(f"u{i}", spots[i], draw(st.floats(min_value=0.5, max_value=20)))
        for i in range(n_units)
    ]
    n_jobs = draw(st.integers(0, 8))
    jobs = [
        JobRequest(f"j{i}", draw(cells), draw(cells), draw(masses), draw(st.integers(0, 3)))
        for i in range(n_jobs)
    ]
    return units, jobs


@settings(max_examples=150, deadline=None)
@given(fleets())
def test_capacity_always_respected_and_assignment_is_one_to_one(
    fleet: tuple[list[UnitSlot], list[JobRequest]],
) -> None:
    units, jobs = fleet
    out = allocate(CACHE, units, jobs)
    by_unit = {u.id: u for u in units}
    by_job = {j.id: j for j in jobs}
    assert len(set(out.values())) == len(out)  # one job per unit
    for job_id, unit_id in out.items():
        assert by_job[job_id].mass_kg <= by_unit[unit_id].capacity_kg
    # Maximal: an unassigned job has no free unit that could take it.
    free_units = [u for u in units if u.id not in out.values()]
    for job in jobs:
        if job.id not in out:
            assert all(feasible(CACHE, u, job) is None for u in free_units)


@settings(max_examples=100, deadline=None)
@given(st.lists(cells, min_size=3, max_size=3, unique=True), masses)
def test_prefers_the_nearer_capable_unit(spots: list[Cell], mass: float) -> None:
    job_at, a_at, b_at = spots
    job = JobRequest("j", job_at, job_at, mass)
    a = UnitSlot("a", a_at, mass + 1)
    b = UnitSlot("b", b_at, mass + 1)
    da, db = CACHE.distance(a_at, job_at), CACHE.distance(b_at, job_at)
    chosen = allocate(CACHE, [a, b], [job])["j"]
    if da < db:
        assert chosen == "a"
    elif db < da:
        assert chosen == "b"


def test_nearer_unit_loses_when_it_cannot_carry() -> None:
    job = JobRequest("j", Cell(0, 0), Cell(9, 9), 8.0)
    near = UnitSlot("near", Cell(1, 0), 2.0)
    far = UnitSlot("far", Cell(9, 9), 10.0)
    assert allocate(CACHE, [near, far], [job]) == {"j": "far"}


def test_true_distance_not_straight_line() -> None:
    # Behind a wall: (3, 3) is one square from (3, 2)'s wall block but far around by path.
    grid = GridMap.from_rows([".....", ".@@@.", ".@.@.", ".@.@.", "....."])
    cache = DistanceFieldCache(grid)
    job = JobRequest("j", Cell(2, 0), Cell(2, 0), 1.0)
    inside = UnitSlot("inside", Cell(2, 2), 5.0)  # 2 rows away, but the way round is long
    outside = UnitSlot("outside", Cell(4, 3), 5.0)
    assert cache.distance(Cell(2, 2), Cell(2, 0)) > cache.distance(Cell(4, 3), Cell(2, 0))
    assert allocate(cache, [inside, outside], [job]) == {"j": "outside"}


def test_unreachable_units_never_get_the_job() -> None:
    grid = GridMap.from_rows(["..@..", "..@..", "..@.."])
    cache = DistanceFieldCache(grid)
    job = JobRequest("j", Cell(0, 0), Cell(1, 2), 1.0)
    cut_off = UnitSlot("cut", Cell(3, 0), 5.0)
    assert allocate(cache, [cut_off], [job]) == {}
    able = UnitSlot("able", Cell(1, 1), 5.0)
    assert allocate(cache, [cut_off, able], [job]) == {"j": "able"}


def test_higher_priority_first_when_units_are_scarce() -> None:
    unit = UnitSlot("u", Cell(0, 0), 5.0)
    near_low = JobRequest("low", Cell(1, 0), Cell(1, 0), 1.0, priority=0)
    far_high = JobRequest("high", Cell(9, 9), Cell(9, 9), 1.0, priority=5)
    assert allocate(CACHE, [unit], [near_low, far_high]) == {"high": "u"}


def test_impossible_mass_is_named_with_the_largest_capacity() -> None:
    reason = capacity_reason(50.0, [2.0, 20.0, 5.0])
    assert reason == "mass 50.0 kg exceeds every unit's capacity (largest 20.0 kg)"
    assert capacity_reason(20.0, [2.0, 20.0]) is None
    assert capacity_reason(1.0, []) is None  # no unit known yet: wait, do not reject


@settings(max_examples=100, deadline=None)
@given(fleets())
def test_every_pair_allocated_is_feasible_and_no_job_is_left_to_an_idle_unit_able_to_do_it(
    fleet: tuple[list[UnitSlot], list[JobRequest]],
) -> None:
    units, jobs = fleet
    pairs = allocate(CACHE, units, jobs)
    by_id = {u.id: u for u in units}
    travel = [feasible(CACHE, by_id[u], j) for j in jobs if (u := pairs.get(j.id))]
    assert None not in travel
    # The pairs are maximal: no job left out could have been done by a unit left idle.
    idle = [u for u in units if u.id not in pairs.values()]
    for job in jobs:
        if job.id not in pairs:
            assert all(feasible(CACHE, u, job) is None for u in idle)


def test_a_unit_reported_off_the_map_gets_no_job() -> None:
    job = JobRequest("j", FREE[0], FREE[1], 1.0)
    assert allocate(CACHE, [UnitSlot("lost", Cell(-1, 99), 10.0)], [job]) == {}
    assert allocate(CACHE, [UnitSlot("u", FREE[2], 10.0)], [job]) == {"j": "u"}
