"""The pure coordinator core with the real unit core (robots' UnitLogic) on a simulated world,
late and lost messages: safe, and every job done.

Units' sensors do not see each other here: the coordinator's orders alone must keep them apart,
so a move the world refuses (`prevented`) is a failure of the coordinator.
"""

from __future__ import annotations

import random
from collections.abc import Callable

import pytest

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.planning.validate import validate_windows
from gridfleet.coordinator.window import MAX_WINDOW
from gridfleet.coordinator.world import FLEET_KNOWN_AFTER_S
from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol import (
    CancelJob,
    Connection,
    ControlUnit,
    Factsheet,
    Order,
    Reply,
    SetGoal,
    SubmitJob,
)
from gridfleet.robots.unit import UnitLogic

from support.coordinator_drive import (
    TOPICS,
    from_unit,
    make_core,
    meet,
    orders_in,
    reply_in,
    request,
    step_hearing_itself,
)
from support.coordinator_fakes import ROOM_ROWS, Yard
from support.effects import header

ROWS = ROOM_ROWS


def check_released_disjoint(units: list[UnitLogic], grid: GridMap) -> None:
    """The units' released windows, as they stand, pass the validator: contiguous from each
    unit, on free squares, no square of one unit's window held by or standing under another
    (units run on their own clocks: "it leaves as I enter" is not safe), so no swap either."""
    positions = [u.position for u in units]
    problems = validate_windows(grid, positions, [u.released for u in units], bound=MAX_WINDOW)
    assert problems == [], problems


def simulate(
    n_units: int,
    n_jobs: int,
    seed: int,
    p_state: float,
    p_order: float,
    steps: int = 1500,
    hidden: set[Cell] | None = None,
    window: int = 1,
) -> tuple[CoordinatorCore, Yard, int]:
    rng = random.Random(seed)
    grid = GridMap.from_rows(ROWS)
    free = [c for c in grid.free_cells() if c not in (hidden or set())]
    core = make_core(grid, seed=seed, window=window)
    world = core.world
    spots = rng.sample(free, n_units)
    capacities = [rng.choice([2.0, 5.0, 10.0, 20.0]) for _ in range(n_units)]
    capacities[0] = 20.0
    units = [UnitLogic(f"u{i}", grid, spots[i], capacities[i], 1.0) for i in range(n_units)]
    yard = Yard(grid, units, hidden or (), sensors_see_units=False)
    now = 0.0
    for u in units:
        u.start(now)
        meet(core, yard.state(u.unit_id), u.capacity_kg)
    for j in range(n_jobs):
        p, d = rng.sample(free, 2)
        req = SubmitJob(
            header=header("t"),
            request_id=f"r{j}",
            reply_to="t",
            pickup=p,
            dropoff=d,
            mass_kg=rng.choice([0.5, 1.5, 4.0, 8.0, 15.0]),
        )
        assert reply_in(request(core, "submit_job", req, now)).accepted
    pending: list[tuple[int, str, Order]] = []  # (deliver at step, unit, message)
    for t in range(steps):
        now += 1.0
        for uid, order in orders_in(core.step(now)).items():
            if rng.random() < p_order:
                pending.append((t + rng.choice([0, 0, 1]), uid, order))
        due = [m for m in pending if m[0] <= t]
        pending = [m for m in pending if m[0] > t]
        for _, uid, order in due:
            yard.units[uid].on_order(order, now)
        check_released_disjoint(units, grid)
        for u in rng.sample(units, len(units)):
            yard.tick(u.unit_id, now)
        assert (yard.world.prevented, yard.world.collisions) == (0, 0), f"at step {t}"
        for u in units:
            uid = u.unit_id
            heard = rng.random() < p_state or now - (world.units[uid].state_at or 0) >= 3
            if heard:
                from_unit(core, "state", uid, yard.state(uid), now)
        if all(j.final for j in core.jobs.jobs.values()):
            return core, yard, t
    raise AssertionError(
        f"jobs not finished after {steps} steps: "
        f"{[(j.id, j.state, j.unit) for j in core.jobs.jobs.values() if not j.final]}"
    )


@pytest.mark.parametrize("window", [1, 4])
@pytest.mark.parametrize("seed", range(4))
def test_jobs_finish_safely_with_reliable_messages(seed: int, window: int) -> None:
    core, _, _ = simulate(4, 12, seed, p_state=1.0, p_order=1.0, window=window)
    assert all(j.state in ("done", "rejected") for j in core.jobs.jobs.values())


@pytest.mark.parametrize("window", [1, 4])
@pytest.mark.parametrize("seed", range(4))
def test_jobs_finish_safely_with_late_and_lost_messages(seed: int, window: int) -> None:
    core, _, _ = simulate(8, 20, seed, p_state=0.6, p_order=0.7, window=window)
    assert all(j.state in ("done", "rejected") for j in core.jobs.jobs.values())


