"""The coordinator's metrics in the Prometheus format (docs/monitoring.md lists them).

Shell side only: the core stays free of clocks and HTTP. Two halves:
- what the core's state says at scrape time (units by connection and status, jobs by state, the
  stop, the achieved step period), read by a Collector through a snapshot taken on the
  coordinator's own event loop, so a scrape never sees a dict half-way through a change;
- what passes through the shell (step and planner time, messages in and out, refusals, job state
  transitions, units lost and recovered, the stop's latency), counted as it happens;
- every component's failed handlers, as their reports on `errors` tell them (gridfleet/failures.py).
Labels are bounded: topic kinds, states, reason kinds, energy plans. No job ids; unit ids
only on the battery gauge (one series per unit that reports energy: bounded by the fleet).
"""

from __future__ import annotations

import asyncio
import time
from collections import Counter as Tally
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import wraps
from typing import Any, get_args

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric

from gridfleet import __version__
from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.jobs import Job
from gridfleet.errors import ProtocolError
from gridfleet.failures import COMPONENTS, parse_failure
from gridfleet.failures import OTHER as OTHER_COMPONENT
from gridfleet.metrics import read_on_loop
from gridfleet.protocol import TOPICS, ErrorReport, decode
from gridfleet.protocol.messages import EnergyPlan, JobState, UnitStatus
from gridfleet.protocol.stop import LATCH

CONNECTIONS = ("online", "offline", "broken", "unknown")  # unknown: not heard yet
STATUSES = (*get_args(UnitStatus), "unknown")  # unknown: no state yet
JOB_STATES: tuple[str, ...] = get_args(JobState)
ENERGY_PLANS: tuple[str, ...] = get_args(EnergyPlan)
STOP_SOURCES = {LATCH: "latch", "stop": "unit", "device_stop": "device"}  # topic kind -> label
OTHER = "other"
_TOPIC_CACHE = 4096  # topics whose kind is remembered (units x kinds; cleared when full)

STEP_BUCKETS = (0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5)
JOB_BUCKETS = (1.0, 2.0, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1800.0, 3600.0, 7200.0)
STOP_BUCKETS = (0.05, 0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0, 10.0)

# Reason kinds of rejected and failed jobs: the core's reasons are sentences naming units and
# squares (unbounded); a label takes the kind. The phrases are those of allocation.py and
# progress.py (tests/coordinator/test_metrics.py builds allocation.py's with its own functions).
_REASON_KINDS = (
    ("exceeds every unit's capacity", "over_capacity"),
    ("cannot be reached", "unreachable"),
    ("can reach pickup", "unreachable"),
    ("was lost carrying", "unit_lost"),
    ("no longer carries", "item_lost"),
)
REASON_KINDS = ("over_capacity", "unreachable", "unit_lost", "item_lost", OTHER)


def reason_kind(reason: str | None) -> str:
    """The bounded kind of a job's reason (`other` for any sentence not known here)."""
    for phrase, kind in _REASON_KINDS:
        if reason is not None and phrase in reason:
            return kind
    return OTHER


@dataclass(frozen=True)
class Snapshot:
    """The core's state as one scrape shows it (taken on the coordinator's loop)."""

    units: Tally[tuple[str, str]]  # (connection, status) -> units
    lost: int
    jobs: Mapping[str, int]
    estop: bool
    stop_sources: Tally[str]
    step: int
    step_period_s: float
    achieved_step_s: float | None
    obstacles: int
    connected: bool
    battery: Mapping[str, float] = field(default_factory=dict)  # unit -> its charge (%)
    plans: Mapping[str, int] = field(default_factory=dict)  # energy plan -> units
    charges_started: int = 0
    charged_s: float = 0.0
    zones: int = 0  # zones closed (protocol.md §5.11)
    zoned_squares: int = 0  # squares they close


