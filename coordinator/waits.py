"""Why each job that is not final waits (protocol.md §5.3): a code and the same in words.

Pure: the job book, the unit records and whether the fleet is stopped in; one (code, words) or
None per job out. A person looking at the queue should never have to guess.
"""

from __future__ import annotations

from coordinator.jobs import Job, JobBook
from coordinator.world import UnitRecord

Wait = tuple[str, str]  # (WaitCode, words)


def why_waiting(
    job: Job,
    jobs: JobBook,
    units: dict[str, UnitRecord],
    active: set[str],
    pinned: frozenset[str] | set[str] = frozenset(),
) -> Wait | None:
    """Why `job` is not moving on now, or None when nothing holds it up (`pinned`: units held
    at a goal, which take no jobs)."""
    if job.state == "queued":
        return _why_queued(job, jobs, units, active, pinned)
    rec = units.get(job.unit or "")
    if rec is None or rec.state is None:
        return None
    if rec.id not in active:
        return ("unit_away", f"its unit {rec.id} is not heard from ({rec.connection or 'silent'})")
    if rec.state.status == "waiting":
        why = rec.state.wait_reason or "its way is blocked"
        return ("unit_waiting", f"its unit {rec.id} waits: {why}")
    return None


def _why_queued(
    job: Job,
    jobs: JobBook,
    units: dict[str, UnitRecord],
    active: set[str],
    pinned: frozenset[str] | set[str],
) -> Wait | None:
    capable = sorted(
        u.id
        for u in units.values()
        if u.factsheet is not None and u.factsheet.capacity_kg >= job.mass_kg
    )
    online = [u for u in capable if u in active]
    if not online:
        away = ", ".join(capable) or "none known"
        return ("no_capable_unit", f"no unit that can carry {job.mass_kg} kg is online ({away})")
    busy = {j.unit for j in jobs.active()}
    free = [u for u in online if u not in busy and u not in pinned and _takes_jobs(units[u])]
    if free:
        return None  # one of them gets it at the next allocation
    return (
        "no_unit_free",
        f"every unit that can carry {job.mass_kg} kg is busy ({', '.join(online)})",
    )


def _takes_jobs(rec: UnitRecord) -> bool:
    st = rec.state
    return st is not None and st.job_id is None and st.mode == "coordinated" and not st.estop


def explain_waits(
    jobs: JobBook,
    units: dict[str, UnitRecord],
    active: set[str],
    pinned: set[str],
    stopped: bool,
) -> None:
    """Set every non-final job's wait (the book lists the jobs whose wait changed)."""
    for job in [*jobs.queued(), *jobs.active()]:
        if stopped:
            jobs.explain(job, ("fleet_stopped", "the emergency stop is engaged"))
        else:
            jobs.explain(job, why_waiting(job, jobs, units, active, pinned))
