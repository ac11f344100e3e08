"""The login's HTTP side: the session cookie and the /api/login and /api/logout routes."""

from __future__ import annotations

import secrets
from datetime import timedelta

from flask import Flask, Response, jsonify, request, session

from gridfleet.accounts import Account
from gridfleet.dashboard.audit import LoginReporter, as_user
from gridfleet.dashboard.login import (
    SESSION_S,
    LoginRefused,
    SessionBook,
    check_login,
    session_account,
    session_tag,
)
from gridfleet.dashboard.revoke import SessionRevoker
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.session_login import make_session_password
from gridfleet.throttle import LoginThrottle

NOT_JSON = 'send {"username": …, "password": …} as JSON'
API_PREFIX = "/api/v1/"


def current_user(settings: DashboardSettings, secret: bytes, book: SessionBook) -> Account | None:
    """The account this request's session is logged in as (None: anonymous, or no accounts)."""
    if settings.accounts is None:
        return None
    user = session.get("user")
    if user is None or book.user_of(session.get("sid")) != user:
        return None  # logged out, expired, or from before a restart
    return session_account(settings.accounts, secret, user, session.get("tag"))


def broker_password(settings: DashboardSettings, book: SessionBook, user: Account) -> str | None:
    """This session's own broker password, when the broker checks them (None: the account's)."""
    sid = session.get("sid")
    expires = book.expires(sid)
    if not settings.session_passwords or not isinstance(sid, str) or expires is None:
        return None
    return make_session_password(user.name, user.password, sid, expires)


def cross_site(method: str, origin: str | None, host_url: str, is_json: bool) -> str | None:
    """Why a request that changes something is refused as cross-site (None: it is the page's).

    The page sends JSON (another site's form cannot without the browser asking us first), and
    a browser names the page's origin, which must be this server's.
    """
    if method in ("GET", "HEAD", "OPTIONS"):
        return None
    if not is_json:
        return "send JSON: the dashboard's page does, another site's form cannot"
    if origin is not None and origin.rstrip("/") != host_url.rstrip("/"):
        return f"a request from {origin} is not the dashboard's page"
    return None


def install_login(
    app: Flask,
    settings: DashboardSettings,
    audit: LoginReporter | None = None,
    revoker: SessionRevoker | None = None,
) -> tuple[bytes, SessionBook]:
    """Configure the session cookie and add the login routes; the session secret and book.

    With `audit`, every login and logout is reported to the audit trail, and failed logins as
    `LoginReporter.failed` bounds them: a few from each address one by one, then a count. With
    `revoker`, a session closed before its end (logout, eviction) has its broker password taken
    back.
    """
    # Random per start unless configured: a restart then logs everybody out (docs/dashboard.md).
    secret = settings.secret_key or secrets.token_bytes(32)
    app.secret_key = secret
    app.config.update(
        SESSION_COOKIE_NAME="gridfleet_session",
        SESSION_COOKIE_HTTPONLY=True,
        # Sent only with requests from the page itself: another site cannot use the login.
        SESSION_COOKIE_SAMESITE="Strict",
        SESSION_COOKIE_SECURE=settings.https,
        PERMANENT_SESSION_LIFETIME=timedelta(seconds=SESSION_S),
    )
    book = SessionBook(closed=None if revoker is None else revoker.revoke)

    @app.before_request
    def refuse_cross_site() -> tuple[Response, int] | None:
        if request.path.startswith(API_PREFIX):
            # The HTTP API's own guard: the same Origin rule, JSON bodies, and changes only with
            # a bearer token, which no other site's page holds (dashboard/api/__init__.py).
            return None
        origin = request.headers.get("Origin")
        why = cross_site(request.method, origin, request.host_url, request.is_json)
        return (jsonify({"error": why}), 403) if why else None

    # Per address and per name at an address, never per name alone: guesses from one address
    # never make a right password from another wait (as found, one wrong password every 2.5 s
    # kept `operator` at 429). A name at an address: 5, then one every 12 s; an address: 10,
    # then one every 6 s (a check costs ~1 us: this bounds guesses, not work). A success
    # resets neither, so one good login cannot clear the failures of guesses beside it.
    throttle = LoginThrottle(pair_burst=5, pair_per_s=1 / 12, address_burst=10, address_per_s=1 / 6)

    @app.post("/api/login")
    def login() -> tuple[Response, int]:
        if settings.accounts is None:
            return jsonify({"error": "this dashboard has no accounts: no login needed"}), 400
        # JSON only: a form on another site cannot send it without the browser asking us first.
        body = request.get_json(silent=True) if request.is_json else None
        if not isinstance(body, dict) or not all(
            isinstance(body.get(k), str) for k in ("username", "password")
        ):
            return jsonify({"error": NOT_JSON}), 400
        who, name = request.remote_addr or "?", body["username"]
        wait = throttle.wait_s(name, who)
        if wait > 0:
            text = f"too many failed logins: try again in {wait:.0f} s"
            if audit is not None:
                # Counted, not each written: a flood must not fill the audit (audit.py).
                audit.failed(as_user(name), who, "too many failed logins", throttled=True)
            response = jsonify({"error": text})
            response.headers["Retry-After"] = str(max(1, round(wait)))
            return response, 429
        try:
            account = check_login(settings.accounts, body["username"], body["password"])
        except LoginRefused as refused:
            throttle.failed(name, who, known_name=name in settings.accounts.accounts)
            if audit is not None:
                audit.failed(as_user(name), who, str(refused))
            session.clear()
            return jsonify({"error": str(refused)}), 401
        book.close(session.get("sid"))
        session.clear()
        session.permanent = True  # the cookie ends with the session, not the browser
        session["user"] = account.name
        session["tag"] = session_tag(secret, account)
        session["sid"] = book.open(account.name)
        if audit is not None:
            audit.report("login", account.name, who)
        return jsonify({"user": account.name}), 200

    @app.post("/api/logout")
    def logout() -> tuple[Response, int]:
        user = current_user(settings, secret, book)  # who logs out (None: nobody was in)
        if audit is not None and user is not None:
            audit.report("logout", user.name, request.remote_addr)
        book.close(session.get("sid"))  # a copy of the cookie opens nothing any more
        session.clear()
        return jsonify({"ok": True}), 200

    return secret, book
