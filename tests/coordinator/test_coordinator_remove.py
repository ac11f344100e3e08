"""`requests/remove_unit` (protocol.md §6.11): a lost unit an operator knows is off the floor.

Exact-publish for what the core says (refusals, the clears of the unit's retained topics, the
reply, the audit, the events), and with the real unit core (robots' UnitLogic) for what it frees:
a job that waited for the square a lost unit kept goes on once that unit is removed.
"""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path
from typing import Literal

from test_coordinator_effects import GRID, error, reply, state, submit

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.jobs import JobBook
from gridfleet.coordinator.moves import Follow
from gridfleet.coordinator.removals import Removal
from gridfleet.coordinator.store import JobStore
from gridfleet.coordinator.world import World
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import Connection, ControlUnit, Factsheet, RemoveUnit
from gridfleet.protocol.messages import AuditEntry, Header
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
from support.effects import FIXED, header, header_json, published, stamper

CLEARED = [
    ("gridfleet/v1/units/unit1/state", "", 0, True),
    ("gridfleet/v1/units/unit1/factsheet", "", 1, True),
    ("gridfleet/v1/units/unit1/vehicle", "", 1, True),
    ("gridfleet/v1/units/unit1/connection", "", 1, True),
]


def remove(request_id: str, unit: str = "unit1", reason: str | None = None) -> RemoveUnit:
    return RemoveUnit(
        header=header("op"), request_id=request_id, reply_to="op", unit=unit, reason=reason
    )


def connection(
    unit: str, state: Literal["online", "offline", "broken"], header_: Header | None = None
) -> Connection:
    return Connection(header=header_ or header(unit), state=state)


def lost_core() -> CoordinatorCore:
    """Connected, unit1 (5 kg) met at [0, 0], then offline: lost."""
    core = make_core(GRID)
    core.on_connect()
    meet(core, state(), capacity_kg=5.0)
    from_unit(core, "connection", "unit1", connection("unit1", "offline"), 0.1)
    return core


def test_an_online_unit_is_not_removed_and_says_how() -> None:
    core = make_core(GRID)
    core.on_connect()
    meet(core, state(), capacity_kg=5.0)
    why = (
        "unit unit1 is online and heard from: only a lost unit (offline, broken or silent) can "
        "be removed; take it out of service and switch it off first"
    )
    assert published(request(core, "remove_unit", remove("r1"), 0.5)) == [
        error(0, "gridfleet/v1/requests/remove_unit", f"RemoveUnit: {why}", "r1"),
        reply(0, "r1", False, why, None, "conflict"),
    ]
    assert "unit1" in core.world.units and "unit1" not in core.removals


def test_an_unknown_unit_is_not_removed() -> None:
    core = lost_core()
    effects = request(core, "remove_unit", remove("r1", "ghost"), 0.5)
    assert published(effects) == [
        error(0, "gridfleet/v1/requests/remove_unit", "RemoveUnit: unknown unit 'ghost'", "r1"),
        reply(0, "r1", False, "unknown unit 'ghost'", None, "unknown_unit"),
    ]
    (entry,) = effects.audit.entries
    assert (entry.act, entry.target, entry.outcome) == ("remove_unit", "ghost", "refused")


def test_a_lost_unit_is_removed_its_topics_cleared_audited_and_told() -> None:
    core = lost_core()
    effects = request(core, "remove_unit", remove("r1", reason="fell off the dock"), 0.5)
    said = "unit unit1 removed; it had no job"
    assert published(effects) == [*CLEARED, reply(0, "r1", True, said, None)]
    assert effects.audit.entries == (
        AuditEntry(
            at=FIXED,
            actor="op",
            verified=False,
            via="op",
            act="remove_unit",
            target="unit1",
            detail=f"{said}; fell off the dock",
            outcome="accepted",
        ),
    )
    assert [e.text for e in effects.events] == ["unit unit1 removed by op: fell off the dock"]
    assert effects.removals == (("unit1", Removal(FIXED, "op")),)
    assert "unit1" not in core.world.units
    # Forgotten by planning and the views: the next step's routes name nobody.
    routes = [p for p in published(core.step(1.0)) if p[0].endswith("/fleet/routes")]
    assert routes == [
        ("gridfleet/v1/fleet/routes", {"header": header_json("coordinator", 0), "step": 1,
                                       "routes": {}}, 0, True)
    ]  # fmt: skip


