"""Who may open the dashboard: the login check, the session's tag and the failed-login throttle,
without Flask (app.py is their I/O shell)."""

from __future__ import annotations

import hashlib
import hmac
import threading
import time
from collections import OrderedDict, deque
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


class Throttle:
    """Failed logins per client address: after `limit` within `window_s`, that address waits.

    Bounded memory: at most `max_clients` addresses are remembered, the oldest forgotten first.
    """

    def __init__(
        self,
        limit: int = 5,
        window_s: float = 60.0,
        clock: Callable[[], float] = time.monotonic,
        max_clients: int = 10_000,
    ) -> None:
        self.limit = limit
        self.window_s = window_s
        self.clock = clock
        self.max_clients = max_clients
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self._lock = threading.Lock()  # the server answers each request in its own thread

    def wait_s(self, who: str) -> float:
        """Seconds `who` must wait before trying again (0: go ahead)."""
        with self._lock:
            recent = self._recent(who)
            if len(recent) < self.limit:
                return 0.0
            return max(0.0, recent[0] + self.window_s - self.clock())

    def failed(self, who: str) -> None:
        """Count one failed login of `who`."""
        with self._lock:
            recent = self._recent(who)
            recent.append(self.clock())
            self._failures[who] = recent
            self._failures.move_to_end(who)
            while len(self._failures) > self.max_clients:
                self._failures.popitem(last=False)

    def succeeded(self, who: str) -> None:
        """Forget `who`'s failures."""
        with self._lock:
            self._failures.pop(who, None)

    def _recent(self, who: str) -> deque[float]:
        recent = self._failures.get(who) or deque(maxlen=self.limit)
        horizon = self.clock() - self.window_s
        while recent and recent[0] <= horizon:
            recent.popleft()
        return recent