def snapshot(core: CoordinatorCore, connected: bool) -> Snapshot:
    """What the core's state says now (call it on the coordinator's loop)."""
    units: Tally[tuple[str, str]] = Tally()
    lost = 0
    for rec in core.world.units.values():
        status = rec.state.status if rec.state is not None else "unknown"
        units[(rec.connection or "unknown", status)] += 1
        lost += rec.lost_since is not None
    view = core.stop.view
    sources: Tally[str] = Tally({"latch": int(view.latch_engaged)})
    for topic in view.presses:
        sources[STOP_SOURCES.get(_kind(core, topic), OTHER)] += 1
    return Snapshot(
        units=units,
        lost=lost,
        jobs={str(state): n for state, n in core.jobs.counts().items()},
        estop=core.estop,
        stop_sources=sources,
        step=core.step_no,
        step_period_s=core.world.step_period_s,
        achieved_step_s=core.pace.achieved_step_s,
        obstacles=len(core.world.obstacles),
        connected=connected,
        battery={
            rec.id: rec.state.battery_pct
            for rec in core.world.units.values()
            if rec.state is not None and rec.state.battery_pct is not None
        },
        plans=Tally(u.plan for u in core.energy.units_view().values()),
        charges_started=core.energy.started,
        charged_s=core.energy.charged_s,
        zones=len(core.zones),
        zoned_squares=int(core.zones.mask().sum()) if core.zones else 0,
    )


def _kind(core: CoordinatorCore, topic: str) -> str:
    try:
        return core.topics.parse(topic)[0]
    except ProtocolError:
        return OTHER


class StateCollector:
    """The gauges read from the core at scrape time."""

    def __init__(self, take: Callable[[], Snapshot]) -> None:
        self._take = take

    def collect(self) -> Iterable[Metric]:
        """One family per figure, every label value present (zero included)."""
        s = self._take()
        units = GaugeMetricFamily(
            "gridfleet_units",
            "Units the coordinator knows, by connection and by the status of their latest state.",
            labels=["connection", "status"],
        )
        for connection in CONNECTIONS:
            for status in STATUSES:
                units.add_metric([connection, status], s.units[(connection, status)])
        yield units
        yield GaugeMetricFamily(
            "gridfleet_units_lost",
            "Units lost now: offline, broken, or their states silent for 5 step periods.",
            value=s.lost,
        )
        jobs = GaugeMetricFamily("gridfleet_jobs", "Jobs by state.", labels=["state"])
        for state in JOB_STATES:
            jobs.add_metric([state], s.jobs.get(state, 0))
        yield jobs
        yield GaugeMetricFamily(
            "gridfleet_estop_engaged", "1 while the emergency stop holds the fleet.", value=s.estop
        )
        sources = GaugeMetricFamily(
            "gridfleet_estop_sources",
            "What holds the stop: the operators' latch, units' and devices' presses.",
            labels=["source"],
        )
        for source in STOP_SOURCES.values():
            sources.add_metric([source], s.stop_sources[source])
        yield sources
        yield CounterMetricFamily(
            "gridfleet_steps", "Coordinator steps taken since it started.", value=s.step
        )
        yield GaugeMetricFamily(
            "gridfleet_step_period_seconds", "The step period asked for.", value=s.step_period_s
        )
        if s.achieved_step_s is not None:  # absent until the first few seconds are measured
            yield GaugeMetricFamily(
                "gridfleet_step_achieved_seconds",
                "The mean step interval achieved over the last few seconds.",
                value=s.achieved_step_s,
            )
        yield GaugeMetricFamily(
            "gridfleet_obstacles_discovered",
            "Obstacles units discovered that the map did not have.",
            value=s.obstacles,
        )
        yield GaugeMetricFamily(
            "gridfleet_zones_closed", "Zones closed now (no unit is sent in).", value=s.zones
        )
        yield GaugeMetricFamily(
            "gridfleet_zone_squares_closed",
            "Squares of the map the closed zones cover.",
            value=s.zoned_squares,
        )
        yield GaugeMetricFamily(
            "gridfleet_coordinator_connected",
            "1 while the coordinator is connected to its broker.",
            value=s.connected,
        )
        battery = GaugeMetricFamily(
            "gridfleet_unit_battery_percent",
            "Each unit's charge as its latest state reports it (units that report energy).",
            labels=["unit"],
        )
        for unit, pct in sorted(s.battery.items()):
            battery.add_metric([unit], pct)
        yield battery
        plans = GaugeMetricFamily(
            "gridfleet_units_energy_plan",
            "Units the energy policy sends to, holds at or queues for a charger, or cannot help.",
            labels=["plan"],
        )
        for plan in ENERGY_PLANS:
            plans.add_metric([plan], s.plans.get(plan, 0))
        yield plans
        yield CounterMetricFamily(
            "gridfleet_charges_started",
            "Charges started (a unit's state said it charges).",
            value=s.charges_started,
        )
        yield CounterMetricFamily(
            "gridfleet_charging_seconds",
            "Seconds units charged: the charges ended and those under way.",
            value=s.charged_s,
        )
        info = GaugeMetricFamily(
            "gridfleet_coordinator_info", "The coordinator's version.", labels=["version"]
        )
        info.add_metric([__version__], 1)
        yield info


