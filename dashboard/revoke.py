"""The dashboard's word to the embedded broker that a page session is over: its broker password
is taken back (`broker/revoke`, protocol.md §10), from a thread of its own.

Each revocation is kept until its session's end (at most SESSION_S) and sent again whenever the
link comes back: a broker that restarted meanwhile, having forgotten what it was told, hears it
again. A dashboard that restarts forgets them itself (and every session with them): the
passwords it handed out before then stop at their own end.
"""

from __future__ import annotations

import asyncio
import logging
import secrets
import threading
import time
from collections.abc import Callable

import aiomqtt

from gridfleet.accounts import Accounts
from gridfleet.bus import connect_first
from gridfleet.config import owned_client_id, with_credentials
from gridfleet.dashboard.audit import reporting_account
from gridfleet.endpoint import send
from gridfleet.outbound import Outbound
from gridfleet.protocol import HeaderStamper, Topics
from gridfleet.protocol.messages import BrokerRevoke
from gridfleet.session_login import RevokedSessions
from gridfleet.tasks import cancel_and_wait

log = logging.getLogger("gridfleet.dashboard")
RECONNECT_S = 1.0  # between attempts to reach the broker


class SessionRevoker:
    """Tells the broker of every page session that ended early; `revoke` never blocks."""

    def __init__(
        self, url: str, topics: Topics, username: str, wall: Callable[[], float] = time.time
    ) -> None:
        self.url = url
        self.topics = topics
        self.wall = wall
        self.client_id = owned_client_id(username, f"revoke-{secrets.token_hex(3)}")
        self._stamp = HeaderStamper(self.client_id)
        self._lock = threading.Lock()  # the server answers each request in its own thread
        self._revoked = RevokedSessions()  # what is in force: said again after every reconnect
        self._pending: list[tuple[str, int]] = []  # not sent on this link yet
        self._stopping = False
        self._loop: asyncio.AbstractEventLoop | None = None  # the sending thread's, once it runs
        self._wake: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._main, name="gridfleet-revoke", daemon=True)
        self.sent = 0  # revocations the broker acknowledged (tests watch it)

    def start(self) -> SessionRevoker:
        """Start the sending thread; returns self."""
        self._thread.start()
        return self

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the thread (what was not sent yet is dropped)."""
        with self._lock:
            self._stopping = True
        self._poke()
        self._thread.join(timeout)

    def revoke(self, sid: str, expires: int) -> None:
        """Take session `sid`'s broker password back (kept, and said again, until `expires`)."""
        with self._lock:
            if not self._revoked.revoke(sid, expires, self.wall()):
                return  # over already: its password has expired
            self._pending.append((sid, expires))
        self._poke()

    def _poke(self) -> None:
        """Wake the sending thread (from any thread)."""
        with self._lock:
            loop, wake = self._loop, self._wake
        if loop is not None and wake is not None:
            loop.call_soon_threadsafe(wake.set)

    def _main(self) -> None:
        asyncio.run(self._serve())

    async def _serve(self) -> None:
        """Connect (again, after a loss), say every revocation in force, then each new one."""
        wake = asyncio.Event()
        with self._lock:
            self._loop, self._wake = asyncio.get_running_loop(), wake
        while not self._stopping:
            try:
                async with connect_first(self.url, self.client_id) as client:
                    with self._lock:
                        batch = list(self._revoked.live(self.wall()).items())
                        self._pending.clear()
                    # Lost link: the messages' iteration raises (nothing is subscribed).
                    watch = asyncio.create_task(self._watch(client))
                    try:
                        while True:
                            for sid, expires in batch:
                                await self._send(client, sid, expires)
                            await first_of_task(wake, watch)
                            wake.clear()
                            if watch.done():
                                watch.result()  # raises the MqttError of the lost link
                            with self._lock:
                                if self._stopping:
                                    return
                                batch, self._pending = self._pending, []
                    finally:
                        await cancel_and_wait(watch)
            except aiomqtt.MqttError as exc:
                if self._stopping:
                    return
                log.warning("revoke: cannot reach the broker (%s); trying again", exc)
                await asyncio.sleep(RECONNECT_S)  # pacing of reconnection attempts

    async def _watch(self, client: aiomqtt.Client) -> None:
        """Until the link is lost (then MqttError)."""
        async for _ in client.messages:
            pass

    async def _send(self, client: aiomqtt.Client, sid: str, expires: int) -> None:
        """Publish one revocation (QoS 1, not retained); a lost link raises."""
        message = BrokerRevoke(header=self._stamp("revoke"), sid=sid, expires=expires)
        await send(client, Outbound.of("revoke", self.topics.fleet("revoke"), message))
        self.sent += 1


async def first_of_task(wake: asyncio.Event, task: asyncio.Task[None]) -> None:
    """Until `wake` is set or `task` has ended."""
    waiter = asyncio.create_task(wake.wait())
    try:
        await asyncio.wait({waiter, task}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        await cancel_and_wait(waiter)


def session_revoker(accounts: Accounts | None, url: str | None, root: str) -> SessionRevoker | None:
    """A started revoker, as the dashboard account, for a broker that checks session passwords."""
    if accounts is None or url is None:
        return None
    account = reporting_account(accounts)
    if account is None:
        return None
    login = with_credentials(url, account.name, account.password)
    return SessionRevoker(login, Topics(root), account.name).start()