def test_hidden_obstacles_are_reported_and_planned_around() -> None:
    core, _, _ = simulate(4, 10, 7, p_state=1.0, p_order=1.0, hidden={Cell(5, 1), Cell(8, 5)})
    assert all(j.state in ("done", "rejected") for j in core.jobs.jobs.values())


def one_unit(capacity_kg: float) -> tuple[CoordinatorCore, Yard]:
    """A core on ROWS with one unit `u` at (0, 0), online and heard from."""
    grid = GridMap.from_rows(ROWS)
    core = make_core(grid)
    yard = Yard(grid, [UnitLogic("u", grid, Cell(0, 0), capacity_kg, 1.0)])
    meet(core, yard.state("u"), capacity_kg)
    return core, yard


def step_one(core: CoordinatorCore, yard: Yard, now: float) -> bool:
    """One coordinator step; the unit follows its order (if it got one) and reports back."""
    orders = orders_in(core.step(now))
    if "u" in orders:
        yard.units["u"].on_order(orders["u"], now)
    yard.tick("u", now)
    from_unit(core, "state", "u", yard.state("u"), now)
    return "u" in orders


def test_goal_pins_a_unit_until_reached() -> None:
    core, yard = one_unit(5.0)

    ids = iter(range(1, 100))

    def set_goal(unit: str, target: Cell) -> Reply:
        # Each request its own id: a reused id is a retry of the first (protocol.md §6).
        rid = f"g{next(ids)}"
        goal = SetGoal(header=header("t"), request_id=rid, reply_to="t", unit=unit, target=target)
        return reply_in(request(core, "set_goal", goal, 0.0))

    bad = set_goal("nobody", Cell(1, 1))
    assert not bad.accepted and "unknown unit" in (bad.reason or "")
    wall = set_goal("u", Cell(2, 2))
    assert not wall.accepted and "wall" in (wall.reason or "")
    assert set_goal("u", Cell(9, 3)).accepted
    for t in range(1, 60):
        assert step_one(core, yard, float(t))
        if yard.units["u"].position == Cell(9, 3):
            break
    assert yard.units["u"].position == Cell(9, 3)
    core.step(100.0)
    assert core.directives.goals == {}


def _carrying_unit() -> tuple[CoordinatorCore, Yard, float]:
    """One unit under way to the dropoff with a job's item on board."""
    core, yard = one_unit(10.0)
    _submit(core, "r", Cell(0, 1), Cell(9, 9))
    now = 0.0
    while core.jobs.jobs[next(iter(core.jobs.jobs))].state != "to_dropoff":
        now += 1.0
        assert now < 30, "never loaded"
        assert step_one(core, yard, now)
    return core, yard, now


def _run_to_end(core: CoordinatorCore, yard: Yard, now: float) -> str:
    job = next(iter(core.jobs.jobs.values()))
    for _ in range(60):
        now += 1.0
        step_one(core, yard, now)
        if job.final:
            break
    return job.state


def test_a_carrying_unit_that_is_only_late_finishes_its_job() -> None:
    core, yard, now = _carrying_unit()
    for _ in range(30):  # 30 s of silence: lost for a while, but the item is on board
        now += 1.0
        step_hearing_itself(core, now)
    job = next(iter(core.jobs.jobs.values()))
    assert job.state == "to_dropoff" and job.unit == "u"
    assert _run_to_end(core, yard, now) == "done"


def test_a_carrying_unit_gone_for_good_fails_its_job_with_the_reason() -> None:
    core, _, now = _carrying_unit()
    for _ in range(200):
        now += 1.0
        step_hearing_itself(core, now)
    job = next(iter(core.jobs.jobs.values()))
    assert job.state == "failed" and "lost carrying the item" in (job.reason or "")


def test_a_coordinator_that_hears_nothing_takes_the_silence_for_its_own() -> None:
    # Cut off from the broker, it hears nobody, not even its own status: however long that
    # lasts, the unit's absence is not known, and the job whose item it carries does not fail.
    core, yard, now = _carrying_unit()
    job = next(iter(core.jobs.jobs.values()))
    for _ in range(300):  # three times the failure timeout (20 x its 5 s loss timeout)
        now += 1.0
        core.step(now)
    assert job.state == "to_dropoff" and job.unit == "u"
    # Back on the network: the unit was only cut off with it, and finishes.
    from_unit(core, "state", "u", yard.state("u"), now)
    assert _run_to_end(core, yard, now) == "done"


def test_after_its_own_silence_the_coordinator_counts_a_units_absence_from_when_it_hears() -> None:
    core, _, now = _carrying_unit()
    job = next(iter(core.jobs.jobs.values()))
    for _ in range(60):  # deaf for a minute, then its own status comes back; the unit's does not
        now += 1.0
        core.step(now)
    healed = now
    while job.state == "to_dropoff":
        now += 1.0
        assert now < healed + 200, "never failed"
        step_hearing_itself(core, now)
    # 20 loss timeouts (100 s) of absence heard, not counting the minute it heard nothing.
    assert job.state == "failed" and now - healed >= 100


