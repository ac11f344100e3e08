"""Operator requests (protocol.md §6): queue a job, cancel one, send a unit to a goal, pause or
take a unit out of service or send it to charge, clear obstacles, remove a lost unit for good.

Pure: each request is checked against the world and the job book by its handler in `HANDLERS`,
`(request, RequestContext) -> Outcome`, and answered with the Outcome; a refused request changes
nothing. What a handler changed beyond the job book (a unit's control, obstacles cleared) it
notes in the context, for the core to persist and re-plan around.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from gridfleet.coordinator.allocation import capacity_reason, reach_reason
from gridfleet.coordinator.directives import Directives
from gridfleet.coordinator.energy import EnergyPolicy
from gridfleet.coordinator.jobs import CARRYING_STATES, Job, JobBook
from gridfleet.coordinator.places import Refusal, Role, Spot
from gridfleet.coordinator.world import World
from gridfleet.coordinator.zones import ZoneBook, zone_refusal
from gridfleet.errors import ProtocolError
from gridfleet.grid import Cell
from gridfleet.paths import UNREACHABLE, DistanceFieldCache
from gridfleet.protocol import (
    CancelJob,
    ClearObstacles,
    CloseZone,
    ControlUnit,
    OpenZone,
    RemoveUnit,
    SetGoal,
    SubmitJob,
)
from gridfleet.protocol.constants import MAX_OPEN_JOBS, MAX_OPEN_JOBS_PER_ACCOUNT
from gridfleet.protocol.messages import RefusalCode, Request, UnitControlState


@dataclass(frozen=True)
class Outcome:
    """The answer to a request: accepted or not, why (or, for an accepted `remove_unit`, what
    became of its job), and the job it concerns."""

    accepted: bool
    reason: str | None = None
    job_id: str | None = None
    code: RefusalCode | None = None  # why it was refused, for machines (Reply.code)


@dataclass
class RequestContext:
    """What a request's handler reads and changes, the same for every kind of request."""

    world: World
    jobs: JobBook
    directives: Directives
    cache: DistanceFieldCache  # distances on the map as it is
    step_no: int
    sender: str | None  # the request's header.sender
    # The sender's account and how many of its jobs are not finished yet (None: no sender),
    # worked out only when a handler asks (a submit).
    account: Callable[[], tuple[str, int] | None]
    requeue: Callable[[Job, str], None]  # a job back to the queue, with the reason
    # What the handler changed beyond the job book: a unit's control (None: lifted), squares
    # that are no obstacle any more.
    controls: list[tuple[str, UnitControlState | None]] = field(default_factory=list)
    cleared: list[Cell] = field(default_factory=list)
    now: float = 0.0  # the core's clock (monotonic seconds): whether a unit is heard from
    removed: list[str] = field(default_factory=list)  # units removed for good: to forget
    energy: EnergyPolicy | None = None  # who charges where: `charge` asks it (energy.py)
    zones: ZoneBook | None = None  # the closed zones: closed and opened here (zones.py)
    at: datetime | None = None  # the core's wall clock: when a zone was closed
    actor: str | None = None  # the account owning the sender (without accounts: the sender)


_OUT_OF_SERVICE = "unit {unit} is out of service: put it back in service first"


