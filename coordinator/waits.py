"""Why each job that is not final waits (protocol.md §5.3): a code and the same in words.

Pure: the job book, the unit records, the units held (at a goal, paused, out of service) and
whether the fleet is stopped in; one (code, words) or None per job out. A person looking at the
queue should never have to guess.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from typing import Protocol

from gridfleet.coordinator.jobs import Job, JobBook
from gridfleet.coordinator.world import UnitRecord, World
from gridfleet.grid import Cell, Direction
from gridfleet.protocol.constants import MAX_TEXT
from gridfleet.protocol.messages import WaitCode

Wait = tuple[WaitCode, str]  # (code, words)
_CONTROL_WORDS = {"paused": "paused", "out_of_service": "out of service"}
_CONTROL_CODES: dict[str, WaitCode] = {
    "paused": "unit_paused",
    "out_of_service": "unit_out_of_service",
}
NAMED = 8  # units a reason names before "and N more": a hall of 500 must fit in MAX_TEXT


def _named(items: list[str]) -> str:
    """`a, b, c`, or the first NAMED and how many more."""
    if len(items) <= NAMED:
        return ", ".join(items)
    return f"{', '.join(items[:NAMED])} and {len(items) - NAMED} more"


class EnergyWords(Protocol):
    """What the energy policy says of a unit that takes no job for want of charge (energy.py)."""

    def charging_words(self, unit: str) -> str | None:
        """Why `unit` takes no job now for its charge ("charging: 62 % of 80 %"), or None."""
        ...

    def unknown_words(self, unit: str) -> str | None:
        """Why `unit` takes no job while its charge is not known yet, or None."""
        ...

    def short_of(self, unit: str, pickup: Cell, dropoff: Cell) -> tuple[float, float] | None:
        """(its charge, the charge the job needs) when `unit` could not finish it, else None."""
        ...

    def wanted(self, unit: str, needs_pct: float) -> None:
        """A job waits for `unit` to have `needs_pct`: it is to charge for it (energy.py)."""
        ...


# A unit with a job that has not moved for this long (steps, and at least seconds) is stuck, and
# its job says so and names the unit in its way.
STUCK_STEPS, STUCK_MIN_S = 30, 10.0


def stuck_after_s(step_period_s: float) -> float:
    """How long a unit with a job may stand still before its job says it is stuck."""
    return max(STUCK_MIN_S, STUCK_STEPS * step_period_s)


def blocker(
    unit_id: str,
    world: World,
    target: Cell | None,
    distance: Callable[[Cell, Cell], float],
) -> str | None:
    """The unit standing on the square that brings `unit_id` nearest to `target`."""
    rec = world.units.get(unit_id)
    if rec is None or rec.position is None or target is None or target == rec.position:
        return None
    here, grid = rec.position, world.grid
    ahead = [c for c in (here.step(d) for d in Direction) if grid.is_free(c)]
    if not ahead:
        return None
    best = min(ahead, key=lambda c: distance(c, target))
    return next(
        (u.id for u in world.units.values() if u.id != unit_id and u.position == best), None
    )


class StuckNews:
    """Which jobs' units got stuck since the last look (told once, until they move again)."""

    def __init__(self) -> None:
        self._told: set[str] = set()

    def newly_stuck(self, jobs: JobBook) -> list[Job]:
        """The jobs waiting `unit_stuck` now that were not last time."""
        stuck = [j for j in jobs.active() if j.wait == "unit_stuck"]
        new = [j for j in stuck if j.id not in self._told]
        self._told = {j.id for j in stuck}
        return new


@dataclass(frozen=True)
class Stuck:
    """How to tell a unit that has stopped making progress: the time, the threshold, who blocks."""

    now: float
    after_s: float  # a unit with a job not moving for this long is stuck
    blocker: Callable[[str], str | None] = lambda _: None  # the unit in its way, if known
    since: float = float("-inf")  # the fleet moves since (the stop's release): count from then


_SPANS = ((3600, "over an hour"), (600, "over 10 min"), (300, "over 5 min"), (60, "over a minute"))


def _over(seconds: float) -> str:
    """A stand-still in words that change seldom (the view goes out again when they do)."""
    return next((words for limit, words in _SPANS if seconds >= limit), f"{seconds:.0f} s")


def _clipped(wait: Wait | None) -> Wait | None:
    """Words within the protocol's MAX_TEXT (a unit's own reason may already be that long)."""
    if wait is None or len(wait[1]) <= MAX_TEXT:
        return wait
    return (wait[0], wait[1][: MAX_TEXT - 1] + "…")


