"""The step rate the coordinator achieves, measured over a few seconds (protocol.md §5.5).

Pure: the time comes in. The status is retained at QoS 1, so the measurement is published once
per window, not every step.
"""

from __future__ import annotations

RATE_WINDOW_S = 5.0


class StepRate:
    """The mean step interval over the last finished window; `stepped` after every step."""

    def __init__(self, window_s: float = RATE_WINDOW_S) -> None:
        self.window_s = window_s
        self.achieved_step_s: float | None = None
        self._since: tuple[float, int] | None = None  # (time, step number) the window began at

    def stepped(self, step_no: int, now: float) -> bool:
        """Count step `step_no` made at `now`; True when a window ended (a new figure is due)."""
        if self._since is None:
            self._since = (now, step_no)
            return False
        began, first = self._since
        if now - began < self.window_s or step_no <= first:
            return False
        self.achieved_step_s = round((now - began) / (step_no - first), 6)
        self._since = (now, step_no)
        return True
