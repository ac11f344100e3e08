"""The job history (protocol.md §6.10): every change in a job's life, with its time.

Pure: the shell hands over the jobs each input changed and the wall-clock time, and stores the
entries returned; a query is checked here before the store runs it. A change is a new state, a
new unit or a new reason to wait: a job that waits for the same reason step after step is one
entry, not one a step.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from datetime import datetime, timedelta

from gridfleet.coordinator.jobs import Job
from gridfleet.protocol.messages import JobHistoryEntry, JobHistoryQuery

# What makes an entry: (state, unit, wait code).
Key = tuple[str, str | None, str | None]
# A job's last entry and when it was submitted, as the store has them (None: never recorded).
Lookup = Callable[[str], tuple[Key, datetime] | None]
DEFAULT_RETENTION_DAYS = 400.0  # a year, and the same weeks of the year before
MAX_RANGE = timedelta(days=3660)  # ten years: anything longer is a mistake in the dates


def key_of(job: Job) -> Key:
    """What an entry records of `job`: a change in any of it is a new entry."""
    return (job.state, job.unit, None if job.final else job.wait)


def entry_of(job: Job, at: datetime, submitted_at: datetime) -> JobHistoryEntry:
    """`job` as it is at `at`, submitted at `submitted_at`."""
    reason = job.reason if job.final else (job.wait_reason or job.reason)
    return JobHistoryEntry(
        at=at,
        job=job.id,
        state=job.state,
        unit=job.unit,
        wait=None if job.final else job.wait,
        reason=reason,
        since_submitted_s=round(max(0.0, (at - submitted_at).total_seconds()), 3),
        pickup=job.pickup,
        dropoff=job.dropoff,
        mass_kg=job.mass_kg,
        priority=job.priority,
        submitted_by=job.submitted_by,
    )


class JobChanges:
    """Turns the jobs an input changed into history entries, one per real change."""

    def __init__(self, lookup: Lookup) -> None:
        self._lookup = lookup  # a job not seen since the start (restored): its stored last entry
        self._known: dict[str, tuple[Key, datetime]] = {}  # open jobs only: bounded

    def entries(self, jobs: Iterable[Job], at: datetime) -> list[JobHistoryEntry]:
        """The entries for `jobs`, changed at `at` (a job whose entry would repeat is left out)."""
        out = []
        for job in jobs:
            known = self._known.get(job.id) or self._lookup(job.id)
            key = key_of(job)
            if known is not None and known[0] == key:
                self._remember(job, known)
                continue
            submitted_at = known[1] if known is not None else at
            out.append(entry_of(job, at, submitted_at))
            self._remember(job, (key, submitted_at))
        return out

    def _remember(self, job: Job, known: tuple[Key, datetime]) -> None:
        if job.final:
            self._known.pop(job.id, None)  # it never changes again
        else:
            self._known[job.id] = known


def range_problem(query: JobHistoryQuery, now: datetime) -> str | None:
    """Why the query's time range cannot be answered, in one line; None when it can."""
    until = query.until or now
    for name, at in (("since", query.since), ("until", query.until)):
        if at is not None and at.tzinfo is None:
            return f"{name} {at.isoformat()} has no time zone: add one (Z for UTC)"
    if query.since >= until:
        return f"since {_iso(query.since)} is not before until {_iso(until)}"
    if until - query.since > MAX_RANGE:
        return f"since {_iso(query.since)} to until {_iso(until)} spans more than ten years"
    return None


def _iso(at: datetime) -> str:
    return at.isoformat().replace("+00:00", "Z")
