"""An order sent to a vehicle, until a state shows it, pure: when to send it again.

A vehicle takes its orders at QoS 0 (the spec's), so one can be lost; the same order again is
discarded by the spec. The latest order sent is kept until a state shows the vehicle following it
(its orderId and orderUpdateId) or refusing one, and is due again RESEND_S after it went.
"""

from __future__ import annotations

from typing import Any

RESEND_S = 1.0  # an order or a resume not seen taking effect by then is sent again


class OrderResend:
    """The latest order sent to the vehicle and when, until a state shows it taken or refused."""

    def __init__(self) -> None:
        self._sent: tuple[dict[str, Any], float] | None = None

    @property
    def pending(self) -> bool:
        """Whether an order went that no state has shown yet."""
        return self._sent is not None

    def sent(self, message: dict[str, Any], now: float) -> None:
        """An order (or the same again) went to the vehicle at `now`."""
        self._sent = (message, now)

    def seen(self, order_id: str, update_id: int, refused: bool) -> None:
        """A state: done with the order once the vehicle follows it, or refused an order."""
        if self._sent is None:
            return
        message = self._sent[0]
        if refused or (order_id, update_id) == (message["orderId"], message["orderUpdateId"]):
            self._sent = None

    def due(self, now: float) -> dict[str, Any] | None:
        """The order to send again (with fresh headers), once RESEND_S has gone unanswered."""
        if self._sent is None:
            return None
        message, sent_at = self._sent
        return None if now - sent_at < RESEND_S else message
