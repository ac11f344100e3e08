"""The dashboard's login without a browser: the pure check and throttle, then the Flask app."""

from __future__ import annotations

import json
import urllib.request
from pathlib import Path

import pytest
from flask import Flask
from flask.testing import FlaskClient

from gridfleet.accounts import Accounts, default_accounts, write_accounts
from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.cli import secret_from, settings_from, tls_from
from gridfleet.dashboard.login import (
    REFUSED,
    SESSIONS_PER_ACCOUNT,
    LoginRefused,
    SessionBook,
    check_login,
    session_account,
    session_tag,
)
from gridfleet.dashboard.server import DashboardServer
from gridfleet.dashboard.settings import DashboardSettings, browser_broker_url
from gridfleet.errors import ConfigError
from gridfleet.system.cli import build_parser


@pytest.fixture
def accounts() -> Accounts:
    return default_accounts(["unit1"])


@pytest.fixture
def app(accounts: Accounts) -> Flask:
    return create_app(DashboardSettings(broker_ws="ws://127.0.0.1:9001", accounts=accounts))


@pytest.fixture
def client(app: Flask) -> FlaskClient:
    return app.test_client()


def log_in(client: FlaskClient, user: str, password: str) -> tuple[int, dict[str, object]]:
    res = client.post("/api/login", json={"username": user, "password": password})
    return res.status_code, res.get_json()


# ---- pure -------------------------------------------------------------------------------------


def test_check_login_takes_people_accounts_only(accounts: Accounts) -> None:
    for name in ("operator", "dashboard"):
        assert check_login(accounts, name, accounts.get(name).password).name == name
    for user, password in (("operator", "wrong password!"), ("nobody", "whatever1234")):
        with pytest.raises(LoginRefused, match=f"^{REFUSED}$"):  # same words: no name leaks
            check_login(accounts, user, password)
    with pytest.raises(LoginRefused, match="unit1 is a unit account: log in with an operator"):
        check_login(accounts, "unit1", accounts.get("unit1").password)


def test_a_session_ends_when_the_password_changes(accounts: Accounts) -> None:
    secret = b"s" * 32
    operator = accounts.get("operator")
    tag = session_tag(secret, operator)
    assert session_account(accounts, secret, "operator", tag) == operator
    changed = default_accounts(["unit1"])  # same names, new passwords
    assert session_account(changed, secret, "operator", tag) is None
    assert session_account(accounts, b"t" * 32, "operator", tag) is None  # another secret
    unit_tag = session_tag(secret, accounts.get("unit1"))
    assert session_account(accounts, secret, "unit1", unit_tag) is None  # not a person's account
    assert session_account(accounts, secret, None, tag) is None


def test_the_page_reaches_a_wildcard_broker_where_it_reached_the_page() -> None:
    assert browser_broker_url("ws://0.0.0.0:9001", "192.168.1.10:5000") == "ws://192.168.1.10:9001"
    assert browser_broker_url("wss://0.0.0.0:9001", "fleet.lan") == "wss://fleet.lan:9001"
    assert browser_broker_url("ws://[::]:9001", "[fd00::5]:5000") == "ws://[fd00::5]:9001"
    assert browser_broker_url("ws://10.0.0.2:9001", "other:5000") == "ws://10.0.0.2:9001"


@pytest.mark.parametrize(
    ("url", "words"),
    [
        ("ws://u:pw1234567890@127.0.0.1:9001", "no login in the URL"),
        ("mqtts://127.0.0.1:8883", "ws://host:port or wss://"),
    ],
)
def test_dashboard_urls_the_page_cannot_use_are_refused(url: str, words: str) -> None:
    with pytest.raises(ConfigError, match=words):
        DashboardSettings(broker_ws=url)


def test_wss_is_accepted_and_accounts_need_someone_to_log_in(accounts: Accounts) -> None:
    assert DashboardSettings(broker_ws="wss://fleet.lan:9001").broker_ws == "wss://fleet.lan:9001"
    units_only = Accounts({"unit1": accounts.get("unit1")})
    with pytest.raises(ConfigError, match="nobody could log in"):
        DashboardSettings(accounts=units_only)


def test_session_secret_comes_from_the_environment_or_is_random() -> None:
    assert secret_from({}) is None
    assert secret_from({"GRIDFLEET_DASHBOARD_SECRET": "k" * 40}) == b"k" * 40
    with pytest.raises(ConfigError, match="at least 32"):
        secret_from({"GRIDFLEET_DASHBOARD_SECRET": "short"})


def test_cli_reads_the_accounts_file(tmp_path: Path, accounts: Accounts) -> None:
    path = tmp_path / "accounts.toml"
    write_accounts(accounts, path)
    args = build_parser(only="dashboard").parse_args(["dashboard", "--accounts", str(path)])
    settings = settings_from(args, {})
    assert settings.accounts == accounts and settings.secret_key is None


# ---- the app ----------------------------------------------------------------------------------


