"""The planner's way out of a livelock: notice the fleet going round in circles, then search.

PIBT is fast but incomplete: with fixed targets a few agents can push each other back and forth
forever while the rest wait on their targets. `Unjam` notes every configuration the fleet enters
while the targets stay the same; one entered a third time means going round in circles, and so do
STALL steps in a row none of which brought the fleet nearer its targets in all. Then
LaCAM (`coordinator.planning.lacam`) searches a way for everyone from there, a little every
step while the fleet holds still (so no step takes long), and the planner follows the way it finds a
configuration at a time. Units move asynchronously: an agent takes its next square of the plan
when it stands on its square of the current one, only when whoever holds that square leaves it in
the same step, and the plan goes on once every agent is where it says.

Pure: flat squares in (y * width + x, as `coordinator.planning.pibt`), next squares out.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from gridfleet.coordinator.planning.lacam import Config, LaCAM, NoSolution
from gridfleet.coordinator.planning.parking import nearest_first
from gridfleet.coordinator.planning.pibt import NONE, Index

REVISITS = 2  # a configuration entered this many times again means a livelock
STALL = 64  # ...and so do this many steps in a row without getting nearer the targets
SEARCH_NODES = 2000  # LaCAM's first budget, in successors tried; doubled on each retry...
MAX_SEARCH_NODES = 64_000  # ...up to this
STEP_WORK = 8000  # agents times successors a step may search for (~35 ms on this machine)
PATIENCE = 16  # steps the fleet may take to reach the plan's next configuration before it is
# dropped (a unit lost or stopped would hold the others on a plan that cannot go on)


@dataclass
class Unjam:
    """Livelock detection and the plan out of it; kept by the planner between steps."""

    nbrs: Sequence[tuple[Index, ...]]
    field_of: Callable[[Index], Sequence[int]]  # the distance field towards a square
    seed: int = 0
    search_nodes: int = SEARCH_NODES
    searches: int = 0  # how many times a livelock was seen and searched out of
    _key: tuple[tuple[str, ...], Config] | None = None
    _entered: dict[Config, int] = field(default_factory=dict)
    _last: Config | None = None
    _nearest: int = 0  # the least total distance to the targets seen under this key
    _stalled: int = 0  # steps since that least distance was seen
    _baseline: Config | None = None  # the first configuration under this key, not yet summed
    _failed: int = 0  # searches out of budget under this key
    _retry_at: float = REVISITS + 1
    _due: bool = False  # a search is due, and waits for the units still driving to stop
    _search: LaCAM | None = None  # under way, from `_search_from`
    _search_from: Config = ()
    _search_budget: int = 0
    _plan: list[Config] | None = None
    _at: int = 0  # the plan's configuration the fleet has last reached in full
    _waited: int = 0  # steps since it reached it

    def moves(
        self,
        names: Sequence[str],
        pos: Sequence[Index],
        goal: Sequence[Index],
        frozen: Sequence[bool],
        reserved: set[Index],
    ) -> list[Index] | None:
        """Next squares while getting out of a livelock; None: plan this step as usual."""
        key = (tuple(names), tuple(goal))
        if key != self._key:
            self._reset(key)
        config = tuple(pos)
        if self._plan is not None:
            out = self._follow(config, frozen, reserved)
            if out is not None:
                return out
        if self._search is not None:
            return self._go_on(config, frozen, reserved)
        if all(g in (NONE, p) for p, g in zip(pos, goal, strict=True)):
            self._due = False
            return None
        entered = self._entered.get(config, 0)
        if config != self._last:
            self._last = config
            entered = self._entered[config] = entered + 1
        if self._stalled == 0:
            # The first step under these targets: its distance is the baseline, wanted only if a
            # second step comes under them (a lifelong fleet's targets change nearly every step,
            # and summing 10,000 units' distances every step cost ~12 ms).
            self._stalled, self._baseline = 1, config
            return None
        if self._baseline is not None:
            self._nearest, self._baseline = self._distance(self._baseline, goal), None
        total = self._distance(config, goal)
        if total < self._nearest:
            self._nearest, self._stalled = total, 0
            self._due = False  # nearer the targets than ever under them: no livelock after all
        self._stalled += 1
        if entered < self._retry_at and self._stalled < STALL * (self._retry_at - REVISITS):
            return None
        if any(frozen):
            # Search once the fleet is still: it starts from where everyone stands. Meanwhile
            # `busy` holds every released window to its next square, so those still driving stop.
            self._due = True
            return None
        self._due = False
        self._stalled = 1
        # An agent with no target stays where it is at the end, though it may make way meanwhile.
        goals = self._one_each(
            config, [p if g == NONE else g for p, g in zip(config, goal, strict=True)]
        )
        if goals is None:
            self._retry_at = float("inf")  # not with these targets: wait for them to change
            return None
        self._search = LaCAM(self.nbrs, config, goals, [self.field_of(g) for g in goals], self.seed)
        self._search_from = config
        self._search_budget = min(self.search_nodes << self._failed, MAX_SEARCH_NODES)
        self.searches += 1
        return self._go_on(config, frozen, reserved)

    def _one_each(self, config: Config, goals: list[Index]) -> list[Index] | None:
        """The goals with each square wanted by one agent only, or None when that cannot be.

        Two agents may be sent to one square (two jobs picked up at one place): no configuration
        has both there, so a search for one would only hold the fleet still until its budget ran
        out, again and again. The agent nearest such a square keeps it; each other one ends where
        it stands, or, where that is a square somebody keeps, on the nearest square nobody does
        (three units bringing jobs to one drop-off beside two going to another went round in
        circles for good when the one left standing on the other's drop-off gave up the search).
        They get their own goals once free, planned as usual.
        """
        wanted: dict[Index, list[int]] = {}
        for i, g in enumerate(goals):
            wanted.setdefault(g, []).append(i)
        if all(len(agents) == 1 for agents in wanted.values()):
            return goals
        out = list(goals)
        kept: set[Index] = set()
        left: list[int] = []
        for g, agents in wanted.items():
            field = self.field_of(g)
            keeper = min(agents, key=lambda i: (field[config[i]], i))
            kept.add(g)
            left.extend(i for i in agents if i != keeper)
        for i in sorted(left):
            end = next((s for s in nearest_first(self.nbrs, config[i]) if s not in kept), None)
            if end is None:
                return None
            out[i] = end
            kept.add(end)
        return out

    def _distance(self, config: Config, goal: Sequence[Index]) -> int:
        """The fleet's total distance to its targets."""
        return sum(self.field_of(g)[p] for p, g in zip(config, goal, strict=True) if g != NONE)

    @property
    def following(self) -> bool:
        """Is a plan out of a livelock being followed?"""
        return self._plan is not None

    @property
    def busy(self) -> bool:
        """Is a way out of a livelock due, being searched or followed?

        Released windows give no square beyond a unit's next one meanwhile (coordinator.core):
        with windows some unit of a livelocked fleet was nearly always still driving, so the
        search, which starts only from a still fleet, never began (1 simulate run in 342 over
        MQTT went round in circles to its step limit, bench/README.md).
        """
        return self._due or self._search is not None or self._plan is not None

    def _reset(self, key: tuple[tuple[str, ...], Config]) -> None:
        self._key = key
        self._entered.clear()
        self._last = None
        self._stalled = 0
        self._baseline = None
        self._failed = 0
        self._retry_at = REVISITS + 1
        self._due = False
        self._plan = None
        self._search = None

    def _go_on(
        self, config: Config, frozen: Sequence[bool], reserved: set[Index]
    ) -> list[Index] | None:
        """Search a step's worth: the way out once found, else everyone stays meanwhile."""
        search = self._search
        assert search is not None
        if config != self._search_from:
            self._search = None  # someone moved after all (by hand, say): PIBT again
            return None
        limit = min(search.tries + max(1, STEP_WORK // len(config)), self._search_budget)
        try:
            plan = search.solve(lambda: search.tries >= limit)
        except NoSolution:
            self._search = None
            self._retry_at = float("inf")  # not with these targets: wait for them to change
            return None
        if plan is None:
            if search.tries < self._search_budget:
                return list(config)
            self._search = None
            self._retry_at = 2 * self._entered.get(config, 1)  # try again later, with more
            self._failed += 1
            return None
        self._search = None
        self._plan, self._at, self._waited = plan, 0, -1
        return self._follow(config, frozen, reserved)

    def _follow(
        self, config: Config, frozen: Sequence[bool], reserved: set[Index]
    ) -> list[Index] | None:
        plan = self._plan
        assert plan is not None
        self._waited += 1
        while self._at + 1 < len(plan) and config == plan[self._at + 1]:
            self._at += 1
            self._waited = 0
        if self._at + 1 >= len(plan):
            self._plan = None  # done: everyone is on the plan's last configuration
            return None
        now, nxt = plan[self._at], plan[self._at + 1]
        if self._waited > PATIENCE or any(
            c != a and c != b for c, a, b in zip(config, now, nxt, strict=True)
        ):
            # Held up, or the fleet left the plan (a unit was moved by hand, say): PIBT again,
            # and no new search before this configuration has come round twice as often.
            self._plan = None
            self._retry_at = max(self._retry_at, 2 * self._entered.get(config, 1))
            self._stalled = 1
            return None
        moving = {
            i
            for i, (c, a, b) in enumerate(zip(config, now, nxt, strict=True))
            if c == a != b and not frozen[i] and b not in reserved
        }
        holder = {c: i for i, c in enumerate(config)}
        held = True
        while held:  # drop moves into squares whose holders stay; repeat, as those stay too
            held = False
            for i in list(moving):
                h = holder.get(nxt[i])
                if h is not None and h not in moving:
                    moving.discard(i)
                    held = True
        return [nxt[i] if i in moving else c for i, c in enumerate(config)]