def test_a_carrying_unit_that_restarts_finishes_its_job() -> None:
    # A restarted units process says goodbye, then resumes with the item on board (`--state`).
    core, yard, now = _carrying_unit()
    from_unit(core, "connection", "u", Connection(header=header("u"), state="offline"), now)
    for _ in range(3):
        now += 1.0
        core.step(now)
    assert next(iter(core.jobs.jobs.values())).state == "to_dropoff"
    from_unit(core, "connection", "u", Connection(header=header("u"), state="online"), now)
    from_unit(core, "state", "u", yard.state("u"), now)
    assert _run_to_end(core, yard, now) == "done"


def test_a_carrying_unit_offline_for_good_fails_its_job() -> None:
    core, _, now = _carrying_unit()
    from_unit(core, "connection", "u", Connection(header=header("u"), state="offline"), now)
    for _ in range(200):  # 20 times its 5 s loss timeout, not at once: it may come back with it
        now += 1.0
        step_hearing_itself(core, now)
    job = next(iter(core.jobs.jobs.values()))
    assert job.state == "failed" and "lost carrying the item" in (job.reason or "")


def _submit(
    core: CoordinatorCore, rid: str, pickup: Cell, dropoff: Cell, mass_kg: float = 1.0
) -> None:
    assert _ask_submit(core, rid, pickup, dropoff, mass_kg).accepted


def _ask_submit(
    core: CoordinatorCore,
    rid: str,
    pickup: Cell,
    dropoff: Cell,
    mass_kg: float = 1.0,
    now: float = 0.0,
) -> Reply:
    req = SubmitJob(
        header=header("t"),
        request_id=rid,
        reply_to="t",
        pickup=pickup,
        dropoff=dropoff,
        mass_kg=mass_kg,
    )
    return reply_in(request(core, "submit_job", req, now))


def _steps_until(core: CoordinatorCore, yard: Yard, now: float, done: Callable[[], bool]) -> float:
    for _ in range(60):
        now += 1.0
        step_one(core, yard, now)
        if done():
            return now
    raise AssertionError("not within 60 steps")


def test_a_unit_back_with_the_item_of_a_failed_job_puts_it_back_and_works_again() -> None:
    # The soak found this: a job failed while its units process was down; the process resumed
    # with the item on board, and the unit, never given another job, stood for ever.
    core, yard, now = _carrying_unit()
    for _ in range(200):  # gone long enough for its job to fail
        now += 1.0
        step_hearing_itself(core, now)
    failed = next(iter(core.jobs.jobs.values()))
    assert failed.state == "failed"
    unit = yard.units["u"]
    assert unit.job_id == failed.id
    from_unit(core, "state", "u", yard.state("u"), now)  # back, the item still on board
    _submit(core, "r2", Cell(9, 1), Cell(0, 0))
    now = _steps_until(core, yard, now, lambda: unit.job_id is None)
    assert unit.position == failed.pickup and unit.load_kg == 0.0  # put back where it was
    second = core.jobs.get("r2") or next(j for j in core.jobs.jobs.values() if j is not failed)
    _steps_until(core, yard, now, lambda: second.state == "done")
    assert failed.state == "failed"  # final: it never changes again


def test_a_cancelled_carried_job_frees_its_unit_for_the_next_one() -> None:
    core, yard, now = _carrying_unit()
    job = next(iter(core.jobs.jobs.values()))
    cancel = CancelJob(header=header("t"), request_id="c", reply_to="t", job_id=job.id)
    assert reply_in(request(core, "cancel_job", cancel, now)).accepted
    assert job.state == "cancelled" and f"back at its pickup {list(job.pickup)}" in (
        job.reason or ""
    )
    _submit(core, "r2", Cell(9, 1), Cell(0, 0))
    unit = yard.units["u"]
    now = _steps_until(core, yard, now, lambda: unit.job_id is None)
    assert unit.position == job.pickup
    second = next(j for j in core.jobs.jobs.values() if j is not job)
    _steps_until(core, yard, now, lambda: second.state == "done")


