"""What the dashboard's failed logins write to the audit: each one while few, then a count."""

from __future__ import annotations

from flask import Flask
from flask.testing import FlaskClient

from gridfleet.accounts import default_accounts
from gridfleet.dashboard.audit import (
    FAILURE_WINDOW_S,
    FAILURES_REPORTED,
    OTHERS,
    FailureDigest,
    LoginReporter,
    Tally,
)
from gridfleet.dashboard.auth import install_login
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.protocol import Topics


class Clock:
    """A monotonic clock the test moves."""

    def __init__(self) -> None:
        self.s = 1000.0

    def __call__(self) -> float:
        return self.s


def rows(reporter: LoginReporter) -> list[tuple[str, str | None, str | None, str | None]]:
    """(event, user, address, reason) of each report waiting to go to the audit."""
    return [(r.event, r.user, r.address, r.reason) for r in reporter.pending()]


def test_a_flood_of_failed_logins_writes_a_few_rows_and_a_count_of_the_rest() -> None:
    # As found: every failed login, throttled or not, wrote a row (4,027 rows, ~7 MB, in 15 s).
    accounts = default_accounts(["unit1"])
    clock = Clock()
    # Not started: what it would send waits in its queue, for the test to read.
    reporter = LoginReporter("mqtt://127.0.0.1:9", Topics("site"), "dashboard", clock=clock)
    app = Flask(__name__)
    install_login(app, DashboardSettings(accounts=accounts), reporter)
    web, elsewhere = app.test_client(), app.test_client()
    elsewhere.environ_base["REMOTE_ADDR"] = "127.0.0.2"

    def fail(client: FlaskClient, n: int) -> int:
        body = {"username": f"guess{n}", "password": f"wrong password {n}"}
        return client.post("/api/login", json=body).status_code

    statuses = [fail(web, n) for n in range(300)]
    assert set(statuses) <= {401, 429} and 429 in statuses  # throttled ones are counted too
    # Each of the first few refused passwords one by one; the rest, and every 429, not.
    alone = [n for n, status in enumerate(statuses) if status == 401][:FAILURES_REPORTED]
    assert rows(reporter) == [
        ("login_failed", f"guess{n}", "127.0.0.1", "wrong user name or password") for n in alone
    ]
    first = len(alone)
    # Another address gets its own few; a right password is always recorded.
    fail(elsewhere, 0)
    operator = accounts.get("operator")
    login = elsewhere.post(
        "/api/login", json={"username": "operator", "password": operator.password}
    )
    assert login.status_code == 200
    assert rows(reporter)[first:] == [
        ("login_failed", "guess0", "127.0.0.2", "wrong user name or password"),
        ("login", "operator", "127.0.0.2", None),
    ]
    # Once the window is over, one row counts what was not written one by one.
    clock.s += FAILURE_WINDOW_S
    reporter.flush()
    throttled = statuses.count(429)
    summary = rows(reporter)[first + 2 :]
    assert summary == [
        (
            "login_failed",
            None,
            "127.0.0.1",
            f"{300 - first} more failed logins from this address in "
            f"{FAILURE_WINDOW_S:.0f} s, not recorded one by one ({throttled} refused as too many)",
        )
    ]
    reporter.flush()  # told once
    assert len(rows(reporter)) == first + 3


def test_each_address_has_its_few_rows_a_window_and_many_addresses_share_one_count() -> None:
    clock = Clock()
    digest = FailureDigest(per_window=3, window_s=60, clock=clock, addresses=2)
    assert [digest.admit("10.0.0.1") for _ in range(5)] == [True] * 3 + [False] * 2
    assert digest.admit("10.0.0.2") and not digest.admit("10.0.0.2", throttled=True)
    assert not digest.admit("10.0.0.3") and not digest.admit("10.0.0.4")  # past 2 addresses
    assert digest.due() == []  # nothing is over yet
    clock.s += 60
    assert digest.due() == [
        Tally("10.0.0.1", 2, 0, 60),
        Tally("10.0.0.2", 1, 1, 60),
        Tally(OTHERS, 2, 0, 60),
    ]
    assert digest.admit("10.0.0.1") and digest.due() == []  # a new window, its own few
    assert Tally(OTHERS, 2, 0, 60).reason().startswith("2 more failed logins from other addresses")
