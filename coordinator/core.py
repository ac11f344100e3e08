"""The coordinator's decisions, without I/O: requests, job progress, allocation, planning, orders.

The service feeds it decoded messages and a monotonic time; each `step` returns the orders to send
and the routes to show. Safety rules (protocol.md §4.4, §8), each in the module named:

- A square stays reserved for a unit until its state shows it left: its reported square, the
  squares it still may drive (`state.released`) and, until it has acknowledged our latest change,
  every square we sent it since its last acknowledgement (orders.py).
- Only *settled* units (acknowledged, nothing left to drive) get new moves; the planner never
  produces a swap, a vertex conflict or a rotation, so releasing a square that a unit is being
  released out of in the same step (following) is the only way into an occupied square, and that
  square is released only once the leader's state shows it gone (moves.py).
- A unit in motion gets its remaining squares again (heartbeat), or a hold when it has waited too
  long or its way is blocked by a newly known obstacle (orders.py).
- With the emergency stop engaged every unit gets holds and nothing is planned or allocated.

Lost units (connection offline/broken or state silent for 5 step periods): their squares stay
reserved; a job not yet picked up goes back to the queue; a job whose item the unit had already
picked up becomes `failed` (progress.py).
"""

from __future__ import annotations

from dataclasses import dataclass

from coordinator import requests
from coordinator.jobs import JobBook
from coordinator.moves import Moves
from coordinator.orders import OrderPlan, Orders
from coordinator.planner import Planner
from coordinator.progress import JobProgress
from coordinator.requests import Outcome
from coordinator.world import World
from gridfleet.grid import Cell
from gridfleet.protocol import CancelJob, RouteView, SetGoal, SubmitJob
from gridfleet.protocol.constants import MAX_PLANNED

PLANNED_SHOWN = min(MAX_PLANNED, 64)  # squares of the planned rest an order shows


@dataclass(frozen=True)
class StepResult:
    """What one step decided."""

    step: int
    orders: dict[str, OrderPlan]
    routes: dict[str, RouteView]


class CoordinatorCore:
    """World, jobs, allocation and planning; pure (time comes in as an argument)."""

    def __init__(self, world: World, jobs: JobBook, nonce: str, seed: int = 0) -> None:
        self.world = world
        self.jobs = jobs
        self.planner = Planner(world.grid, seed=seed)
        self.step_no = 0
        self.estop = False
        self.goals: dict[str, Cell] = {}
        self.orders = Orders(nonce)
        self.moves = Moves(self.planner)
        self.progress = JobProgress(world, jobs, self.goals)
        self.progress.requeue_on_restart()

    # ---- requests -------------------------------------------------------------------------

    def submit(self, req: SubmitJob, sender: str | None) -> Outcome:
        """Queue a job, or refuse it (nothing changes) with the reason."""
        return requests.submit(req, sender, self.world, self.jobs, self.step_no)

    def cancel(self, req: CancelJob, sender: str | None) -> Outcome:
        """Cancel a queued job or abort an active one; refuse unknown and final jobs."""
        return requests.cancel(req, sender, self.world, self.jobs, self.step_no)

    def set_goal(self, req: SetGoal) -> Outcome:
        """Pin a unit to a square (or clear its goal); refuse unknown units and bad squares."""
        return requests.set_goal(req, self.world, self.jobs, self.goals, self.planner.cache)

    def set_estop(self, engaged: bool) -> bool:
        """Engage or release the stop; True when it changed."""
        changed = engaged != self.estop
        self.estop = engaged
        return changed

    def on_new_obstacles(self) -> None:
        """Re-plan on the grid with the newly reported obstacles."""
        self.planner.set_grid(self.world.grid)

    # ---- the step ------------------------------------------------------------------------

    def step(self, now: float) -> StepResult:
        """Advance jobs, allocate, plan, and make one order per unit that can hear it."""
        self.step_no += 1
        units = [u for u in self.world.units.values() if u.state is not None]
        active = self.world.roll_call(now)
        self.progress.advance(units, active, now, self.step_no)
        settled = {u.id for u in units if u.id in active and self.orders.settled(u)}
        if not self.estop:
            self.progress.allocate(units, active, settled, self.planner.cache, self.step_no)
            self.progress.dispatch(units, active)
        targets = {u.id: self.progress.target(u.id) for u in units}
        moves: dict[str, Cell] = {}
        if not self.estop:
            movable = {
                u.id
                for u in units
                if u.id in settled
                and u.state is not None
                and not u.state.estop
                and u.state.mode == "coordinated"
            }
            moves = self.moves.plan(
                units,
                movable,
                lambda u: self.orders.reserved(u, now, self.world),
                targets,
                self.progress.urgency(units),
            )
        orders: dict[str, OrderPlan] = {}
        routes: dict[str, RouteView] = {}
        for u in units:
            if u.id not in active:
                # Lost units get no orders: a unit that is alive but cut off holds still after
                # 3 step periods without orders (protocol.md §8).
                routes[u.id] = RouteView()
                continue
            order = self.orders.order(
                u,
                settled=u.id in settled,
                move=moves.get(u.id),
                target=targets[u.id],
                action=self.progress.action(u.id),
                estop=self.estop,
                grid=self.world.grid,
                route=lambda start, target: self.planner.route(start, target, PLANNED_SHOWN),
                step_no=self.step_no,
            )
            orders[u.id] = order
            routes[u.id] = RouteView(
                released=order.released,  # type: ignore[arg-type]
                planned=order.planned,  # type: ignore[arg-type]
                target=order.target,
            )
        return StepResult(self.step_no, orders, routes)

    def holds(self) -> dict[str, OrderPlan]:
        """A hold for every unit that has had an order and has not said it is gone."""
        out = {}
        for u in list(self.world.units.values()):
            if u.state is None or u.connection in ("offline", "broken"):
                continue
            plan = self.orders.hold(u.id, self.step_no)
            if plan is not None:
                out[u.id] = plan
        return out