@dataclass
class _Seen:
    """A job's last state seen, and since when it waits in the queue (None: it does not)."""

    state: str
    submitted_at: float | None  # None: from before this coordinator started
    queued_since: float | None


class CoordinatorMetrics:
    """A coordinator's registry: what passes through its shell, its core's state when scraped."""

    def __init__(
        self,
        core: CoordinatorCore,
        *,
        connected: Callable[[], bool] = lambda: True,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.core = core
        self.clock = clock
        self._connected = connected
        self._loop: asyncio.AbstractEventLoop | None = None
        self.registry = CollectorRegistry()
        r = self.registry
        self.step_seconds = Histogram(
            "gridfleet_step_duration_seconds",
            "Time the coordinator takes to decide one step (allocation, planning, orders).",
            buckets=STEP_BUCKETS,
            registry=r,
        )
        self.planner_seconds = Histogram(
            "gridfleet_planner_duration_seconds",
            "Time the planner takes for one step of the fleet's moves.",
            buckets=STEP_BUCKETS,
            registry=r,
        )
        self.received = Counter(
            "gridfleet_messages_received",
            "Messages the coordinator received, by topic kind.",
            ["kind"],
            registry=r,
        )
        self.sent = Counter(
            "gridfleet_messages_sent",
            "Messages the coordinator published, by topic kind.",
            ["kind"],
            registry=r,
        )
        self.refused = Counter(
            "gridfleet_messages_refused",
            "Messages refused with a report on `errors` (invalid, or refused requests), by kind.",
            ["kind"],
            registry=r,
        )
        self.handler_failures = Counter(
            "gridfleet_handler_failures",
            "Messages a component's handler failed on (a bug), as its reports on `errors` tell, "
            "by the kind of component.",
            ["component"],
            registry=r,
        )
        self.jobs_done = Counter("gridfleet_jobs_done", "Jobs done.", registry=r)
        self.jobs_rejected = Counter(
            "gridfleet_jobs_rejected",
            "Jobs rejected (no unit could ever do them), by reason kind.",
            ["reason"],
            registry=r,
        )
        self.jobs_failed = Counter(
            "gridfleet_jobs_failed",
            "Jobs failed under way, by reason kind.",
            ["reason"],
            registry=r,
        )
        self.jobs_cancelled = Counter("gridfleet_jobs_cancelled", "Jobs cancelled.", registry=r)
        self.queue_wait = Histogram(
            "gridfleet_job_queue_wait_seconds",
            "Time a job waited in the queue before a unit was assigned to it (each wait).",
            buckets=JOB_BUCKETS,
            registry=r,
        )
        self.job_duration = Histogram(
            "gridfleet_job_duration_seconds",
            "Time from a job's submission to its end, by how it ended.",
            ["state"],
            buckets=JOB_BUCKETS,
            registry=r,
        )
        self.unit_losses = Counter(
            "gridfleet_unit_losses",
            "Times a unit was lost (offline, broken or silent).",
            registry=r,
        )
        self.unit_recoveries = Counter(
            "gridfleet_unit_recoveries", "Times a lost unit was heard from again.", registry=r
        )
        self.estop_stopped = Histogram(
            "gridfleet_estop_stopped_seconds",
            "From the coordinator seeing the stop engaged to every unit it hears reporting "
            "itself stopped.",
            buckets=STOP_BUCKETS,
            registry=r,
        )
        for reason in REASON_KINDS:  # present from the start: rate() needs the zero before
            self.jobs_rejected.labels(reason)
            self.jobs_failed.labels(reason)
        for state in ("done", "cancelled", "failed"):
            self.job_duration.labels(state)
        for component in (*COMPONENTS, OTHER_COMPONENT):
            self.handler_failures.labels(component)
        r.register(StateCollector(self._snapshot))
        self._kinds: dict[str, str] = {}
        self._jobs = {
            j.id: _Seen(j.state, None, None) for j in (*core.jobs.queued(), *core.jobs.active())
        }
        self._lost: set[str] = set()
        self._engaged_at: float | None = None  # when the stop was seen engaged
        self._stop_pending = False  # engaged, and not every unit heard from says stopped yet
        self._timed_planner()

    # ---- at scrape time ----------------------------------------------------------------

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Scrapes from other threads take their snapshot on `loop` (the coordinator's)."""
        self._loop = loop

    def _snapshot(self) -> Snapshot:
        return read_on_loop(self._loop, lambda: snapshot(self.core, self._connected()))

    # ---- as things pass through the shell ------------------------------------------------

    def kind(self, topic: str) -> str:
        """The topic kind of `topic` (`other` for one outside the root), remembered."""
        kind = self._kinds.get(topic)
        if kind is None:
            if len(self._kinds) >= _TOPIC_CACHE:
                self._kinds.clear()
            kind = self._kinds[topic] = _kind(self.core, topic)
        return kind

    def received_one(self, topic: str, refused: bool) -> None:
        """A message handled; `refused`: the core reported it on `errors`."""
        kind = self.kind(topic)
        self.received.labels(kind).inc()
        if refused:
            self.refused.labels(kind).inc()
        self._check_stop()

    def error_reported(self, payload: bytes) -> None:
        """A report on `errors`: the failures it tells of counted (a refusal, or junk, is not)."""
        try:
            report = decode(ErrorReport, payload, TOPICS["errors"].max_bytes)
        except ProtocolError:
            return
        failure = parse_failure(report.reason)
        if failure is not None:
            self.handler_failures.labels(failure.component).inc(failure.count)

    def sent_some(self, topics: Sequence[str]) -> None:
        """Messages handed to the broker."""
        for topic in topics:
            self.sent.labels(self.kind(topic)).inc()

    def stepped(self, seconds: float) -> None:
        """A step took `seconds`; who is lost now."""
        self.step_seconds.observe(seconds)
        lost = {rec.id for rec in self.core.world.units.values() if rec.lost_since is not None}
        self.unit_losses.inc(len(lost - self._lost))
        # A unit forgotten (another map's) is not one heard again.
        back = {u for u in self._lost - lost if u in self.core.world.units}
        self.unit_recoveries.inc(len(back))
        self._lost = lost
        self._check_stop()

    def jobs_changed(self, jobs: Iterable[Job]) -> None:
        """Jobs the core persisted: their state transitions, counted and timed."""
        now = self.clock()
        for job in jobs:
            seen = self._jobs.get(job.id)
            if seen is None:  # submitted now
                seen = _Seen("new", now, None)
            if job.state == seen.state:
                continue  # only its wait explained differently
            if job.state == "queued":
                seen.queued_since = now
            elif seen.queued_since is not None:
                self.queue_wait.observe(now - seen.queued_since)
                seen.queued_since = None
            seen.state = job.state
            if not job.final:
                self._jobs[job.id] = seen
                continue
            self._jobs.pop(job.id, None)
            if job.state == "done":
                self.jobs_done.inc()
            elif job.state == "rejected":
                self.jobs_rejected.labels(reason_kind(job.reason)).inc()
            elif job.state == "failed":
                self.jobs_failed.labels(reason_kind(job.reason)).inc()
            else:
                self.jobs_cancelled.inc()
            if seen.submitted_at is not None and job.state != "rejected":
                self.job_duration.labels(job.state).observe(now - seen.submitted_at)

    def _check_stop(self) -> None:
        """Time the stop: from engaged to every unit heard from reporting itself stopped."""
        if not self.core.estop:
            self._engaged_at = None
            return
        now = self.clock()
        if self._engaged_at is None:
            self._engaged_at = now
            self._stop_pending = True
        if not self._stop_pending:
            return
        heard = [
            rec.state
            for rec in self.core.world.units.values()
            if rec.state is not None and rec.lost_since is None
        ]
        if heard and all(state.estop for state in heard):
            self.estop_stopped.observe(now - self._engaged_at)
            self._stop_pending = False

    def _timed_planner(self) -> None:
        """The planner's step, timed: wrapped on this core's planner, the core stays clock-free."""
        planner = self.core.planner
        inner = planner.step

        @wraps(inner)
        def step(*args: Any, **kwargs: Any) -> Any:
            began = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                self.planner_seconds.observe(time.perf_counter() - began)

        planner.step = step  # type: ignore[method-assign]
