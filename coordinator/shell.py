"""The coordinator's I/O shell: moves bytes between the broker, the job store and the core.

Every decision is the core's (coordinator/core.py): the shell hands it what arrives and the time,
and does what the returned Effects say: persist, publish, come back for batched views, and pace
the step loop (one step per period, waiting a while for the last step's acknowledgements while
more than a third of the units it ordered owe them: core.py, ACK_WAIT_S). With `metrics`,
it also counts what passes through it and serves `/metrics` (metrics.py; nothing is counted
without), and follows `errors` for every component's failed handlers (`handler_failures`).
"""

from __future__ import annotations

import asyncio
import logging
import secrets
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from gridfleet.coordinator.audit import DEFAULT_AUDIT_DAYS, Identity
from gridfleet.coordinator.audit_store import AuditStore
from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.effects import Effects
from gridfleet.coordinator.energy import EnergySettings
from gridfleet.coordinator.history import DEFAULT_RETENTION_DAYS, JobChanges
from gridfleet.coordinator.history_store import HistoryStore
from gridfleet.coordinator.jobs import JobBook
from gridfleet.coordinator.records import Entry, RecordKind, RecordsDesk, answer
from gridfleet.coordinator.store import JobStore, default_db_path
from gridfleet.coordinator.window import DEFAULT_WINDOW
from gridfleet.coordinator.world import World
from gridfleet.endpoint import Backoff, Endpoint
from gridfleet.grid import GridMap
from gridfleet.protocol import SUBSCRIBE_QOS, Charger, HeaderStamper, Place, Topics
from gridfleet.tasks import cancel_and_wait, first_of

if TYPE_CHECKING:  # prometheus_client and its HTTP server: imported only with --metrics
    from gridfleet.coordinator.metrics import CoordinatorMetrics
    from gridfleet.metrics import MetricsOptions, MetricsServer

log = logging.getLogger("gridfleet.coordinator")
# Requests answered in one go: their answers share a round trip to the broker, and between two
# batches the reader takes what arrived meanwhile.
SERVE_BATCH = 50
SERVE_BATCH_S = 0.02  # and at most this long answering them


