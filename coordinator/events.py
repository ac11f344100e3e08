"""The coordinator's recent history in plain words (`fleet/events`, protocol.md §5.7).

Pure: the core tells it what changed and when (a datetime from its stamper's clock); it keeps at
most MAX_EVENTS, says which are new (to store), and whether the view is out of date.

What it keeps is not simply the latest: the stop's engagements and units lost are safety history,
so chatter never pushes them out (only newer ones do, past SAFETY_EVENTS), and a unit's lines
are at most UNIT_EVENTS per unit, so one flapping unit cannot push out everybody else's (as found:
120 flaps of one unit left no trace of who engaged the stop).
"""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime

from gridfleet.coordinator.jobs import Job
from gridfleet.coordinator.places import Spot
from gridfleet.protocol import EventEntry, EventsView, Header
from gridfleet.protocol.constants import MAX_TEXT
from gridfleet.protocol.messages import MAX_EVENTS, EventKind

SAFETY_EVENTS = 50  # stop and loss lines kept whatever else happens (the latest this many)
UNIT_EVENTS = 4  # a unit's latest online/offline/lost lines kept
_LOST = "lost (its connection broke)"  # its will; "lost (no state for ...)": fell silent
_HEARD = "heard again"


def _is_safety(entry: EventEntry) -> bool:
    """A stop engaged or released, a unit lost or removed, a zone closed or opened: what a person
    asks about afterwards."""
    lost = " lost (" in entry.text or " removed by " in entry.text
    zoned = entry.text.startswith("zone ") and (
        " closed by " in entry.text or " opened by " in entry.text
    )
    return (
        entry.kind == "stop" or (entry.kind == "unit" and lost) or (entry.kind == "zone" and zoned)
    )


def _kg(mass: float) -> str:
    return f"{mass:g} kg"


class EventLog:
    """The latest events, oldest first; `fresh` holds those not stored yet."""

    def __init__(self) -> None:
        self.events: list[EventEntry] = []
        self.fresh: list[EventEntry] = []
        self.dirty = False
        self._jobs: dict[str, tuple[str, str | None]] = {}  # job -> (state, unit) last told
        # Jobs from before a restart: their steps count from another run, so no duration.
        self._earlier: set[str] = set()

    def restore(self, events: Iterable[EventEntry]) -> None:
        """The history kept before a restart (oldest first); the view goes out again."""
        for entry in events:
            self._keep(entry)
        self.dirty = True

    def _keep(self, entry: EventEntry) -> None:
        """Append `entry`, then drop what the retention rules above say is least worth keeping."""
        self.events.append(entry)
        if entry.kind == "unit" and entry.unit is not None:
            mine = [e for e in self.events if e.kind == "unit" and e.unit == entry.unit]
            if len(mine) > UNIT_EVENTS:
                self.events.remove(mine[0])
        while len(self.events) > MAX_EVENTS:
            safety = [e for e in self.events if _is_safety(e)]
            chatter = [e for e in self.events if not _is_safety(e)]
            oldest = safety[0] if len(safety) > SAFETY_EVENTS or not chatter else chatter[0]
            self.events.remove(oldest)

    def know(self, jobs: Iterable[Job]) -> None:
        """Jobs as they stand (loaded from the store): only later changes are events."""
        for job in jobs:
            self._jobs[job.id] = (job.state, job.unit)
            self._earlier.add(job.id)

    def add(
        self,
        at: datetime,
        kind: EventKind,
        text: str,
        job: str | None = None,
        unit: str | None = None,
    ) -> None:
        """One event, its text cut to one protocol text's length."""
        line = " ".join(text.split())[:MAX_TEXT]
        entry = EventEntry(at=at, kind=kind, text=line, job=job, unit=unit)
        self._keep(entry)
        self.fresh.append(entry)
        self.dirty = True

    def jobs_changed(self, at: datetime, jobs: Iterable[Job], step_period_s: float) -> None:
        """An event for each job whose state or unit changed since it was last told."""
        for job in jobs:
            before = self._jobs.get(job.id)
            now = (job.state, job.unit)
            if before == now:
                continue
            self._jobs[job.id] = now
            text = self._job_text(job, before, step_period_s)
            if text is not None:
                self.add(at, "job", text, job=job.id, unit=job.unit)

    def _job_text(
        self, job: Job, before: tuple[str, str | None] | None, step_period_s: float
    ) -> str | None:
        """What happened to `job`, in words; None when nothing worth telling (a re-plan)."""
        name = f"job {job.id}"
        if before is None:
            if job.state == "rejected":
                return None  # refused as it came: the refusal event says why, naming the job
            by = f" by {job.submitted_by}" if job.submitted_by else ""
            return (
                f"{name} queued{by} ({_kg(job.mass_kg)}, "
                f"{Spot(job.pickup, job.pickup_place).words()} -> "
                f"{Spot(job.dropoff, job.dropoff_place).words()})"
            )
        state, unit = before
        if job.state == "done":
            took = ""
            if job.done_step is not None and job.id not in self._earlier:
                took = f" in {(job.done_step - job.created_step) * step_period_s:.1f} s"
            return f"{name} done by {job.unit or unit}{took}"
        if job.state in ("cancelled", "failed", "rejected"):
            why = job.reason or ""
            if why.startswith(job.state):  # "cancelled by op; ...": said once, not twice
                return f"{name} {why}"
            return f"{name} {job.state}" + (f": {why}" if why else "")
        if job.state in ("loaded", "to_dropoff") and state not in ("loaded", "to_dropoff"):
            return f"{job.unit} picked up {name}"
        if job.unit is not None and job.unit != unit and job.state in ("assigned", "to_pickup"):
            return f"{name} assigned to {job.unit}"
        if job.state == "queued" and state != "queued":
            why = (job.reason or "").removesuffix("; re-queued")
            return f"{name} back in the queue" + (f": {why}" if why else "")
        return None

    def unit_changed(self, at: datetime, unit: str, connection: str) -> None:
        """A unit came online, went offline, was lost (its last will) or was heard again."""
        words = {"online": "online", "offline": "offline", "broken": _LOST, "heard": _HEARD}
        self.add(at, "unit", f"unit {unit} {words.get(connection, connection)}", unit=unit)

    def unit_silent(self, at: datetime, unit: str, silent_s: float) -> None:
        """A unit still `online` whose states stopped: lost to the fleet (protocol.md §8)."""
        self.add(at, "unit", f"unit {unit} lost (no state for {silent_s:.1f} s)", unit=unit)

    def take(self, header: Header) -> EventsView:
        """The view, which counts as sent from here on (the caller checks `dirty` first)."""
        self.dirty = False
        return EventsView(header=header, events=list(self.events))

    def take_fresh(self) -> tuple[EventEntry, ...]:
        """The events not stored yet (they count as stored from here on)."""
        fresh, self.fresh = tuple(self.fresh), []
        return fresh