def explain_waits(
    jobs: JobBook,
    units: Mapping[str, UnitRecord],
    active: Collection[str],
    stopped: bool,
    goals: Collection[str] = (),
    controls: Mapping[str, str] | None = None,
    stuck: Stuck | None = None,
    energy: EnergyWords | None = None,
    zone_wait: Callable[[Job], Wait | None] | None = None,
) -> None:
    """Set every non-final job's wait (the book lists the jobs whose wait changed); `zone_wait`:
    why closed zones hold a job up, if they do (zones.py), before any other reason but the stop."""
    controls = controls or {}
    # A queued job's wait depends on its mass alone (which units could carry it, and are they
    # free): worked out once a mass, not once a job (5,000 queued jobs each listing the active
    # ones stretched the step to half a second). With energy, on its squares too (how far).
    queued_by: dict[tuple[float, Cell | None, Cell | None], Wait | None] = {}
    for job in [*jobs.queued(), *jobs.active()]:
        if stopped:
            jobs.explain(job, ("fleet_stopped", "the emergency stop is engaged"))
        elif zone_wait is not None and (closed := zone_wait(job)) is not None:
            jobs.explain(job, _clipped(closed))
        elif job.state == "queued":
            key = (job.mass_kg, *((job.pickup, job.dropoff) if energy else (None, None)))
            if key not in queued_by:
                queued_by[key] = _clipped(
                    _why_queued(job, jobs, units, active, goals, controls, energy)
                )
            jobs.explain(job, queued_by[key])
        else:
            why = why_waiting(job, jobs, units, active, goals, controls, stuck)
            jobs.explain(job, _clipped(why))


def why_waiting(
    job: Job,
    jobs: JobBook,
    units: Mapping[str, UnitRecord],
    active: Collection[str],
    goals: Collection[str] = (),
    controls: Mapping[str, str] | None = None,
    stuck: Stuck | None = None,
    energy: EnergyWords | None = None,
) -> Wait | None:
    """Why `job` is not moving on now, or None when nothing holds it up."""
    controls = controls or {}
    if job.state == "queued":
        return _why_queued(job, jobs, units, active, goals, controls, energy)
    held = controls.get(job.unit or "")
    if held is not None:
        return (_CONTROL_CODES[held], f"its unit {job.unit} is {_CONTROL_WORDS[held]}")
    rec = units.get(job.unit or "")
    if rec is None or rec.state is None:
        return None
    if rec.id not in active:
        return ("unit_away", f"its unit {rec.id} is not heard from ({rec.connection or 'silent'})")
    if stuck is not None and rec.moved_at is not None:
        still = stuck.now - max(rec.moved_at, stuck.since)
        if still >= stuck.after_s:
            where = list(rec.state.position)
            blocker = stuck.blocker(rec.id)
            why = f"; {blocker} stands where it must go" if blocker else ""
            return (
                "unit_stuck",
                f"its unit {rec.id} has not moved for {_over(still)} at {where}{why}",
            )
    if rec.state.status == "waiting":
        why = rec.state.wait_reason or "its way is blocked"
        return ("unit_waiting", f"its unit {rec.id} waits: {why}")
    return None


def _why_queued(
    job: Job,
    jobs: JobBook,
    units: Mapping[str, UnitRecord],
    active: Collection[str],
    goals: Collection[str],
    controls: Mapping[str, str],
    energy: EnergyWords | None = None,
) -> Wait | None:
    capable = sorted(
        u.id
        for u in units.values()
        if u.factsheet is not None and u.factsheet.capacity_kg >= job.mass_kg
    )
    online = [u for u in capable if u in active]
    if not online:
        away = _named(capable) or "none known"
        return ("no_capable_unit", f"no unit that can carry {job.mass_kg} kg is online ({away})")
    busy = jobs.busy_units()
    why_not = {}
    charging: dict[str, str] = {}  # unit -> "charging: 62 % of 80 %"
    short: dict[str, tuple[float, float]] = {}  # unit -> (its charge, the charge the job needs)
    for u in online:
        if u in controls:
            why_not[u] = _CONTROL_WORDS[controls[u]]
        elif u in goals:
            why_not[u] = "sent to a goal"
        elif u in busy or not _takes_jobs(units[u]):
            why_not[u] = "busy"
        elif energy is not None and (unknown := energy.unknown_words(u)) is not None:
            why_not[u] = unknown
        elif energy is not None:
            words = energy.charging_words(u)
            lacks = None if words is not None else energy.short_of(u, job.pickup, job.dropoff)
            if words is not None:
                charging[u] = why_not[u] = words
            elif lacks is not None:
                short[u] = lacks
                why_not[u] = f"battery too low ({lacks[0]:.0f} %, needs {lacks[1]:.0f} %)"
    if len(why_not) < len(online):
        return None  # a free one gets it at the next allocation
    if all(why == "busy" for why in why_not.values()):
        words = f"every unit that can carry {job.mass_kg} kg is busy ({_named(online)})"
    elif len(charging) + len(short) == len(why_not):
        if charging:
            each = _named([f"{u} {why}" for u, why in charging.items()])
            return (
                "unit_charging",
                f"every unit that can carry {job.mass_kg} kg is charging ({each})",
            )
        best = max(short, key=lambda u: (short[u][0], u))
        has, needs = short[best]
        if energy is not None:
            energy.wanted(best, needs)  # the unit nearest to it charges for it
        return (
            "battery_low",
            f"battery too low for this job ({best} has {has:.0f} %, needs {needs:.0f} %)",
        )
    else:
        each = _named([f"{u} {why}" for u, why in why_not.items()])
        words = f"no unit that can carry {job.mass_kg} kg is free ({each})"
    return ("no_unit_free", words)


def _takes_jobs(rec: UnitRecord) -> bool:
    st = rec.state
    return st is not None and st.job_id is None and st.mode == "coordinated" and not st.estop
