"""Jobs and their life cycle (protocol.md §5.3, §6): pure, no storage, no clock.

queued → assigned → to_pickup → loaded → to_dropoff → done; or cancelled / rejected / failed.
The queue view lists the jobs not finished, the latest finished ones and jobs done per minute, so
its size does not grow with the jobs that ever finished.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Collection
from dataclasses import asdict, dataclass
from typing import Any

from gridfleet.grid import Cell
from gridfleet.protocol import Header, JobsView, JobView
from gridfleet.protocol.messages import (
    CHART_MINUTES,
    FINAL_JOB_STATES,
    FINISHED_LISTED,
    JobState,
    RefusalCode,
    WaitCode,
)

ACTIVE_STATES = frozenset({"assigned", "to_pickup", "loaded", "to_dropoff"})
CARRYING_STATES = frozenset({"loaded", "to_dropoff"})


@dataclass
class Job:
    """One job and where it is in its life cycle."""

    id: str
    pickup: Cell
    dropoff: Cell
    mass_kg: float
    priority: int = 0
    state: JobState = "queued"
    unit: str | None = None
    reason: str | None = None
    submitted_by: str | None = None
    created_step: int = 0
    done_step: int | None = None
    order: int = 0  # submission order, so views and allocation are stable
    wait: WaitCode | None = None  # why it waits, while it is not final
    wait_reason: str | None = None  # the same in words
    pickup_place: str | None = None  # the place its pickup was named by (None: a square)
    dropoff_place: str | None = None
    refusal: RefusalCode | None = None  # why it was rejected, for machines (Reply.code)

    @property
    def final(self) -> bool:
        """Done, cancelled, rejected or failed: it never changes again."""
        return self.state in FINAL_JOB_STATES

    def view(self) -> JobView:
        """As the queue view shows it."""
        return JobView(
            id=self.id,
            pickup=self.pickup,
            dropoff=self.dropoff,
            mass_kg=self.mass_kg,
            priority=self.priority,
            state=self.state,
            unit=self.unit,
            reason=self.reason,
            submitted_by=self.submitted_by,
            created_step=self.created_step,
            done_step=self.done_step,
            wait=None if self.final else self.wait,
            wait_reason=None if self.final else self.wait_reason,
            pickup_place=self.pickup_place,
            dropoff_place=self.dropoff_place,
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain data for storage."""
        d = asdict(self)
        d["pickup"] = list(self.pickup)
        d["dropoff"] = list(self.dropoff)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Job:
        """Inverse of to_dict (a row stored before places and refusal codes loads without them)."""
        d = dict(d)
        if d["state"] == "rejected" and d.get("refusal") is None:  # rejected before 1.6
            too_heavy = "exceeds every unit's capacity" in (d.get("reason") or "")
            d["refusal"] = "too_heavy" if too_heavy else "unreachable"
        d["pickup"] = Cell(*d["pickup"])
        d["dropoff"] = Cell(*d["dropoff"])
        return cls(**d)


