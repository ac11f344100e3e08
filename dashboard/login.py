"""Who may open the dashboard: the login check and the session's tag, without Flask (auth.py is
their I/O shell; failed logins are throttled by `gridfleet.throttle.LoginThrottle`)."""

from __future__ import annotations

import hashlib
import hmac

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
