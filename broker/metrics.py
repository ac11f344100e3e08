"""The embedded broker's metrics in the Prometheus format (docs/monitoring.md lists them)."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric

from gridfleet.broker.stats import REFUSALS, BrokerFigures


class BrokerCollector:
    """The broker's figures at scrape time, each as a gauge or a counter."""

    def __init__(self, take: Callable[[], BrokerFigures | None]) -> None:
        self._take = take

    def collect(self) -> Iterable[Metric]:
        """Nothing while the broker is not running."""
        f = self._take()
        if f is None:
            return
        gauges = (
            ("clients", "Clients connected now.", f.clients),
            (
                "sessions",
                "Sessions kept, persistent ones of clients not connected included.",
                f.sessions,
            ),
            (
                "queued_messages",
                "Messages waiting in connected clients' backlogs.",
                f.queued_messages,
            ),
            ("queued_bytes", "Bytes of the messages waiting in clients' backlogs.", f.queued_bytes),
            ("retained_messages", "Retained messages held.", f.retained),
            ("routing_messages", "Messages received and waiting to be routed.", f.routing),
        )
        for name, text, value in gauges:
            yield GaugeMetricFamily(f"gridfleet_broker_{name}", text, value=value)
        counters = (
            ("messages_received", "Messages clients published (wills included).", f.received),
            (
                "messages_delivered",
                "Copies of messages handed to subscribers (dropped ones included).",
                f.delivered,
            ),
            (
                "messages_dropped",
                "Copies dropped because the subscriber's backlog was full (it does not read).",
                f.dropped,
            ),
        )
        for name, text, value in counters:
            yield CounterMetricFamily(f"gridfleet_broker_{name}", text, value=value)
        refused = CounterMetricFamily(
            "gridfleet_broker_refused",
            "What the broker refused: connections (accounts), websockets (origins), publishes.",
            labels=["what"],
        )
        for what in REFUSALS:
            refused.add_metric([what], f.refused.get(what, 0))
        yield refused


def broker_registry(take: Callable[[], BrokerFigures | None]) -> CollectorRegistry:
    """A registry of the broker's own (the process's figures are not the fleet's)."""
    registry = CollectorRegistry()
    registry.register(BrokerCollector(take))
    return registry
