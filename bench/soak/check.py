"""The soak's oracle: a pure function of the events recorded during a run.

Checks: zero collisions (the world simulation's own count), no move while a stop is engaged,
every job ends exactly once (none lost, none done twice), and no unit stranded.
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Literal

FINAL = frozenset({"done", "cancelled", "rejected", "failed"})

Square = tuple[int, int]


@dataclass(frozen=True)
class Truth:
    """One line of the units process's ground truth (`gridfleet robots --truth`)."""

    t: float
    pid: int
    collisions: int
    positions: dict[str, Square]


@dataclass(frozen=True)
class Stop:
    """The stop as the listener saw it change: engaged (latch or press) or released.

    `where`: on the central broker, or on a bridged hall's own (its units cannot know it sooner).
    """

    t: float
    engaged: bool
    where: Literal["central", "hall"] = "central"


@dataclass(frozen=True)
class Released:
    """The soak's operator published a release (the first, or one given again)."""

    t: float


@dataclass(frozen=True)
class Held:
    """The coordinator's status said the fleet held (its stop) or not, at `t` by its own stamp.

    Units move only on the coordinator's orders, which it gives only while it holds no stop: its
    stamped release is when moves may begin, however late the listener heard of it.
    """

    t: float
    engaged: bool


@dataclass(frozen=True)
class JobSeen:
    """A job's state in a `fleet/jobs` view the listener received."""

    t: float
    job: str
    state: str


@dataclass(frozen=True)
class StateSeen:
    """A unit's state the listener received: where it stood and whether it had work."""

    t: float
    unit: str
    position: Square
    busy: bool  # not idle, or carrying a job, and not held by a stop (status `stopped`)


@dataclass(frozen=True)
class Disturbed:
    """A window in which units may legitimately stand still: a fault and its recovery."""

    start: float
    end: float


Event = Truth | Stop | Released | Held | JobSeen | StateSeen | Disturbed


@dataclass(frozen=True)
class SoakLimits:
    """How long is too long."""

    step_s: float
    grace_steps: float = 2.0  # one step to read the stop, one for the truth sampler's phase
    stranded_s: float = 30.0  # undisturbed seconds a busy unit may stand on one square


@dataclass
class SoakVerdict:
    """What the checks found; `ok` when nothing."""

    collisions: int = 0
    moved_while_stopped: int = 0
    jobs_submitted: int = 0
    jobs_done: int = 0
    jobs_lost: int = 0
    jobs_duplicated: int = 0
    units_stranded: int = 0
    details: list[str] = field(default_factory=list)
    # With a bridged hall: moves after the central broker had the stop but before the hall's
    # broker did (the bridge's delay; told, not a failure), and the worst such delay.
    moved_before_the_hall_had_it: int = 0
    worst_stop_to_hall_s: float | None = None

    @property
    def ok(self) -> bool:
        """True when every check passed."""
        return not (
            self.collisions
            or self.moved_while_stopped
            or self.jobs_lost
            or self.jobs_duplicated
            or self.units_stranded
        )


def check(events: Iterable[Event], limits: SoakLimits) -> SoakVerdict:
    """Run every check over the recorded events (any order: they are sorted by time)."""
    ordered = sorted(events, key=_time)
    verdict = SoakVerdict()
    truths = [e for e in ordered if isinstance(e, Truth)]
    verdict.collisions = _collisions(truths, verdict.details)
    releases = [e.t for e in ordered if isinstance(e, Released)]
    central = [e for e in ordered if isinstance(e, Stop) and e.where == "central"]
    held = [e for e in ordered if isinstance(e, Held)]
    stops = _stop_windows(central, releases, held)
    hall = [e for e in ordered if isinstance(e, Stop) and e.where == "hall"]
    if hall:
        # A hall's units are stopped from when its broker has the stop: nothing reaches them
        # sooner. What moved before that is the bridge's delay, counted apart.
        had = _stop_windows(hall, releases)
        known = _overlaps(stops, had)
        verdict.moved_while_stopped = _moved_while_stopped(truths, known, limits, verdict.details)
        # From each stop seen centrally to the hall's having it (its window ending after it).
        reached = [(s, min((h for h, end in had if end > s), default=e)) for s, e in stops]
        early = [(s, min(h, e)) for (s, e), (_, h) in zip(stops, reached, strict=True) if h > s]
        verdict.moved_before_the_hall_had_it = _moved_while_stopped(truths, early, limits, [])
        delays = [max(0.0, h - s) for s, h in reached if h != float("inf")]
        verdict.worst_stop_to_hall_s = max(delays, default=None)
    else:
        verdict.moved_while_stopped = _moved_while_stopped(truths, stops, limits, verdict.details)
    _jobs([e for e in ordered if isinstance(e, JobSeen)], verdict)
    quiet = [(d.start, d.end) for d in ordered if isinstance(d, Disturbed)] + stops
    states = [e for e in ordered if isinstance(e, StateSeen)]
    verdict.units_stranded = _stranded(states, quiet, limits, verdict.details)
    return verdict


def _time(event: Event) -> float:
    return event.start if isinstance(event, Disturbed) else event.t