def test_a_heavy_job_waits_for_the_only_unit_that_can_carry_it_to_restart() -> None:
    # The soak found heavy jobs rejected ("exceeds every unit's capacity") while the units
    # process restarted: every unit had said offline for a second.
    core, yard = one_unit(10.0)
    small = UnitLogic("small", core.world.grid, Cell(9, 9), 5.0, 1.0)
    meet(core, small.report(header("small")), 5.0)  # online: it could carry 5 kg at most
    offline = Connection(header=header("u"), state="offline")
    from_unit(core, "connection", "u", offline, 0.0)
    _submit(core, "heavy", Cell(9, 1), Cell(0, 0), mass_kg=7.0)
    job = next(iter(core.jobs.jobs.values()))
    for now in (1.0, 2.0, 3.0):
        core.step(now)
    assert job.state == "queued"
    from_unit(core, "connection", "u", Connection(header=header("u"), state="online"), 3.0)
    from_unit(core, "state", "u", yard.state("u"), 3.0)
    _steps_until(core, yard, 3.0, lambda: job.state == "done")


# `assigned` lasts only within a step here: a unit that hears from us gets it `to_pickup` at once.
@pytest.mark.parametrize("state", ["queued", "to_pickup", "loaded", "to_dropoff"])
def test_a_job_cancelled_in_any_state_leaves_its_unit_free_for_the_next(state: str) -> None:
    # Issue 14: a cancel after pick-up took the unit out of service for good.
    core, yard = one_unit(10.0)
    _submit(core, "first", Cell(0, 3), Cell(9, 9))
    job = next(iter(core.jobs.jobs.values()))
    now = 0.0
    if state != "queued":
        now = _steps_until(core, yard, now, lambda: job.state == state)
    cancel = CancelJob(header=header("t"), request_id="c", reply_to="t", job_id=job.id)
    assert reply_in(request(core, "cancel_job", cancel, now)).accepted
    assert job.state == "cancelled"
    _submit(core, "second", Cell(9, 1), Cell(0, 0))
    second = next(j for j in core.jobs.jobs.values() if j is not job)
    unit = yard.units["u"]
    _steps_until(core, yard, now, lambda: second.state == "done")
    assert job.state == "cancelled" and unit.job_id is None and unit.load_kg == 0.0


POCKET_ROWS = [*ROWS[:9], "........@."]  # (9, 9) is reached only through (9, 8)


def _pocket_unit() -> tuple[CoordinatorCore, Yard]:
    grid = GridMap.from_rows(POCKET_ROWS)
    core = make_core(grid)
    yard = Yard(grid, [UnitLogic("u", grid, Cell(0, 0), 10.0, 1.0)])
    meet(core, yard.state("u"), 10.0)
    return core, yard


def _obstacle_found(core: CoordinatorCore, yard: Yard, square: Cell, now: float) -> None:
    """A scout standing next to `square` (a unit reports only what is next to it) reports it as
    an obstacle it has just sensed."""
    beside = next(c for c in (square.step(d) for d in Direction) if core.world.grid.is_free(c))
    update = {"position": beside, "obstacles": [square], "job_id": None, "load_kg": 0.0}
    state = yard.state("u").model_copy(update=update)
    from_unit(core, "state", "scout", state, now)


def test_a_job_no_unit_could_ever_finish_is_refused_at_submission_with_the_reason() -> None:
    core, yard = _pocket_unit()
    _obstacle_found(core, yard, Cell(9, 8), 0.0)  # the pocket's only way in is blocked
    reply = _ask_submit(core, "r", Cell(5, 9), Cell(9, 9))
    assert not reply.accepted
    assert reply.reason == "dropoff [9, 9] cannot be reached from pickup [5, 9]"
    job = next(iter(core.jobs.jobs.values()))
    assert (job.state, job.reason) == ("rejected", reply.reason)


def test_a_job_walled_off_by_a_discovered_obstacle_fails_with_the_reason() -> None:
    core, yard = _pocket_unit()
    _submit(core, "r", Cell(5, 9), Cell(9, 9))
    job = next(iter(core.jobs.jobs.values()))
    core.step(1.0)
    assert job.state == "to_pickup"
    _obstacle_found(core, yard, Cell(9, 8), 1.0)
    core.step(2.0)
    assert job.state == "failed"
    assert job.reason == "dropoff [9, 9] cannot be reached from pickup [5, 9]"


def test_a_restarted_coordinator_waits_to_hear_the_fleet_before_rejecting_a_heavy_job() -> None:
    # CI saw it: restarted mid-run, the coordinator had heard the light units' factsheets but not
    # yet the heavy one's, and rejected the restored job that only the heavy unit can carry.
    core, yard = one_unit(5.0)
    core.world.fleet_known_after_s = FLEET_KNOWN_AFTER_S
    core.world.first_heard_at = core.world.heard_at = 0.0
    heavy = _ask_submit(core, "r1", Cell(9, 1), Cell(0, 0), mass_kg=8.0)
    assert heavy.accepted  # not yet known to be beyond the whole fleet
    strong = UnitLogic("strong", core.world.grid, Cell(9, 9), 10.0, 1.0)
    from_unit(core, "connection", "strong", Connection(header=header("strong"), state="online"), 1)
    fs = Factsheet(header=header("strong"), capacity_kg=10.0, step_period_s=1.0)
    from_unit(core, "factsheet", "strong", fs, 1.0)
    from_unit(core, "state", "strong", strong.report(header("strong")), 1.0)
    job = core.jobs.jobs[heavy.job_id or ""]
    for now in (FLEET_KNOWN_AFTER_S + 1.0, FLEET_KNOWN_AFTER_S + 2.0):
        from_unit(core, "state", "strong", strong.report(header("strong")), now - 0.5)
        step_one(core, yard, now)
        assert job.state in ("queued", "assigned", "to_pickup"), job.state
    assert job.unit == "strong"


