"""Who may open the dashboard: the login check and the session's tag, without Flask (auth.py is
their I/O shell; failed logins are throttled by `gridfleet.throttle.LoginThrottle`)."""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable

from gridfleet.accounts import Account, Accounts, Role

# People log in with the people's-side accounts: their broker rules are the dashboard's.
LOGIN_ROLES: tuple[Role, ...] = ("operator", "dashboard")
REFUSED = "wrong user name or password"
# Compared against when the user is unknown, so an unknown name costs what a known one does.
_NOBODY = "x" * 32


class LoginRefused(Exception):
    """A login that does not open the dashboard; the message says why, in words."""


def check_login(accounts: Accounts, username: str, password: str) -> Account:
    """The account `username` logs in to, or LoginRefused.

    Unknown user and wrong password get the same words (nobody learns which names exist); a right
    password on a unit's or the coordinator's account is told which accounts may log in.
    """
    account = accounts.accounts.get(username)
    expected = account.password if account is not None else _NOBODY
    same = hmac.compare_digest(password.encode(), expected.encode())
    if account is None or not same:
        raise LoginRefused(REFUSED)
    if account.role not in LOGIN_ROLES:
        raise LoginRefused(
            f"{username} is a {account.role} account: log in with an operator or dashboard account"
        )
    return account


def session_tag(secret: bytes, account: Account) -> str:
    """What a session keeps besides the name: changes when the account's password does.

    A session cookie made before a password change then no longer hands out the new password.
    Keyed with the server's secret: the cookie is signed, not encrypted, so anyone can read it.
    """
    message = f"{account.name}\0{account.password}".encode()
    return hmac.new(secret, message, hashlib.sha256).hexdigest()


def session_account(accounts: Accounts, secret: bytes, user: object, tag: object) -> Account | None:
    """The account a session (its `user` and `tag`) still stands for, or None."""
    if not isinstance(user, str) or not isinstance(tag, str):
        return None
    account = accounts.accounts.get(user)
    if account is None or account.role not in LOGIN_ROLES:
        return None
    return account if hmac.compare_digest(tag, session_tag(secret, account)) else None


SESSION_S = 12 * 3600.0  # a login lasts a working day at most, then the person logs in again
# Sessions one account keeps open at once (browsers, machines of a shared control-room account).
SESSIONS_PER_ACCOUNT = 50


class SessionBook:
    """The sessions the server still honours: a login opens one, logout or age closes it.

    A signed cookie alone cannot be taken back: one copied before logout still opened the page.
    The cookie names a session here instead; what is not here (closed, expired, or from before
    a restart) is logged out. At most `per_account` are kept for each account, its oldest
    closed first: one account's logins never close another's (as found, 10,001 logins as one
    account closed everybody else's), and the book stays bounded by the accounts file.
    """

    def __init__(
        self,
        lifetime_s: float = SESSION_S,
        clock: Callable[[], float] = time.monotonic,
        per_account: int = SESSIONS_PER_ACCOUNT,
        wall: Callable[[], float] = time.time,
        closed: Callable[[str, int], None] | None = None,
    ) -> None:
        self.lifetime_s = lifetime_s
        self.clock = clock
        self.per_account = per_account
        self.wall = wall
        # Told of each session closed before its end (logout, a new login, an eviction), with
        # that end: its broker password is taken back (dashboard/revoke.py).
        self.closed = closed
        self._open: dict[str, tuple[str, float, int]] = {}  # id: (user, ends at, its unix end)
        self._by_user: dict[str, OrderedDict[str, None]] = {}  # user: their ids, oldest first
        self._lock = threading.Lock()  # the server answers each request in its own thread

    def open(self, user: str) -> str:
        """A new session for `user`; its id (random, 128 bits)."""
        sid = secrets.token_urlsafe(16)
        evicted: list[tuple[str, int]] = []
        with self._lock:
            ends = int(self.wall() + self.lifetime_s)
            self._open[sid] = (user, self.clock() + self.lifetime_s, ends)
            mine = self._by_user.setdefault(user, OrderedDict())
            mine[sid] = None
            while len(mine) > self.per_account:
                oldest, _ = mine.popitem(last=False)
                entry = self._open.pop(oldest, None)
                if entry is not None:
                    evicted.append((oldest, entry[2]))
        self._tell(evicted)
        return sid

    def __len__(self) -> int:
        with self._lock:
            return len(self._open)

    def user_of(self, sid: object) -> str | None:
        """The user session `sid` is open for, or None (closed, expired, unknown)."""
        if not isinstance(sid, str):
            return None
        with self._lock:
            entry = self._open.get(sid)
            if entry is None:
                return None
            if self.clock() >= entry[1]:
                self._forget(sid)
                return None
            return entry[0]

    def expires(self, sid: object) -> int | None:
        """When open session `sid` ends, in unix seconds (None: it is not open)."""
        if self.user_of(sid) is None:
            return None
        with self._lock:
            entry = self._open.get(sid) if isinstance(sid, str) else None
            return None if entry is None else entry[2]

    def close(self, sid: object) -> None:
        """End session `sid` (nothing when it is not open)."""
        if isinstance(sid, str):
            with self._lock:
                entry = self._forget(sid)
            self._tell([] if entry is None else [(sid, entry[2])])

    def _tell(self, ended: list[tuple[str, int]]) -> None:
        """Tell `closed` of the sessions closed before their end (the lock not held)."""
        if self.closed is not None:
            for sid, ends in ended:
                self.closed(sid, ends)

    def _forget(self, sid: str) -> tuple[str, float, int] | None:
        """Drop `sid` from both indexes (the lock held); its entry, if it was open."""
        entry = self._open.pop(sid, None)
        if entry is None:
            return None
        mine = self._by_user.get(entry[0])
        if mine is not None:
            mine.pop(sid, None)
            if not mine:
                del self._by_user[entry[0]]
        return entry