def test_a_removed_units_job_not_picked_up_goes_back_to_the_queue() -> None:
    core = make_core(GRID)
    core.on_connect()
    meet(core, state(), capacity_kg=5.0)
    request(core, "submit_job", submit(), 0.0)
    core.step(1.0)
    assert core.jobs.jobs["job-1"].state == "to_pickup"
    from_unit(core, "connection", "unit1", connection("unit1", "broken"), 1.1)
    answer = reply_in(request(core, "remove_unit", remove("r2"), 1.2))
    assert (answer.accepted, answer.reason, answer.job_id) == (
        True,
        "unit unit1 removed; job job-1 back in the queue",
        "job-1",
    )
    job = core.jobs.jobs["job-1"]
    assert (job.state, job.unit, job.reason) == (
        "queued",
        None,
        "unit unit1 removed by op; re-queued",
    )
    assert "job-1" not in core.progress.requeued_from  # never adopted by unit1 again


def test_a_removed_unit_that_carried_the_item_fails_its_job_with_the_reason() -> None:
    core = make_core(GRID)
    core.on_connect()
    meet(core, state(Cell(3, 0)), capacity_kg=5.0)
    request(core, "submit_job", submit(), 0.0)  # its pickup is [3, 0], where unit1 stands
    core.step(1.0)
    from_unit(core, "state", "unit1", state(Cell(3, 0), 1, job_id="job-1", load_kg=1.0), 1.5)
    core.step(2.0)
    assert core.jobs.jobs["job-1"].state == "loaded"
    from_unit(core, "connection", "unit1", connection("unit1", "offline"), 2.1)
    effects = request(core, "remove_unit", remove("r2"), 2.2)
    job = core.jobs.jobs["job-1"]
    assert (job.state, job.reason) == (
        "failed",
        "unit unit1 was removed by op carrying the item, last seen at [3, 0]: the item left with it",
    )
    said = "unit unit1 removed; job job-1 failed: the item left with it"
    assert reply_in(effects).reason == said
    assert [e.detail for e in effects.audit.entries] == [said]
    assert [p.id for p in effects.persist] == ["job-1"]


def test_removing_lifts_the_units_control_and_goal() -> None:
    core = lost_core()
    out = ControlUnit(
        header=header("op"), request_id="c1", reply_to="op", unit="unit1", command="out_of_service"
    )
    assert reply_in(request(core, "control_unit", out, 0.2)).accepted
    effects = request(core, "remove_unit", remove("r1"), 0.5)
    assert effects.controls == (("unit1", None),)
    assert dict(core.directives.controls) == {}


