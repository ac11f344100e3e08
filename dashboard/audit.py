"""The dashboard's logins for the audit trail: each login, logout and failed login, reported to
the coordinator as a request (`requests/audit_login`, protocol.md §6.9) from a thread of its own.

Why a request to the coordinator and not a store of the dashboard's own: `gridfleet audit` and a
page then read one trail, kept and pruned in one place, over the protocol like everything else;
and only a dashboard account may send the request (the broker's ACL; the coordinator checks the
role too), so an operator cannot write logins into it. A report is re-sent, the same, until the
coordinator answers, for up to REPORT_WAIT_S after the event (a restarting coordinator misses
nothing); after that it is only in the dashboard's log.

Failed logins are anybody's to make, so they are bounded: each address's first FAILURES_REPORTED
in FAILURE_WINDOW_S are reported one by one, and the rest (and every attempt refused as too many,
HTTP 429) are counted and reported as one row when the window is over (as found, every one wrote
a row: 4,027 rows, ~7 MB, in 15 s).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

import aiomqtt

from gridfleet.accounts import Account, Accounts
from gridfleet.bus import connect_first
from gridfleet.config import owned_client_id, with_credentials
from gridfleet.endpoint import payload_of, send
from gridfleet.errors import ProtocolError
from gridfleet.outbound import Outbound
from gridfleet.protocol import SUBSCRIBE_QOS, HeaderStamper, Reply, Topics, decode, validate_id
from gridfleet.protocol.messages import AuditLogin, LoginEvent
from gridfleet.tasks import cancel_and_wait

log = logging.getLogger("gridfleet.dashboard")
REPORT_WAIT_S = 60.0  # how long a report is re-sent for, counted from its event
RETRY_S = 2.0  # the wait for a reply before a report goes again (doubling up to RETRY_MOST_S)
RETRY_MOST_S = 10.0
RECONNECT_S = 2.0  # between attempts to reach the broker
ADDRESS_CHARS = 64
FAILURES_REPORTED = 10  # failed logins from one address reported one by one in a window
FAILURE_WINDOW_S = 60.0
FAILING_ADDRESSES = 1024  # addresses counted apart at once; more share one count
FLUSH_CHECK_S = 5.0  # how often the reporting thread looks for a window that is over
OTHERS = ""  # the count of the addresses beyond FAILING_ADDRESSES


def reporting_account(accounts: Accounts) -> Account | None:
    """The account the dashboard reports as: `dashboard`, else the first dashboard account."""
    named = accounts.accounts.get("dashboard")
    if named is not None and named.role == "dashboard":
        return named
    return next((a for a in accounts.accounts.values() if a.role == "dashboard"), None)


def as_user(name: str) -> str | None:
    """A typed user name as the report's `user`: an id, or None (it is not one: not recorded)."""
    try:
        return validate_id(name, "user")
    except ProtocolError:
        return None


@dataclass
class _Window:
    """One address's failed logins since `start`: reported one by one, and only counted."""

    start: float
    reported: int = 0
    counted: int = 0
    throttled: int = 0  # of those counted, refused as too many (HTTP 429)


@dataclass(frozen=True)
class Tally:
    """The failed logins from one address (OTHERS: from many) counted, not reported one by one."""

    address: str
    counted: int
    throttled: int
    window_s: float

    def reason(self) -> str:
        """The summary row's words."""
        where = (
            "this address"
            if self.address != OTHERS
            else "other addresses (too many to count apart)"
        )
        return (
            f"{self.counted} more failed logins from {where} in {self.window_s:.0f} s, "
            f"not recorded one by one ({self.throttled} refused as too many)"
        )


class FailureDigest:
    """Which failed logins the audit gets one by one; the rest are counted (pure: clock in)."""

    def __init__(
        self,
        per_window: int = FAILURES_REPORTED,
        window_s: float = FAILURE_WINDOW_S,
        clock: Callable[[], float] = time.monotonic,
        addresses: int = FAILING_ADDRESSES,
    ) -> None:
        self.per_window = per_window
        self.window_s = window_s
        self.clock = clock
        self.addresses = addresses
        self._windows: OrderedDict[str, _Window] = OrderedDict()  # oldest window first
        self._due: list[Tally] = []

    def admit(self, address: str, *, throttled: bool = False) -> bool:
        """Whether this failed login from `address` is reported one by one (else it is counted)."""
        now = self.clock()
        self._expire(now)
        if address not in self._windows and len(self._windows) >= self.addresses:
            address = OTHERS  # many addresses at once: they share one count
        window = self._windows.get(address)
        if window is None:
            window = self._windows[address] = _Window(now)
        if not throttled and address != OTHERS and window.reported < self.per_window:
            window.reported += 1
            return True
        window.counted += 1
        window.throttled += throttled
        return False

    def due(self) -> list[Tally]:
        """The counts of the windows that are over (each once)."""
        self._expire(self.clock())
        due, self._due = self._due, []
        return due

    def _expire(self, now: float) -> None:
        while self._windows:
            address, window = next(iter(self._windows.items()))
            if now - window.start < self.window_s:
                return
            del self._windows[address]
            if window.counted:
                self._due.append(Tally(address, window.counted, window.throttled, self.window_s))


@dataclass(frozen=True)
class _Pending:
    """A report waiting for its reply, and when to give up on it."""

    request: AuditLogin
    until: datetime