class CoordinatorShell:
    """The coordinator's I/O shell: `await CoordinatorShell(...).run(shutdown)`; `ready` once online."""

    def __init__(
        self,
        broker: str,
        grid: GridMap,
        *,
        root: str = "gridfleet",
        step_s: float = 1.0,
        db_path: str | Path | None = None,
        client_id: str | None = None,
        seed: int = 0,
        window: int = DEFAULT_WINDOW,
        clock: Callable[[], float] = time.monotonic,
        metrics: MetricsOptions | None = None,
        identity: Identity | None = None,
        audit_days: float = DEFAULT_AUDIT_DAYS,
        history_days: float = DEFAULT_RETENTION_DAYS,
        chargers: Sequence[Charger] = (),
        energy: EnergySettings | None = None,
        places: Sequence[Place] = (),
    ) -> None:
        self.broker = broker
        self.topics = Topics(root)
        # The sender its messages name, and its MQTT client id: one per root by default, so
        # fleets sharing a broker do not take each other's connection (Topics.client_id).
        sender = client_id or "coordinator"
        client_id = client_id or self.topics.client_id("coordinator")
        self.step_s = step_s
        self.clock = clock
        self.store = JobStore(db_path if db_path is not None else default_db_path())
        # The audit trail: tables of its own in the same database (coordinator/audit.py).
        identity = identity or Identity()
        path = db_path if db_path is not None else default_db_path()
        self.audit_store = AuditStore(path, audit_days)
        # Every change of every job, with its time (coordinator/history.py): the same database.
        self.history = HistoryStore(path, history_days)
        self.job_changes = JobChanges(self.history.last)
        # Where the record queries the core checked are answered from (records.py).
        self.desks: dict[RecordKind, RecordsDesk[Entry]] = {
            "audit": self.audit_store,
            "job_history": self.history,
        }
        self.core = CoordinatorCore(
            World(grid, step_period_s=step_s, chargers=tuple(chargers), places=tuple(places)),
            JobBook(self.store.load()),
            nonce=secrets.token_hex(3),
            seed=seed,
            topics=self.topics,
            stamp=HeaderStamper(sender),
            controls=self.store.load_controls(),
            removals=self.store.load_removals(),
            zones=self.store.load_zones(),  # closed before a restart: closed still
            window=window,
            identity=identity,
            energy=energy,
        )
        self.core.audit.restore(self.audit_store.load_seen())
        self.core.answers.restore(self.store.load_answers())  # retries across a restart
        self.core.events.restore(self.store.load_events())
        for zone in self.core.zones.ignored:
            log.warning(
                "zone %s (%s to %s) is not on this map: not in force (open it to forget it)",
                zone.name,
                list(zone.first),
                list(zone.last),
            )
        self.world = self.core.world
        self._errors = self.topics.fleet("errors")
        self.endpoint = Endpoint(
            broker,
            client_id,
            name="coordinator",
            subscriptions=self._subscriptions,
            component="coordinator",
            report=lambda topic, reason: self.core.say.error(topic, reason, None),
            will=lambda: self.core.status("broken"),
            online=lambda: self.core.status("online"),
            offline=lambda: self.core.status("offline"),
            backoff=Backoff(0.1, 2.0),
        )
        self.ready = asyncio.Event()
        self.on_broker: str | None = None  # the broker of the latest session (None: none yet)
        self._acked = asyncio.Event()  # set whenever nothing is awaited any more
        self._views_later: asyncio.Task[None] | None = None
        self._requests = asyncio.Event()  # set when requests wait in the core's inbox
        # Metrics only when asked for (--metrics): otherwise nothing is counted at all.
        self.metrics: CoordinatorMetrics | None = None
        self.metrics_server: MetricsServer | None = None
        if metrics is not None:
            from gridfleet.coordinator.metrics import CoordinatorMetrics
            from gridfleet.metrics import MetricsServer

            self.metrics = CoordinatorMetrics(self.core, connected=self.ready.is_set, clock=clock)
            self.metrics_server = MetricsServer(self.metrics.registry, metrics)
        self._save(self.core.restored())

    def _subscriptions(self) -> list[tuple[str, int]]:
        """The core's, and with metrics `errors`, where every component tells its failures."""
        followed = list(self.core.subscriptions())
        if self.metrics is not None:
            followed.append((self._errors, SUBSCRIBE_QOS))
        return followed

    @property
    def errors_sent(self) -> int:
        """Error reports made so far (tests watch it)."""
        return self.core.errors_reported

    async def run(self, shutdown: asyncio.Event) -> None:
        """Serve until `stop` is set; reconnects with back-off when the broker goes away."""
        try:
            if self.metrics is not None and self.metrics_server is not None:
                self.metrics.bind(asyncio.get_running_loop())
                self.metrics_server.start()
                log.info("coordinator metrics on %s", self.metrics_server.url)
            await self.endpoint.run(
                shutdown,
                self.handle,
                on_connect=self._on_connect,
                on_disconnect=lambda _: self.ready.clear(),
                during=self._steps,
                on_stop=lambda: self._apply(self.core.halt_orders()),
            )
        finally:
            if self.metrics_server is not None:
                self.metrics_server.stop()
            self.store.close()
            self.audit_store.close()
            self.history.close()

    async def _on_connect(self) -> None:
        # Another broker than the session before: a failover, whose retained latch may be stale.
        broker, before = self.endpoint.where, self.on_broker
        self.on_broker = broker
        moved = before is not None and before != broker
        if moved:
            log.warning("coordinator failed over from %s to %s", before, broker)
        await self._apply(self.core.on_connect(self.clock(), moved=moved))
        self.ready.set()
        log.info("coordinator online at %s (root %s)", self.endpoint.where, self.topics.root)

    async def handle(self, topic: str, payload: bytes) -> None:
        """One inbound message, to the core; then whatever it says to do."""
        if topic == self._errors:  # followed for the metrics alone (its own reports too)
            if self.metrics is not None:
                self.metrics.error_reported(payload)
            return
        errors = self.core.errors_reported
        retained = self.endpoint.retained  # of this message: read before anything awaits
        effects, waits = self.core.offer(topic, payload, self.clock(), retained=retained)
        if waits:
            self._requests.set()  # answered by _serve, between what else arrives
        elif self.metrics is not None:
            self.metrics.received_one(topic, refused=self.core.errors_reported > errors)
        await self._apply(effects)

    async def _serve(self, shutdown: asyncio.Event) -> None:
        """Answer the requests waiting in the core's inbox, a batch at a time, for a session.

        Between batches the reader takes whatever arrived (states, the stop, cancels): one
        account's flood never keeps the coordinator from reading, and its queue at the broker
        never grows (it overflowed, and the broker dropped the coordinator's messages).
        """
        while not shutdown.is_set():
            await first_of(shutdown, self._requests)
            self._requests.clear()
            await self.answer_waiting(shutdown)

    async def answer_waiting(self, shutdown: asyncio.Event | None = None) -> None:
        """Answer every request waiting in the inbox (until `shutdown`), a batch at a time."""
        while len(self.core.inbox) and not (shutdown is not None and shutdown.is_set()):
            batch = []
            began = time.perf_counter()
            for _ in range(SERVE_BATCH):
                if time.perf_counter() - began > SERVE_BATCH_S:
                    break  # the reader's turn: what arrives meanwhile is read between batches
                errors = self.core.errors_reported
                served = self.core.serve_one(self.clock())
                if served is None:
                    break
                topic, effects = served
                if self.metrics is not None:
                    self.metrics.received_one(topic, self.core.errors_reported > errors)
                batch.append(effects)
            if not batch:
                return
            await self._apply(*batch)
            await asyncio.sleep(0)  # a turn for the reader and the step loop

    async def _steps(self, shutdown: asyncio.Event) -> None:
        """The step loop and the requests' answers, for as long as a session lasts."""
        serving = asyncio.create_task(self._serve(shutdown))
        if len(self.core.inbox):
            self._requests.set()  # left from the session before: answered on this one
        next_at = self.clock()
        try:
            while not shutdown.is_set():
                began = time.perf_counter()
                effects = self.core.step(self.clock())
                if self.metrics is not None:
                    self.metrics.stepped(time.perf_counter() - began)
                await self._apply(effects)
                next_at += self.step_s
                delay = max(0.0, next_at - self.clock())
                if delay == 0.0:
                    next_at = self.clock()  # late: no burst of steps to catch up
                await first_of(shutdown, timeout=delay)
                until = effects.acks_until
                if until is not None and self.core.orders.holding_back and self.clock() < until:
                    self._acked.clear()
                    await first_of(shutdown, self._acked, timeout=until - self.clock())
                    next_at = max(next_at, self.clock())
        finally:
            await cancel_and_wait(serving)
            if self._views_later is not None:
                await cancel_and_wait(self._views_later)

    async def _apply(self, *batch: Effects) -> None:
        if not self.core.orders.holding_back:
            self._acked.set()
        outs = []
        self._save(*batch)
        for effects in batch:
            for level, line in effects.log:
                log.log(level, line)
            if effects.views_at is not None:
                self._views_later = asyncio.create_task(self._views_after(effects.views_at))
            # Every message is handed to the client before any acknowledgement is awaited: in
            # the core's order on the wire (paho queues each in the first, synchronous part of a
            # publish), and a step's hundred orders take one round trip to the broker, not 100.
            outs += [out for out in effects.publish if not self.core.withdrawn(out)]
            for record in effects.records:  # checked by the core: read here, from its store
                page = answer(record, self.desks[record.kind], self.core.say)
                if page is not None:
                    outs.append(page)
        sends = [asyncio.ensure_future(self.endpoint.publish(out)) for out in outs]
        if self.metrics is not None:
            self.metrics.sent_some([out.topic for out in outs])
        if sends:
            await asyncio.gather(*sends)

    def _save(self, *batch: Effects) -> None:
        """Store what `batch` changed, each kind in one transaction (a batch of 50 answers in
        one, not fifty: the commits had been most of what a flood of requests cost)."""
        persist = tuple({job.id: job for e in batch for job in e.persist}.values())
        answered = tuple(a for e in batch for a in e.answered)
        if self.metrics is not None and persist:
            self.metrics.jobs_changed(persist)
        if persist or answered:
            self.store.save(persist, answered)
        if persist:
            now = self.core.say.stamp.now()
            self.history.add(self.job_changes.entries(persist, now), now)
        controls = tuple(c for e in batch for c in e.controls)
        if controls:
            self.store.save_controls(controls)
        removals = tuple(r for e in batch for r in e.removals)
        if removals:
            self.store.save_removals(removals)
        zones = tuple(z for e in batch for z in e.zones)
        if zones:
            self.store.save_zones(zones)
        charges = tuple(c for e in batch for c in e.charges)
        if charges:
            self.history.add_charges(charges)
        events = tuple(ev for e in batch for ev in e.events)
        if events:
            self.store.save_events(events)
        self.audit_store.add(entry for e in batch for entry in e.audit.entries)
        self.audit_store.save_seen(seen for e in batch for seen in e.audit.seen)
        self.audit_store.prune(self.core.say.stamp.now().timestamp())  # about once an hour

    async def _views_after(self, at: float) -> None:
        await asyncio.sleep(max(0.0, at - self.clock()))  # pacing: the end of a batch period
        await self._apply(self.core.views_due(self.clock()))