def test_a_job_too_heavy_for_the_whole_fleet_is_rejected_once_the_fleet_is_known() -> None:
    core, yard = one_unit(5.0)
    core.world.fleet_known_after_s = FLEET_KNOWN_AFTER_S
    core.world.first_heard_at = core.world.heard_at = 0.0
    heavy = _ask_submit(core, "r1", Cell(9, 1), Cell(0, 0), mass_kg=8.0)
    assert heavy.accepted
    job = core.jobs.jobs[heavy.job_id or ""]
    step_one(core, yard, 1.0)
    assert job.state == "queued"
    from_unit(core, "state", "u", yard.state("u"), FLEET_KNOWN_AFTER_S)  # heard for long enough
    step_one(core, yard, FLEET_KNOWN_AFTER_S + 0.5)
    assert (job.state, job.reason) == (
        "rejected",
        "mass 8.0 kg exceeds every unit's capacity (largest 5.0 kg)",
    )
    late = _ask_submit(core, "r2", Cell(9, 1), Cell(0, 0), 8.0, FLEET_KNOWN_AFTER_S + 1.0)
    assert (late.accepted, late.reason) == (False, job.reason)  # refused at once from now on


def test_its_own_status_heard_back_the_coordinator_knows_the_fleet_at_once() -> None:
    # Subscribed to last: the retained factsheets came before it (inbound.subscriptions).
    core, _ = one_unit(5.0)
    core.world.fleet_known_after_s = FLEET_KNOWN_AFTER_S
    core.world.first_heard_at = core.world.heard_at = 0.0
    assert not core.world.fleet_known()
    own = core.status("online")  # as it published it on connecting, and the broker sent back
    core.on_message(own.topic, own.payload, 0.5)
    assert core.world.fleet_known()
    heavy = _ask_submit(core, "r1", Cell(9, 1), Cell(0, 0), 8.0, 0.6)
    assert (heavy.accepted, heavy.reason) == (
        False,
        "mass 8.0 kg exceeds every unit's capacity (largest 5.0 kg)",
    )


def test_its_own_status_back_the_fleet_is_known_only_with_the_factsheet_of_every_unit_heard() -> (
    None
):
    # The known flake (a heavy job rejected just after a restart): a unit's state was heard, its
    # retained factsheet not yet, and the coordinator's own status came back first.
    core, _ = one_unit(5.0)
    core.world.fleet_known_after_s = FLEET_KNOWN_AFTER_S
    core.world.first_heard_at = core.world.heard_at = 0.0
    strong = UnitLogic("strong", core.world.grid, Cell(9, 9), 10.0, 1.0)
    from_unit(core, "state", "strong", strong.report(header("strong")), 0.2)
    own = core.status("online")
    core.on_message(own.topic, own.payload, 0.5)
    assert not core.world.fleet_known()
    heavy = _ask_submit(core, "r1", Cell(9, 1), Cell(0, 0), 8.0, 0.6)
    assert heavy.accepted  # queued: "strong" may carry it
    fs = Factsheet(header=header("strong"), capacity_kg=10.0, step_period_s=1.0)
    from_unit(core, "factsheet", "strong", fs, 0.7)
    assert core.world.fleet_known()


def _wait(job_id: str, core: CoordinatorCore) -> tuple[str | None, str | None]:
    view = core.jobs.jobs[job_id].view()
    return view.wait, view.wait_reason


def test_every_waiting_job_says_why_in_code_and_words() -> None:
    # Issue 14: in --demo, heavy jobs piled up while two units idled and nothing said why.
    core, yard = one_unit(10.0)
    small = UnitLogic("small", core.world.grid, Cell(9, 9), 2.0, 1.0)
    meet(core, small.report(header("small")), 2.0)
    _submit(core, "a", Cell(9, 1), Cell(0, 0), mass_kg=7.0)
    _submit(core, "b", Cell(5, 9), Cell(0, 9), mass_kg=7.0)
    jobs = core.jobs.jobs
    now = _steps_until(core, yard, 0.0, lambda: any(j.state == "to_pickup" for j in jobs.values()))
    first = next(j.id for j in jobs.values() if j.state == "to_pickup")
    second = next(j.id for j in jobs.values() if j.state == "queued")
    assert _wait(second, core) == (
        "no_unit_free",
        "every unit that can carry 7.0 kg is busy (u)",
    )
    core.on_message(TOPICS.fleet("estop"), b"engaged|dashboard|test", now + 0.5)
    step_one(core, yard, now + 1.0)
    assert _wait(first, core) == ("fleet_stopped", "the emergency stop is engaged")
    core.on_message(TOPICS.fleet("estop"), b"released|dashboard|test", now + 1.5)
    offline = Connection(header=header("u"), state="offline")
    from_unit(core, "connection", "u", offline, now + 1.5)
    core.step(now + 2.0)
    assert _wait(second, core) == (
        "no_capable_unit",
        "no unit that can carry 7.0 kg is online (u)",
    )
    assert core.jobs.jobs[first].state == "queued"  # re-queued: not picked up yet
    assert _wait(first, core)[0] == "no_capable_unit"