class LoginReporter:
    """Reports login events to the coordinator; `report` never blocks the page's request."""

    def __init__(
        self,
        url: str,
        topics: Topics,
        username: str,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.url = url
        self.topics = topics
        self.client_id = owned_client_id(username, f"audit-{secrets.token_hex(3)}")
        self._stamp = HeaderStamper(self.client_id)
        self._lock = threading.Lock()  # the server answers each request in its own thread
        self._count = 0
        self._failures = FailureDigest(clock=clock)  # used under _lock
        self._queue: queue.Queue[_Pending | None] = queue.Queue()
        self._thread = threading.Thread(target=self._main, name="gridfleet-audit", daemon=True)
        self.sent = 0  # reports the coordinator answered (tests watch it)

    def start(self) -> LoginReporter:
        """Start the reporting thread; returns self."""
        self._thread.start()
        return self

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the thread (what was not answered yet is dropped, with a line in the log)."""
        self._queue.put(None)
        self._thread.join(timeout)

    def report(
        self, event: LoginEvent, user: str | None, address: str | None, reason: str | None = None
    ) -> None:
        """Queue one event, stamped now."""
        with self._lock:
            self._count += 1
            request = AuditLogin(
                header=self._stamp("audit_login"),
                request_id=f"{self.client_id}-{self._count}"[-64:],
                reply_to=self.client_id,
                event=event,
                user=user,
                address=None if address is None else address[:ADDRESS_CHARS],
                reason=reason,
            )
        until = request.header.timestamp + timedelta(seconds=REPORT_WAIT_S)
        self._queue.put(_Pending(request, until))

    def failed(
        self, user: str | None, address: str, reason: str, *, throttled: bool = False
    ) -> None:
        """A failed login: reported one by one while few from `address`, else counted."""
        with self._lock:
            due = self._failures.due()
            alone = self._failures.admit(address, throttled=throttled)
        self._tell(due)
        if alone:
            self.report("login_failed", user, address, reason)

    def flush(self) -> None:
        """Report the counts of failed logins whose window is over."""
        with self._lock:
            due = self._failures.due()
        self._tell(due)

    def _tell(self, tallies: list[Tally]) -> None:
        for tally in tallies:
            address = None if tally.address == OTHERS else tally.address
            self.report("login_failed", None, address, tally.reason())

    def pending(self) -> list[AuditLogin]:
        """The reports not sent yet, oldest first (the one being sent not among them)."""
        with self._queue.mutex:
            return [p.request for p in self._queue.queue if p is not None]

    def _next(self) -> _Pending | None:
        """The next report to send (None: stop), flushing counts that are due meanwhile."""
        while True:
            try:
                return self._queue.get(timeout=FLUSH_CHECK_S)
            except queue.Empty:
                self.flush()

    def _main(self) -> None:
        asyncio.run(self._serve())

    async def _serve(self) -> None:
        """Connect (again, after a loss) and deliver the reports in order."""
        loop = asyncio.get_running_loop()
        current: _Pending | None = None
        while True:
            try:
                async with connect_first(self.url, self.client_id) as client:
                    replies: dict[str, asyncio.Future[Reply]] = {}
                    await client.subscribe(self.topics.reply(self.client_id), qos=SUBSCRIBE_QOS)
                    listener = asyncio.create_task(self._listen(client, replies))
                    try:
                        while True:
                            if current is None:
                                current = await loop.run_in_executor(None, self._next)
                            if current is None:
                                return  # stopped
                            await self._deliver(client, current, replies)
                            current = None
                    finally:
                        await cancel_and_wait(listener)
            except aiomqtt.MqttError as exc:
                log.warning("audit: cannot reach the broker (%s); trying again", exc)
                await asyncio.sleep(RECONNECT_S)  # pacing of reconnection attempts

    async def _listen(
        self, client: aiomqtt.Client, replies: dict[str, asyncio.Future[Reply]]
    ) -> None:
        async for message in client.messages:
            try:
                reply = decode(Reply, payload_of(message))
            except ProtocolError as exc:
                log.warning("audit: ignored a bad reply: %s", exc)
                continue
            future = replies.pop(reply.request_id, None)
            if future is not None and not future.done():
                future.set_result(reply)

    async def _deliver(
        self, client: aiomqtt.Client, pending: _Pending, replies: dict[str, asyncio.Future[Reply]]
    ) -> None:
        """Send one report until its reply comes or its time is up; a lost link raises."""
        request = pending.request
        future: asyncio.Future[Reply] = asyncio.get_running_loop().create_future()
        replies[request.request_id] = future
        out = Outbound.of("audit_login", self.topics.request("audit_login"), request)
        pause = RETRY_S
        while (left := (pending.until - datetime.now(UTC)).total_seconds()) > 0:
            await send(client, out)
            with contextlib.suppress(TimeoutError):
                reply = await asyncio.wait_for(asyncio.shield(future), min(pause, left))
                if not reply.accepted:
                    log.warning("audit: the coordinator refused a login report: %s", reply.reason)
                self.sent += 1
                return
            pause = min(2 * pause, RETRY_MOST_S)
        replies.pop(request.request_id, None)
        log.warning(
            "audit: no answer from the coordinator for %.0f s: %s of %s not recorded",
            REPORT_WAIT_S,
            request.event,
            request.user or "an unknown user",
        )


def login_reporter(accounts: Accounts | None, url: str | None, root: str) -> LoginReporter | None:
    """A started reporter for a dashboard with accounts and a broker to report to, or None."""
    if accounts is None or url is None:
        return None
    account = reporting_account(accounts)
    if account is None:
        log.warning("audit: no dashboard account in the accounts file: logins are not audited")
        return None
    login = with_credentials(url, account.name, account.password)
    return LoginReporter(login, Topics(root), account.name).start()
