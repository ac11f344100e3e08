"""The dashboard's HTTP API served for a test, and a real HTTP client (httpx) to call it."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx

from gridfleet.accounts import Accounts, write_accounts
from gridfleet.api_tokens import issue_token, revoke_tokens
from gridfleet.dashboard.api.context import ApiConfig
from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.server import DashboardServer
from gridfleet.dashboard.settings import DashboardSettings

from support.wait import wait_for

# Short waits: a test's fleet answers within a second; a refusal must not take 10 s to come.
TEST_CONFIG = ApiConfig(request_s=5.0, connect_s=5.0, view_s=3.0, heartbeat_s=0.5, retry_s=0.5)
PAGE_WS = "ws://127.0.0.1:9"  # the page's broker: no page is loaded in these tests


@dataclass
class ApiServer:
    """A dashboard serving the API on a free port; `client()` makes httpx clients for it."""

    server: DashboardServer

    @property
    def base(self) -> str:
        """The API's base URL, e.g. http://127.0.0.1:PORT/api/v1."""
        return f"{self.server.url}/api/v1"

    def client(self, token: str | None = None, timeout: float = 30.0) -> httpx.Client:
        """A client of the API, with a bearer token or none."""
        headers = {} if token is None else {"Authorization": f"Bearer {token}"}
        return httpx.Client(base_url=self.base, headers=headers, timeout=timeout)


@contextlib.contextmanager
def serving(
    broker_url: str,
    root: str,
    *,
    accounts: Accounts | None = None,
    accounts_file: Path | None = None,
    session_passwords: bool = False,
    config: ApiConfig = TEST_CONFIG,
) -> Iterator[ApiServer]:
    """The dashboard of `root`, its API reaching the fleet at `broker_url`."""
    settings = DashboardSettings(
        broker_ws=PAGE_WS,
        root=root,
        accounts=accounts,
        accounts_file=accounts_file,
        audit_broker=broker_url,
        session_passwords=session_passwords,
    )
    app = create_app(settings, config)
    server = DashboardServer(app).start()
    try:
        yield ApiServer(server)
    finally:
        server.stop()  # and the API's connections
        # The dashboard's own threads that talk to the broker (with accounts).
        revoker, audit = app.extensions["gridfleet_revoker"], app.extensions["gridfleet_audit"]
        if revoker is not None:
            revoker.stop()
        if audit is not None:
            audit.stop(timeout=2)


def online(api: httpx.Client, timeout: float = 30.0) -> None:
    """Until the API says the coordinator is online."""

    def up() -> bool:
        answer = api.get("/coordinator")
        return answer.status_code == 200 and answer.json()["state"] == "online"

    wait_for(up, timeout=timeout, interval=0.1, what="the API to see the coordinator online")


def job_ids(api: httpx.Client) -> list[str]:
    """The ids of every job the queue view lists (all pages)."""
    ids: list[str] = []
    cursor: str | None = None
    while True:
        params = {"limit": 500} | ({} if cursor is None else {"cursor": cursor})
        page = api.get("/jobs", params=params)
        assert page.status_code == 200, page.text
        ids += [j["id"] for j in page.json()["jobs"]]
        cursor = page.json()["next_cursor"]
        if cursor is None:
            return ids


def with_token(accounts_file: Path, accounts: Accounts, name: str) -> tuple[str, str, Accounts]:
    """A new token of account `name`, written to the file: its text, its id, the accounts."""
    text, record, held = issue_token(accounts, name)
    write_accounts(held, accounts_file)
    return text, record.id, held


def without_token(accounts_file: Path, accounts: Accounts, name: str, token_id: str) -> Accounts:
    """Account `name`'s token revoked, in the file."""
    _, kept = revoke_tokens(accounts, name, token_id)
    write_accounts(kept, accounts_file)
    return kept


def problem(answer: httpx.Response, status: int, code: str) -> dict[str, object]:
    """The answer's problem body, once checked to be `status` and `code` as problem+json."""
    assert answer.status_code == status, (answer.status_code, answer.text)
    assert answer.headers["content-type"].startswith("application/problem+json"), answer.headers
    body = answer.json()
    assert body["status"] == status and body["code"] == code, body
    assert body["type"] == f"urn:gridfleet:problem:{code}", body
    return dict(body)
