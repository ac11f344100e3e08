"""The audit trail's decisions, without I/O: who did what, when, and whether it was carried out.

The core hands `AuditLog` every request it answered and every stop payload it read; the log makes
the entries (protocol.md §6.8), and the dashboard's login reports (`requests/audit_login`,
`AuditLog.login`); a page of entries (`requests/audit`) is a record query as the job history's
(records.py: the core checks it, the shell reads it from the store). Who did it comes from the
broker, never from the payload alone:

- a request's `header.sender` and the latch's `by` are ids of the account that published them
  when the broker drops any other (the embedded broker with accounts: `vouched`); the entry names
  that account and says `verified`. On a broker that does not check (Mosquitto, or none with
  accounts) they are the client's claim: recorded as such, `verified` false;
- a unit's or device's press is on its own topic, which the broker's ACL binds to its account;
- a login is the dashboard's word, and only a dashboard account may send it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING

from gridfleet.config import names_owned_id
from gridfleet.coordinator.requests import Outcome
from gridfleet.protocol import (
    CancelJob,
    ClearObstacles,
    CloseZone,
    ControlUnit,
    EstopSignal,
    OpenZone,
    RemoveUnit,
    SetGoal,
    SubmitJob,
    decode_estop,
    encode_estop,
)
from gridfleet.protocol.messages import (
    AuditAct,
    AuditEntry,
    AuditLogin,
    Request,
)
from gridfleet.protocol.stop import LATCH
from gridfleet.squares import Cell

if TYPE_CHECKING:  # the accounts' file models load pydantic's plugins, and with them sockets
    from gridfleet.accounts import Accounts, Role

DEFAULT_AUDIT_DAYS = 90.0  # how long entries are kept unless --audit-days says
READ_ROLES: tuple[Role, ...] = ("operator", "dashboard")  # who may read the audit
REPORT_ROLES: tuple[Role, ...] = ("dashboard",)  # who may report logins
TARGET_CHARS = 200
# A dashboard retries a report for a minute at most: the latest this many are enough to know.
LOGINS_REMEMBERED = 1000


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
        where = f"{_asked(req.pickup)} -> {_asked(req.dropoff)}"  # a place by its name
        return "submit_job", req.job_id, f"{req.mass_kg:g} kg, {where}, priority {req.priority}"
    if isinstance(req, CancelJob):
        return "cancel_job", req.job_id, None
    if isinstance(req, SetGoal):
        if req.target is None:
            return "clear_goal", req.unit, None
        return "set_goal", req.unit, f"to {list(req.target)}"
    if isinstance(req, ControlUnit):
        return req.command, req.unit, None
    if isinstance(req, RemoveUnit):
        return "remove_unit", req.unit, req.reason
    if isinstance(req, CloseZone):  # the rectangle as asked (its corners in either order)
        return "close_zone", f"{req.name} {list(req.first)} to {list(req.last)}", req.reason
    if isinstance(req, OpenZone):
        return "open_zone", req.name, None
    if isinstance(req, ClearObstacles):
        if req.squares is None:
            return "clear_obstacles", "all", None
        squares = ", ".join(str(list(c)) for c in req.squares)
        if len(squares) > TARGET_CHARS:
            squares = f"{squares[: TARGET_CHARS - 20]}... ({len(req.squares)} squares)"
        return "clear_obstacles", squares, None
    raise ValueError(f"{type(req).__name__} is no operator act")


def _asked(where: Cell | str) -> str:
    """A job's pickup or dropoff as the request gave it: a place's name, or a square."""
    return where if isinstance(where, str) else str(list(where))


class AuditLog:
    """Makes audit entries from the requests the core answered and the stop payloads it read."""

    def __init__(self, identity: Identity | None = None) -> None:
        self.identity = identity or Identity()
        self._seen: dict[str, bytes] = {}  # stop topic -> the payload last taken into account
        self._presses: dict[str, EstopSignal] = {}  # held presses: the latch's copies of them
        self._fresh: list[AuditEntry] = []
        self._seen_fresh: dict[str, bytes] = {}
        # Login reports already stored, oldest first: a retry is answered, not stored again.
        self._logins: dict[tuple[str, str], None] = {}

    def restore(self, seen: Iterable[tuple[str, bytes]]) -> None:
        """The stop payloads seen before a restart: their retained copies are no new acts."""
        self._seen.update(seen)

    def request(self, at: datetime, req: Request, outcome: Outcome) -> None:
        """A new request the core answered (a retry is the same act: not passed in again)."""
        act, target, detail = request_act(req)
        if isinstance(req, RemoveUnit | OpenZone) and outcome.accepted:
            # What became of its job; the zone opened, its rectangle and why it was closed.
            detail = "; ".join(d for d in (outcome.reason, detail) if d)
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
                reason=None if outcome.accepted else outcome.reason,
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

    def login(self, req: AuditLogin) -> str | None:
        """A dashboard's login report, recorded once: why it is refused (None: it is not)."""
        key = (req.header.sender, req.request_id)
        if key in self._logins:  # a retry: stored already, answered again
            return None
        why = self.identity.refusal(req.header.sender, REPORT_ROLES, "report logins")
        if why is not None:
            return why
        self._fresh.append(login_entry(req, self.identity))
        self._logins[key] = None
        while len(self._logins) > LOGINS_REMEMBERED:
            del self._logins[next(iter(self._logins))]
        return None

    def take(self) -> AuditNews:
        """The entries and seen payloads since the last call (the shell stores them)."""
        news = AuditNews(tuple(self._fresh), tuple(self._seen_fresh.items()))
        self._fresh.clear()
        self._seen_fresh.clear()
        return news


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