class JobBook:
    """Every job the coordinator knows, in submission order; `changed` lists jobs to persist."""

    def __init__(self, jobs: list[Job] | None = None) -> None:
        self.jobs: dict[str, Job] = {}
        self.changed: set[str] = set()
        self._next = 1
        self._counts: Counter[JobState] = Counter()
        self._finished: deque[str] = deque(maxlen=FINISHED_LISTED)  # ids, the newest last
        self._done_steps: deque[int] = deque()  # when jobs were done, oldest first
        # Indexes, so a step costs the jobs open, not every job ever finished (it grows all day).
        self._open: dict[str, Job] = {}  # not final, in submission order
        self._held: dict[str, Job] = {}  # unit -> the job it works on
        self._open_by: Counter[str | None] = Counter()  # jobs not final per submitter
        for job in sorted(jobs or [], key=lambda j: j.order):
            self.jobs[job.id] = job
            self._counts[job.state] += 1
            self._index(job, None)
        self._next = 1 + max((j.order for j in self.jobs.values()), default=0)
        ended = sorted(
            (j for j in self.jobs.values() if j.final),
            key=lambda j: (j.done_step if j.done_step is not None else j.created_step, j.order),
        )
        for job in ended:
            self._ended(job)

    def _index(self, job: Job, held_by: str | None) -> None:
        """Bring the indexes up to `job`, which unit `held_by` worked on before the change."""
        if job.final:
            if self._open.pop(job.id, None) is not None:
                self._open_by[job.submitted_by] -= 1
                if not self._open_by[job.submitted_by]:
                    del self._open_by[job.submitted_by]
        else:
            if job.id not in self._open:
                self._open_by[job.submitted_by] += 1
            self._open[job.id] = job
        if held_by is not None and self._held.get(held_by) is job:
            del self._held[held_by]
            # Two jobs on one unit is a bug elsewhere, but the other one must not be forgotten.
            other = next((j for j in self.active() if j.unit == held_by), None)
            if other is not None:
                self._held[held_by] = other
        if job.state in ACTIVE_STATES and job.unit is not None:
            self._held.setdefault(job.unit, job)

    def _ended(self, job: Job) -> None:
        self._finished.append(job.id)
        if job.state == "done" and job.done_step is not None:
            self._done_steps.append(job.done_step)

    def new_id(self) -> str:
        """A free id `job-<n>`."""
        n = self._next
        while f"job-{n}" in self.jobs:
            n += 1
        return f"job-{n}"

    def add(self, job: Job) -> Job:
        """Register a new job (its id must be free)."""
        if job.id in self.jobs:
            raise ValueError(f"job id {job.id!r} is taken")
        job.order = self._next
        self._next += 1
        self.jobs[job.id] = job
        self._counts[job.state] += 1
        self._index(job, None)
        if job.final:  # refused at submission: listed as finished at once
            self._ended(job)
        self.changed.add(job.id)
        return job

    def get(self, job_id: str) -> Job | None:
        """The job with `job_id`, if any."""
        return self.jobs.get(job_id)

    def set(self, job: Job, state: JobState, **fields: Any) -> None:
        """Move `job` to `state` (and set other fields); final jobs never change."""
        if job.final:
            raise ValueError(f"job {job.id} is already {job.state}")
        self._counts[job.state] -= 1
        self._counts[state] += 1
        held_by = job.unit if job.state in ACTIVE_STATES else None
        job.state = state
        for key, value in fields.items():
            setattr(job, key, value)
        self._index(job, held_by)
        if job.final:
            self._ended(job)
        self.changed.add(job.id)

    def explain(self, job: Job, wait: tuple[WaitCode, str] | None) -> None:
        """Say why `job` waits (code, words), or that it does not; listed as changed if new."""
        code, words = wait or (None, None)
        if (job.wait, job.wait_reason) != (code, words):
            job.wait, job.wait_reason = code, words
            self.changed.add(job.id)

    def counts(self) -> dict[JobState, int]:
        """How many jobs are in each state (those with none left out)."""
        return {state: n for state, n in self._counts.items() if n > 0}

    @property
    def open_count(self) -> int:
        """Jobs not final (queued or under way)."""
        return len(self._open)

    def open_by_submitter(self) -> Counter[str | None]:
        """Jobs not final, per the sender that submitted them."""
        return self._open_by

    def queued(self) -> list[Job]:
        """Jobs waiting for a unit, in submission order."""
        return [j for j in self._open.values() if j.state == "queued"]

    def active(self) -> list[Job]:
        """Jobs under way (assigned to a unit)."""
        return [j for j in self._open.values() if j.state in ACTIVE_STATES]

    def busy_units(self) -> Collection[str]:
        """The units working on a job."""
        return self._held.keys()

    def of_unit(self, unit_id: str) -> Job | None:
        """The job `unit_id` is working on, if any."""
        return self._held.get(unit_id)

    def view(self, header: Header, step_no: int = 0, step_period_s: float = 1.0) -> JobsView:
        """The retained queue view at coordinator step `step_no`."""
        finished = [self.jobs[i] for i in reversed(self._finished)]
        return JobsView(
            header=header,
            jobs=[j.view() for j in self._open.values()],
            finished=[j.view() for j in finished],
            counts=self.counts(),
            done_per_minute=self.done_per_minute(step_no, step_period_s),
        )

    def done_per_minute(self, step_no: int, step_period_s: float) -> list[int]:
        """Jobs done in each of the last CHART_MINUTES minutes of steps, the current one last."""
        per_minute = max(1, round(60 / step_period_s))  # steps in a minute
        done = self._done_steps
        while done and (step_no - done[0]) // per_minute >= CHART_MINUTES:
            done.popleft()
        counts = [0] * CHART_MINUTES
        for at in done:
            ago = (step_no - at) // per_minute
            if 0 <= ago < CHART_MINUTES:
                counts[CHART_MINUTES - 1 - ago] += 1
        return counts
