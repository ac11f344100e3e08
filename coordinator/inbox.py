"""Operators' requests waiting for the coordinator, fairly: per account, urgent kinds first (pure).

The shell reads every message at once and hands requests here instead of answering each before
reading the next: one account's flood of 5,000 `submit_job`s had kept the coordinator from reading
units' states and cancels for minutes (the broker dropped its queued messages). Each account may
have at most `per_account` requests waiting; one more is refused at once, in words, and changes
nothing. Each account's requests are answered in the order they came; accounts take turns, and
one whose next request is urgent (a cancel, a control, a goal, cleared obstacles, a unit
removed, a zone closed or opened, rather than a new job or a history query) goes first: another operator's cancel waits behind at most one
request of a flooder's, never behind its whole queue.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from dataclasses import dataclass, field

from gridfleet.coordinator.inbound import Arrival

# A client of gridfleet's own keeps at most 8 to 10 requests in flight (aiomqtt's pending-calls
# bound): 200 waiting is a script's burst, not a console's.
MAX_WAITING_PER_ACCOUNT = 200
# Answered ahead of new work: what stops, frees or steers what is already moving.
URGENT = frozenset(
    {
        "cancel_job",
        "control_unit",
        "set_goal",
        "clear_obstacles",
        "remove_unit",
        "close_zone",
        "open_zone",
    }
)


@dataclass(frozen=True)
class Waiting:
    """One request as it arrived, decoded: its account (who waits for it), kind and topic."""

    account: str
    kind: str
    topic: str
    arrival: Arrival


class Inbox:
    """Requests waiting, per account in the order they came; `offer` refuses over the limit."""

    def __init__(self, per_account: int = MAX_WAITING_PER_ACCOUNT) -> None:
        if per_account < 1:
            raise ValueError(f"an inbox needs per_account >= 1 ({per_account})")
        self.per_account = per_account
        # per account (whose turn is next first) its requests, oldest first
        self._queues: OrderedDict[str, deque[Waiting]] = OrderedDict()
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def waiting(self, account: str) -> int:
        """How many of `account`'s requests wait."""
        return len(self._queues.get(account, ()))

    def offer(self, request: Waiting) -> str | None:
        """Queue `request`; or, when its account has `per_account` waiting, why not (in words)."""
        count = self.waiting(request.account)
        if count >= self.per_account:
            return (
                f"too many requests: account {request.account!r} has {count} waiting for an "
                f"answer (at most {self.per_account}); send more once answers come"
            )
        self._queues.setdefault(request.account, deque()).append(request)
        self._count += 1
        return None

    def take(self) -> Waiting | None:
        """The next request to answer (None: none waits).

        An account's own requests keep their order (its cancel of a job it has just submitted
        comes after that submit); among accounts, one whose next request is urgent goes first,
        then each in turn.
        """
        if not self._queues:
            return None
        account = next(
            (a for a, queue in self._queues.items() if queue[0].kind in URGENT),
            next(iter(self._queues)),
        )
        queue = self._queues.pop(account)
        request = queue.popleft()
        if queue:
            self._queues[account] = queue  # to the back of the line: the next account goes first
        self._count -= 1
        return request


# Requests refused for want of room, told on `errors` (every page and terminal reads it) at most
# once a second per account, with how many more were refused since: a flood's refusals are
# answered one by one on the sender's own reply topic, not relayed to everybody.
REFUSALS_TOLD_EVERY_S = 1.0


@dataclass(frozen=True)
class Untold:
    """Refusals of one account not told yet: how many, and the latest one's topic and reason."""

    count: int
    topic: str
    reason: str


@dataclass
class Refusals:
    """When each account's inbox refusals were last told, and how many were not told since."""

    every_s: float = REFUSALS_TOLD_EVERY_S
    _told_at: dict[str, float] = field(default_factory=dict)
    _untold: dict[str, Untold] = field(default_factory=dict)

    def refused(self, account: str, topic: str, reason: str, now: float) -> bool:
        """One more refused: True to tell it now, False when it is counted for later."""
        if now < self._told_at.get(account, float("-inf")) + self.every_s:
            count = self._untold[account].count if account in self._untold else 0
            self._untold[account] = Untold(count + 1, topic, reason)
            return False
        self._told_at[account] = now
        return True

    def due(self, now: float) -> list[tuple[str, Untold]]:
        """(account, its refusals not told yet) for each whose second is over."""
        out = []
        for account, untold in list(self._untold.items()):
            if now >= self._told_at.get(account, float("-inf")) + self.every_s:
                del self._untold[account]
                self._told_at[account] = now
                out.append((account, untold))
        for account, at in list(self._told_at.items()):
            if account not in self._untold and now >= at + self.every_s:
                del self._told_at[account]  # quiet for a second: forgotten (bounded memory)
        return out
