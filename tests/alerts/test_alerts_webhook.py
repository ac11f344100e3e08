"""The webhook's queue and sender: bounded, kept in SQLite across restarts, delivered in order."""

from __future__ import annotations

import asyncio
from pathlib import Path

from gridfleet.alerts.webhook import Backoff, NoticeQueue, Webhook


def test_a_full_queue_drops_its_oldest_notices(tmp_path: Path) -> None:
    queue = NoticeQueue(tmp_path / "q.sqlite3", limit=3)
    for n in range(5):
        queue.put(f"notice {n}".encode())
    assert (len(queue), queue.dropped) == (3, 2)
    head = queue.head()
    assert head is not None and head[1] == b"notice 2"


def test_what_was_not_delivered_survives_a_restart(tmp_path: Path) -> None:
    path = tmp_path / "q.sqlite3"
    queue = NoticeQueue(path)
    queue.put(b"raised")
    queue.put(b"cleared")
    queue.close()
    again = NoticeQueue(path)
    head = again.head()
    assert head is not None and head[1] == b"raised" and len(again) == 2


async def test_a_failing_receiver_is_tried_again_and_gets_every_notice_in_order() -> None:
    got: list[bytes] = []
    tries = 0
    shutdown = asyncio.Event()

    def post(url: str, body: bytes) -> None:
        nonlocal tries
        tries += 1
        if tries <= 2:  # down at first
            raise ConnectionRefusedError("connection refused")
        got.append(body)
        if len(got) == 2:
            shutdown.set()

    webhook = Webhook("http://127.0.0.1:9/hook", NoticeQueue(), backoff=Backoff(0, 0), post=post)
    webhook.put(b"raised")
    webhook.put(b"cleared")
    await asyncio.wait_for(webhook.run(shutdown), 30)
    assert got == [b"raised", b"cleared"]
    assert (webhook.sent, webhook.failures, len(webhook.queue)) == (2, 2, 0)
