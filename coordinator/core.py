"""The coordinator's decisions, without I/O: requests, job progress, allocation, planning, orders.

The service feeds it decoded messages and a monotonic time; each `step` returns the orders to send
and the views to publish. Safety rules (protocol.md §4.4, §8) live here:

- A square stays reserved for a unit until its state shows it left: its reported square, the
  squares it still may drive (`state.released`) and, until it has acknowledged our latest change,
  every square we sent it since its last acknowledgement.
- Only *settled* units (acknowledged, nothing left to drive) get new moves; the planner never
  produces a swap, a vertex conflict or a rotation, so releasing a square that a unit is being
  released out of in the same step (following) is the only way into an occupied square.
- A unit in motion gets its remaining squares again (heartbeat), or a hold when it has waited too
  long or its way is blocked by a newly known obstacle.
- With the emergency stop engaged every unit gets holds and nothing is planned or allocated.

Lost units (connection offline/broken or state silent for 5 step periods): their squares stay
reserved; a job not yet picked up goes back to the queue; a job whose item the unit had already
picked up becomes `failed` (the item is on a unit nobody can reach; an operator must recover it),
with a reason naming the unit and the square where it was last seen.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from coordinator.allocation import JobRequest, UnitSlot, allocate, capacity_reason
from coordinator.jobs import CARRYING_STATES, Job, JobBook
from coordinator.planner import AgentSpec, Planner
from coordinator.world import UnitRecord, World, cell, cells
from gridfleet.errors import ProtocolError
from gridfleet.grid import Cell
from gridfleet.paths import UNREACHABLE
from gridfleet.protocol import Action, CancelJob, RouteView, SetGoal, SubmitJob
from gridfleet.protocol.constants import (
    HOLD_AFTER_STEPS,
    MAX_PLANNED,
    MIN_TIMEOUT_S,
    STALE_AFTER_STEPS,
)

WAIT_BEFORE_HOLD = 3  # coordinator steps a unit may wait on a released square before we re-plan it
LOST_CARRYING_STEPS = 20  # stale periods a carrying unit may be silent before its job fails
LOST_CARRYING_MIN_S = 10.0
FOLLOW_PATIENCE = 3  # coordinator steps a follower waits for its leader to leave before re-planning


@dataclass(frozen=True)
class OrderPlan:
    """One order to send (the header is added by the service)."""

    order_id: str
    update_id: int
    step: int
    released: list[Cell]
    planned: list[Cell]
    target: Cell | None
    action: Action | None


@dataclass
class Outcome:
    """The answer to a request: accepted or not, why, and the job it concerns."""

    accepted: bool
    reason: str | None = None
    job_id: str | None = None


@dataclass
class Track:
    """Our side of one unit's orders."""

    order_id: str | None = None
    route_no: int = 0
    update_id: int = 0
    content_update: int = 0  # update id at which the current released squares were first sent
    sent: list[Cell] = field(default_factory=list)  # released squares of the latest order
    unacked: set[Cell] = field(default_factory=set)  # every square sent since the last ack
    target: Cell | None = None
    waiting: int = 0
    lost_since: float | None = None  # when we stopped hearing from it (None: active)
    follow: Cell | None = None  # planned into a square its occupant is leaving: released once empty
    follow_steps: int = 0  # steps it has waited for `follow` to empty


@dataclass
class StepResult:
    """What one step decided."""

    step: int
    orders: dict[str, OrderPlan]
    routes: dict[str, RouteView]
    jobs_changed: bool