def test_a_carried_job_whose_unit_is_away_says_so() -> None:
    core, _, now = _carrying_unit()
    offline = Connection(header=header("u"), state="offline")
    from_unit(core, "connection", "u", offline, now)
    core.step(now + 1.0)
    job = next(iter(core.jobs.jobs))
    assert _wait(job, core) == ("unit_away", "its unit u is not heard from (offline)")


def test_a_final_job_says_no_wait() -> None:
    core, yard = one_unit(10.0)
    _submit(core, "a", Cell(9, 1), Cell(0, 0))
    job = next(iter(core.jobs.jobs.values()))
    _steps_until(core, yard, 0.0, lambda: job.state == "done")
    assert job.view().wait is None and job.view().wait_reason is None


def _control(core: CoordinatorCore, unit: str, command: str, rid: str) -> Reply:
    req = ControlUnit(header=header("t"), request_id=rid, reply_to="t", unit=unit, command=command)
    return reply_in(request(core, "control_unit", req, 0.0))


def test_a_paused_unit_holds_with_its_job_and_finishes_it_once_resumed() -> None:
    core, yard = one_unit(10.0)
    _submit(core, "a", Cell(9, 1), Cell(0, 0))
    job = next(iter(core.jobs.jobs.values()))
    now = _steps_until(core, yard, 0.0, lambda: job.state == "to_pickup")
    assert _control(core, "u", "pause", "p1").accepted
    unit = yard.units["u"]
    for _ in range(2):  # what it was released before the pause, then nothing
        now += 1.0
        step_one(core, yard, now)
    where = unit.position
    for _ in range(5):
        now += 1.0
        step_one(core, yard, now)
    assert unit.position == where and job.state == "to_pickup" and job.unit == "u"
    assert _wait(job.id, core) == ("unit_paused", "its unit u is paused")
    assert _control(core, "u", "resume", "p2").accepted
    _steps_until(core, yard, now, lambda: job.state == "done")


def test_a_unit_out_of_service_gives_its_job_back_and_takes_none_until_back() -> None:
    core, yard = one_unit(10.0)
    _submit(core, "a", Cell(9, 1), Cell(0, 0))
    job = next(iter(core.jobs.jobs.values()))
    now = _steps_until(core, yard, 0.0, lambda: job.state == "to_pickup")
    assert _control(core, "u", "out_of_service", "o1").accepted
    assert (job.state, job.unit) == ("queued", None)
    for _ in range(5):
        now += 1.0
        step_one(core, yard, now)
    assert job.state == "queued"
    assert _wait(job.id, core) == (
        "no_unit_free",
        "no unit that can carry 1.0 kg is free (u out of service)",
    )
    assert _control(core, "u", "in_service", "o2").accepted
    _steps_until(core, yard, now, lambda: job.state == "done")


def test_unit_control_refusals_are_in_words() -> None:
    core, _ = one_unit(10.0)
    assert _control(core, "ghost", "pause", "r1").reason == "unknown unit 'ghost'"
    assert _control(core, "u", "resume", "r2").reason == "unit u is not paused"
    assert _control(core, "u", "out_of_service", "r3").accepted
    refused = _control(core, "u", "pause", "r4")
    assert refused.reason == "unit u is out of service: put it back in service first"
    assert _control(core, "u", "resume", "r5").reason == "unit u is not paused (out of service)"


