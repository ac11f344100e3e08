"""Named places in the pure core (protocol.md §5.10): a submit's pickup and dropoff by name are
resolved to the map's squares, kinds checked, the names kept on the job, its views, its history,
its events and its audit; every bad name is refused with its code and reason and changes nothing.
The store keeps the names across a reopen, and a store written before them still loads.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.history import entry_of
from gridfleet.coordinator.history_store import HistoryStore
from gridfleet.coordinator.jobs import JobBook
from gridfleet.coordinator.store import JobStore
from gridfleet.coordinator.world import World
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import Charger, Leds, Place, Sensors, SubmitJob, UnitState
from gridfleet.protocol.messages import JobHistoryQuery

from support.coordinator_drive import TOPICS, from_unit, meet, request
from support.effects import FIXED, header, header_json, published, stamper

GRID = GridMap.from_rows(["......", ".@....", "......"])
C1 = Charger(name="C1", square=Cell(5, 2))
PLACES = (
    Place(name="A3", square=Cell(3, 0), kinds=["pickup"]),
    Place(name="A4", square=Cell(4, 0), kinds=["pickup"]),
    Place(name="B1", square=Cell(0, 1), kinds=["pickup", "dropoff"]),
    Place(name="P2", square=Cell(0, 2), kinds=["dropoff"]),
    Place(name="park", square=Cell(5, 0), kinds=["parking"]),
    Place(name="C1", square=Cell(5, 2), kinds=["charger"]),
)
ERRORS = "gridfleet/v1/errors"
REPLY = "gridfleet/v1/replies/op"
SUBMIT = "gridfleet/v1/requests/submit_job"
KNOWN = "the places are A3, A4, B1, C1, P2, park"


def make(places: tuple[Place, ...] = PLACES, grid: GridMap = GRID) -> CoordinatorCore:
    """Connected, with unit1 (5 kg) idle at [0, 0], on `grid` with charger C1 and `places`."""
    world = World(grid, fleet_known_after_s=0.0, chargers=(C1,), places=places)
    core = CoordinatorCore(world, JobBook(), "n", topics=TOPICS, stamp=stamper("coordinator"))
    core.on_connect()
    meet(core, unit_state(), capacity_kg=5.0)
    return core


def unit_state(seq: int = 0, **over: Any) -> UnitState:
    state = UnitState(
        header=header("unit1", seq),
        step=seq,
        position=Cell(0, 0),
        direction="-",
        status="idle",
        leds=Leds(),
        sensors=Sensors(N="wall", E="free", S="free", W="wall"),
    )
    return state.model_copy(update=over)


def submit(
    pickup: Any = "A3", dropoff: Any = "P2", request_id: str = "r1", **over: Any
) -> SubmitJob:
    return SubmitJob(
        header=header("op"),
        request_id=request_id,
        reply_to="op",
        pickup=pickup,
        dropoff=dropoff,
        **{"mass_kg": 1.5, **over},
    )


def reply(
    request_id: str,
    accepted: bool,
    reason: str | None,
    job_id: str | None,
    code: str | None,
    seq: int = 0,
) -> tuple[str, dict[str, Any], int, bool]:
    body = {
        "header": header_json("coordinator", seq),
        "request_id": request_id,
        "accepted": accepted,
        "reason": reason,
        "job_id": job_id,
        "code": code,
    }
    return (REPLY, body, 1, False)


def refused(core: CoordinatorCore, req: SubmitJob) -> list[Any]:
    """What a submit that must be refused publishes; it must change nothing."""
    before = dict(core.jobs.jobs)
    effects = request(core, "submit_job", req, 1.0)
    assert effects.persist == () and core.jobs.jobs == before, "a refusal changes nothing"
    return published(effects)


def error(reason: str) -> tuple[str, dict[str, Any], int, bool]:
    body = {
        "header": header_json("coordinator", 0),
        "topic": SUBMIT,
        "reason": f"SubmitJob: {reason}",
        "request_id": "r1",
    }
    return (ERRORS, body, 1, False)


def test_the_map_view_lists_the_places() -> None:
    world = World(GRID, chargers=(C1,), places=PLACES)
    view = world.fleet_map(header("coordinator"))
    assert json.loads(view.model_dump_json())["places"] == [
        {"name": "A3", "square": [3, 0], "kinds": ["pickup"]},
        {"name": "A4", "square": [4, 0], "kinds": ["pickup"]},
        {"name": "B1", "square": [0, 1], "kinds": ["pickup", "dropoff"]},
        {"name": "P2", "square": [0, 2], "kinds": ["dropoff"]},
        {"name": "park", "square": [5, 0], "kinds": ["parking"]},
        {"name": "C1", "square": [5, 2], "kinds": ["charger"]},
    ]


def test_a_world_refuses_a_place_on_a_wall_and_two_places_of_one_name() -> None:
    with pytest.raises(ValueError, match=r"place W at \[1, 1\] is off the map or a wall"):
        World(GRID, places=(Place(name="W", square=Cell(1, 1), kinds=["pickup"]),))
    with pytest.raises(ValueError, match="two places have one name"):
        World(GRID, places=(PLACES[0], PLACES[0]))


def test_a_job_by_place_names_is_queued_at_their_squares_and_keeps_the_names() -> None:
    core = make()
    effects = request(core, "submit_job", submit(), 0.0)
    assert published(effects)[0] == reply("r1", True, None, "job-1", None)
    (job,) = effects.persist
    assert (job.pickup, job.dropoff, job.pickup_place, job.dropoff_place) == (
        Cell(3, 0),
        Cell(0, 2),
        "A3",
        "P2",
    )
    view = job.view()
    assert (view.pickup, view.dropoff, view.pickup_place, view.dropoff_place) == (
        Cell(3, 0),
        Cell(0, 2),
        "A3",
        "P2",
    )
    jobs_view = next(body for topic, body, *_ in published(effects) if topic.endswith("fleet/jobs"))
    (listed,) = jobs_view["jobs"]
    assert (listed["pickup_place"], listed["dropoff_place"]) == ("A3", "P2")
    entry = entry_of(job, FIXED, FIXED)
    assert (entry.pickup, entry.pickup_place, entry.dropoff, entry.dropoff_place) == (
        Cell(3, 0),
        "A3",
        Cell(0, 2),
        "P2",
    )
    (event,) = [e.text for e in effects.events if e.kind == "job"]
    assert event == "job job-1 queued by op (1.5 kg, A3 [3, 0] -> P2 [0, 2])"
    (audited,) = effects.audit.entries
    assert (audited.act, audited.detail) == ("submit_job", "1.5 kg, A3 -> P2, priority 0")


def test_a_place_and_a_square_mix_and_a_square_names_no_place() -> None:
    core = make()
    effects = request(core, "submit_job", submit("B1", [3, 2]), 0.0)
    assert published(effects)[0] == reply("r1", True, None, "job-1", None)
    (job,) = effects.persist
    assert (job.pickup, job.pickup_place, job.dropoff, job.dropoff_place) == (
        Cell(0, 1),
        "B1",
        Cell(3, 2),
        None,
    )
    (event,) = [e.text for e in effects.events if e.kind == "job"]
    assert event == "job job-1 queued by op (1.5 kg, B1 [0, 1] -> [3, 2])"
    effects = request(
        core, "submit_job", submit([3, 0], [0, 2], "r2"), 1.0
    )  # A3's and P2's squares
    (job,) = effects.persist
    assert (job.pickup_place, job.dropoff_place) == (None, None), "a square is only a square"


def test_an_unknown_place_is_refused_naming_the_places() -> None:
    core = make()
    reason = f"unknown place 'Q9': {KNOWN}"
    assert refused(core, submit("Q9")) == [
        error(reason),
        reply("r1", False, reason, None, "unknown_place"),
    ]
    reason = f"unknown place 'P9': {KNOWN}"
    assert refused(core, submit(dropoff="P9", request_id="r2"))[1] == reply(
        "r2", False, reason, None, "unknown_place", seq=1
    )


def test_an_unknown_place_lists_twenty_names_in_order_and_counts_the_rest() -> None:
    wide = GridMap.from_rows(["." * 11] * 3)
    squares = [Cell(x, y) for y in (0, 1) for x in range(11)]  # 22 of them
    many = tuple(
        Place(name=f"S{n:02d}", square=square, kinds=["pickup"])
        for n, square in enumerate(reversed(squares))  # in no order: listed in order
    )
    core = make(many, wide)
    names = ", ".join(f"S{n:02d}" for n in range(20))
    reason = f"unknown place 'S99': the places are {names} (and 2 more)"
    assert refused(core, submit("S99"))[1] == reply("r1", False, reason, None, "unknown_place")


def test_a_name_on_a_map_without_places_is_refused_saying_so() -> None:
    core = make(())
    reason = "unknown place 'A3': the map has no places"
    assert refused(core, submit())[1] == reply("r1", False, reason, None, "unknown_place")


@pytest.mark.parametrize(
    ("pickup", "dropoff", "reason"),
    [
        ("P2", "P2", "place P2 is not a pickup (it is: dropoff)"),
        ("A3", "A4", "place A4 is not a dropoff (it is: pickup)"),
        ("park", "P2", "place park is not a pickup (it is: parking)"),
        ("A3", "C1", "place C1 is not a dropoff (it is: charger)"),
    ],
    ids=["dropoff as pickup", "pickup as dropoff", "parking", "charger"],
)
def test_a_place_of_another_kind_is_refused_saying_what_it_is(
    pickup: str, dropoff: str, reason: str
) -> None:
    core = make()
    assert refused(core, submit(pickup, dropoff)) == [
        error(reason),
        reply("r1", False, reason, None, "bad_square"),
    ]


def test_a_place_on_a_discovered_obstacle_is_refused_naming_the_place() -> None:
    core = make()
    seen = Sensors(N="wall", E="free", S="obstacle", W="wall")
    from_unit(core, "state", "unit1", unit_state(1, obstacles=[Cell(0, 1)], sensors=seen), 0.5)
    reason = "pickup B1 [0, 1] is on a known obstacle"
    assert refused(core, submit("B1"))[1] == reply("r1", False, reason, None, "bad_square")


def test_a_place_on_a_charger_given_the_kind_of_a_pickup_is_refused_as_a_charger() -> None:
    # The scenario refuses such a place at load (a unit charging there would block it); the
    # coordinator's own check says so all the same.
    on_charger = (Place(name="dock", square=Cell(5, 2), kinds=["pickup"]),)
    core = make(on_charger)
    reason = "pickup dock [5, 2] is charger C1: a unit charging there would block it"
    assert refused(core, submit("dock", [0, 2]))[1] == reply(
        "r1", False, reason, None, "bad_square"
    )


def test_a_job_by_name_retried_with_its_id_is_the_same_job_and_by_its_squares_is_not() -> None:
    core = make()
    request(core, "submit_job", submit(job_id="tote-1"), 0.0)
    again = published(request(core, "submit_job", submit(request_id="r2", job_id="tote-1"), 1.0))
    assert again[0] == reply("r2", True, None, "tote-1", None, seq=1)
    squares = submit([3, 0], [0, 2], "r3", job_id="tote-1")
    reason = "job id 'tote-1' is taken"
    assert refused(core, squares)[1] == reply("r3", False, reason, "tote-1", "conflict", seq=2)


def test_the_names_outlive_a_store_reopen_and_a_store_written_before_them_loads(
    tmp_path: Path,
) -> None:
    db = tmp_path / "coordinator.sqlite3"
    core = make()
    effects = request(core, "submit_job", submit(), 0.0)
    store = JobStore(db)
    store.save(effects.persist, effects.answered)
    # A row written before 1.6: no place names, no refusal code (a rejected job's is derived).
    old = {
        "id": "old-1", "pickup": [3, 0], "dropoff": [0, 2], "mass_kg": 50.0, "priority": 0,
        "state": "rejected", "unit": None, "submitted_by": "op", "created_step": 0,
        "done_step": 0, "order": 9, "wait": None, "wait_reason": None,
        "reason": "mass 50.0 kg exceeds every unit's capacity (largest 5.0 kg)",
    }  # fmt: skip
    store._db.execute(
        "INSERT INTO jobs (id, ord, data) VALUES (?, ?, ?)", ("old-1", 9, json.dumps(old))
    )
    store._db.commit()
    store.close()
    reopened = JobStore(db)
    job, legacy = reopened.load()
    reopened.close()
    assert (job.id, job.pickup_place, job.dropoff_place) == ("job-1", "A3", "P2")
    assert job.view().pickup_place == "A3"
    assert (legacy.pickup_place, legacy.dropoff_place, legacy.refusal) == (None, None, "too_heavy")
    # A restarted coordinator answers the same job again, by its names.
    world = World(GRID, fleet_known_after_s=0.0, chargers=(C1,), places=PLACES)
    restarted = CoordinatorCore(
        world, JobBook([job, legacy]), "n", topics=TOPICS, stamp=stamper("coordinator")
    )
    restarted.on_connect()
    retry = request(restarted, "submit_job", submit(request_id="r9", job_id="job-1"), 0.0)
    assert published(retry)[0] == reply("r9", True, None, "job-1", None)
    heavy = submit([3, 0], [0, 2], "r10", job_id="old-1", mass_kg=50.0)
    reason = "mass 50.0 kg exceeds every unit's capacity (largest 5.0 kg)"
    assert published(request(restarted, "submit_job", heavy, 0.0))[1] == (
        reply("r10", False, reason, "old-1", "too_heavy", seq=1)
    )


def test_the_history_keeps_the_names_across_a_reopen_and_a_history_before_them_loads(
    tmp_path: Path,
) -> None:
    db = tmp_path / "history.sqlite3"
    # A history written before 1.6: its table without the place columns, one entry in it.
    with sqlite3.connect(db) as old:
        old.execute(
            "CREATE TABLE job_history (id INTEGER PRIMARY KEY AUTOINCREMENT, at REAL NOT NULL, "
            "job TEXT NOT NULL, state TEXT NOT NULL, unit TEXT, wait TEXT, reason TEXT, "
            "since_submitted_s REAL NOT NULL, pickup_x INTEGER NOT NULL, pickup_y INTEGER NOT "
            "NULL, dropoff_x INTEGER NOT NULL, dropoff_y INTEGER NOT NULL, mass_kg REAL NOT "
            "NULL, priority INTEGER NOT NULL, submitted_by TEXT)"
        )
        old.execute(
            "INSERT INTO job_history (at, job, state, unit, wait, reason, since_submitted_s, "
            "pickup_x, pickup_y, dropoff_x, dropoff_y, mass_kg, priority, submitted_by) "
            "VALUES (?, 'job-0', 'queued', NULL, NULL, NULL, 0, 1, 0, 2, 2, 1.0, 0, 'op')",
            (FIXED.timestamp(),),
        )
    core = make()
    (job,) = request(core, "submit_job", submit(), 0.0).persist
    store = HistoryStore(db)
    store.add([entry_of(job, FIXED, FIXED)], FIXED)
    store.close()
    reopened = HistoryStore(db)
    query = JobHistoryQuery(
        header=header("op"), request_id="h1", reply_to="op", since=FIXED.replace(year=2025)
    )
    entries, _ = reopened.query(query, FIXED.replace(year=2027))
    reopened.close()
    assert [(e.job, e.pickup_place, e.dropoff_place) for e in entries] == [  # type: ignore[union-attr]
        ("job-0", None, None),
        ("job-1", "A3", "P2"),
    ]