def _collisions(truths: Sequence[Truth], details: list[str]) -> int:
    # Each units process counts from zero: the total is the sum of every run's last count.
    last: dict[int, int] = {}
    for truth in truths:
        last[truth.pid] = max(last.get(truth.pid, 0), truth.collisions)
    total = sum(last.values())
    if total:
        details.append(f"{total} collisions counted by the world simulation")
    return total


def _stop_windows(
    stops: Sequence[Stop], releases: Sequence[float], held: Sequence[Held] = ()
) -> list[tuple[float, float]]:
    """[engaged, released) windows; one still engaged at the end lasts for ever.

    The listener hears the release after the units may have: it shares one broker queue with
    all the fleet's traffic (`#`), under load lags by seconds, and on a cluster may sit on a
    node that relays late. A window therefore ends at the coordinator's own stamped release
    (`Held`) if one came after the operator's first release in the window; else at the
    operator's latest release before the listener saw the fleet released (a release that did
    not take, with a press still held, was given again: moves before that one count).
    """
    windows: list[tuple[float, float]] = []
    since: float | None = None
    for stop in stops:
        if stop.engaged and since is None:
            since = stop.t
        elif not stop.engaged and since is not None:
            given = [r for r in releases if since <= r <= stop.t]
            end = max(given, default=stop.t)
            if given:
                took = [h.t for h in held if not h.engaged and given[0] <= h.t <= stop.t]
                end = min([end, *took[:1]])
            windows.append((since, end))
            since = None
    if since is not None:
        windows.append((since, float("inf")))
    return windows


def _overlaps(
    a: Sequence[tuple[float, float]], b: Sequence[tuple[float, float]]
) -> list[tuple[float, float]]:
    """Where windows of `a` and of `b` overlap."""
    return [
        (max(s1, s2), min(e1, e2))
        for (s1, e1), (s2, e2) in itertools.product(a, b)
        if max(s1, s2) < min(e1, e2)
    ]


def _moved_while_stopped(
    truths: Sequence[Truth],
    stops: Sequence[tuple[float, float]],
    limits: SoakLimits,
    details: list[str],
) -> int:
    """Units whose square changed between two truth samples both well inside a stop window."""
    grace = limits.grace_steps * limits.step_s
    moved: set[tuple[str, int]] = set()  # (unit, window) counted once each
    for n, (start, end) in enumerate(stops):
        inside = [t for t in truths if start + grace <= t.t < end]
        # Across process runs too: a restarted units process must resume where its units stood.
        for before, after in itertools.pairwise(inside):
            for unit, square in after.positions.items():
                was = before.positions.get(unit)
                if was is not None and was != square and (unit, n) not in moved:
                    moved.add((unit, n))
                    details.append(
                        f"{unit} moved {list(was)} -> {list(square)} at {after.t:.2f}, "
                        f"{after.t - start:.2f} s after the stop was seen engaged"
                    )
    return len(moved)


def _jobs(seen: Sequence[JobSeen], verdict: SoakVerdict) -> None:
    """Every job seen must end, and end once: its states after a final one never change."""
    history: dict[str, list[str]] = defaultdict(list)
    for event in seen:
        states = history[event.job]
        if not states or states[-1] != event.state:
            states.append(event.state)
    verdict.jobs_submitted = len(history)
    for job, states in history.items():
        finals = [s for s in states if s in FINAL]
        verdict.jobs_done += states[-1] == "done"
        if states[-1] not in FINAL:
            verdict.jobs_lost += 1
            verdict.details.append(f"job {job} never ended: {' -> '.join(states)}")
        elif len(finals) > 1 or states.index(finals[0]) != len(states) - 1:
            verdict.jobs_duplicated += 1
            verdict.details.append(f"job {job} ended more than once: {' -> '.join(states)}")


def _stranded(
    states: Sequence[StateSeen],
    quiet: Sequence[tuple[float, float]],
    limits: SoakLimits,
    details: list[str],
) -> int:
    """Busy units that stood on one square for `stranded_s` of undisturbed time."""
    stranded: set[str] = set()
    since: dict[str, tuple[float, Square]] = {}  # unit -> (when it became busy here, square)
    for state in states:
        was = since.get(state.unit)
        if not state.busy:
            since.pop(state.unit, None)
            continue
        if was is None or was[1] != state.position:
            since[state.unit] = (state.t, state.position)
            continue
        still = state.t - was[0] - _overlap(was[0], state.t, quiet)
        if still >= limits.stranded_s and state.unit not in stranded:
            stranded.add(state.unit)
            details.append(
                f"{state.unit} busy on {list(state.position)} for {still:.1f} undisturbed s "
                f"(from {was[0]:.2f})"
            )
    return len(stranded)


def _overlap(start: float, end: float, windows: Sequence[tuple[float, float]]) -> float:
    """Seconds of [start, end] covered by the (possibly overlapping) windows."""
    covered = 0.0
    cursor = start
    for w_start, w_end in sorted(windows):
        lo, hi = max(w_start, cursor), min(w_end, end)
        if hi > lo:
            covered += hi - lo
            cursor = hi
    return covered
