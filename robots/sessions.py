"""Which coordinator session a unit last told who it is, from the statuses it reads (§5.5).

A coordinator learns a unit's capacity from the unit's retained `connection` and `factsheet`,
read on subscribing. Not every broker gives them to it: RabbitMQ keeps retained messages per
node and never delivers them to a wildcard subscription (`units/+/factsheet`), a broker
restarted without persistence has none, and a node that dies takes its copies along. So a unit
tells every new coordinator session again: `CoordinatorSessions.new_session` says when a
status is the first `online` of a session this unit has not announced itself to since it
connected. Pure; the unit's core says what to publish.

How a session shows on the wire, by the coordinator's code (coordinator/shell.py, gridfleet/
endpoint.py): one `HeaderStamper` per process, counting `coordinator/status` messages across its
reconnects. Each connection's last will (`broken`) is stamped first and its `online` next, so a
freshly started process says `online` with seq 1 (seq 0 is its first will; a core driven without
an endpoint, as in tests and the lockstep run, starts at 0), and a reconnect or failover of the
same process counts on. A status that is new, then, when it is `online` and
- the first this connection of the unit hears, and not the retained one read on subscribing
  (that coordinator was subscribed before the unit connected and announced itself): a
  coordinator that came up after the unit subscribed may have missed what it said;
- after a `broken` or `offline` (a session ended: a restart, or a reconnect of the same process
  on a broker whose retained records may be another's, after a failover);
- from another sender than the last (another coordinator);
- numbered no higher than the last, but not the same message (its counter began again: a new
  process, whose `online` a unit may read without the will or goodbye of the old one).
The same status read again (QoS 1 redelivered, or replayed on subscribing again) is no news.
"""

from __future__ import annotations

from gridfleet.protocol import CoordinatorStatus, Header


class CoordinatorSessions:
    """Tells the first `online` of each coordinator session from what a unit reads after it."""

    def __init__(self) -> None:
        self._last: Header | None = None  # the latest `online` heard on this connection
        self._ended = False  # a `broken` or `offline` heard since it

    def reset(self) -> None:
        """The unit's connection ended: the next one announces itself on connecting."""
        self._last, self._ended = None, False

    def new_session(self, status: CoordinatorStatus, *, retained: bool = False) -> bool:
        """Whether `status` opens a coordinator session this connection has not been told in.

        `retained`: the broker replayed it on subscribing, not published since.
        """
        if status.state != "online":
            self._ended = True
            return False
        last, ended = self._last, self._ended
        head = status.header
        self._last, self._ended = head, False
        if last is None:
            return ended or not retained
        if ended or head.sender != last.sender:
            return True
        return head.seq <= last.seq and head != last
