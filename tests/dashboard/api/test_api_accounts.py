"""The API with accounts, on the embedded broker that checks them: tokens, roles, the page's login
for reads, revocation at the next request, wrong tokens throttled and told to the audit, and
every act audited with its account (the broker vouching for it)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from gridfleet.accounts import Account, Accounts, default_accounts, new_password, write_accounts
from gridfleet.dashboard.api.fleet import api_client_id
from gridfleet.protocol import Topics
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.scenario import load_scenario
from gridfleet.system.assembly import Assembly, SystemSpec

from support.api_client import online, problem, serving, with_token, without_token
from support.paths import MAPS
from support.wait import wait_for

PLAYFIELD = MAPS / "playfield.toml"
JOB = {"pickup": [1, 1], "dropoff": [8, 8], "mass_kg": 1.5}


@dataclass
class Site:
    """A fleet whose broker checks accounts, and the accounts file its dashboard reads."""

    url: str
    root: str
    accounts: Accounts
    path: Path


@pytest.fixture
def site(tmp_path: Path) -> Iterator[Site]:
    units = [u.id for u in load_scenario(PLAYFIELD).units]
    accounts = default_accounts(units).with_account(Account("vera", new_password(), "viewer"))
    path = tmp_path / "accounts.toml"
    write_accounts(accounts, path)
    spec = SystemSpec(
        load_scenario(PLAYFIELD),
        root=DEFAULT_ROOT,  # its own broker: the ids without a root tag, as a site has them
        step_s=0.05,
        db_path=tmp_path / "jobs.db",
        accounts=accounts,
        ws_port=None,
    )
    assembly = Assembly(spec, "threads")
    system = assembly.start_threads()
    try:
        yield Site(system.url, DEFAULT_ROOT, accounts, path)
    finally:
        assembly.stop()


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
def test_tokens_say_who_calls_and_roles_say_what_they_may(site: Site) -> None:
    operator, operator_id, accounts = with_token(site.path, site.accounts, "operator")
    viewer, _, accounts = with_token(site.path, accounts, "vera")
    dashboard, _, accounts = with_token(site.path, accounts, "dashboard")
    served = serving(
        site.url, site.root, accounts=accounts, accounts_file=site.path, session_passwords=True
    )
    with (
        served as api_server,
        api_server.client(operator) as ann,
        api_server.client(viewer) as vera,
    ):
        online(ann)
        # No token: 401, saying what to send.
        with api_server.client() as nobody:
            body = problem(nobody.get("/jobs"), 401, "unauthorized")
            assert "Authorization: Bearer TOKEN" in str(body["detail"])
            assert nobody.get("/jobs").headers["WWW-Authenticate"].startswith("Bearer")
            problem(nobody.post("/jobs", json=JOB), 401, "unauthorized")
        with api_server.client("not-a-token") as stranger:
            problem(stranger.get("/jobs"), 401, "wrong_token")

        # An operator changes; the coordinator's audit names the account, vouched for.
        made = ann.post("/jobs", json=JOB, headers={"Idempotency-Key": "order-1"})
        assert made.status_code == 201, made.text
        job = made.json()
        assert job["submitted_by"] == api_client_id("operator", Topics(site.root))

        def audited() -> list[dict[str, object]]:
            trail = ann.get("/audit", params={"since": "1h"}).json()["entries"]
            return [e for e in trail if e["act"] == "submit_job" and e["target"] == job["id"]]

        entry = wait_for(audited, timeout=10, what="the submit in the audit")[0]
        assert (entry["actor"], entry["verified"], entry["via"]) == (
            "operator",
            True,
            job["submitted_by"],
        )

        # A viewer reads, and changes nothing.
        assert vera.get("/jobs").status_code == 200
        assert vera.get(f"/jobs/{job['id']}").json()["id"] == job["id"]
        assert vera.get("/units").status_code == 200
        assert vera.get("/stop").json()["engaged"] is False
        for refused in (
            vera.post("/jobs", json=JOB),
            vera.delete(f"/jobs/{job['id']}"),
            vera.post("/units/unit1/control", json={"command": "pause"}),
            vera.put("/zones/z1", json={"first": [0, 0], "last": [1, 1], "reason": "x"}),
            vera.post("/stop", json={"reason": "no"}),
            vera.get("/history"),
            vera.get("/history/charges"),
            vera.get("/audit"),
        ):
            body = problem(refused, 403, "role")
            assert str(body["detail"]).startswith("account vera is a viewer account")
        assert ann.get(f"/jobs/{job['id']}").json()["state"] != "cancelled"
        assert ann.get("/stop").json()["engaged"] is False

        # The stop: a dashboard account's token engages, only an operator releases.
        with api_server.client(dashboard) as board:
            stopped = board.post("/stop", json={"reason": "forklift in aisle 2"})
            assert stopped.status_code == 200, stopped.text
            assert stopped.json()["latch"]["by"] == api_client_id("dashboard", Topics(site.root))
            body = problem(board.delete("/stop"), 403, "role")
            assert "only an operator account" in str(body["detail"])
        released = ann.delete("/stop", params={"reason": "aisle 2 clear"})
        assert released.status_code == 200, released.text
        assert released.json()["engaged"] is False
        assert "released (it was engaged by dashboard-api" in released.json()["message"]

        # The page's login opens reads only.
        page = httpx.Client(base_url=api_server.server.url, timeout=30)
        with page:
            login = page.post(
                "/api/login",
                json={"username": "operator", "password": accounts.get("operator").password},
            )
            assert login.status_code == 200, login.text
            assert page.get("/api/v1/jobs").status_code == 200
            body = problem(page.post("/api/v1/jobs", json=JOB), 401, "unauthorized")
            assert "reads only" in str(body["detail"])

        # A revoked token stops at the next request, without a restart.
        without_token(site.path, accounts, "operator", operator_id)
        problem(ann.get("/jobs"), 401, "wrong_token")
        assert vera.get("/jobs").status_code == 200


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
def test_wrong_tokens_are_throttled_and_told_to_the_audit(site: Site) -> None:
    operator, _, accounts = with_token(site.path, site.accounts, "operator")
    served = serving(site.url, site.root, accounts=accounts, accounts_file=site.path)
    with served as guessed, guessed.client("gft1_0badc0de_" + "x" * 43) as guesser:
        statuses = [guesser.get("/jobs").status_code for _ in range(12)]
        assert statuses[:10] == [401] * 10 and statuses[10:] == [429, 429], statuses
        throttled = problem(guesser.get("/jobs"), 429, "throttled")
        assert "too many wrong API tokens" in str(throttled["detail"])
        assert int(guesser.get("/jobs").headers["Retry-After"]) >= 1
        # From this address, even a right token waits now (per address, as passwords).
        with guessed.client(operator) as ann:
            problem(ann.get("/jobs"), 429, "throttled")
        # The failed logins went to the audit, as the page's wrong passwords do. Read from a
        # dashboard of its own (this one makes 127.0.0.1 wait).
        reading = serving(site.url, site.root, accounts=accounts, accounts_file=site.path)
        with reading as other, other.client(operator) as reader:

            def failed() -> list[dict[str, object]]:
                trail = reader.get("/audit", params={"since": "1h"}).json()["entries"]
                return [e for e in trail if e["act"] == "login_failed"]

            found = wait_for(failed, timeout=20, interval=0.2, what="failed logins audited")
            assert found[0]["reason"] == "API: wrong or revoked API token"
            assert found[0]["detail"] == "from 127.0.0.1"