def test_a_removed_units_old_word_is_ignored_and_a_fresh_online_joins_it_as_new() -> None:
    core = make_core(GRID)
    core.on_connect()
    meet(core, state(), capacity_kg=5.0)
    assert orders_in(core.step(0.2))["unit1"].order_id == "n-unit1-1"
    from_unit(core, "connection", "unit1", connection("unit1", "offline"), 0.3)
    request(core, "remove_unit", remove("r1"), 0.5)
    # Its last state again (retained, or late), and its old `online`: nothing of it comes back.
    assert published(from_unit(core, "state", "unit1", state(seq=5), 0.6)) == []
    assert (
        published(from_unit(core, "connection", "unit1", connection("unit1", "online"), 0.6)) == []
    )
    assert "unit1" not in core.world.units and core.errors_reported == 0
    # The coordinator's own clears come back (empty): not refused, and now it may rejoin.
    for topic, *_ in CLEARED:
        assert published(core.on_message(topic, b"", 0.7)) == []
    assert core.removals.units["unit1"].cleared and core.errors_reported == 0
    effects = from_unit(core, "connection", "unit1", connection("unit1", "online"), 0.8)
    assert [e.text for e in effects.events] == [
        "unit unit1 joins again after its removal, as new",
        "unit unit1 online",
    ]
    assert effects.removals == (("unit1", None),) and "unit1" not in core.removals
    fs = Factsheet(header=header("unit1"), capacity_kg=5.0, step_period_s=1.0)
    from_unit(core, "factsheet", "unit1", fs, 0.8)
    # A new unit: its square may be anywhere free (not within 2 of [0, 0], where it was lost) ...
    assert published(from_unit(core, "state", "unit1", state(Cell(3, 2), seq=0), 0.9)) == []
    assert core.world.units["unit1"].position == Cell(3, 2)
    # ... and its orders are a new route: an id it may still hold as accepted is never reused.
    order = orders_in(core.step(2.0))["unit1"]
    assert order.order_id == "n-unit1-2" and order.update_id == 1


def test_an_online_stamped_after_the_removal_rejoins_without_the_clear_heard_back() -> None:
    # Where the coordinator's account may not clear the unit's topics, the clear never comes
    # back: a unit restarted since says so with an `online` stamped after the removal.
    core = lost_core()
    request(core, "remove_unit", remove("r1"), 0.5)
    later = Header(seq=1, timestamp=FIXED + timedelta(seconds=30), sender="unit1")
    from_unit(core, "connection", "unit1", connection("unit1", "online", later), 0.6)
    assert "unit1" not in core.removals and "unit1" in core.world.units


def test_a_square_another_unit_holds_is_refused_to_a_rejoining_unit() -> None:
    core = lost_core()
    meet(core, state(Cell(3, 2)).model_copy(update={"header": header("unit2")}), 5.0)
    request(core, "remove_unit", remove("r1"), 0.5)
    core.on_message(CLEARED[-1][0], b"", 0.6)
    from_unit(core, "connection", "unit1", connection("unit1", "online"), 0.7)
    refused = published(from_unit(core, "state", "unit1", state(Cell(3, 2)), 0.8))
    why = (
        "position [3, 2] is held by unit unit2 (its latest state is there): two units "
        "never share a square"
    )
    assert refused == [error(0, "gridfleet/v1/units/unit1/state", why)]
    assert core.world.units["unit1"].state is None  # joined, but not on unit2's square


def test_a_removal_outlives_a_restart_and_an_old_retained_state_stays_ignored(
    tmp_path: Path,
) -> None:
    store = JobStore(tmp_path / "db")
    core = lost_core()
    effects = request(core, "remove_unit", remove("r1"), 0.5)
    store.save_removals(effects.removals)
    # Restarted before its clears came back (or where they cannot): they go out again at once.
    again = CoordinatorCore(
        World(GRID, step_period_s=1.0, fleet_known_after_s=0.0),
        JobBook(),
        nonce="m",
        topics=TOPICS,
        stamp=stamper("coordinator"),
        removals=store.load_removals(),
    )
    assert published(again.on_connect())[: len(CLEARED)] == CLEARED
    # The broker's retained copies of its old word, replayed: ignored, no square reserved.
    from_unit(again, "connection", "unit1", connection("unit1", "online"), 0.1)
    from_unit(again, "state", "unit1", state(), 0.1)
    assert "unit1" not in again.world.units
    store.save_removals(again.on_message(CLEARED[-1][0], b"", 0.2).removals)
    assert store.load_removals() == {"unit1": Removal(FIXED, "op", cleared=True)}
    store.close()