class CoordinatorCore:
    """World, jobs, allocation and planning; pure (time comes in as an argument)."""

    def __init__(self, world: World, jobs: JobBook, nonce: str, seed: int = 0) -> None:
        self.world = world
        self.jobs = jobs
        self.nonce = nonce
        self.planner = Planner(world.grid, seed=seed)
        self._cache = self.planner.cache
        self.step_no = 0
        self.estop = False
        self.goals: dict[str, Cell] = {}
        self.tracks: dict[str, Track] = {}
        self._requeue_on_restart()

    def _requeue_on_restart(self) -> None:
        # Jobs not picked up yet go back to the queue; carried ones wait for their unit's state.
        for job in self.jobs.active():
            if job.state not in CARRYING_STATES:
                self.jobs.set(job, "queued", unit=None, reason="coordinator restarted; re-queued")

    # ---- requests -------------------------------------------------------------------------

    def submit(self, req: SubmitJob, sender: str | None) -> Outcome:
        """Queue a job, or refuse it (nothing changes) with the reason."""
        try:
            self.world.check_square(req.pickup, "pickup")
            self.world.check_square(req.dropoff, "dropoff")
        except ProtocolError as exc:
            return Outcome(False, str(exc))
        if req.job_id is not None and req.job_id in self.jobs.jobs:
            return Outcome(False, f"job id {req.job_id!r} is taken", req.job_id)
        job_id = req.job_id or self.jobs.new_id()
        job = Job(
            id=job_id,
            pickup=cell(req.pickup),
            dropoff=cell(req.dropoff),
            mass_kg=req.mass_kg,
            priority=req.priority,
            submitted_by=sender,
            created_step=self.step_no,
        )
        reason = capacity_reason(req.mass_kg, self.world.capacities())
        if reason is not None:
            job.state = "rejected"
            job.reason = reason
            self.jobs.add(job)
            return Outcome(False, reason, job_id)
        self.jobs.add(job)
        return Outcome(True, None, job_id)

    def cancel(self, req: CancelJob, sender: str | None) -> Outcome:
        """Cancel a queued job or abort an active one; refuse unknown and final jobs."""
        job = self.jobs.get(req.job_id)
        if job is None:
            return Outcome(False, f"unknown job {req.job_id!r}", req.job_id)
        if job.final:
            return Outcome(False, f"job {job.id} is already {job.state}", job.id)
        who = sender or "an operator"
        if job.state in CARRYING_STATES and job.unit is not None:
            rec = self.world.units.get(job.unit)
            where = list(rec.position) if rec and rec.position else "unknown"
            reason = f"cancelled by {who}; the item stays on unit {job.unit} at {where}"
        elif job.unit is not None:
            reason = f"cancelled by {who}; unit {job.unit} released"
        else:
            reason = f"cancelled by {who}"
        self.jobs.set(job, "cancelled", reason=reason, done_step=self.step_no)
        return Outcome(True, None, job.id)

    def set_goal(self, req: SetGoal) -> Outcome:
        """Pin a unit to a square (or clear its goal); refuse unknown units and bad squares."""
        rec = self.world.units.get(req.unit)
        if rec is None or rec.state is None:
            return Outcome(False, f"unknown unit {req.unit!r}")
        if req.target is None:
            self.goals.pop(req.unit, None)
            return Outcome(True)
        try:
            self.world.check_square(req.target, "target")
        except ProtocolError as exc:
            return Outcome(False, str(exc))
        if rec.position is not None and (
            self._cache.distance(rec.position, cell(req.target)) == UNREACHABLE
        ):
            return Outcome(False, f"unit {req.unit} cannot reach {list(req.target)}")
        self.goals[req.unit] = cell(req.target)
        job = self.jobs.of_unit(req.unit)
        if job is not None and job.state not in CARRYING_STATES:
            # The goal pins the unit: its job goes back to the queue for another unit.
            self.jobs.set(job, "queued", unit=None, reason=f"unit {req.unit} sent to a goal")
        return Outcome(True)

    def set_estop(self, engaged: bool) -> bool:
        """Engage or release the stop; True when it changed."""
        changed = engaged != self.estop
        self.estop = engaged
        return changed

    def on_new_obstacles(self) -> None:
        """Re-plan on the grid with the newly reported obstacles."""
        self.planner.set_grid(self.world.grid)
        self._cache = self.planner.cache

    # ---- the step ------------------------------------------------------------------------

    def step(self, now: float) -> StepResult:
        """Advance jobs, allocate, plan, and make one order per unit that can hear it."""
        self.step_no += 1
        units = [u for u in self.world.units.values() if u.state is not None]
        active = {u.id for u in units if self.world.is_active(u, now)}
        for u in units:
            track = self.tracks.setdefault(u.id, Track())
            if u.id in active:
                track.lost_since = None
            elif track.lost_since is None:
                track.lost_since = now
        self._adopt_carried(units, active)
        self._progress_jobs(units, active, now)
        settled = {u.id for u in units if u.id in active and self._settled(u)}
        if not self.estop:
            self._allocate(units, active, settled)
        targets = {u.id: self._target(u) for u in units}
        moves = self._plan(units, active, settled, targets, now)
        orders: dict[str, OrderPlan] = {}
        routes: dict[str, RouteView] = {}
        for u in units:
            if u.id not in active:
                # Lost units get no orders: a unit that is alive but cut off holds still after
                # 3 step periods without orders (protocol.md §8).
                routes[u.id] = RouteView()
                continue
            order = self._order_for(u, u.id in settled, moves.get(u.id), targets[u.id])
            orders[u.id] = order
            routes[u.id] = RouteView(
                released=order.released,  # type: ignore[arg-type]
                planned=order.planned,  # type: ignore[arg-type]
                target=order.target,
            )
        changed = bool(self.jobs.changed)
        return StepResult(self.step_no, orders, routes, changed)

    def _settled(self, u: UnitRecord) -> bool:
        assert u.state is not None
        return self._acked(u) and not u.state.released

    def _acked(self, u: UnitRecord) -> bool:
        assert u.state is not None
        t = self.tracks.get(u.id)
        if t is None or t.order_id is None:
            return True
        return u.state.order_id == t.order_id and u.state.order_update_id >= t.content_update

    def _adopt_carried(self, units: list[UnitRecord], active: set[str]) -> None:
        # A unit that reports carrying a job we think is not picked up yet (it picked the item up
        # just before a coordinator restart, whose store still had the job waiting) has it.
        for u in units:
            st = u.state
            if st is None or st.job_id is None or u.id not in active:
                continue
            job = self.jobs.get(st.job_id)
            if job is not None and not job.final and job.state not in CARRYING_STATES:
                self.jobs.set(job, "loaded", unit=u.id, reason=None)

    def _progress_jobs(self, units: list[UnitRecord], active: set[str], now: float) -> None:
        by_id = {u.id: u for u in units}
        for job in self.jobs.active():
            rec = by_id.get(job.unit or "")
            if rec is None or rec.state is None:
                continue  # not heard yet (e.g. after a restart): wait
            st = rec.state
            if rec.id not in active:
                if job.state in CARRYING_STATES:
                    # The item is on that unit: nobody else can finish the job. A unit that is
                    # only late (a busy machine, a network hiccup) carries on when it is heard
                    # again, so wait for it; give up once it has said goodbye or stayed away.
                    lost_since = self.tracks[rec.id].lost_since
                    away = 0.0 if lost_since is None else now - lost_since
                    if rec.connection == "offline" or away > self._give_up_after_s(rec):
                        self.jobs.set(
                            job,
                            "failed",
                            reason=f"unit {rec.id} was lost carrying the item, last seen at "
                            f"{list(st.position)}",
                            done_step=self.step_no,
                        )
                else:
                    self.jobs.set(
                        job, "queued", unit=None, reason=f"unit {rec.id} was lost; re-queued"
                    )
                continue
            if job.state in ("assigned", "to_pickup"):
                if st.job_id == job.id:
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
                    self.jobs.set(job, "done", done_step=self.step_no, reason=None)
                else:
                    self.jobs.set(
                        job,
                        "failed",
                        reason=f"unit {rec.id} no longer carries the item (at {list(st.position)})",
                        done_step=self.step_no,
                    )
        for unit_id, goal in list(self.goals.items()):
            rec = by_id.get(unit_id)
            if rec is not None and rec.position == goal:
                del self.goals[unit_id]

    def _give_up_after_s(self, rec: UnitRecord) -> float:
        """How long a unit carrying an item may stay silent before its job fails."""
        return max(LOST_CARRYING_MIN_S, LOST_CARRYING_STEPS * self.world.stale_after_s(rec))

    def _allocate(self, units: list[UnitRecord], active: set[str], settled: set[str]) -> None:
        capacities = self.world.capacities()
        for job in self.jobs.queued():
            reason = capacity_reason(job.mass_kg, capacities)
            if reason is not None:
                self.jobs.set(job, "rejected", reason=reason, done_step=self.step_no)
        busy = {j.unit for j in self.jobs.active()}
        slots = []
        for u in units:
            if (
                u.id in active
                and u.id in settled
                and u.id not in busy
                and u.id not in self.goals
                and u.factsheet is not None
                and u.state is not None
                and u.state.job_id is None
                and u.state.mode == "coordinated"
                and not u.state.estop
            ):
                free = u.factsheet.capacity_kg - u.state.load_kg
                slots.append(UnitSlot(u.id, cell(u.state.position), free))
        queued = self.jobs.queued()
        if not slots or not queued:
            return
        requests = [JobRequest(j.id, j.pickup, j.dropoff, j.mass_kg, j.priority) for j in queued]
        for job_id, unit_id in allocate(self._cache, slots, requests).items():
            job = self.jobs.jobs[job_id]
            self.jobs.set(job, "assigned", unit=unit_id, reason=None)

    def _target(self, u: UnitRecord) -> Cell | None:
        goal = self.goals.get(u.id)
        if goal is not None:
            return goal
        job = self.jobs.of_unit(u.id)
        if job is not None:
            return job.dropoff if job.state in CARRYING_STATES else job.pickup
        return None

    def _action(self, u: UnitRecord) -> Action | None:
        job = self.jobs.of_unit(u.id)
        if job is None or u.id in self.goals:
            return None
        if job.state == "assigned":
            self.jobs.set(job, "to_pickup")
        if job.state in CARRYING_STATES:
            return Action(kind="drop", job_id=job.id, square=job.dropoff, mass_kg=job.mass_kg)
        return Action(kind="pick", job_id=job.id, square=job.pickup, mass_kg=job.mass_kg)

    def _reserved(self, u: UnitRecord, now: float) -> set[Cell]:
        assert u.state is not None
        t = self.tracks.get(u.id)
        if t is not None and t.lost_since is not None:
            period = max(self.world.step_period_s, self.world.stale_after_s(u) / STALE_AFTER_STEPS)
            hold_after = max(MIN_TIMEOUT_S, HOLD_AFTER_STEPS * period) + period
            if now - t.lost_since > hold_after:
                return set()  # it holds still by now: only its last square stays reserved
        out = set(cells(u.state.released))
        if t is not None and not self._acked(u):
            out |= t.unacked
        return out

    def _plan(
        self,
        units: list[UnitRecord],
        active: set[str],
        settled: set[str],
        targets: dict[str, Cell | None],
        now: float,
    ) -> dict[str, Cell]:
        if self.estop:
            return {}
        agents: dict[str, AgentSpec] = {}
        reserved: set[Cell] = set()
        seen: set[Cell] = set()
        following: dict[str, Cell] = {}
        released_to_others: set[Cell] = set()  # squares units may still drive into
        for u in units:
            assert u.state is not None
            pos = cell(u.state.position)
            if pos in seen or not self.planner.grid.is_free(pos):
                return {}  # inconsistent snapshot (states in flight): hold everyone this step
            seen.add(pos)
            movable = u.id in settled and u.id in active and not u.state.estop
            movable = movable and u.state.mode == "coordinated"
            held = self._reserved(u, now) - {pos}
            reserved |= held
            released_to_others |= held
            t = self.tracks.setdefault(u.id, Track())
            if t.follow is not None and movable and t.follow_steps < FOLLOW_PATIENCE:
                # It keeps its planned square (nobody else may take it) and waits for it to empty.
                following[u.id] = t.follow
                reserved.add(t.follow)
                t.follow_steps += 1
                # Frozen for this step, but with its target, so it keeps its priority.
                agents[u.id] = AgentSpec(pos, targets[u.id], frozen=True)
                continue
            t.follow = None
            agents[u.id] = AgentSpec(pos, targets[u.id] if movable else None, frozen=not movable)
        # A reserved square may hold another unit (a follower waits for it to leave): that unit
        # may stay or leave, but nobody else may be released into it.
        urgency = {}
        for u in units:
            job = self.jobs.of_unit(u.id)
            if job is not None:
                urgency[u.id] = float(job.priority)
        moves = self.planner.step(agents, reserved=reserved, urgency=urgency)
        # Never release a square another unit stands on, not even one it leaves this very step:
        # units keep their own clocks, so "it leaves as I enter" is a collision when it is late.
        # The follower keeps that square as planned and gets it once the leader's state shows
        # it has gone.
        out: dict[str, Cell] = {}
        for uid, nxt in moves.items():
            if nxt == agents[uid].position:
                continue
            if nxt in seen:
                track = self.tracks[uid]
                track.follow, track.follow_steps = nxt, 0
            else:
                out[uid] = nxt
        for uid, square in following.items():
            if square not in seen and square not in released_to_others:
                out[uid] = square
                self.tracks[uid].follow = None
        return out

    def _order_for(
        self, u: UnitRecord, settled: bool, move: Cell | None, target: Cell | None
    ) -> OrderPlan:
        assert u.state is not None
        st = u.state
        t = self.tracks.setdefault(u.id, Track())
        pos = cell(st.position)
        if self._acked(u):
            t.unacked = set()  # what it may still drive is exactly its reported `released`
        if settled or self.estop or st.estop:
            t.waiting = 0
        elif st.status == "waiting":
            t.waiting += 1
        if self.estop:
            released: list[Cell] = []
        elif settled:
            released = [move] if move is not None and move != pos else []
        else:
            remaining = self._remaining(u, t)
            blocked = any(not self.world.grid.is_free(c) for c in remaining)
            released = [] if blocked or t.waiting >= WAIT_BEFORE_HOLD else remaining
        if target != t.target or t.order_id is None:
            t.route_no += 1
            t.order_id = f"{self.nonce}-{u.id}-{t.route_no}"
            t.update_id = 0
            t.target = target
            t.content_update = 0
        t.update_id += 1
        if released != t.sent or t.content_update == 0:
            t.content_update = t.update_id
            t.unacked |= set(released)
            t.sent = released
            t.waiting = 0
        planned: list[Cell] = []
        if target is not None and not self.estop:
            start = released[-1] if released else pos
            planned = self.planner.route(start, target, limit=min(MAX_PLANNED, 64))
        return OrderPlan(
            order_id=t.order_id,
            update_id=t.update_id,
            step=self.step_no,
            released=released,
            planned=planned,
            target=target,
            action=None if self.estop else self._action(u),
        )

    def _remaining(self, u: UnitRecord, t: Track) -> list[Cell]:
        assert u.state is not None
        st = u.state
        if self._acked(u) or not t.sent:
            return cells(st.released)
        pos = cell(st.position)
        if pos in t.sent:
            return t.sent[t.sent.index(pos) + 1 :]
        return list(t.sent) if t.sent[0].manhattan(pos) == 1 else []
