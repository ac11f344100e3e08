"""The test LAN fixture: network namespaces on one bridge (gridfleet.bench.lan), per test."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from gridfleet.bench.lan import Lan, can_make_lans, lan

__all__ = ["Lan", "test_lan"]


@pytest.fixture
def test_lan() -> Iterator[Lan]:
    """A LAN for the test (skipped in one line on a machine that cannot make one)."""
    why_not = can_make_lans()
    if why_not is not None:
        pytest.skip(f"no test LAN: {why_not}")
    with lan() as made:
        yield made