def submit(req: SubmitJob, ctx: RequestContext) -> Outcome:
    """Queue a job, or refuse it (nothing changes) with the reason."""
    world, jobs, sender = ctx.world, ctx.jobs, ctx.sender
    new = req.job_id is None or jobs.get(req.job_id) is None
    if jobs.open_count >= MAX_OPEN_JOBS and new:
        return Outcome(
            False,
            f"the queue is full: {jobs.open_count} jobs are not finished yet (at most "
            f"{MAX_OPEN_JOBS}); wait for some to finish, or cancel some",
            code="queue_full",
        )
    account = ctx.account() if new else None
    if account is not None and account[1] >= MAX_OPEN_JOBS_PER_ACCOUNT:
        return Outcome(
            False,
            f"too many jobs: account {account[0]!r} has {account[1]} not finished yet (at most "
            f"{MAX_OPEN_JOBS_PER_ACCOUNT} an account); wait for some to finish, or cancel some",
            code="too_many",
        )
    spots = _spots(req, ctx)
    if isinstance(spots, Refusal):
        return Outcome(False, spots.reason, code=spots.code)
    pickup, dropoff = spots
    taken = jobs.get(req.job_id) if req.job_id is not None else None
    if taken is not None:
        if not _same_job(taken, req, sender):
            return Outcome(False, f"job id {taken.id!r} is taken", taken.id, "conflict")
        # The same job again from the same client (a retry whose first answer is forgotten):
        # answered as it was then, and nothing changes.
        if taken.state == "rejected":
            return Outcome(False, taken.reason, taken.id, taken.refusal or "too_heavy")
        return Outcome(True, None, taken.id)
    closed = _in_closed_zone(pickup, dropoff, ctx)
    if closed is not None:
        return Outcome(False, closed, code="zone_closed")
    job_id = req.job_id or jobs.new_id()
    job = Job(
        id=job_id,
        pickup=pickup.square,
        dropoff=dropoff.square,
        mass_kg=req.mass_kg,
        priority=req.priority,
        submitted_by=sender,
        created_step=ctx.step_no,
        pickup_place=pickup.place,
        dropoff_place=dropoff.place,
    )
    refusal = _cannot(job, ctx) if world.fleet_known() else None  # else allocation judges it
    if refusal is not None:
        # Listed as rejected (not merely refused) so the queue view shows why.
        job.state = "rejected"
        job.reason = refusal.reason
        job.refusal = refusal.code
        jobs.add(job)
        return Outcome(False, refusal.reason, job_id, refusal.code)
    jobs.add(job)
    return Outcome(True, None, job_id)


def _spots(req: SubmitJob, ctx: RequestContext) -> tuple[Spot, Spot] | Refusal:
    """The job's pickup and dropoff (places resolved by name), each a free square of the map
    and no charger's; or why not."""
    spots = []
    chargers = {c.square: c.name for c in ctx.world.chargers}
    asked: tuple[tuple[Role, Cell | str], ...] = (("pickup", req.pickup), ("dropoff", req.dropoff))
    for role, where in asked:
        spot = ctx.world.named.resolve(where, role)
        if isinstance(spot, Refusal):
            return spot
        what = role if spot.place is None else f"{role} {spot.place}"
        try:
            ctx.world.check_square(spot.square, what)
        except ProtocolError as exc:
            return Refusal("bad_square", str(exc))
        name = chargers.get(spot.square)
        if name is not None:
            return Refusal(
                "bad_square",
                f"{what} {list(spot.square)} is charger {name}: a unit charging there would "
                "block it",
            )
        spots.append(spot)
    return spots[0], spots[1]


def _cannot(job: Job, ctx: RequestContext) -> Refusal | None:
    """Why no unit of the fleet could ever do `job` (too heavy, or out of every capable unit's
    reach), or None."""
    world = ctx.world
    heavy = capacity_reason(job.mass_kg, world.capacities())
    if heavy is not None:
        return Refusal("too_heavy", heavy)
    far = reach_reason(ctx.cache, job.pickup, job.dropoff, job.mass_kg, world.carriers())
    return None if far is None else Refusal("unreachable", far)


def _same_job(job: Job, req: SubmitJob, sender: str | None) -> bool:
    """Whether `req` from `sender` asks for exactly `job` (a place by the same name)."""
    pickup = job.pickup if job.pickup_place is None else job.pickup_place
    dropoff = job.dropoff if job.dropoff_place is None else job.dropoff_place
    return (pickup, dropoff, job.mass_kg, job.priority, job.submitted_by) == (
        req.pickup,
        req.dropoff,
        req.mass_kg,
        req.priority,
        sender,
    )


def cancel(req: CancelJob, ctx: RequestContext) -> Outcome:
    """Cancel a queued job or abort an active one; refuse unknown and final jobs."""
    world, jobs = ctx.world, ctx.jobs
    job = jobs.get(req.job_id)
    if job is None:
        return Outcome(False, f"unknown job {req.job_id!r}", req.job_id, "unknown_job")
    if job.final:
        return Outcome(False, f"job {job.id} is already {job.state}", job.id, "conflict")
    who = ctx.sender or "an operator"
    if job.state in CARRYING_STATES and job.unit is not None:
        rec = world.units.get(job.unit)
        if world.grid.is_free(job.pickup):
            where = f"at its pickup {list(job.pickup)}"
        else:  # the pickup is blocked now: put down where it stands (returns.py)
            where = f"where it stands ({list(rec.position) if rec and rec.position else '?'})"
        reason = f"cancelled by {who}; unit {job.unit} puts the item back {where}, then is free"
    elif job.unit is not None:
        reason = f"cancelled by {who}; unit {job.unit} released"
    else:
        reason = f"cancelled by {who}"
    jobs.set(job, "cancelled", reason=reason, done_step=ctx.step_no)
    return Outcome(True, None, job.id)


