"""Pause, resume and cancel, pure: what the adapter asked of a vehicle at once, until it shows it.

One state machine of two regions, each with its transitions in a table (an event from a state the
table does not list is refused: it changes nothing and returns False):

- the pause: NONE (no pause of ours) -pause-> PAUSED (our startPause sent) -resume-> RESUMING (our
  stopPause sent, the vehicle not yet seen unpaused) -resumed-> NONE. A vehicle that let go of
  our pause, or went offline, is NONE again (`let_go`). A resume not seen taking effect for
  RESEND_S is due again (`resend_resume`), also after a pause that came before it was seen:
  REPAUSED (its pause and its resume both pending; `resumed` leaves it PAUSED, `let_go` RESUMING).
- the cancel: NONE -start-> CANCELLING (our cancelOrder in flight, by its action id) -done-> NONE;
  a cancelled order that came to an end under the stop is ENDED (`end_under_stop`), to end on
  the release (`ended`). A new cancel may start from ENDED.
"""

from __future__ import annotations

from collections.abc import Mapping, Set
from enum import Enum
from typing import TypeVar

from gridfleet.robots.vda5050.resend import RESEND_S


class Pause(Enum):
    """Where our pause of the vehicle stands."""

    NONE = "none"
    PAUSED = "paused"
    RESUMING = "resuming"
    REPAUSED = "repaused"


class Cancel(Enum):
    """Where our cancel of the vehicle's order stands."""

    NONE = "none"
    CANCELLING = "cancelling"
    ENDED = "ended"


State = TypeVar("State", Pause, Cancel)
# (event, the state it happens in) -> the state it leads to; any other pair is refused.
PAUSE_MOVES: Mapping[tuple[str, Pause], Pause] = {
    ("pause", Pause.NONE): Pause.PAUSED,
    ("pause", Pause.RESUMING): Pause.REPAUSED,
    ("resume", Pause.PAUSED): Pause.RESUMING,
    ("resume", Pause.REPAUSED): Pause.RESUMING,
    ("resumed", Pause.RESUMING): Pause.NONE,
    ("resumed", Pause.REPAUSED): Pause.PAUSED,
    ("let_go", Pause.PAUSED): Pause.NONE,
    ("let_go", Pause.REPAUSED): Pause.RESUMING,
}
RESUME_PENDING = frozenset({Pause.RESUMING, Pause.REPAUSED})  # our stopPause not yet seen
CANCEL_MOVES: Mapping[tuple[str, Cancel], Cancel] = {
    ("start", Cancel.NONE): Cancel.CANCELLING,
    ("start", Cancel.ENDED): Cancel.CANCELLING,
    ("done", Cancel.CANCELLING): Cancel.NONE,
    ("end_under_stop", Cancel.NONE): Cancel.ENDED,
    ("ended", Cancel.ENDED): Cancel.NONE,
}


def _move(moves: Mapping[tuple[str, State], State], event: str, now: State) -> tuple[State, bool]:
    """The state `event` leads to from `now`, and whether the table allows it (else `now`)."""
    target = moves.get((event, now))
    return (now, False) if target is None else (target, True)


class PauseCancel:
    """Our pause and our cancel of one vehicle, each by its explicit transitions."""

    def __init__(self) -> None:
        self.pause_state = Pause.NONE
        self.cancel_state = Cancel.NONE
        self._resume_at = 0.0  # when our last stopPause went, while it is pending
        self._cancel_id: str | None = None  # our cancelOrder's action id, while CANCELLING

    def _pause_event(self, event: str) -> bool:
        """Apply one event of the pause; whether the table allowed it."""
        self.pause_state, allowed = _move(PAUSE_MOVES, event, self.pause_state)
        return allowed

    def _cancel_event(self, event: str) -> bool:
        """Apply one event of the cancel; whether the table allowed it."""
        self.cancel_state, allowed = _move(CANCEL_MOVES, event, self.cancel_state)
        return allowed

    # ---- the pause ----------------------------------------------------------------------------

    def pause(self) -> bool:
        """Our startPause is to go (refused when it went already)."""
        return self._pause_event("pause")

    def resume(self, now: float) -> bool:
        """Our stopPause is to go, after our startPause (refused without one)."""
        if not self._pause_event("resume"):
            return False
        self._resume_at = now
        return True

    def resend_resume(self, now: float) -> bool:
        """The vehicle still shows paused: whether our stopPause is due again (RESEND_S on)."""
        if self.pause_state not in RESUME_PENDING or now - self._resume_at < RESEND_S:
            return False
        self._resume_at = now
        return True

    def resumed(self) -> bool:
        """The vehicle shows unpaused: our resume took effect (refused without one)."""
        return self._pause_event("resumed")

    def let_go(self) -> bool:
        """The vehicle let go of our pause, or went offline (refused without one)."""
        return self._pause_event("let_go")

    # ---- the cancel ---------------------------------------------------------------------------

    @property
    def cancelling(self) -> bool:
        """Whether our cancelOrder is in flight."""
        return self.cancel_state is Cancel.CANCELLING

    def start_cancel(self, action_id: str) -> bool:
        """Our cancelOrder `action_id` is to go (refused while one is in flight)."""
        if not self._cancel_event("start"):
            return False
        self._cancel_id = action_id
        return True

    def cancel_done(self, seen: Set[str]) -> bool:
        """Whether the actions a state shows finished or failed end our cancelOrder."""
        if self._cancel_id not in seen or not self._cancel_event("done"):
            return False
        self._cancel_id = None
        return True

    def end_under_stop(self) -> bool:
        """The cancelled order came to an end under the stop: it ends on the release."""
        return self._cancel_event("end_under_stop")

    def ended(self) -> bool:
        """A cancelled order that ended under the stop has ended now (refused when none did)."""
        return self._cancel_event("ended")
