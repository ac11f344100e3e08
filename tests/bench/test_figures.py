"""The benches' percentiles are values that were measured."""

from __future__ import annotations

import math

from gridfleet.bench.figures import percentile


def test_a_percentile_is_the_measured_value_at_or_above_it() -> None:
    samples = [5.0, 1.0, 4.0, 2.0, 3.0]
    assert percentile(samples, 0.0) == 1.0
    assert percentile(samples, 0.5) == 3.0
    assert percentile(samples, 0.6) == 4.0  # between 3 and 4: the one above, never 3.4
    assert percentile(samples, 0.99) == 5.0
    assert percentile(samples, 1.0) == 5.0
    assert percentile([7.5], 0.99) == 7.5


def test_no_samples_or_an_infinite_one_is_no_figure() -> None:
    assert percentile([], 0.5) is None
    assert percentile([1.0, math.inf], 1.0) is None
    assert percentile([1.0, 2.0, math.inf], 0.5) == 2.0
