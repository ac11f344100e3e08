"""The vehicle's charge, pure: our startCharging and stopCharging, until its state shows them.

VDA 5050 (2.0 and 2.1, §6.8): `startCharging` is FINISHED once "the AGV reports
.batteryState.charging: true", FAILED when it "could not be started (e.g., not aligned to
charger)"; `stopCharging` "deactivates the charging process to send a new order", and a vehicle
reports `charging: false` only "when it is ready to receive orders". So while the vehicle
charges, or our start or stop is in flight, no order goes to it (core.py holds them back), and an
order taking it elsewhere first stops the charge.

One state machine, its transitions in a table (an event from a state the table does not list is
refused: it changes nothing and returns False):

- NONE (no charge) -start-> STARTING (our startCharging in flight) -started-> CHARGING;
  STARTING -failed-> FAILED: not tried again until the charge is ordered afresh (`forget`: the
  order names another square or none, or the vehicle left), never in a loop.
- CHARGING -stop-> STOPPING (our stopCharging in flight) -stopped-> NONE (the vehicle reports
  charging false); STOPPING -stop_failed-> REFUSED (it charges on and said it cannot stop: no
  stopCharging again until it reports charging false).
- CHARGING -ended-> ENDED: the vehicle ended the charge itself (full, as the spec lets it, or its
  charger's doing): not started again until the charge is ordered afresh.
- NONE -adopted-> CHARGING: a vehicle seen charging that we did not start (it came on line so) is
  charging all the same: it must be stopped before it moves.

An action of ours that no state lists for RESEND_S is sent again under the same id (the vehicle
takes its instant actions at QoS 0: one may be lost; the same id again is the same action).
"""

from __future__ import annotations

from collections.abc import Mapping, Set
from enum import Enum

from gridfleet.grid import Cell
from gridfleet.robots.vda5050.resend import RESEND_S


class Charge(Enum):
    """Where the vehicle's charge stands, as far as the adapter knows."""

    NONE = "none"
    STARTING = "starting"
    CHARGING = "charging"
    STOPPING = "stopping"
    REFUSED = "refused"  # it failed our stopCharging and charges on
    FAILED = "failed"  # our startCharging failed here
    ENDED = "ended"  # the vehicle ended the charge itself


MOVES: Mapping[tuple[str, Charge], Charge] = {
    ("start", Charge.NONE): Charge.STARTING,
    ("started", Charge.STARTING): Charge.CHARGING,
    ("failed", Charge.STARTING): Charge.FAILED,
    ("adopted", Charge.NONE): Charge.CHARGING,
    ("adopted", Charge.ENDED): Charge.CHARGING,
    ("stop", Charge.CHARGING): Charge.STOPPING,
    ("stopped", Charge.STOPPING): Charge.NONE,
    ("stopped", Charge.REFUSED): Charge.NONE,
    ("stop_failed", Charge.STOPPING): Charge.REFUSED,
    ("ended", Charge.CHARGING): Charge.ENDED,
    ("forget", Charge.FAILED): Charge.NONE,
    ("forget", Charge.ENDED): Charge.NONE,
}
# While so, the vehicle is no vehicle to send an order to.
BUSY = frozenset({Charge.STARTING, Charge.CHARGING, Charge.STOPPING, Charge.REFUSED})


class Charging:
    """Our start and stop of one vehicle's charge, by explicit transitions."""

    def __init__(self) -> None:
        self.state = Charge.NONE
        self.square: Cell | None = None  # where the charge was started (or failed, or ended)
        self.action_id: str | None = None  # our start or stop in flight
        self._sent_at = 0.0
        self._listed = False  # a state has listed our action in flight

    def _event(self, event: str) -> bool:
        target = MOVES.get((event, self.state))
        if target is None:
            return False
        self.state = target
        if target not in (Charge.STARTING, Charge.STOPPING):
            self.action_id = None
        return True

    @property
    def busy(self) -> bool:
        """Whether it charges, or our start or stop is in flight: no order may go to it."""
        return self.state in BUSY

    def start(self, action_id: str, square: Cell, now: float) -> bool:
        """Our startCharging `action_id` is to go, at `square` (refused unless NONE)."""
        if not self._event("start"):
            return False
        self.action_id, self.square, self._sent_at = action_id, square, now
        self._listed = False
        return True

    def stop(self, action_id: str, now: float) -> bool:
        """Our stopCharging `action_id` is to go (refused unless CHARGING)."""
        if not self._event("stop"):
            return False
        self.action_id, self._sent_at, self._listed = action_id, now, False
        return True

    def forget(self) -> bool:
        """The charge is ordered afresh (elsewhere, or none): a failed or ended one is over."""
        if not self._event("forget"):
            return False
        self.square = None
        return True

    def let_go(self) -> None:
        """The vehicle went off line or restarted: what it does now its next state tells."""
        self.state, self.square, self.action_id = Charge.NONE, None, None

    def seen(
        self,
        charging: bool,
        finished: Set[str],
        failed: Set[str],
        square: Cell | None,
    ) -> str | None:
        """A state of the vehicle (charging or not, its action ids FINISHED and FAILED, standing
        on `square`): what happened to the charge, if anything did ("started", "failed",
        "stopped", "stop_failed", "ended", "adopted")."""
        ours = self.action_id
        if self.state is Charge.STARTING:
            if ours in failed and not charging:
                return "failed" if self._event("failed") else None
            if ours in finished or charging:
                return "started" if self._event("started") else None
            return None
        if self.state in (Charge.STOPPING, Charge.REFUSED) and not charging:
            return "stopped" if self._event("stopped") else None
        if self.state is Charge.STOPPING and ours in failed:
            return "stop_failed" if self._event("stop_failed") else None
        if self.state is Charge.CHARGING and not charging:
            return "ended" if self._event("ended") else None
        if charging and self._event("adopted"):
            self.square = square
            return "adopted"
        return None

    def heard(self, listed: Set[str]) -> None:
        """A state lists these action ids: ours in flight among them has reached the vehicle."""
        if self.action_id is not None and self.action_id in listed:
            self._listed = True

    def resend(self, listed: Set[str], now: float) -> str | None:
        """Our start or stop in flight, due again: no state has listed it for RESEND_S (once one
        has, the vehicle has it: its outcome is awaited, however long)."""
        if self.action_id is None or self._listed:
            return None
        if self.action_id in listed:
            self._listed = True
            return None
        if now - self._sent_at < RESEND_S:
            return None
        self._sent_at = now
        return self.action_id