def passwords(accounts: Accounts) -> list[bytes]:
    return [a.password.encode() for a in accounts.accounts.values()]


def test_anonymous_visitor_gets_401_and_no_credential(
    client: FlaskClient, accounts: Accounts
) -> None:
    res = client.get("/api/settings")
    assert res.status_code == 401
    assert res.get_json()["error"] == "log in to see the fleet"
    assert res.headers["Cache-Control"] == "no-store"
    raw = res.data + str(res.headers).encode()
    assert not any(p in raw for p in passwords(accounts))
    assert b"broker_ws" not in res.data and b"mqtt" not in res.data
    page = client.get("/")
    assert page.status_code == 200 and b'id="login-form"' in page.data
    assert not any(p in page.data for p in passwords(accounts))


def test_wrong_password_says_so_and_opens_no_session(
    client: FlaskClient, accounts: Accounts
) -> None:
    status, body = log_in(client, "operator", "not the password")
    assert (status, body) == (401, {"error": REFUSED})
    assert client.get_cookie("gridfleet_session") is None
    assert client.get("/api/settings").status_code == 401
    status, body = log_in(client, "unit1", accounts.get("unit1").password)
    assert status == 401 and "log in with an operator or dashboard account" in str(body["error"])
    assert client.get("/api/settings").status_code == 401


def test_login_gives_the_person_their_own_broker_account_until_logout(
    client: FlaskClient, accounts: Accounts
) -> None:
    operator = accounts.get("operator")
    assert log_in(client, "operator", operator.password) == (200, {"user": "operator"})
    cookie = client.get_cookie("gridfleet_session")
    assert cookie is not None and cookie.same_site == "Strict" and cookie.http_only
    assert operator.password not in cookie.value  # the session names the user, never a password
    body = client.get("/api/settings").get_json()
    assert body["mqtt"] == {"username": "operator", "password": operator.password}
    assert body["login"] == {"required": True, "user": "operator"}
    assert body["broker_ws"] == "ws://127.0.0.1:9001"
    assert client.post("/api/logout", json={}).status_code == 200
    res = client.get("/api/settings")
    assert res.status_code == 401 and operator.password.encode() not in res.data


def test_logout_revokes_the_session_even_for_a_copy_of_its_cookie(
    app: Flask, accounts: Accounts
) -> None:
    # As found: an old cookie, copied before logout, still got the broker password.
    person, thief = app.test_client(), app.test_client()
    assert log_in(person, "operator", accounts.get("operator").password)[0] == 200
    cookie = person.get_cookie("gridfleet_session")
    assert cookie is not None and cookie.expires is not None  # it ends, not with the browser
    thief.set_cookie("gridfleet_session", cookie.value)
    assert thief.get("/api/settings").status_code == 200
    assert person.post("/api/logout", json={}).status_code == 200
    res = thief.get("/api/settings")
    assert res.status_code == 401 and accounts.get("operator").password.encode() not in res.data


def test_a_session_ends_after_its_lifetime() -> None:
    now = [0.0]
    book = SessionBook(lifetime_s=60, clock=lambda: now[0])
    sid = book.open("ann")
    assert book.user_of(sid) == "ann" and book.user_of("forged") is None
    now[0] = 59.9
    assert book.user_of(sid) == "ann"
    now[0] = 60.0
    assert book.user_of(sid) is None
    book.close("never opened")  # nothing happens


def test_one_accounts_logins_close_only_that_accounts_oldest_sessions() -> None:
    # As found: 10,001 logins as one account closed every other account's session.
    book = SessionBook(per_account=2)
    ann, bob = book.open("ann"), book.open("bob")
    flood = [book.open("operator") for _ in range(10_001)]
    assert book.user_of(ann) == "ann" and book.user_of(bob) == "bob"
    assert [book.user_of(s) for s in flood[-3:]] == [None, "operator", "operator"]
    assert book.user_of(flood[0]) is None and len(book) == 4  # bounded: 2 per account
    first = book.open("ann")  # ann's own logins still close ann's oldest
    book.open("ann")
    assert (book.user_of(ann), book.user_of(first)) == (None, "ann")


def test_a_flood_of_logins_as_one_account_leaves_everybody_elses_page_open(
    app: Flask, accounts: Accounts
) -> None:
    person, flooder = app.test_client(), app.test_client()
    assert log_in(person, "dashboard", accounts.get("dashboard").password)[0] == 200
    password = accounts.get("operator").password
    first = app.test_client()
    assert log_in(first, "operator", password)[0] == 200
    for _ in range(SESSIONS_PER_ACCOUNT):
        assert log_in(flooder, "operator", password)[0] == 200
        flooder.delete_cookie("gridfleet_session")  # each login a new session, as a script's
    assert person.get("/api/settings").status_code == 200
    assert first.get("/api/settings").status_code == 401  # the account's oldest, closed


