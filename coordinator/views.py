"""Which retained fleet views (map, jobs) are out of date, and when they may go out.

A step publishes the views it changed. A request publishes them at once, unless views went out
for a request less than VIEWS_BATCH_S ago: then once, at the end of that period. A script queueing
hundreds of jobs gets one queue view per period, not one per request (each lists every job, so one
per request grows as the square). Pure: the time comes in as an argument.
"""

from __future__ import annotations

from dataclasses import dataclass

VIEWS_BATCH_S = 0.05


@dataclass
class Views:
    """Dirty flags of the views and the batching of views after requests."""

    map_dirty: bool = True
    jobs_dirty: bool = True
    last_at: float = -VIEWS_BATCH_S  # when views last went out for a request
    pending_at: float | None = None  # when the shell was asked to come back for them

    def reconnected(self) -> None:
        """A new session: every view goes out again, and no batch is pending."""
        self.map_dirty = self.jobs_dirty = True
        self.pending_at = None

    def take(self) -> tuple[bool, bool]:
        """Which views to publish now (map, jobs); they count as published from here on."""
        out = (self.map_dirty, self.jobs_dirty)
        self.map_dirty = self.jobs_dirty = False
        return out

    def after_request(self, now: float) -> tuple[bool, float | None]:
        """(publish now?, when the shell must come back to publish them; None: nothing to arrange)."""
        if now >= self.last_at + VIEWS_BATCH_S:
            self.last_at = now
            return True, None
        if self.pending_at is not None:
            return False, None  # one pending at most: it publishes whatever changed by then
        self.pending_at = self.last_at + VIEWS_BATCH_S
        return False, self.pending_at

    def batch_over(self, now: float) -> None:
        """The batch period a request waited for has ended; its views go out now."""
        self.pending_at = None
        self.last_at = now
