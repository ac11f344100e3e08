"""Who the embedded broker lets in, with accounts: passwords, the client ids each account owns (by
its name, by a vehicle's bound `client_id`, by a session it holds), and throttled failures (pure:
no I/O, the clock comes in).

The broker reads the accounts file, which holds the passwords themselves (clients read theirs
from it): a slow hash of them protects nothing here, and amqtt's Argon2 check cost ~30 ms of the
broker's one event loop per attempt, so a flood of wrong passwords held up every message (STOP
took seconds to reach the units). A keyed digest compared in constant time costs microseconds. A page session's own password
(gridfleet/session_login.py) is an HMAC keyed by its account's password, checked the same way,
and refused once the dashboard has revoked its session (`broker/revoke`) or its end has come.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass

from gridfleet.accounts import Accounts
from gridfleet.config import owner_of
from gridfleet.errors import ProtocolError
from gridfleet.protocol import TOPICS, Topics, decode
from gridfleet.protocol.constants import DEFAULT_ROOT, MAX_REQUEST_BYTES, REMOVED_UNIT_KINDS
from gridfleet.protocol.messages import BrokerRevoke
from gridfleet.session_login import (
    RevokedSessions,
    is_session_password,
    session_password_refusal,
)
from gridfleet.throttle import FailureBudget, LoginThrottle

# Error reports a client may send: a burst, then a few a second (a unit stuck in a loop of errors
# was relayed 1:1 to every page and terminal, 200 a second).
ERRORS_BURST = 20
ERRORS_PER_S = 5.0

# Compared against when the name is unknown, so an unknown name costs what a known one does.
_NOBODY = "\0unknown"


__all__ = ["Gate", "Revocation", "owner_of"]


@dataclass(frozen=True)
class Revocation:
    """What the gate made of a message on `broker/revoke`: the session taken back, or why not."""

    sid: str | None  # None: nothing revoked
    words: str  # for the broker's log


class Gate:
    """Checks a CONNECT's credentials and client id; `refusal` says why not, in words."""

    def __init__(
        self,
        accounts: Accounts,
        clock: Callable[[], float] = time.monotonic,
        throttle: LoginThrottle | None = None,
        root: str = DEFAULT_ROOT,
        wall: Callable[[], float] = time.time,
    ) -> None:
        topics = Topics(root)
        self._topics = topics
        # Where a message names who sent it, for people and the fleet to read (protocol.md §10).
        # Every request kind, the dashboard's login reports for the audit among them.
        requests = [k for k, spec in TOPICS.items() if spec.pattern.startswith("requests/")]
        self._signed = {topics.request(k) for k in requests} | {topics.fleet("errors")}
        # The latch names who engaged or released it (`engaged|<by>|…`), and the audit takes
        # that as who did it: a person's `by` must be an id their account owns. The coordinator
        # copies presses and restores the latch under the cause's own name.
        self._latch = topics.fleet("estop")
        self._copies_latch = {a.name for a in accounts.accounts.values() if a.role == "coordinator"}
        self._errors_topic = topics.fleet("errors")
        self.errors = FailureBudget(ERRORS_BURST, ERRORS_PER_S, clock)
        self._key = secrets.token_bytes(32)
        self._digests = {a.name: self._digest(a.password) for a in accounts.accounts.values()}
        self._nobody = self._digest(_NOBODY)
        # A page session's password (gridfleet/session_login.py) is checked with the account's
        # own, against the wall clock (its end is unix seconds); the dashboard accounts alone
        # take one back, on `broker/revoke`, and a broker restart forgets what they took back.
        self._passwords = {a.name: a.password for a in accounts.accounts.values()}
        self.wall = wall
        self.revoked = RevokedSessions()
        self.revoke_topic = topics.fleet("revoke")
        self._revokers = {a.name for a in accounts.accounts.values() if a.role == "dashboard"}
        # A VDA 5050 vehicle's client id is its vendor's to choose: any id no account owns, by
        # its name or by a vehicle's `client_id` (bound to that vehicle's account, connected or
        # not), and none another account's session holds (`takeover_refusal`).
        self._vehicles = {a.name for a in accounts.accounts.values() if a.role == "vehicle"}
        self._bound = accounts.bound_client_ids()
        # Per address and per name at an address, never per name alone: a stranger's guesses
        # never keep the operator or the coordinator out. An address here is where every
        # component of `gridfleet up` comes from too: a generous burst, and one name's failures
        # spend at most half of it (10, then one per 5 s), so a client retrying a stale password
        # does not shut the others out.
        self.throttle = throttle or LoginThrottle(
            pair_burst=10, pair_per_s=0.2, address_burst=20, address_per_s=1.0, clock=clock
        )

    def _digest(self, password: str) -> bytes:
        return hmac.new(self._key, password.encode(), hashlib.sha256).digest()

    def refusal(
        self, username: str | None, password: str | None, client_id: str, address: str
    ) -> str | None:
        """None to let this CONNECT in; otherwise why it is refused (for the broker's log)."""
        if not username:
            return "no user name (this broker has accounts)"
        wait = self.throttle.wait_s(username, address)
        if wait > 0:
            return (
                f"too many failed logins from {address} (as {username!r}, or as anyone): "
                f"wait {wait:.0f} s"
            )
        known = username in self._digests
        expected = self._digests.get(username, self._nobody)
        right = hmac.compare_digest(self._digest(password or ""), expected) and known
        why = None
        if not right and is_session_password(password):
            secret = self._passwords.get(username, _NOBODY)
            why = session_password_refusal(username, secret, password, self.wall(), self.revoked)
            right = why is None and known
        if not right:
            self.throttle.failed(username, address, known_name=known)
            said = f" ({why})" if why else ""
            return f"wrong user name or password for {username!r}{said}"
        bound = self._bound.get(client_id)
        if bound is not None and bound != username:
            return (
                f"client id {client_id!r} is bound to vehicle account {bound!r} (the client_id "
                f"of its vehicle): {username!r} may not use it"
            )
        if client_id and bound is None:  # empty: the broker makes up one, which nobody owns
            owner = owner_of(client_id, self._digests)
            if owner != username and not (owner is None and username in self._vehicles):
                whose = f"account {owner!r}" if owner else "no account"
                return (
                    f"client id {client_id!r} belongs to {whose}: {username!r} may use "
                    f"{username!r} or ids starting '{username}-' or '{username}@'"
                )
        return None

    def takeover_refusal(
        self, username: str | None, client_id: str, holder: str | None
    ) -> str | None:
        """None to let `username`'s CONNECT take over the session held under `client_id` by
        account `holder` (None: no session holds it); otherwise why not (for the broker's log).

        An account takes over its own sessions (a unit back after a silent cut must win), never
        another account's, whatever the id: one vehicle knocked another off by connecting under
        the unowned id that vehicle had chosen.
        """
        if holder is None or holder == username:
            return None
        return (
            f"client id {client_id!r} is in use by account {holder!r} (a session it holds): "
            f"{username!r} may not take it over"
        )

    def refused_publish(
        self, username: str | None, client_id: str, topic: str, data: bytes
    ) -> str | None:
        """None to pass this PUBLISH on; otherwise why it is dropped (for the broker's log).

        A request or error report names its sender in its header, and people and the coordinator
        take that as who did it: it must be an id the publishing account owns (as found, a job
        submitted with sender `coordinator` was listed as the coordinator's). Error reports are
        also limited per client. What cannot be read passes: the coordinator refuses it in words.
        """
        if topic == self._errors_topic:
            if self.errors.wait_s(client_id) > 0:
                return f"more than {ERRORS_PER_S:g} error reports a second"
            self.errors.failed(client_id)  # spends one of its budget
        return self._content_refusal(username, topic, data)

    def refused_will(self, username: str | None, topic: str, data: bytes) -> str | None:
        """None to register this CONNECT's last will; otherwise why the CONNECT is refused.

        amqtt sends a will itself, past the checks a publish passes (as found: ann's will on
        `requests/cancel_job` naming `operator` was audited as the operator's, verified). Its
        content is fixed at CONNECT, so it is held to the publish rules then; a will is one
        message, so checking it spends none of the client's error reports.
        """
        if topic == self.revoke_topic:
            return "a revocation is the dashboard's word at a logout, never a last will"
        return self._content_refusal(username, topic, data)

    def revocation(self, username: str | None, data: bytes) -> Revocation:
        """Take back the session a message on `broker/revoke` names, if a dashboard account sent it.

        The broker passes such a message to nobody, whoever sent it; another account's is
        dropped as any refused publish is (the ACL refuses it too).
        """
        if username is None or username not in self._revokers:
            return Revocation(None, f"{username!r} is not a dashboard account: dropped")
        try:
            revoke = decode(BrokerRevoke, data, MAX_REQUEST_BYTES)
        except ProtocolError as exc:
            return Revocation(None, f"not a revocation ({exc}): dropped")
        if not self.revoked.revoke(revoke.sid, revoke.expires, self.wall()):
            return Revocation(None, f"session {revoke.sid} has ended already: nothing to revoke")
        return Revocation(revoke.sid, f"session {revoke.sid} revoked by {username!r}")

    def _content_refusal(self, username: str | None, topic: str, data: bytes) -> str | None:
        """Why a message's content is refused: who it says sent it (its header, the latch's)."""
        if topic == self._latch:
            return self._latch_refusal(username, data)
        if data and username in self._copies_latch and self._is_removed_unit_topic(topic):
            return "the coordinator clears a removed unit's retained topics, never writes them"
        if topic not in self._signed or username is None or len(data) > MAX_REQUEST_BYTES:
            return None
        try:
            sender = json.loads(data)["header"]["sender"]
        except RecursionError:  # valid JSON another reader may see a sender in: not passed on
            return "it is nested too deeply to read its sender"
        except (ValueError, KeyError, TypeError):
            return None
        if not isinstance(sender, str):
            return None
        owner = owner_of(sender, self._digests)
        if owner != username:
            return f"its header names sender {sender!r}, an id account {username!r} does not own"
        return None

    def _is_removed_unit_topic(self, topic: str) -> bool:
        """Whether `topic` is one of a unit's own that the coordinator clears at its removal."""
        try:
            kind, ident = self._topics.parse(topic)
        except ProtocolError:
            return False
        return (
            ident is not None
            and kind in REMOVED_UNIT_KINDS
            and topic == self._topics.unit(kind, ident)
        )

    def _latch_refusal(self, username: str | None, data: bytes) -> str | None:
        """Why a latch payload is dropped: its `by` is an id the publishing account does not own.

        What is not a stop signal passes: the coordinator reports it and restores the latch.
        """
        if username is None or username in self._copies_latch:
            return None
        parts = data.split(b"|", 2)
        if len(parts) < 2 or parts[0] not in (b"engaged", b"released"):
            return None
        by = parts[1].decode("utf-8", "replace")
        if owner_of(by, self._digests) != username:
            return f"its latch names {by!r}, an id account {username!r} does not own"
        return None
