"""A long-running service puts what start-up made out of the garbage collector's reach."""

from __future__ import annotations

import asyncio
import gc
from collections.abc import Iterator

import pytest

from gridfleet.heap import freeze, freeze_after_start


@pytest.fixture(autouse=True)
def unfrozen() -> Iterator[None]:
    """The test process's heap as it was: frozen objects are never collected."""
    gc.unfreeze()
    yield
    gc.unfreeze()


def test_freeze_keeps_live_objects_out_of_collections_and_collects_the_garbage_first() -> None:
    class Cycle:
        def __init__(self) -> None:
            self.me = self

    Cycle()  # garbage, reachable only from itself
    kept = [object() for _ in range(100)]
    freeze()
    assert gc.get_freeze_count() >= len(kept)
    assert not any(isinstance(o, Cycle) for o in gc.get_objects())


async def test_a_service_freezes_at_start_and_again_once_its_sessions_are_made() -> None:
    freeze_after_start(settle_s=0.05)
    first = gc.get_freeze_count()
    made_since = [[n] for n in range(1000)]  # tracked containers, made after the first freeze
    deadline = asyncio.get_running_loop().time() + 5
    while gc.get_freeze_count() < first + len(made_since) // 2:
        assert asyncio.get_running_loop().time() < deadline, "no second freeze"
        await asyncio.sleep(0.01)  # polling the freeze count