def test_a_wait_in_a_hall_of_a_hundred_units_names_a_few_and_fits_the_view() -> None:
    # bench system at 100 units: the reason named all 100, passed MAX_TEXT, and the jobs view
    # failed to encode, taking the coordinator's step loop down with it.
    grid = GridMap.from_rows(["." * 20] * 12)
    core = make_core(grid)
    core.on_connect()
    cells = [Cell(x, y) for y in range(0, 12, 2) for x in range(20)][:100]
    for i, cell in enumerate(cells):
        uid = f"u{i:03}"
        meet(core, UnitLogic(uid, grid, cell, 2.0, 1.0).report(header(uid)), 2.0)
    _submit(core, "r1", Cell(1, 1), Cell(18, 11))
    for i in range(100):
        gone = Connection(header=header(f"u{i:03}"), state="offline")
        from_unit(core, "connection", f"u{i:03}", gone, 0.5)
    effects = core.step(1.0)
    (job,) = core.jobs.jobs.values()
    code, words = _wait(job.id, core)
    assert code == "no_capable_unit"
    assert words == (
        "no unit that can carry 1.0 kg is online "
        "(u000, u001, u002, u003, u004, u005, u006, u007 and 92 more)"
    )
    views = [m for m in effects.publish if m.topic == TOPICS.fleet("jobs")]
    assert len(views) == 1  # it went out


