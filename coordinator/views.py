"""Which retained fleet views (map, jobs) are out of date, and when they may go out.

Views go out at most once a period (the step period, within VIEWS_BATCH_S and VIEWS_LONGEST_S):
a step publishes the views that changed once a period has passed since the last; a request
publishes them at once when none went out for a period, else once, at the end of it. Each lists
every job (876 KB at 5,000 jobs), so one operator's flood of 5,000 requests sent it 1,158 times
(717 MB to one page) when views followed each batch of 50 ms; now however many changes come, one
view a period carries them all. Pure: the time comes in."""

from __future__ import annotations

from dataclasses import dataclass

VIEWS_BATCH_S = 0.25  # the shortest period: four a second is all a person reads
VIEWS_LONGEST_S = 1.0  # the longest: a fleet on a slow step still sees its queue change


def views_period_s(step_period_s: float) -> float:
    """How often views may go out on a fleet with this step period."""
    return min(max(VIEWS_BATCH_S, step_period_s), VIEWS_LONGEST_S)


@dataclass
class Views:
    """Dirty flags of the views and the pacing of views between steps."""

    period_s: float = VIEWS_BATCH_S  # views go out at most once in this long
    map_dirty: bool = True
    jobs_dirty: bool = True
    last_at: float = float("-inf")  # when views last went out
    pending_at: float | None = None  # when the shell was asked to come back for them

    def reconnected(self) -> None:
        """A new session: every view goes out again, and no batch is pending."""
        self.map_dirty = self.jobs_dirty = True
        self.pending_at = None

    def take(self, now: float | None = None) -> tuple[bool, bool]:
        """Which views to publish now (map, jobs); they count as published (at `now`) from here."""
        out = (self.map_dirty, self.jobs_dirty)
        if now is not None and any(out):
            self.last_at = now
        self.map_dirty = self.jobs_dirty = False
        return out

    def due(self, now: float) -> bool:
        """Whether a period has passed since views last went out (a step sends them only then)."""
        return now >= self.last_at + self.period_s

    def after_request(self, now: float) -> tuple[bool, float | None]:
        """(publish now?, when the shell must come back to publish them; None: nothing to arrange)."""
        if self.due(now):
            return True, None
        if self.pending_at is not None:
            return False, None  # one pending at most: it publishes whatever changed by then
        self.pending_at = self.last_at + self.period_s
        return False, self.pending_at

    def batch_over(self) -> None:
        """The period a request waited for has ended; its views go out now."""
        self.pending_at = None
