"""The Flask app: the page, its static files, the MQTT.js bundle from node_modules, settings and
the login."""

from __future__ import annotations

from collections.abc import Callable

from flask import Flask, Response, jsonify, request, send_from_directory

from gridfleet.accounts import Accounts
from gridfleet.accounts_watch import AccountsFile
from gridfleet.config import names_this_machine
from gridfleet.dashboard.api import DashboardApp, install_api
from gridfleet.dashboard.api.context import ApiConfig
from gridfleet.dashboard.api.problems import ApiProblem
from gridfleet.dashboard.api.web import is_api
from gridfleet.dashboard.audit import login_reporter
from gridfleet.dashboard.auth import broker_password, current_user, install_login
from gridfleet.dashboard.revoke import session_revoker
from gridfleet.dashboard.settings import (
    INSTALL_HINT,
    LOGIN_FIRST,
    PACKAGE_DIR,
    DashboardSettings,
    browser_broker_url,
    settings_payload,
)

STATIC = PACKAGE_DIR / "static"


def create_app(settings: DashboardSettings, api: ApiConfig | None = None) -> Flask:
    """A Flask app serving the dashboard for `settings`, and its HTTP API (`api`: its waits)."""
    app = DashboardApp(__name__, static_folder=str(STATIC), static_url_path="/static")
    # The page is small and changes with upgrades: never let a browser run yesterday's code.
    app.config["SEND_FILE_MAX_AGE_DEFAULT"] = 0
    app.extensions["gridfleet_settings"] = settings
    # Logins, logouts and failed logins go to the coordinator's audit trail (dashboard/audit.py).
    audit = login_reporter(settings.accounts, settings.audit_broker, settings.root)
    app.extensions["gridfleet_audit"] = audit
    # With session passwords, logouts go to the broker, which then refuses that session's.
    revoker = (
        session_revoker(settings.accounts, settings.audit_broker, settings.root)
        if settings.session_passwords
        else None
    )
    app.extensions["gridfleet_revoker"] = revoker
    secret, book = install_login(app, settings, audit, revoker)
    install_api(
        app,
        url=api_broker(settings),
        root=settings.root,
        accounts=accounts_now(settings),
        session_user=lambda: current_user(settings, secret, book),
        reporter=audit,
        session_passwords=settings.session_passwords,
        config=api,
    )

    @app.before_request
    def refuse_rebound_hosts() -> tuple[Response, int] | None:
        # Without accounts the dashboard serves loopback only, so a browser names it by an
        # address or `localhost`; any other name is a page that rebound its own name to us.
        if settings.accounts is not None or names_this_machine(request.host):
            return None
        why = f"Host {request.host!r} is not this machine's address: open the page at 127.0.0.1"
        if is_api(request.path):
            return ApiProblem("cross_site", why).response(request.path), 403
        return jsonify({"error": why}), 403

    @app.after_request
    def security_headers(response: Response) -> Response:
        # The page loads only its own files and talks MQTT to the broker (another port, so any
        # ws/wss); MQTT.js keeps its keep-alive timer in a worker made from a blob; no site may
        # frame it (clickjacking the STOP/release buttons). The API's docs page has its own.
        response.headers.setdefault(
            "Content-Security-Policy",
            "default-src 'self'; connect-src 'self' ws: wss:; img-src 'self' data:; "
            "worker-src 'self' blob:; "
            "object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'",
        )
        response.headers["X-Frame-Options"] = "DENY"
        response.headers["X-Content-Type-Options"] = "nosniff"
        response.headers["Referrer-Policy"] = "no-referrer"
        if settings.https:
            response.headers["Strict-Transport-Security"] = "max-age=31536000"
        return response

    @app.get("/")
    def index() -> Response:
        return send_from_directory(STATIC, "index.html")

    @app.get("/api/settings")
    def api_settings() -> tuple[Response, int]:
        user = current_user(settings, secret, book)
        if settings.accounts is not None and user is None:
            body, status = {"error": LOGIN_FIRST, "login": {"required": True, "user": None}}, 401
        else:
            present = settings.mqtt_bundle.is_file()
            password = None if user is None else broker_password(settings, book, user)
            body = settings_payload(settings, present, user, request.host, password)
            status = 200
        response = jsonify(body)
        response.headers["Cache-Control"] = "no-store"  # it may hold a password
        return response, status

    @app.get("/vendor/mqtt.esm.js")
    def mqtt_bundle() -> Response:
        bundle = settings.mqtt_bundle
        if not bundle.is_file():
            # A module that throws says what to do, in the console and to the page's loader.
            body = f"throw new Error({INSTALL_HINT!r});\n"
            return Response(body, status=503, mimetype="text/javascript")
        return send_from_directory(bundle.parent, bundle.name, mimetype="text/javascript")

    @app.get("/healthz")
    def healthz() -> Response:
        return jsonify({"ok": True})

    return app


def api_broker(settings: DashboardSettings) -> str:
    """Where the HTTP API reaches the fleet: the dashboard's own broker URL (--audit-broker),
    else the page's, from this machine."""
    return settings.audit_broker or browser_broker_url(settings.broker_ws, "127.0.0.1")


def accounts_now(settings: DashboardSettings) -> Callable[[], Accounts] | None:
    """The accounts as they are now: their file read again when it changed (None: none)."""
    if settings.accounts_file is not None:
        return AccountsFile(settings.accounts_file).current
    accounts = settings.accounts
    return None if accounts is None else (lambda: accounts)
