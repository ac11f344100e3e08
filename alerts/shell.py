"""The alerts process's I/O shell: the broker, the clock, the webhook and `/metrics` around the core.

Every decision is the core's (alerts/core.py); the shell hands it what arrives with the time,
ticks it, tells it when the broker session comes and goes, and does what the Effects say:
publish, queue notices for the webhook, log.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

from gridfleet.alerts.core import AlertsCore, Effects
from gridfleet.alerts.settings import AlertSettings
from gridfleet.alerts.webhook import Backoff as WebhookBackoff
from gridfleet.alerts.webhook import NoticeQueue, Webhook
from gridfleet.endpoint import Backoff, Endpoint
from gridfleet.protocol import HeaderStamper, Topics
from gridfleet.tasks import cancel_and_wait

if TYPE_CHECKING:  # prometheus_client and its HTTP server: imported only with --metrics
    from gridfleet.metrics import MetricsOptions, MetricsServer

log = logging.getLogger("gridfleet.alerts")
TICK_S = 0.25  # how often thresholds are looked at: well under any threshold worth having
SENDER = "alerts"


class AlertsShell:
    """`await AlertsShell(...).run(shutdown)`; `ready` is set while connected and subscribed."""

    def __init__(
        self,
        broker: str,
        settings: AlertSettings,
        *,
        root: str = "gridfleet",
        accounts: Mapping[str, str] | None = None,
        metrics: MetricsOptions | None = None,
        webhook_backoff: WebhookBackoff | None = None,
        clock: Callable[[], float] = time.monotonic,
        tick_s: float = TICK_S,
    ) -> None:
        self.topics = Topics(root)
        self.clock = clock
        self.tick_s = tick_s
        self.core = AlertsCore(
            self.topics,
            settings,
            HeaderStamper(SENDER),
            nonce=secrets.token_hex(3),
            now=clock(),
            accounts=accounts,
        )
        self.webhook: Webhook | None = None
        if settings.webhook is not None:
            queue = NoticeQueue(settings.webhook_queue)
            self.webhook = Webhook(
                settings.webhook, queue, backoff=webhook_backoff or WebhookBackoff()
            )
        self.endpoint = Endpoint(
            broker,
            self.topics.client_id(SENDER),
            name="alerts",
            subscriptions=self.core.subscriptions,
            backoff=Backoff(0.1, 2.0),
            component="alerts",
            report=lambda topic, reason: self.core.report(topic, reason),
        )
        self.ready = asyncio.Event()
        self.metrics_server: MetricsServer | None = None
        self._metrics = metrics

    async def run(self, shutdown: asyncio.Event) -> None:
        """Serve until `shutdown` is set; reconnects with back-off when the broker goes away."""
        tasks: list[asyncio.Task[None]] = []
        try:
            self._serve_metrics()
            if self.webhook is not None:
                tasks.append(asyncio.create_task(self.webhook.run(shutdown)))
                log.info("alerts go to the webhook %s", self.webhook.where)
            tasks.append(asyncio.create_task(self._ticks(shutdown)))
            await self.endpoint.run(
                shutdown,
                self._handle,
                on_connect=self._on_connect,
                on_disconnect=self._on_disconnect,
            )
        finally:
            for task in tasks:
                await cancel_and_wait(task)
            if self.metrics_server is not None:
                self.metrics_server.stop()
            if self.webhook is not None:
                self.webhook.queue.close()

    def _serve_metrics(self) -> None:
        if self._metrics is None:
            return
        from gridfleet.alerts.metrics import alerts_registry, figures
        from gridfleet.metrics import MetricsServer, read_on_loop

        loop = asyncio.get_running_loop()
        registry = alerts_registry(
            lambda: read_on_loop(loop, lambda: figures(self.core, self.webhook))
        )
        self.metrics_server = MetricsServer(registry, self._metrics).start()
        log.info("alerts metrics on %s", self.metrics_server.url)

    async def _on_connect(self) -> None:
        await self._apply(self.core.connected(self.clock()))
        self.ready.set()
        log.info("alerts online at %s (root %s)", self.endpoint.where, self.topics.root)

    def _on_disconnect(self, _reason: str) -> None:
        self.ready.clear()
        # Nothing can be published without a session: the notices (broker_down) still go out.
        self._take(self.core.disconnected(self.clock()))

    async def _handle(self, topic: str, payload: bytes) -> None:
        await self._apply(self.core.on_message(topic, payload, self.clock()))

    async def _ticks(self, shutdown: asyncio.Event) -> None:
        while not shutdown.is_set():
            await self._apply(self.core.tick(self.clock()))
            with contextlib.suppress(TimeoutError):  # pacing, not waiting on news
                await asyncio.wait_for(shutdown.wait(), self.tick_s)

    def _take(self, effects: Effects) -> None:
        for level, line in effects.log:
            log.log(level, line)
        if self.webhook is not None:
            for body in effects.notices:
                self.webhook.put(body)

    async def _apply(self, effects: Effects) -> None:
        self._take(effects)
        for out in effects.publish:
            await self.endpoint.publish(out)