def test_a_job_that_waited_for_the_square_a_lost_unit_kept_goes_on_once_it_is_removed() -> None:
    # Issue 53: hv1, killed on its job's pickup, kept the square; the job, re-queued to u2,
    # waited "hv1 stands where it must go" until the coordinator was restarted.
    grid = GridMap.from_rows(["......"])
    core = make_core(grid)
    hv1 = UnitLogic("hv1", grid, Cell(3, 0), 5.0, 1.0)
    u2 = UnitLogic("u2", grid, Cell(0, 0), 5.0, 1.0)
    yard = Yard(grid, [hv1, u2])
    for unit in ("hv1", "u2"):
        meet(core, yard.state(unit), 5.0)
    crate = submit("j", dropoff=Cell(5, 0))  # pickup [3, 0], where hv1 stands
    assert reply_in(request(core, "submit_job", crate, 0.0)).accepted
    core.step(1.0)
    job = core.jobs.jobs["job-1"]
    assert (job.state, job.unit) == ("to_pickup", "hv1")
    from_unit(core, "connection", "hv1", connection("hv1", "broken"), 1.0)  # killed there
    now = 1.0

    def step() -> None:
        nonlocal now
        now += 1.0
        order = orders_in(core.step(now)).get("u2")
        if order is not None:
            u2.on_order(order, now)
        yard.tick("u2", now)
        from_unit(core, "state", "u2", yard.state("u2"), now)

    while job.wait != "unit_stuck":
        step()
        assert now < 80, f"never stuck: {job.state} {job.unit} {job.wait}"
    assert job.unit == "u2" and "hv1 stands where it must go" in (job.wait_reason or "")
    assert u2.position == Cell(2, 0)
    assert reply_in(request(core, "remove_unit", remove("x", "hv1"), now)).accepted
    yard.world.remove("hv1")  # off the floor, as the operator confirmed
    while job.state != "done":
        step()
        assert now < 120, f"not done after the removal: {job.state} {job.wait_reason}"
    assert yard.world.collisions == 0


def test_a_removed_units_late_last_will_is_cleared_again() -> None:
    # Removed while its dead link was still open: the broker sends its will once the keep-alive
    # runs out, retained, and the page and the status would list it again.
    core = lost_core()
    request(core, "remove_unit", remove("r1"), 0.5)
    core.on_message(CLEARED[-1][0], b"", 0.6)
    late = from_unit(core, "connection", "unit1", connection("unit1", "broken"), 15.0)
    assert published(late) == [CLEARED[-1]]
    assert "unit1" not in core.world.units and core.errors_reported == 0


def test_a_removed_unit_still_on_the_floor_joins_as_new_with_its_next_state() -> None:
    # Removed while only silent (its session never ended): once the clear has come back, a state
    # of it is newer than the removal, and the unit is taken as a new one, not ignored where it
    # stands (other units would be routed through it).
    core = lost_core()
    request(core, "remove_unit", remove("r1"), 0.5)
    assert published(from_unit(core, "state", "unit1", state(Cell(3, 2), seq=9), 0.6)) == []
    assert "unit1" not in core.world.units  # before the clear came back: maybe a retained copy
    core.on_message(CLEARED[-1][0], b"", 0.7)
    effects = from_unit(core, "state", "unit1", state(Cell(3, 2), seq=10), 0.8)
    assert published(effects) == [] and "unit1" not in core.removals
    assert [e.text for e in effects.events][:1] == [
        "unit unit1 joins again after its removal, as new"
    ]
    assert core.world.units["unit1"].position == Cell(3, 2)


def test_an_empty_payload_on_a_units_topic_is_a_clear_never_refused() -> None:
    # `gridfleet clean`, or a removal's clears coming back after the unit rejoined.
    core = lost_core()
    for topic, *_ in CLEARED:
        assert published(core.on_message(topic, b"", 0.5)) == []
    assert core.errors_reported == 0


def test_a_square_a_removed_unit_was_to_follow_into_under_the_stop_is_not_kept() -> None:
    # Under the stop no step plans, so no step drops it: the removal must (else the square is
    # claimed for the removed id, and released to it when it rejoins, wherever it then is).
    core = lost_core()
    core.moves.following["unit1"] = Follow(Cell(0, 1), 3)
    request(core, "remove_unit", remove("r1"), 0.5)
    assert "unit1" not in core.moves.following
