"""The job history (protocol.md §6.10): every change in a job's life, with its time.

Pure: the shell hands over the jobs each input changed and the wall-clock time, and stores the
entries returned (a query is answered as the audit's is: records.py). A change is a new state, a
new unit or a new reason to wait: a job that waits for the same reason step after step is one
entry, not one a step.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from datetime import datetime

from gridfleet.coordinator.jobs import Job
from gridfleet.protocol.messages import JobHistoryEntry

# What makes an entry: (state, unit, wait code).
Key = tuple[str, str | None, str | None]
# A job's last entry and when it was submitted, as the store has them (None: never recorded).
Lookup = Callable[[str], tuple[Key, datetime] | None]
DEFAULT_RETENTION_DAYS = 400.0  # a year, and the same weeks of the year before


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
        pickup_place=job.pickup_place,
        dropoff_place=job.dropoff_place,
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