def set_goal(req: SetGoal, ctx: RequestContext) -> Outcome:
    """Pin a unit to a square (or clear its goal); refuse unknown units and bad squares."""
    world, directives = ctx.world, ctx.directives
    rec = world.units.get(req.unit)
    if rec is None or rec.state is None:
        return Outcome(False, f"unknown unit {req.unit!r}", code="unknown_unit")
    if req.target is None:
        directives.set_goal(req.unit, None)
        return Outcome(True)
    try:
        world.check_square(req.target, "target")
    except ProtocolError as exc:
        return Outcome(False, str(exc), code="bad_square")
    closed = zone_refusal(ctx.zones, req.target, "target")
    if closed is not None:
        return Outcome(False, closed, code="zone_closed")
    if rec.position is not None and ctx.cache.distance(rec.position, req.target) == UNREACHABLE:
        why = f"unit {req.unit} cannot reach {list(req.target)}"
        return Outcome(False, why, code="unreachable")
    directives.set_goal(req.unit, req.target)
    job = ctx.jobs.of_unit(req.unit)
    if job is not None and job.state not in CARRYING_STATES:
        # The goal pins the unit: its job goes back to the queue for another unit (unless the
        # unit's next state shows it had picked the item up already: progress.py adopts it).
        ctx.requeue(job, f"unit {req.unit} sent to a goal")
    return Outcome(True)


def control(req: ControlUnit, ctx: RequestContext) -> Outcome:
    """Pause or resume a unit, take it out of service or back (protocol.md §6.4)."""
    if req.command == "charge":
        return _charge(req, ctx)
    before = ctx.directives.controls.get(req.unit)
    outcome = _control(req, ctx.world, ctx.jobs, ctx.directives)
    after = ctx.directives.controls.get(req.unit)
    if after != before:
        ctx.controls.append((req.unit, after))
    return outcome


def _charge(req: ControlUnit, ctx: RequestContext) -> Outcome:
    """Send a unit to charge (protocol.md §6.4): as soon as it carries nothing (a job not picked
    up yet goes back to the queue), to full_pct, then it works again."""
    unit, energy = req.unit, ctx.energy
    rec = ctx.world.units.get(unit)
    if rec is None:
        return Outcome(False, f"unknown unit {unit!r}", code="unknown_unit")
    if (
        rec.factsheet is None
        or rec.factsheet.energy is None
        or rec.state is None
        or rec.state.battery_pct is None
    ):
        why = f"unit {unit} reports no energy: it has nothing to charge"
        return Outcome(False, why, code="invalid")
    if energy is None or not energy.chargers.chargers:
        return Outcome(False, "the map has no chargers", code="invalid")
    if ctx.directives.controls.get(unit) == "out_of_service":
        return Outcome(False, _OUT_OF_SERVICE.format(unit=unit), code="conflict")
    if not ctx.world.is_active(rec, ctx.now):
        return Outcome(False, f"unit {unit} is not heard from", code="conflict")
    stranded = energy.cannot_charge(
        unit, rec.state.position, rec.state.battery_pct, ctx.cache.distance
    )
    if stranded is not None:
        why = f"unit {unit} cannot be sent to charge: {stranded}"
        return Outcome(False, why, code="unreachable")
    job = ctx.jobs.of_unit(unit)
    if job is not None and job.state not in CARRYING_STATES:
        ctx.requeue(job, f"unit {unit} sent to charge by {ctx.sender or 'an operator'}")
    energy.force(unit)
    return Outcome(True)


def _control(req: ControlUnit, world: World, jobs: JobBook, directives: Directives) -> Outcome:
    unit = req.unit
    if world.units.get(unit) is None:
        return Outcome(False, f"unknown unit {unit!r}", code="unknown_unit")
    held = directives.controls.get(unit)
    if req.command == "pause":
        if held == "out_of_service":
            return Outcome(False, _OUT_OF_SERVICE.format(unit=unit), code="conflict")
        directives.set_control(unit, "paused")
    elif req.command == "resume":
        if held != "paused":
            why = f"unit {unit} is not paused" + (" (out of service)" if held else "")
            return Outcome(False, why, code="conflict")
        directives.set_control(unit, None)
    elif req.command == "out_of_service":
        directives.set_control(unit, "out_of_service")
        job = jobs.of_unit(unit)
        if job is not None and job.state not in CARRYING_STATES:
            jobs.set(job, "queued", unit=None, reason=f"unit {unit} out of service; re-queued")
    else:
        if held != "out_of_service":
            return Outcome(False, f"unit {unit} is not out of service", code="conflict")
        directives.set_control(unit, None)
    return Outcome(True)


