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
    ) -> None:
        self.lifetime_s = lifetime_s
        self.clock = clock
        self.per_account = per_account
        self._open: dict[str, tuple[str, float]] = {}  # id: (user, ends at)
        self._by_user: dict[str, OrderedDict[str, None]] = {}  # user: their ids, oldest first
        self._lock = threading.Lock()  # the server answers each request in its own thread

    def open(self, user: str) -> str:
        """A new session for `user`; its id (random, 128 bits)."""
        sid = secrets.token_urlsafe(16)
        with self._lock:
            self._open[sid] = (user, self.clock() + self.lifetime_s)
            mine = self._by_user.setdefault(user, OrderedDict())
            mine[sid] = None
            while len(mine) > self.per_account:
                oldest, _ = mine.popitem(last=False)
                self._open.pop(oldest, None)
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

    def close(self, sid: object) -> None:
        """End session `sid` (nothing when it is not open)."""
        if isinstance(sid, str):
            with self._lock:
                self._forget(sid)

    def _forget(self, sid: str) -> None:
        """Drop `sid` from both indexes (the lock held)."""
        entry = self._open.pop(sid, None)
        if entry is None:
            return
        mine = self._by_user.get(entry[0])
        if mine is not None:
            mine.pop(sid, None)
            if not mine:
                del self._by_user[entry[0]]
