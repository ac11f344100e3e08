"""Reading a Prometheus scrape in tests: GET a /metrics page, parse it with prometheus_client."""

from __future__ import annotations

import urllib.error
import urllib.request
from dataclasses import dataclass

from prometheus_client.parser import text_string_to_metric_families

Samples = dict[tuple[str, tuple[tuple[str, str], ...]], float]


@dataclass(frozen=True)
class Scrape:
    """One scrape: every sample by (name, labels), and every family's type."""

    samples: Samples
    types: dict[str, str]

    def value(self, name: str, **labels: str) -> float:
        """The sample `name` with exactly `labels` (KeyError when absent)."""
        return self.samples[(name, tuple(sorted(labels.items())))]

    def total(self, name: str, **labels: str) -> float:
        """The sum of the samples `name` whose labels include `labels`."""
        want = set(labels.items())
        return sum(v for (n, ls), v in self.samples.items() if n == name and want <= set(ls))

    def labels_of(self, name: str, label: str) -> set[str]:
        """Every value `label` takes among the samples `name`."""
        return {dict(ls)[label] for (n, ls) in self.samples if n == name}


def parse(text: str) -> Scrape:
    """The Prometheus text format, read with prometheus_client's own parser."""
    samples: Samples = {}
    types = {}
    for family in text_string_to_metric_families(text):
        types[family.name] = family.type
        for s in family.samples:
            samples[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return Scrape(samples, types)


def get(url: str, token: str | None = None) -> tuple[int, str]:
    """(status, body) of a GET, 4xx included."""
    request = urllib.request.Request(url)
    if token is not None:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, response.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()
