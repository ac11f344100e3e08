"""The webhook: each notice POSTed as JSON, in order, retried with back-off until the receiver takes it.

Notices wait in a bounded queue in SQLite (a file, so a receiver that is down still gets what
was raised across a restart of the alerts process; or memory). The POST is the standard
library's urllib in a worker thread: one request at a time, so the receiver sees the notices in
the order they happened. A receiver that answers anything but 2xx, or not at all, is tried
again after 1 s, 2 s, 4 s … at most `most_s`; a full queue drops its oldest notice (logged and
counted), since a pager wants the latest news most.
"""

from __future__ import annotations

import asyncio
import logging
import sqlite3
import urllib.error
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from gridfleet import __version__
from gridfleet.alerts.settings import webhook_where
from gridfleet.tasks import first_of

log = logging.getLogger("gridfleet.alerts.webhook")

QUEUE_LIMIT = 1000  # notices kept for a receiver that is down; older ones go first
POST_TIMEOUT_S = 10.0  # a receiver that accepts the connection and says nothing is down too


@dataclass(frozen=True)
class Backoff:
    """Seconds between tries of one notice: doubling from `first` up to `most`."""

    first: float = 1.0
    most: float = 60.0


class NoticeQueue:
    """Notices not yet delivered, oldest first, in SQLite (`path` None: in memory)."""

    def __init__(self, path: str | Path | None = None, limit: int = QUEUE_LIMIT) -> None:
        self.limit = limit
        self.dropped = 0
        # Used from the event loop's thread only (the POST's thread gets bytes, not the queue).
        self._db = sqlite3.connect(":memory:" if path is None else str(path))
        self._db.execute("CREATE TABLE IF NOT EXISTS notices (id INTEGER PRIMARY KEY, body BLOB)")
        self._db.commit()

    def put(self, body: bytes) -> None:
        """Keep `body` for sending; the oldest notice goes when the queue is full."""
        self._db.execute("INSERT INTO notices (body) VALUES (?)", (body,))
        over = len(self) - self.limit
        if over > 0:
            self._db.execute(
                "DELETE FROM notices WHERE id IN (SELECT id FROM notices ORDER BY id LIMIT ?)",
                (over,),
            )
            self.dropped += over
            log.warning("webhook queue full: dropped the %d oldest notice(s)", over)
        self._db.commit()

    def head(self) -> tuple[int, bytes] | None:
        """The oldest notice (its row id and body), or None."""
        row = self._db.execute("SELECT id, body FROM notices ORDER BY id LIMIT 1").fetchone()
        return None if row is None else (int(row[0]), bytes(row[1]))

    def remove(self, row: int) -> None:
        """Forget a delivered notice."""
        self._db.execute("DELETE FROM notices WHERE id = ?", (row,))
        self._db.commit()

    def __len__(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM notices").fetchone()[0])

    def close(self) -> None:
        """Close the database (what is queued stays in its file)."""
        self._db.close()


def post_json(url: str, body: bytes, timeout_s: float = POST_TIMEOUT_S) -> None:
    """POST `body` as JSON to `url`; raises OSError (urllib's errors are) unless 2xx."""
    request = urllib.request.Request(
        url,
        data=body,
        method="POST",
        headers={
            "Content-Type": "application/json",
            "User-Agent": f"gridfleet-alerts/{__version__}",
        },
    )
    with urllib.request.urlopen(request, timeout=timeout_s) as answer:
        answer.read()
        if not 200 <= answer.status < 300:  # urllib raises for 4xx/5xx; 1xx/3xx end here
            raise urllib.error.HTTPError(url, answer.status, "not 2xx", answer.headers, None)


class Webhook:
    """Delivers the queue's notices to `url`, one at a time: `await webhook.run(shutdown)`."""

    def __init__(
        self,
        url: str,
        queue: NoticeQueue,
        *,
        backoff: Backoff = Backoff(),
        post: Callable[[str, bytes], None] = post_json,
    ) -> None:
        self.url = url
        self.where = webhook_where(url)  # the URL's path may hold a secret: never logged
        self.queue = queue
        self.backoff = backoff
        self._post = post
        self.sent = 0
        self.failures = 0  # tries that failed (each one retried later)
        self._more = asyncio.Event()

    def put(self, body: bytes) -> None:
        """Queue one notice for sending."""
        self.queue.put(body)
        self._more.set()

    async def run(self, shutdown: asyncio.Event) -> None:
        """Send until `shutdown` is set; what is left stays queued (kept in a file, if one)."""
        delay = self.backoff.first
        while not shutdown.is_set():
            head = self.queue.head()
            if head is None:
                self._more.clear()
                await first_of(shutdown, self._more)
                continue
            row, body = head
            try:
                await asyncio.to_thread(self._post, self.url, body)
            except (
                OSError,
                ValueError,
            ) as exc:  # urllib's errors are OSErrors; ValueError: bad URL
                self.failures += 1
                log.warning("webhook %s: %s; trying again in %g s", self.where, exc, delay)
                await first_of(shutdown, timeout=delay)
                delay = min(delay * 2, self.backoff.most)
                continue
            self.queue.remove(row)
            self.sent += 1
            delay = self.backoff.first
