"""Who calls the API, and what their role lets them do (protocol.md §10).

With accounts, every request shows `Authorization: Bearer TOKEN` (gridfleet/api_tokens.py; the
accounts file is read again when it changes, so a revoked token stops at the next request), or,
for reads only, the page's logged-in session cookie. Wrong tokens are throttled per address like
wrong passwords and reported to the audit as failed logins. Without accounts (a dashboard on
loopback) nobody shows anything: the API is the dashboard's own client.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from gridfleet.accounts import Account, Accounts
from gridfleet.api_tokens import (
    TokenCheck,
    TokenMalformed,
    TokenMissing,
    TokenOk,
    TokenThrottled,
    TokenWrong,
    token_throttle,
)
from gridfleet.dashboard.api.problems import ApiProblem
from gridfleet.dashboard.audit import LoginReporter, as_user

Need = Literal["read", "change", "release", "audit"]
# What each need takes: viewers read; operator and dashboard accounts change; only an operator
# releases the stop (a deliberate act of a person, never a dashboard's or a script's token of
# it); the audit is for operator and dashboard accounts (protocol.md §6.8).
ROLES_FOR: dict[Need, tuple[str, ...]] = {
    "read": ("operator", "dashboard", "viewer"),
    "change": ("operator", "dashboard"),
    "release": ("operator",),
    "audit": ("operator", "dashboard"),
}
WORDS_FOR: dict[Need, str] = {
    "read": "use the API",
    "change": "change anything (viewers read)",
    "release": "release the stop (only an operator account does)",
    "audit": "read the audit or the records (operator and dashboard accounts do)",
}
BEARER = 'Bearer realm="gridfleet"'


@dataclass(frozen=True)
class Caller:
    """Who a request is from: an account (None: a dashboard without accounts), and how."""

    account: Account | None
    via: Literal["token", "session", "loopback"]

    @property
    def name(self) -> str:
        """The account's name ('' without accounts)."""
        return "" if self.account is None else self.account.name

    @property
    def password(self) -> str | None:
        """The account's broker password (None without accounts)."""
        return None if self.account is None else self.account.password

    def allowed(self, need: Need) -> bool:
        """Whether this caller may do what `need` names."""
        return self.account is None or self.account.role in ROLES_FOR[need]

    def require(self, need: Need) -> None:
        """403 unless this caller may do what `need` names."""
        if not self.allowed(need):
            assert self.account is not None
            raise ApiProblem(
                "role",
                f"account {self.account.name} is a {self.account.role} account: it may not "
                f"{WORDS_FOR[need]}",
            )


class Identity:
    """Finds the caller of a request: token, session, or nobody needed."""

    def __init__(
        self,
        accounts: Callable[[], Accounts] | None,
        session_user: Callable[[], Account | None],
        reporter: LoginReporter | None = None,
        check: TokenCheck | None = None,
    ) -> None:
        self.accounts = accounts
        self.session_user = session_user
        self.reporter = reporter
        self.check = (
            check
            if check is not None or accounts is None
            else TokenCheck(accounts, token_throttle())
        )

    def caller(self, authorization: str | None, address: str, method: str) -> Caller:
        """The request's caller; 401 (no or bad token), 429 (throttled) or 403 (a role with no
        business here) otherwise."""
        if self.accounts is None or self.check is None:
            return Caller(None, "loopback")
        verdict = self.check.check(authorization, address)
        if isinstance(verdict, TokenOk):
            caller = Caller(verdict.account, "token")
        elif isinstance(verdict, TokenMissing):
            caller = self._session(method)
        elif isinstance(verdict, TokenMalformed):
            raise ApiProblem("unauthorized", verdict.reason, headers={"WWW-Authenticate": BEARER})
        elif isinstance(verdict, TokenWrong):
            self._failed(verdict.account_name, address, verdict.reason, throttled=False)
            raise ApiProblem("wrong_token", verdict.reason, headers={"WWW-Authenticate": BEARER})
        else:
            assert isinstance(verdict, TokenThrottled)
            self._failed(verdict.account_name, address, "too many wrong API tokens", True)
            raise ApiProblem(
                "throttled",
                f"too many wrong API tokens from this address: try again in "
                f"{verdict.retry_after} s",
                retry_after=verdict.retry_after,
            )
        caller.require("read")
        return caller

    def _session(self, method: str) -> Caller:
        """The page's logged-in session, for reads; else 401 saying what to send."""
        user = self.session_user()
        if user is not None and method in ("GET", "HEAD"):
            return Caller(user, "session")
        said = (
            "the page's login is for reads only: send 'Authorization: Bearer TOKEN' to change"
            if user is not None
            else "send 'Authorization: Bearer TOKEN' ('gridfleet accounts token NAME --file "
            "FILE' makes one)"
        )
        raise ApiProblem("unauthorized", said, headers={"WWW-Authenticate": BEARER})

    def _failed(self, account: str | None, address: str, reason: str, throttled: bool) -> None:
        """A wrong token, told to the audit as a failed login (bounded: LoginReporter.failed)."""
        if self.reporter is not None:
            user = None if account is None else as_user(account)
            self.reporter.failed(user, address, f"API: {reason}", throttled=throttled)
