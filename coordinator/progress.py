"""Job progress (protocol.md §5.3, §8): what units' states say about their jobs, and allocation.

Pure: unit records, the job book and a caller-supplied time in; job state changes out (the book's
`changed` set says which). Lost units: a job not yet picked up goes back to the queue; a job whose
item the unit had already picked up becomes `failed` once the unit has stayed away too long (the
item is on a unit nobody can reach), with a reason naming the unit and the square where it was
last seen. A unit that comes back with an item of a job that is over puts it back (returns.py).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from gridfleet.coordinator.allocation import (
    JobRequest,
    UnitSlot,
    allocate,
    capacity_reason,
    reach_reason,
)
from gridfleet.coordinator.directives import Directives
from gridfleet.coordinator.energy import EnergyStep
from gridfleet.coordinator.jobs import CARRYING_STATES, Job, JobBook
from gridfleet.coordinator.returns import stray_items
from gridfleet.coordinator.world import UnitRecord, World
from gridfleet.grid import Cell
from gridfleet.paths import UNREACHABLE, DistanceFieldCache
from gridfleet.protocol import Action

LOST_CARRYING_STEPS = 20  # stale periods a carrying unit may be silent before its job fails
LOST_CARRYING_MIN_S = 10.0


class JobProgress:
    """Moves jobs along their life cycle from what units report; gives queued jobs to units."""

    def __init__(
        self,
        world: World,
        jobs: JobBook,
        directives: Directives,
    ) -> None:
        self.world = world
        self.jobs = jobs
        self.directives = directives  # goals and controls: read here, a goal reached forgotten
        self.returns: dict[str, Action] = {}  # unit -> putting down an item of a job now over
        # Re-queued jobs and the unit they were given to: only that unit may say it has the item.
        self.requeued_from: dict[str, str] = {}

    def requeue_on_restart(self) -> None:
        """Jobs not picked up yet go back to the queue; carried ones wait for their unit's state."""
        for job in self.jobs.active():
            if job.state not in CARRYING_STATES:
                self.requeue(job, "coordinator restarted; re-queued")

    def requeue(self, job: Job, reason: str) -> None:
        """Put a job not picked up yet back in the queue, remembering the unit it was given to."""
        if job.unit is not None:
            self.requeued_from[job.id] = job.unit
        self.jobs.set(job, "queued", unit=None, reason=reason)

    def forget(self, unit_id: str) -> None:
        """A removed unit (§6.11) adopts none of the jobs once re-queued from it, and puts nothing back."""
        for job_id in [j for j, u in self.requeued_from.items() if u == unit_id]:
            del self.requeued_from[job_id]
        self.returns.pop(unit_id, None)

    def advance(self, units: list[UnitRecord], active: set[str], now: float, step_no: int) -> None:
        """Pick-ups, drop-offs, refusals, lost units and goals reached, from the latest states."""
        self._adopt_carried(units, active)
        self._progress_jobs(units, active, now, step_no)
        self.returns = stray_items(units, active, self.jobs, self.world.grid)
        self.directives.goals_reached({u.id: u.position for u in self.world.units.values()})

    def _adopt_carried(self, units: list[UnitRecord], active: set[str]) -> None:
        # A unit that reports carrying a job we think is not picked up yet (it picked the item up
        # just before a coordinator restart, whose store still had the job waiting) has it.
        # A finished job is never queued again: forgotten here, so the map stays as small as the
        # queue (it grew with every job a lost unit ever left behind).
        for job_id in [j for j in self.requeued_from if self._over(j)]:
            del self.requeued_from[job_id]
        for u in units:
            st = u.state
            if st is None or st.job_id is None or u.id not in active:
                continue
            job = self.jobs.get(st.job_id)
            # Only one re-queued from this very unit (by a restart, or by a goal sent while the
            # unit was picking the item up: its state saying so was still on the way) and not
            # carried by another since, and that it can carry: a job given to a unit is loaded
            # when its state says so at the pickup (_progress_jobs), never by a claim made
            # elsewhere. As found: a 2 kg unit "picked up" any queued 15 kg job by naming it in its
            # state. A unit the job went to meanwhile has not got the item (this one has): it is
            # released, and the next allocation gives it other work.
            if job is None or job.state not in ("queued", "assigned", "to_pickup"):
                continue
            if self.requeued_from.get(job.id) != u.id:
                continue
            if u.capacity_kg is None or u.capacity_kg < job.mass_kg:
                continue
            # And only where the item is: its states first named the job on the pickup (as found:
            # back from a silence naming its job a square away, a unit "delivered" it unpicked).
            if u.job_seen_at != job.pickup:
                continue
            del self.requeued_from[job.id]
            self.jobs.set(job, "loaded", unit=u.id, reason=None)

    def _over(self, job_id: str) -> bool:
        job = self.jobs.get(job_id)
        return job is None or job.final

    def _progress_jobs(
        self, units: list[UnitRecord], active: set[str], now: float, step_no: int
    ) -> None:
        by_id = {u.id: u for u in units}
        for job in self.jobs.active():
            rec = by_id.get(job.unit or "")
            if rec is None or rec.state is None:
                continue  # not heard yet (e.g. after a restart): wait
            st = rec.state
            if rec.id not in active:
                if job.state in CARRYING_STATES:
                    # The item is on that unit: nobody else can finish the job. A unit that is
                    # only late (a busy machine, a network hiccup) or restarted (it says goodbye
                    # and resumes with the item on board) carries on when it is heard again, so
                    # wait for it; give up once it has stayed away too long.
                    if self.world.away_s(rec, now) > self._give_up_after_s(rec):
                        self.jobs.set(
                            job,
                            "failed",
                            reason=f"unit {rec.id} was lost carrying the item, last seen at "
                            f"{list(st.position)}",
                            done_step=step_no,
                        )
                else:
                    self.requeue(job, f"unit {rec.id} was lost; re-queued")
                continue
            if job.state in ("assigned", "to_pickup"):
                # Loaded only where the item is: the unit waits there for its next order, so
                # its states say so until we see one (a claim elsewhere is no pick-up, nor is
                # one made elsewhere and carried onto the pickup). Only a job seen loaded can be
                # done: at its dropoff, without the item (moves between accepted states are at
                # most what its wheels could drive by the fleet's clock, world.py).
                if st.job_id == job.id and st.position == job.pickup == rec.job_seen_at:
                    self.jobs.set(job, "loaded", reason=None)
                elif (
                    any(e.code == "over_capacity" for e in st.errors) and st.position == job.pickup
                ):
                    self.jobs.set(
                        job, "queued", unit=None, reason=f"unit {rec.id} refused: over capacity"
                    )
            elif job.state == "loaded" and st.job_id == job.id and st.position != job.pickup:
                self.jobs.set(job, "to_dropoff")
            elif job.state in CARRYING_STATES and st.job_id != job.id:
                if st.position == job.dropoff:
                    self.jobs.set(job, "done", done_step=step_no, reason=None)
                else:
                    self.jobs.set(
                        job,
                        "failed",
                        reason=f"unit {rec.id} no longer carries the item (at {list(st.position)})",
                        done_step=step_no,
                    )

    def _give_up_after_s(self, rec: UnitRecord) -> float:
        """How long a unit carrying an item may stay silent before its job fails."""
        return max(LOST_CARRYING_MIN_S, LOST_CARRYING_STEPS * self.world.stale_after_s(rec))

    def allocate(
        self,
        units: list[UnitRecord],
        active: set[str],
        settled: set[str],
        cache: DistanceFieldCache,
        step_no: int,
        now: float,
        plain: DistanceFieldCache | None = None,
        energy: EnergyStep | None = None,
        to_charger: Callable[[Cell], int | None] = lambda _: 0,
        charge_pcts: Mapping[str, float] | None = None,
    ) -> dict[str, str]:
        """Reject what no unit can carry any more; assign queued jobs to idle, settled units.

        With `energy`, the units it holds back get none and the others only jobs they can finish
        (their limits; `to_charger`: squares from a dropoff to its nearest charger). `cache`:
        distances as planned (round closed zones); `plain`: on the map with every zone open,
        what a job is rejected or failed by (default `cache`). The jobs given: job id -> unit id.
        """
        # Just after a restart, the units heard so far may be only some of the fleet: a queued
        # job that only an unheard unit can carry must wait for it, not be rejected.
        if self.world.fleet_known():
            capacities = self.world.capacities()
            for job in self.jobs.queued():
                reason = capacity_reason(job.mass_kg, capacities)
                if reason is not None:
                    self.jobs.set(
                        job, "rejected", reason=reason, done_step=step_no, refusal="too_heavy"
                    )
            self._fail_unreachable(plain or cache, step_no)
        busy = {j.unit for j in self.jobs.active()}
        slots = []
        for u in units:
            if (
                u.id in active
                and u.id in settled
                and u.id not in busy
                and u.id not in self.directives.goals
                and u.id not in self.directives.controls
                and u.factsheet is not None
                and u.state is not None
                and u.state.job_id is None
                and u.state.mode == "coordinated"
                and not u.state.estop
            ):
                free = u.factsheet.capacity_kg - u.state.load_kg
                if energy is not None and u.id in energy.unavailable:
                    continue
                limit = None if energy is None else energy.limits.get(u.id)
                pct = (charge_pcts or {}).get(u.id, 100.0)
                if limit is None:
                    slots.append(UnitSlot(u.id, u.state.position, free))
                else:
                    slots.append(
                        UnitSlot(u.id, u.state.position, free, limit.moves, limit.stranded, pct)
                    )
        queued = self.jobs.queued()
        if not slots or not queued:
            return {}
        requests = [
            JobRequest(j.id, j.pickup, j.dropoff, j.mass_kg, j.priority, to_charger(j.dropoff))
            for j in queued
        ]
        given = allocate(cache, slots, requests)
        for job_id, unit_id in given.items():
            job = self.jobs.jobs[job_id]
            self.jobs.set(job, "assigned", unit=unit_id, reason=None)
            # Standing still counts from here: idle before it, it was not stuck on this job.
            rec = self.world.unit(unit_id)
            rec.moved_at = now if rec.moved_at is None else max(rec.moved_at, now)
        return given

    def _fail_unreachable(self, cache: DistanceFieldCache, step_no: int) -> None:
        # Discovered obstacles can wall a job's squares off for good (the map only gains them).
        carriers = self.world.carriers()
        for job in self.jobs.active() + self.jobs.queued():
            if job.state in CARRYING_STATES:
                rec = self.world.units.get(job.unit or "")
                pos = rec.position if rec is not None else None
                if pos is None or cache.distance(pos, job.dropoff) != UNREACHABLE:
                    continue
                reason = f"dropoff {list(job.dropoff)} cannot be reached any more from {list(pos)}"
            else:
                reason = reach_reason(cache, job.pickup, job.dropoff, job.mass_kg, carriers) or ""
                if not reason:
                    continue
            self.jobs.set(job, "failed", reason=reason, done_step=step_no)

    def dispatch(self, units: list[UnitRecord], active: set[str]) -> None:
        """An assigned job whose unit hears from us this step is under way (`to_pickup`)."""
        for u in units:
            job = self.jobs.of_unit(u.id)
            goal = u.id in self.directives.goals
            if u.id in active and not goal and job is not None and job.state == "assigned":
                self.jobs.set(job, "to_pickup")

    def target(self, unit_id: str) -> Cell | None:
        """Where a unit is headed: its goal, else its job's pickup or (carrying) dropoff."""
        goal = self.directives.goals.get(unit_id)
        if goal is not None:
            return goal
        stray = self.returns.get(unit_id)
        if stray is not None:
            return stray.square
        job = self.jobs.of_unit(unit_id)
        if job is not None:
            return job.dropoff if job.state in CARRYING_STATES else job.pickup
        return None

    def action(self, unit_id: str) -> Action | None:
        """What a unit does at the end of its route: pick its job's item up, or drop it."""
        if unit_id in self.directives.goals:
            return None
        stray = self.returns.get(unit_id)
        if stray is not None:
            return stray
        job = self.jobs.of_unit(unit_id)
        if job is None:
            return None
        if job.state in CARRYING_STATES:
            return Action(kind="drop", job_id=job.id, square=job.dropoff, mass_kg=job.mass_kg)
        return Action(kind="pick", job_id=job.id, square=job.pickup, mass_kg=job.mass_kg)

    def urgency(self, units: list[UnitRecord]) -> dict[str, float]:
        """Each busy unit's job priority, added to its planning priority."""
        out = {}
        for u in units:
            job = self.jobs.of_unit(u.id)
            if job is not None:
                out[u.id] = float(job.priority)
        return out
