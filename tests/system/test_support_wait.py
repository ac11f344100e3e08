"""The tests' one way to wait: a deadline, and on a timeout what was waited for and where things
stood."""

from __future__ import annotations

import pytest

from support.wait import WaitTimeout, wait_for


def test_a_timeout_says_what_was_awaited_and_what_the_context_says_then() -> None:
    looks: list[int] = []

    def where() -> str:
        looks.append(1)
        return "unit1 at [1, 7]"

    with pytest.raises(WaitTimeout) as caught:
        wait_for(lambda: False, 0.05, what="the job done", context=where)
    assert str(caught.value) == "timed out after 0.05 s waiting for the job done: unit1 at [1, 7]"
    assert looks == [1]  # asked once, at the timeout


def test_a_condition_that_comes_true_returns_its_value_and_never_asks_the_context() -> None:
    def never() -> str:
        raise AssertionError("the context is for a timeout only")

    assert wait_for(lambda: 7, 1, what="seven", context=never) == 7
    with pytest.raises(WaitTimeout, match=r"^timed out after 0\.01 s waiting for x$"):
        wait_for(lambda: 0, 0.01, what="x")