def test_requests_from_other_sites_change_nothing(client: FlaskClient, accounts: Accounts) -> None:
    password = accounts.get("operator").password
    assert log_in(client, "operator", password)[0] == 200
    evil = {"Origin": "https://evil.example"}
    # Logged out by another site's page: refused, the session stays.
    assert client.post("/api/logout", json={}, headers=evil).status_code == 403
    assert client.post("/api/logout", data={"x": "1"}).status_code == 403  # a form
    assert client.get("/api/settings").status_code == 200
    res = client.post(
        "/api/login", json={"username": "operator", "password": password}, headers=evil
    )
    assert res.status_code == 403 and "not the dashboard's page" in res.get_json()["error"]
    own = {"Origin": "http://localhost"}  # the test client's own host
    assert client.post("/api/logout", json={}, headers=own).status_code == 200


def test_every_response_carries_the_security_headers(client: FlaskClient) -> None:
    for path in ("/", "/api/settings", "/static/js/main.js", "/healthz", "/nowhere"):
        headers = client.get(path).headers
        assert "frame-ancestors 'none'" in headers["Content-Security-Policy"], path
        assert headers["X-Content-Type-Options"] == "nosniff", path
        assert headers["X-Frame-Options"] == "DENY" and headers["Referrer-Policy"] == "no-referrer"
        assert "Strict-Transport-Security" not in headers  # plain HTTP: HSTS would mean nothing


def test_login_takes_json_only(client: FlaskClient, accounts: Accounts) -> None:
    password = accounts.get("operator").password
    # What a form on another site could send: refused, however right the password.
    form = client.post("/api/login", data={"username": "operator", "password": password})
    assert form.status_code == 403 and "send JSON" in form.get_json()["error"]
    assert client.post("/api/login", json=["operator", password]).status_code == 400
    assert client.post("/api/login", json={"username": "operator"}).status_code == 400
    assert client.get("/api/login").status_code == 405
    assert client.get("/api/settings").status_code == 401


def test_repeated_failures_are_slowed_down_and_break_nothing(
    client: FlaskClient, accounts: Accounts
) -> None:
    statuses = [log_in(client, "operator", f"guess number {n}")[0] for n in range(8)]
    assert statuses == [401] * 5 + [429] * 3
    res = client.post("/api/login", json={"username": "operator", "password": "x" * 20})
    assert "too many failed logins" in res.get_json()["error"] and int(res.headers["Retry-After"])
    assert client.get("/healthz").status_code == 200  # the server still answers
    # Another address has budgets of its own (guesses from one never lock out another), and
    # a success there clears nobody's failures.
    other = client.application.test_client()
    other.environ_base["REMOTE_ADDR"] = "127.0.0.2"
    assert log_in(other, "operator", "guess from elsewhere")[0] == 401
    assert log_in(other, "operator", accounts.get("operator").password)[0] == 200
    assert log_in(client, "operator", accounts.get("operator").password)[0] == 429
    # The guessing address's other names still have part of its budget.
    assert log_in(client, "dashboard", accounts.get("dashboard").password)[0] == 200


def test_without_accounts_nothing_changes() -> None:
    client = create_app(DashboardSettings()).test_client()
    body = client.get("/api/settings").get_json()
    assert body["mqtt"] is None and body["login"] == {"required": False, "user": None}
    assert json.dumps(body).count("password") == 0
    assert client.post("/api/login", json={"username": "a", "password": "b"}).status_code == 400


def test_https_flags_need_both_files(tmp_path: Path) -> None:
    parser = build_parser(only="dashboard")
    half = parser.parse_args(["dashboard", "--tls-cert", str(tmp_path / "server.pem")])
    with pytest.raises(ConfigError, match="both --tls-cert FILE and --tls-key FILE"):
        tls_from(half)
    missing = parser.parse_args(
        ["dashboard", "--tls-cert", str(tmp_path / "s.pem"), "--tls-key", str(tmp_path / "k")]
    )
    with pytest.raises(ConfigError, match="no such TLS certificate file"):
        tls_from(missing)
    assert tls_from(parser.parse_args(["dashboard"])) is None


def test_the_server_names_no_versions_and_https_asks_for_https_only() -> None:
    with (
        DashboardServer(create_app(DashboardSettings()), port=0) as server,
        urllib.request.urlopen(f"{server.url}/healthz", timeout=10) as res,
    ):
        assert res.headers["Server"] == "gridfleet"  # it was "Werkzeug/3.1.9 Python/3.11.2"
    secure = create_app(DashboardSettings(https=True)).test_client()
    assert secure.get("/").headers["Strict-Transport-Security"] == "max-age=31536000"


def test_without_accounts_a_page_that_rebound_its_name_to_us_gets_nothing() -> None:
    client = create_app(DashboardSettings()).test_client()
    assert client.get("/api/settings", headers={"Host": "127.0.0.1:5000"}).status_code == 200
    assert client.get("/", headers={"Host": "localhost:5000"}).status_code == 200
    rebound = client.get("/api/settings", headers={"Host": "evil.example:5000"})
    assert (
        rebound.status_code == 403 and "not this machine's address" in rebound.get_json()["error"]
    )
