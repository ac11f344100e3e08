"""The audit trail's decisions, without I/O: who did what, when, and whether it was carried out.

The core hands `AuditLog` every request it answered and every stop payload it read; the log makes
the entries (protocol.md §6.8). `AuditDesk` answers the audit's two requests: a page of entries
(`requests/audit`, from a reader the shell gives it) and the dashboard's login reports
(`requests/audit_login`). Who did it comes from the broker, never from the payload alone:

- a request's `header.sender` and the latch's `by` are ids of the account that published them
  when the broker drops any other (the embedded broker with accounts: `vouched`); the entry names
  that account and says `verified`. On a broker that does not check (Mosquitto, or none with
  accounts) they are the client's claim: recorded as such, `verified` false;
- a unit's or device's press is on its own topic, which the broker's ACL binds to its account;
- a login is the dashboard's word, and only a dashboard account may send it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Protocol

from gridfleet.config import names_owned_id
from gridfleet.coordinator.requests import Outcome
from gridfleet.errors import ProtocolError
from gridfleet.outbound import Outbound, error_report
from gridfleet.protocol import (
    CancelJob,
    ClearObstacles,
    ControlUnit,
    EstopSignal,
    HeaderStamper,
    Reply,
    SetGoal,
    SubmitJob,
    Topics,
    decode,
    decode_estop,
    encode_estop,
)
from gridfleet.protocol.codec import reply_address
from gridfleet.protocol.constants import MAX_TEXT
from gridfleet.protocol.messages import (
    AuditAct,
    AuditEntry,
    AuditLogin,
    AuditPage,
    AuditQuery,
    Request,
)
from gridfleet.protocol.stop import LATCH

if TYPE_CHECKING:  # the accounts' file models load pydantic's plugins, and with them sockets
    from gridfleet.accounts import Accounts, Role

DEFAULT_AUDIT_DAYS = 90.0  # how long entries are kept unless --audit-days says
READ_ROLES: tuple[Role, ...] = ("operator", "dashboard")  # who may read the audit
REPORT_ROLES: tuple[Role, ...] = ("dashboard",)  # who may report logins
QUERY_KINDS = ("audit", "audit_login")  # the requests AuditDesk answers
TARGET_CHARS = 200
# A dashboard retries a report for a minute at most: the latest this many are enough to know.
LOGINS_REMEMBERED = 1000


def _as_utc(moment: datetime) -> datetime:
    """`moment` in UTC; a time without a zone is read as UTC (as every time in protocol.md)."""
    return moment.replace(tzinfo=UTC) if moment.tzinfo is None else moment.astimezone(UTC)


@dataclass(frozen=True)
class Identity:
    """Who is who on the broker, as far as the coordinator knows (its accounts file)."""

    accounts: Accounts | None = None
    vouched: bool = False  # the broker drops a request or latch naming an id not its account's

    def account_of(self, client: str) -> str | None:
        """The account owning client id `client` (the longest name that owns it), or None."""
        if self.accounts is None:
            return None
        owners = [n for n in self.accounts.accounts if names_owned_id(n, client)]
        return max(owners, key=len, default=None)

    def actor(self, client: str) -> tuple[str, bool]:
        """(the actor to record, whether the broker vouched for it) for a request's sender."""
        owner = self.account_of(client)
        if owner is None:
            return client, False  # no accounts, or none owns it: what the client claimed
        return owner, self.vouched

    def press_actor(self, kind: str, source: str) -> tuple[str, bool]:
        """The account of a unit's or device's press: its topic, which the ACL binds to it."""
        if self.accounts is None:
            return source, False
        for account in self.accounts.accounts.values():
            units = {account.unit, *(v.unit for v in account.vehicles)}
            if kind == "device_stop" and account.role == "device" and account.name == source:
                return account.name, True
            if kind == "stop" and account.role in ("unit", "vda5050") and source in units:
                return account.name, True
        return source, False

    def _role(self, client: str) -> Role | None:
        owner = self.account_of(client)
        return None if owner is None or self.accounts is None else self.accounts.get(owner).role

    def refusal(self, client: str, roles: Sequence[Role], what: str) -> str | None:
        """Why `client` may not do `what` (None: it may); without accounts everybody may."""
        if self.accounts is None:
            return None
        role = self._role(client)
        if role in roles:
            return None
        whose = (
            f"{'an' if role[0] in 'aeiou' else 'a'} {role} account's" if role else "no account's"
        )
        return f"{client} is {whose} client: only {' and '.join(roles)} accounts may {what}"


@dataclass(frozen=True)
class AuditNews:
    """What the audit made since it was last asked: entries, and stop payloads seen (to store)."""

    entries: tuple[AuditEntry, ...] = ()
    seen: tuple[tuple[str, bytes], ...] = ()


