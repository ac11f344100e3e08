"""The alerts process's metrics in the Prometheus format: every alert is also a metric.

Read at scrape time from a snapshot taken on the process's own event loop (`read_on_loop`), so a
scrape never sees the core half-way through a change. Labels are the rules alone (bounded): no
unit or job ids.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from gridfleet.alerts.core import RULES, AlertsCore
from gridfleet.alerts.webhook import Webhook


@dataclass(frozen=True)
class Figures:
    """What one scrape reports, copied out of the core and the webhook."""

    active: dict[str, int] = field(default_factory=dict)
    unacknowledged: dict[str, int] = field(default_factory=dict)
    raised: dict[str, int] = field(default_factory=dict)
    cleared: dict[str, int] = field(default_factory=dict)
    webhook: tuple[int, int, int, int] | None = None  # sent, failures, dropped, queued


def figures(core: AlertsCore, webhook: Webhook | None) -> Figures:
    """A snapshot of the figures (call it on the event loop that changes them)."""
    active: dict[str, int] = dict.fromkeys(RULES, 0)
    unacknowledged = dict(active)
    for alert in core.active.values():
        active[alert.rule] += 1
        unacknowledged[alert.rule] += alert.acked_by is None
    hook = None
    if webhook is not None:
        hook = (webhook.sent, webhook.failures, webhook.queue.dropped, len(webhook.queue))
    return Figures(
        active,
        unacknowledged,
        {rule: core.raised_total[rule] for rule in RULES},
        {rule: core.cleared_total[rule] for rule in RULES},
        hook,
    )


class _AlertsCollector(Collector):
    def __init__(self, read: Callable[[], Figures]) -> None:
        self._read = read

    def collect(self) -> Iterable[Metric]:
        f = self._read()
        for name, text, values in (
            ("gridfleet_alerts_active", "alerts in force, by rule", f.active),
            (
                "gridfleet_alerts_unacknowledged",
                "alerts in force that nobody has acknowledged, by rule",
                f.unacknowledged,
            ),
        ):
            gauge = GaugeMetricFamily(name, text, labels=["rule"])
            for rule, n in values.items():
                gauge.add_metric([rule], n)
            yield gauge
        for name, text, values in (
            ("gridfleet_alerts_raised", "alerts raised, by rule", f.raised),
            ("gridfleet_alerts_cleared", "alerts cleared, by rule", f.cleared),
        ):
            counter = CounterMetricFamily(name, text, labels=["rule"])
            for rule, n in values.items():
                counter.add_metric([rule], n)
            yield counter
        if f.webhook is not None:
            sent, failures, dropped, queued = f.webhook
            yield CounterMetricFamily(
                "gridfleet_alerts_webhook_sent", "notices the webhook's receiver took", sent
            )
            yield CounterMetricFamily(
                "gridfleet_alerts_webhook_failures",
                "tries to POST a notice that failed (each tried again later)",
                failures,
            )
            yield CounterMetricFamily(
                "gridfleet_alerts_webhook_dropped",
                "notices dropped undelivered from a full queue",
                dropped,
            )
            yield GaugeMetricFamily(
                "gridfleet_alerts_webhook_queued", "notices waiting for the receiver", queued
            )


def alerts_registry(read: Callable[[], Figures]) -> CollectorRegistry:
    """A registry of its own holding the alerts' metrics, read through `read`."""
    registry = CollectorRegistry(auto_describe=True)
    registry.register(_AlertsCollector(read))
    return registry