def clear_obstacles(req: ClearObstacles, ctx: RequestContext) -> Outcome:
    """Forget discovered obstacles an operator says are gone (the squares cleared: `ctx.cleared`).

    Refused, changing nothing, when a square named is not a discovered obstacle (a typo must not
    pass for done). A unit that still sees one reports it again at its next state.
    """
    world = ctx.world
    if req.squares is not None:
        unknown = [c for c in req.squares if c not in world.obstacles]
        if unknown:
            known = ", ".join(str(list(c)) for c in sorted(world.obstacles)[:10]) or "none"
            why = f"{list(unknown[0])} is not a discovered obstacle (known: {known})"
            return Outcome(False, why, code="bad_square")
    ctx.cleared += world.clear_obstacles(req.squares)
    return Outcome(True)


def remove(req: RemoveUnit, ctx: RequestContext) -> Outcome:
    """Forget a lost unit an operator says is off the floor (protocol.md §6.11); its job goes
    back to the queue, or fails when the item left with the unit. Refused for a unit heard from."""
    world, jobs, unit = ctx.world, ctx.jobs, req.unit
    rec = world.units.get(unit)
    if rec is None:
        return Outcome(False, f"unknown unit {unit!r}", code="unknown_unit")
    if world.is_active(rec, ctx.now):
        return Outcome(
            False,
            f"unit {unit} is online and heard from: only a lost unit (offline, broken or "
            "silent) can be removed; take it out of service and switch it off first",
            code="conflict",
        )
    who = ctx.sender or "an operator"
    job = jobs.of_unit(unit)
    where = f", last seen at {list(rec.position)}" if rec.position is not None else ""
    if job is None:
        fate = f"unit {unit} removed; it had no job"
    elif job.state in CARRYING_STATES:
        reason = f"unit {unit} was removed by {who} carrying the item{where}: the item left with it"
        jobs.set(job, "failed", reason=reason, done_step=ctx.step_no)
        fate = f"unit {unit} removed; job {job.id} failed: the item left with it"
    else:
        # Not through ctx.requeue: a removed unit never adopts its old job again (§6.11).
        jobs.set(job, "queued", unit=None, reason=f"unit {unit} removed by {who}; re-queued")
        fate = f"unit {unit} removed; job {job.id} back in the queue"
    ctx.removed.append(unit)
    return Outcome(True, fate, None if job is None else job.id)


def _in_closed_zone(pickup: Spot, dropoff: Spot, ctx: RequestContext) -> str | None:
    """Why a job is refused while its pickup or dropoff lies in a closed zone, or None."""
    for role, spot in (("pickup", pickup), ("dropoff", dropoff)):
        what = role if spot.place is None else f"{role} {spot.place}"
        why = zone_refusal(ctx.zones, spot.square, what)
        if why is not None:
            return why
    return None


def close_zone(req: CloseZone, ctx: RequestContext) -> Outcome:
    """Close a rectangle of squares (protocol.md §6.12); a zone closed again as it is changes
    nothing, closed otherwise is refused (open it first)."""
    if ctx.zones is None or ctx.at is None:
        return Outcome(False, "this coordinator keeps no zones", code="invalid")
    decision = ctx.zones.close(req, ctx.actor or ctx.sender, ctx.at)
    return Outcome(decision.accepted, decision.reason, code=decision.code)


def open_zone(req: OpenZone, ctx: RequestContext) -> Outcome:
    """Open a closed zone again (protocol.md §6.13); refused for a zone not closed."""
    if ctx.zones is None:
        return Outcome(False, "this coordinator keeps no zones", code="invalid")
    decision = ctx.zones.open(req.name)
    return Outcome(decision.accepted, decision.reason, code=decision.code)


# Each operator request's handler (each takes its own kind of request).
HANDLERS: dict[type[Request], Callable[[Any, RequestContext], Outcome]] = {
    SubmitJob: submit,
    CancelJob: cancel,
    SetGoal: set_goal,
    ControlUnit: control,
    ClearObstacles: clear_obstacles,
    RemoveUnit: remove,
    CloseZone: close_zone,
    OpenZone: open_zone,
}