def request_act(req: Request) -> tuple[AuditAct, str | None, str | None]:
    """(act, target, detail) of an operator's request."""
    if isinstance(req, SubmitJob):
        where = f"{list(req.pickup)} -> {list(req.dropoff)}"
        return "submit_job", req.job_id, f"{req.mass_kg:g} kg, {where}, priority {req.priority}"
    if isinstance(req, CancelJob):
        return "cancel_job", req.job_id, None
    if isinstance(req, SetGoal):
        if req.target is None:
            return "clear_goal", req.unit, None
        return "set_goal", req.unit, f"to {list(req.target)}"
    if isinstance(req, ControlUnit):
        return req.command, req.unit, None
    if isinstance(req, ClearObstacles):
        if req.squares is None:
            return "clear_obstacles", "all", None
        squares = ", ".join(str(list(c)) for c in req.squares)
        if len(squares) > TARGET_CHARS:
            squares = f"{squares[: TARGET_CHARS - 20]}... ({len(req.squares)} squares)"
        return "clear_obstacles", squares, None
    raise ValueError(f"{type(req).__name__} is no operator act")


class AuditLog:
    """Makes audit entries from the requests the core answered and the stop payloads it read."""

    def __init__(self, identity: Identity | None = None) -> None:
        self.identity = identity or Identity()
        self._seen: dict[str, bytes] = {}  # stop topic -> the payload last taken into account
        self._presses: dict[str, EstopSignal] = {}  # held presses: the latch's copies of them
        self._fresh: list[AuditEntry] = []
        self._seen_fresh: dict[str, bytes] = {}

    def restore(self, seen: Iterable[tuple[str, bytes]]) -> None:
        """The stop payloads seen before a restart: their retained copies are no new acts."""
        self._seen.update(seen)

    def request(self, at: datetime, req: Request, outcome: Outcome) -> None:
        """A new request the core answered (a retry is the same act: not passed in again)."""
        act, target, detail = request_act(req)
        actor, verified = self.identity.actor(req.header.sender)
        self._fresh.append(
            AuditEntry(
                at=at,
                actor=actor,
                verified=verified,
                via=req.header.sender,
                act=act,
                target=target if target is not None else outcome.job_id,
                detail=detail,
                outcome="accepted" if outcome.accepted else "refused",
                reason=outcome.reason,
            )
        )

    def stop(self, at: datetime, kind: str, source: str | None, topic: str, payload: bytes) -> None:
        """A valid payload on the latch or a press (the core has applied it already).

        Recorded when it differs from the last one taken into account on its topic: a retained
        copy replayed on a reconnect or after a restart, or the latch the coordinator restored,
        is no new act. The coordinator's copy of a press onto the latch is the press's act.
        """
        signal = decode_estop(payload) if payload else None
        canonical = encode_estop(signal) if signal is not None else b""
        if kind != LATCH:
            if signal is None:
                self._presses.pop(topic, None)  # cleared, by the coordinator after a release
            else:
                self._presses[topic] = signal
        if self._seen.get(topic) == canonical:
            return
        self._seen[topic] = canonical
        self._seen_fresh[topic] = canonical
        if signal is None:
            return
        if kind != LATCH:
            assert source is not None, "a press names its source"
            actor, verified = self.identity.press_actor(kind, source)
        elif signal in self._presses.values():
            return  # the coordinator mirrored a press into the latch
        else:
            actor, verified = self.identity.actor(signal.by)
        self._fresh.append(
            AuditEntry(
                at=at,
                actor=actor,
                verified=verified,
                via=signal.by,
                act="stop_engage" if signal.engaged else "stop_release",
                target=None if kind == LATCH else source,
                detail=signal.reason or None,
                outcome="accepted",
            )
        )

    def take(self) -> AuditNews:
        """The entries and seen payloads since the last call (the shell stores them)."""
        news = AuditNews(tuple(self._fresh), tuple(self._seen_fresh.items()))
        self._fresh.clear()
        self._seen_fresh.clear()
        return news


class AuditReader(Protocol):
    """Where the desk reads entries from (the shell's AuditStore)."""

    def page(
        self, since: float, until: float, actor: str | None, after: int, limit: int
    ) -> list[tuple[int, AuditEntry]]:
        """Up to `limit` entries with since <= at < until (epoch s) and id > `after`, by id."""
        ...


@dataclass(frozen=True)
class Answer:
    """What the desk says to one message: what to publish, and entries to store first."""

    publish: tuple[Outbound, ...] = ()
    entries: tuple[AuditEntry, ...] = ()
    log: tuple[str, ...] = field(default=())


def check_range(since: datetime, until: datetime | None, now: datetime) -> str | None:
    """Why a time range is refused (None: it is fine): `since` after `until`."""
    end = _as_utc(until) if until is not None else now
    if _as_utc(since) > end:
        what = "until" if until is not None else "now"
        return f"since {_as_utc(since).isoformat()} is after {what} {end.isoformat()}"
    return None