def test_a_view_that_cannot_be_built_is_reported_and_the_orders_still_go(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    core, _ = one_unit(10.0)
    core.on_connect()
    _submit(core, "a", Cell(9, 1), Cell(0, 0))

    def broken(*_: object) -> None:
        raise ValueError("too long")

    monkeypatch.setattr(core.say, "jobs", broken)
    effects = core.step(1.0)
    assert "u" in orders_in(effects)
    errors = [m for m in effects.publish if m.topic == TOPICS.fleet("errors")]
    assert len(errors) == 1 and b"internal error in the views" in errors[0].payload


def test_a_unit_idle_for_long_is_not_stuck_the_moment_it_is_given_a_job() -> None:
    # As found: a job just given to a vehicle idle for minutes read "its unit ... has not moved
    # for over a minute" (its stillness was counted from its last move, before the job).
    core, yard = one_unit(5.0)
    for now in range(1, 100):  # idle, heard, standing still for over a minute
        step_one(core, yard, float(now))
    _submit(core, "r", Cell(9, 1), Cell(0, 0))
    (job,) = core.jobs.jobs.values()
    core.step(100.0)  # given the job: the wait is told in the same step
    assert job.unit == "u" and _wait(job.id, core)[0] != "unit_stuck", _wait(job.id, core)


def test_a_unit_with_a_job_that_stops_making_progress_says_it_is_stuck_and_who_blocks() -> None:
    # The hour-long warehouse demo: a loaded unit sat behind an idle one in a dead end for 21
    # minutes, and its job's "waiting for" stayed empty. (Steps of 1 s: stuck after 30 s.)
    grid = GridMap.from_rows(["......"])
    core = make_core(grid)
    core.on_connect()
    u = UnitLogic("u", grid, Cell(0, 0), 5.0, 1.0)
    b = UnitLogic("b", grid, Cell(1, 0), 0.5, 1.0)  # too weak for the job: it stays idle
    meet(core, u.report(header("u")), 5.0)
    meet(core, b.report(header("b")), 0.5)
    _submit(core, "r", Cell(3, 0), Cell(5, 0))
    (job,) = core.jobs.jobs.values()

    def step_at(now: float) -> None:  # neither unit moves: b is in u's way
        core.step(now)
        from_unit(core, "state", "u", u.report(header("u")), now)
        from_unit(core, "state", "b", b.report(header("b")), now)

    for now in range(1, 30):
        step_at(float(now))
    assert _wait(job.id, core)[0] != "unit_stuck"  # 29 s: traffic, not yet a jam
    effects = core.step(31.0)
    # Counted from the job given to it (the first step, at 1 s), not from when it was met.
    stuck = "its unit u has not moved for 30 s at [0, 0]; b stands where it must go"
    assert _wait(job.id, core) == ("unit_stuck", stuck)
    assert [e.text for e in effects.events] == [f"job {job.id}: {stuck}"]  # told once
    from_unit(core, "state", "u", u.report(header("u")), 31.0)
    from_unit(core, "state", "b", b.report(header("b")), 31.0)
    for now in range(32, 62):
        step_at(float(now))
    assert _wait(job.id, core)[1].startswith("its unit u has not moved for over a minute")
    # Held by the emergency stop, a unit is not stuck: it counts again from the release.
    core.on_message(TOPICS.fleet("estop"), b"engaged|dashboard|test", 62.0)
    step_at(63.0)
    assert _wait(job.id, core)[0] == "fleet_stopped"
    core.on_message(TOPICS.fleet("estop"), b"released|dashboard|test", 64.0)
    step_at(65.0)
    assert _wait(job.id, core)[0] != "unit_stuck"
    for now in range(66, 95):  # 31 s after the last step under the stop (63)
        step_at(float(now))
    assert _wait(job.id, core)[1].startswith("its unit u has not moved for 31 s")


def test_an_order_that_changes_nothing_goes_out_again_after_a_quarter_of_the_hold_time() -> None:
    grid = GridMap.from_rows(ROWS)
    core = make_core(grid, step_s=0.1)
    yard = Yard(grid, [UnitLogic("u", grid, Cell(0, 0), 10.0, 0.1)])
    meet(core, yard.state("u"), 10.0, step_s=0.1)
    sent = [k for k in range(1, 8) if step_one(core, yard, k * 0.1)]
    # Idle: a halt order at once, then the same again every other step (a unit holds after 0.5 s
    # without orders; a quarter of that is 0.125 s).
    assert sent == [1, 3, 5, 7]
    assert yard.units["u"].status == "idle"
    # New squares go out at once, between two repeats, and the unit drives them.
    _submit(core, "r1", Cell(5, 0), Cell(9, 0))
    assert step_one(core, yard, 0.8)
    assert yard.units["u"].position != Cell(0, 0)


def test_a_goal_sent_as_the_unit_picks_up_leaves_the_job_with_the_item() -> None:
    # Found by a playfield run: the goal re-queued the job while the state saying "picked up"
    # was on its way; another unit was sent for the same item and the first put it back.
    core, yard = one_unit(5.0)
    other = UnitLogic("v", core.world.grid, Cell(9, 9), 5.0, 1.0)
    yard = Yard(core.world.grid, [yard.units["u"], other])
    meet(core, yard.state("v"), 5.0)
    _submit(core, "r", Cell(0, 1), Cell(9, 1))
    job = next(iter(core.jobs.jobs.values()))
    unit = yard.units["u"]
    now = 0.0

    def step_heard(tick: tuple[str, ...]) -> dict[str, Order]:
        orders = orders_in(core.step(now))
        for uid in tick:
            if uid in orders:
                yard.units[uid].on_order(orders[uid], now)
            yard.tick(uid, now)
        for uid in ("u", "v"):
            from_unit(core, "state", uid, yard.state(uid), now)
        return orders

    order = None
    while order is None or order.action is None:
        now += 1.0
        assert now < 10, "never sent to the pickup"
        order = step_heard(("v",)).get("u", order)
    assert order.action.kind == "pick" and job.unit == "u"
    # u has its order to the pickup; the goal comes before it moves, and while its states
    # are on the way the core steps on: the job goes to v.
    goal = SetGoal(header=header("t"), request_id="g", reply_to="t", unit="u", target=Cell(5, 0))
    assert reply_in(request(core, "set_goal", goal, now)).accepted
    assert job.state == "queued"
    while job.unit != "v":
        now += 1.0
        assert now < 20, "never given to v"
        step_heard(("v",))
    unit.on_order(order, now)  # late: u acts on its order to pick up
    while unit.job_id is None:
        now += 1.0
        assert now < 30, "never picked up"
        yard.tick("u", now)
    from_unit(core, "state", "u", yard.state("u"), now)  # u has the item, not v
    now += 1.0
    core.step(now)
    assert (job.state, job.unit) == ("loaded", "u")
    assert core.jobs.of_unit("v") is None
    for _ in range(80):
        now += 1.0
        step_heard(("u", "v"))
        if job.final:
            break
    assert (job.state, job.unit) == ("done", "u")
    assert other.job_id is None and other.load_kg == 0.0  # v never picked anything up


def test_a_lost_units_released_squares_stay_reserved_for_as_long_as_it_is_lost() -> None:
    # Unheard, it may have driven them (a VDA 5050 vehicle drives its whole base): nobody else
    # is released one of them, however long it stays lost.
    core, yard = one_unit(5.0)
    other = UnitLogic("v", core.world.grid, Cell(4, 0), 5.0, 1.0)
    yard = Yard(core.world.grid, [yard.units["u"], other])
    meet(core, yard.state("v"), 5.0)
    lost = yard.units["u"]
    goal = SetGoal(header=header("t"), request_id="g1", reply_to="t", unit="u", target=Cell(3, 0))
    assert reply_in(request(core, "set_goal", goal, 0.0)).accepted
    now = 0.0
    while not lost.released:
        now += 1.0
        assert now < 10, "u never released a square"
        if (order := orders_in(core.step(now)).get("u")) is not None:
            lost.on_order(order, now)
        from_unit(core, "state", "v", yard.state("v"), now)
    from_unit(core, "state", "u", yard.state("u"), now)  # its last word: released, not driven
    ahead = set(lost.released)
    goal = goal.model_copy(update={"request_id": "g2", "unit": "v", "target": Cell(1, 0)})
    assert reply_in(request(core, "set_goal", goal, now)).accepted
    for _ in range(200):  # u says nothing more: lost after a few seconds, for good
        now += 1.0
        order = orders_in(core.step(now)).get("v")
        if order is not None:
            assert not ahead & set(order.released), f"{order.released} released at {now} s"
            other.on_order(order, now)
        yard.tick("v", now)
        from_unit(core, "state", "v", yard.state("v"), now)
    assert core.world.units["u"].lost_since is not None
    assert other.position not in ahead
