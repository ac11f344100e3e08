"""Our pause, resume and cancel of a vehicle as one state machine, pure: every transition the table
allows, every one it refuses (changing nothing), and the resends of a resume and of an order."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from gridfleet.robots.vda5050.pause_cancel import (
    CANCEL_MOVES,
    PAUSE_MOVES,
    Cancel,
    Pause,
    PauseCancel,
)
from gridfleet.robots.vda5050.resend import RESEND_S, OrderResend


def paused_as(state: Pause) -> PauseCancel:
    """A machine brought to `state` of the pause by its own transitions."""
    machine = PauseCancel()
    if state is not Pause.NONE:
        assert machine.pause()
    if state in (Pause.RESUMING, Pause.REPAUSED):
        assert machine.resume(0.0)
    if state is Pause.REPAUSED:
        assert machine.pause()
    assert machine.pause_state is state
    return machine


def cancelled_as(state: Cancel) -> PauseCancel:
    """A machine brought to `state` of the cancel by its own transitions."""
    machine = PauseCancel()
    if state is Cancel.CANCELLING:
        assert machine.start_cancel("cancelOrder-1")
    if state is Cancel.ENDED:
        assert machine.end_under_stop()
    assert machine.cancel_state is state
    return machine


PAUSE_EVENTS: dict[str, Callable[[PauseCancel], bool]] = {
    "pause": lambda m: m.pause(),
    "resume": lambda m: m.resume(5.0),
    "resumed": lambda m: m.resumed(),
    "let_go": lambda m: m.let_go(),
}
CANCEL_EVENTS: dict[str, Callable[[PauseCancel], bool]] = {
    "start": lambda m: m.start_cancel("cancelOrder-2"),
    "done": lambda m: m.cancel_done({"cancelOrder-1"}),
    "end_under_stop": lambda m: m.end_under_stop(),
    "ended": lambda m: m.ended(),
}


@pytest.mark.parametrize("state", list(Pause))
@pytest.mark.parametrize("event", list(PAUSE_EVENTS))
def test_each_pause_event_moves_as_the_table_says_or_is_refused(state: Pause, event: str) -> None:
    machine = paused_as(state)
    target = PAUSE_MOVES.get((event, state))
    allowed = PAUSE_EVENTS[event](machine)
    assert allowed is (target is not None)
    assert machine.pause_state is (target or state)
    assert machine.cancel_state is Cancel.NONE  # the other region is untouched


@pytest.mark.parametrize("state", list(Cancel))
@pytest.mark.parametrize("event", list(CANCEL_EVENTS))
def test_each_cancel_event_moves_as_the_table_says_or_is_refused(state: Cancel, event: str) -> None:
    machine = cancelled_as(state)
    target = CANCEL_MOVES.get((event, state))
    allowed = CANCEL_EVENTS[event](machine)
    assert allowed is (target is not None)
    assert machine.cancel_state is (target or state)
    assert machine.pause_state is Pause.NONE


def test_a_pause_resume_and_its_effect_in_order() -> None:
    machine = PauseCancel()
    assert machine.pause() and machine.pause_state is Pause.PAUSED
    assert not machine.pause()  # sent already: refused, and nothing goes again
    assert machine.resume(1.0) and machine.pause_state is Pause.RESUMING
    assert machine.resumed() and machine.pause_state is Pause.NONE


def test_a_resume_without_a_pause_is_refused_and_changes_nothing() -> None:
    machine = PauseCancel()
    assert not machine.resume(1.0)
    assert machine.pause_state is Pause.NONE
    assert not machine.resend_resume(10.0)  # no resume of ours to send again


def test_a_pause_before_the_resume_is_seen_keeps_both_pending() -> None:
    machine = paused_as(Pause.RESUMING)  # stopPause sent at 0.0
    assert machine.pause() and machine.pause_state is Pause.REPAUSED
    assert machine.resend_resume(RESEND_S)  # as the adapter always did: see the core's caller
    assert machine.resumed() and machine.pause_state is Pause.PAUSED  # the pause stays
    assert not machine.resend_resume(RESEND_S * 3)


def test_going_offline_forgets_a_pause_but_not_a_resume_in_flight() -> None:
    assert paused_as(Pause.PAUSED).let_go()
    resuming = paused_as(Pause.RESUMING)
    assert not resuming.let_go() and resuming.pause_state is Pause.RESUMING
    repaused = paused_as(Pause.REPAUSED)
    assert repaused.let_go() and repaused.pause_state is Pause.RESUMING


def test_a_resume_not_seen_is_due_again_every_resend_period() -> None:
    machine = PauseCancel()
    machine.pause()
    machine.resume(10.0)
    assert not machine.resend_resume(10.0 + RESEND_S / 2)
    assert machine.resend_resume(10.0 + RESEND_S)
    assert not machine.resend_resume(10.0 + RESEND_S * 1.5)  # counted from the resend
    assert machine.resend_resume(10.0 + RESEND_S * 2)
    assert machine.resumed()
    assert not machine.resend_resume(10.0 + RESEND_S * 5)


def test_a_cancel_is_done_only_by_its_own_action_and_once() -> None:
    machine = PauseCancel()
    assert machine.start_cancel("cancelOrder-7") and machine.cancelling
    assert not machine.start_cancel("cancelOrder-8")  # one in flight: refused
    assert not machine.cancel_done({"startPause-3"}) and machine.cancelling
    assert machine.cancel_done({"startPause-3", "cancelOrder-7"})
    assert machine.cancel_state is Cancel.NONE and not machine.cancelling
    assert not machine.cancel_done({"cancelOrder-7"})  # the same state again: nothing more


def test_a_cancel_that_ended_under_the_stop_ends_on_the_release() -> None:
    machine = PauseCancel()
    machine.start_cancel("cancelOrder-1")
    machine.cancel_done({"cancelOrder-1"})
    assert machine.end_under_stop() and machine.cancel_state is Cancel.ENDED
    assert not machine.end_under_stop()  # once
    assert machine.ended() and machine.cancel_state is Cancel.NONE
    assert not machine.ended()  # nothing ended under the stop: refused


def test_pausing_and_cancelling_go_on_side_by_side() -> None:
    machine = PauseCancel()
    machine.start_cancel("cancelOrder-1")
    assert machine.pause() and machine.cancelling
    assert machine.cancel_done({"cancelOrder-1"}) and machine.pause_state is Pause.PAUSED


# ---- an order's resends ------------------------------------------------------------------------

ORDER = {"orderId": "gf-o", "orderUpdateId": 3, "headerId": 1}


def test_an_order_not_seen_is_due_again_after_the_resend_period() -> None:
    resend = OrderResend()
    assert resend.due(100.0) is None and not resend.pending
    resend.sent(ORDER, 10.0)
    assert resend.due(10.0 + RESEND_S / 2) is None
    assert resend.due(10.0 + RESEND_S) == ORDER


@pytest.mark.parametrize(
    ("order_id", "update_id", "refused", "done"),
    [
        ("gf-o", 3, False, True),  # it follows the order
        ("gf-o", 2, False, False),  # an older update: not yet
        ("other", 3, False, False),
        ("other", 0, True, True),  # it refused an order: nothing to send again
    ],
)
def test_a_state_ends_the_resends_when_it_shows_the_order_or_a_refusal(
    order_id: str, update_id: int, refused: bool, done: bool
) -> None:
    resend = OrderResend()
    resend.sent(ORDER, 10.0)
    resend.seen(order_id, update_id, refused)
    assert resend.pending is not done
    assert (resend.due(20.0) is None) is done