class AuditDesk:
    """Answers `requests/audit` (a page) and `requests/audit_login` (the dashboard's reports)."""

    def __init__(self, topics: Topics, stamp: HeaderStamper, identity: Identity) -> None:
        self.topics = topics
        self.stamp = stamp
        self.identity = identity
        self._kinds = {topics.request(k): k for k in QUERY_KINDS}
        # Login reports already stored, oldest first: a retry is answered, not stored again.
        self._answered: dict[tuple[str, str], None] = {}

    def reads(self, topic: str) -> bool:
        """Whether `topic` is one of the desk's."""
        return topic in self._kinds

    def on_message(self, topic: str, payload: bytes, reader: AuditReader) -> Answer:
        """The answer to one request on the desk's topics; a bad one is refused in words."""
        kind = self._kinds[topic]
        try:
            if kind == "audit":
                return self._query(decode(AuditQuery, payload), reader)
            return self._login(decode(AuditLogin, payload))
        except ProtocolError as exc:
            # Answered as any request is: on its reply topic too, when that can still be read.
            reason = str(exc)[:MAX_TEXT]
            request_id, reply_to = reply_address(payload)
            out = [self._error(topic, reason, request_id)]
            if request_id is not None and reply_to is not None:
                if kind == "audit":
                    out.append(self._page(reply_to, request_id, False, reason))
                else:
                    out.append(self._refused(reply_to, request_id, reason))
            return Answer(tuple(out), log=(f"refused a message on {topic}: {exc}",))

    def _error(self, topic: str, reason: str, request_id: str | None) -> Outbound:
        out = error_report(self.stamp("errors"), topic, reason, request_id)
        return Outbound.of("errors", self.topics.fleet("errors"), out)

    def _query(self, q: AuditQuery, reader: AuditReader) -> Answer:
        now = self.stamp.now()
        why = self.identity.refusal(q.header.sender, READ_ROLES, "read the audit")
        why = why or check_range(q.since, q.until, now)
        if why is not None:
            out = [self._error(self.topics.request("audit"), f"AuditQuery: {why}", q.request_id)]
            if q.reply_to is not None:
                out.append(self._page(q.reply_to, q.request_id, False, why))
            return Answer(
                tuple(out), log=(f"refused an audit query from {q.header.sender}: {why}",)
            )
        if q.reply_to is None:
            return Answer()  # nobody to tell
        until = _as_utc(q.until) if q.until is not None else now
        after = int(q.cursor) if q.cursor is not None else 0
        since = _as_utc(q.since).timestamp()
        # One more than asked: whether there is a next page, without a second query.
        rows = reader.page(since, until.timestamp(), q.actor, after, q.limit + 1)
        shown = rows[: q.limit]
        cursor = str(shown[-1][0]) if len(rows) > q.limit else None
        entries = [entry for _, entry in shown]
        return Answer((self._page(q.reply_to, q.request_id, True, None, entries, cursor),))

    def _page(
        self,
        reply_to: str,
        request_id: str,
        accepted: bool,
        reason: str | None,
        entries: Sequence[AuditEntry] = (),
        cursor: str | None = None,
    ) -> Outbound:
        page = AuditPage(
            header=self.stamp("audit_reply"),
            request_id=request_id,
            accepted=accepted,
            reason=reason,
            entries=list(entries),
            next_cursor=cursor,
        )
        return Outbound.of("audit_reply", self.topics.audit_reply(reply_to), page)

    def _login(self, req: AuditLogin) -> Answer:
        sender = req.header.sender
        key = (sender, req.request_id)
        if key in self._answered:  # a retry: stored already, answered again
            return Answer(self._reply(req, True, None))
        why = self.identity.refusal(sender, REPORT_ROLES, "report logins")
        if why is not None:
            topic = self.topics.request("audit_login")
            out = (self._error(topic, f"AuditLogin: {why}", req.request_id),)
            return Answer(out + self._reply(req, False, why), log=(why,))
        entry = login_entry(req, self.identity)
        self._answered[key] = None
        while len(self._answered) > LOGINS_REMEMBERED:
            del self._answered[next(iter(self._answered))]
        return Answer(self._reply(req, True, None), (entry,))

    def _reply(self, req: AuditLogin, accepted: bool, reason: str | None) -> tuple[Outbound, ...]:
        if req.reply_to is None:
            return ()
        reply = Reply(
            header=self.stamp("reply"), request_id=req.request_id, accepted=accepted, reason=reason
        )
        return (Outbound.of("reply", self.topics.reply(req.reply_to), reply),)

    def _refused(self, reply_to: str, request_id: str, reason: str) -> Outbound:
        """The reply to a login report that did not decode."""
        reply = Reply(
            header=self.stamp("reply"), request_id=request_id, accepted=False, reason=reason
        )
        return Outbound.of("reply", self.topics.reply(reply_to), reply)


def login_entry(req: AuditLogin, identity: Identity) -> AuditEntry:
    """The entry for a dashboard's login report: the person's account, vouched by the dashboard.

    Its time is the dashboard's (the report may arrive later, retried). A failed login names
    what was typed, not an account anybody proved: never `verified`.
    """
    reporter, vouched = identity.actor(req.header.sender)
    return AuditEntry(
        at=req.header.timestamp,
        actor=req.user,
        verified=vouched and req.event != "login_failed" and req.user is not None,
        via=reporter,
        act=req.event,
        target=None,
        detail=f"from {req.address}" if req.address else None,
        outcome="refused" if req.event == "login_failed" else "accepted",
        reason=req.reason,
    )
