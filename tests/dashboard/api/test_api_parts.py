"""The API's parts without a fleet: the document, the docs page and its CSP, the guard in front of
every route (other sites, bodies, tokens, roles), problems, keys, times, pages and events."""

from __future__ import annotations

import base64
import hashlib
import json
import re
from datetime import UTC, datetime, timedelta
from typing import get_args

import pytest
from flask.testing import FlaskClient

from gridfleet.accounts import Account, default_accounts, new_password
from gridfleet.api_tokens import issue_token
from gridfleet.dashboard.api.docs import same_items
from gridfleet.dashboard.api.events import ChangeTracker, EventLog
from gridfleet.dashboard.api.idempotency import derived_id
from gridfleet.dashboard.api.params import JobsQuery, at_moment
from gridfleet.dashboard.api.problems import STATUS_OF_CODE
from gridfleet.dashboard.api.routes_jobs import jobs_page
from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.protocol import JobsView, validate_id
from gridfleet.protocol.messages import JobView, RefusalCode, Zone, ZonesView
from gridfleet.protocol.stop import StopView

from support.effects import header

JOB = {"pickup": [1, 1], "dropoff": [8, 8], "mass_kg": 1.5}
# Every endpoint SITE_SPEC §3 names (and /coordinator), with its methods.
ENDPOINTS = {
    "/api/v1/jobs": {"get", "post"},
    "/api/v1/jobs/{job_id}": {"get", "delete"},
    "/api/v1/units": {"get"},
    "/api/v1/units/{unit_id}": {"get"},
    "/api/v1/units/{unit_id}/control": {"post"},
    "/api/v1/places": {"get"},
    "/api/v1/zones": {"get"},
    "/api/v1/zones/{name}": {"put", "delete"},
    "/api/v1/stop": {"get", "post", "delete"},
    "/api/v1/history": {"get"},
    "/api/v1/history/charges": {"get"},
    "/api/v1/audit": {"get"},
    "/api/v1/events": {"get"},
    "/api/v1/coordinator": {"get"},
}


@pytest.fixture
def web() -> FlaskClient:
    """A dashboard without accounts, its broker nowhere (nothing here reaches the fleet)."""
    return create_app(DashboardSettings(broker_ws="ws://127.0.0.1:9")).test_client()


def test_the_document_is_openapi_3_1_of_every_endpoint_from_the_protocols_models(
    web: FlaskClient,
) -> None:
    doc = web.get("/api/v1/openapi.json").get_json()
    assert doc["openapi"] == "3.1.0"
    assert {path: set(item) for path, item in doc["paths"].items()} == ENDPOINTS
    schemas = doc["components"]["schemas"]
    # The protocol's own models, keyword for keyword as pydantic writes them.
    ref = "#/components/schemas/{model}"
    for model in (JobView, Zone):
        assert schemas[model.__name__] == same_items(
            model.model_json_schema(ref_template=ref, mode="serialization")
        )
    # A map's keys are said (flask-openapi3's own schema objects drop `propertyNames`).
    counts = schemas["JobsPage"]["properties"]["counts"]
    assert counts["propertyNames"]["enum"][0] == "queued"
    # A square is two coordinates 0-4095, in words every tool reads.
    assert schemas["JobView"]["properties"]["pickup"] == {
        "items": {"maximum": 4095, "minimum": 0, "type": "integer"},
        "maxItems": 2,
        "minItems": 2,
        "title": "Pickup",
        "type": "array",
    }
    # Every ref resolves; every problem is problem+json; every route is bearer-protected.
    for found in re.findall(r'"\$ref": "#/components/schemas/([^"]+)"', json.dumps(doc)):
        assert found in schemas, found
    for path, item in doc["paths"].items():
        for method, operation in item.items():
            assert operation["security"] == [{"bearer": []}], (path, method)
            for status, answer in operation["responses"].items():
                if int(status) >= 400:
                    assert list(answer["content"]) == ["application/problem+json"], (path, status)
    assert doc["components"]["securitySchemes"]["bearer"]["scheme"] == "bearer"
    submit = doc["paths"]["/api/v1/jobs"]["post"]
    assert [p["name"] for p in submit["parameters"]] == ["Idempotency-Key"]
    assert submit["requestBody"]["content"]["application/json"]["example"]["pickup"] == "A1"


def test_the_docs_page_renders_the_document_under_a_csp_of_its_own(web: FlaskClient) -> None:
    page = web.get("/api/v1/docs")
    assert page.status_code == 200
    html = page.get_data(as_text=True)
    policy = page.headers["Content-Security-Policy"]
    (script,) = re.findall(r"<script>(.*?)</script>", html, re.S)
    digest = base64.b64encode(hashlib.sha256(script.encode()).digest()).decode()
    assert f"script-src 'self' 'sha256-{digest}'" in policy
    assert "frame-ancestors 'none'" in policy and "unsafe-eval" not in policy
    assert "https://" not in html  # Swagger UI's files are the wheel's, no CDN
    for asset in re.findall(r'(?:src|href)="(swagger/[^"]+)"', html):
        assert web.get(f"/api/v1/{asset}").status_code == 200, asset
    # The page itself keeps its own policy.
    assert "connect-src 'self' ws: wss:" in web.get("/").headers["Content-Security-Policy"]


def test_the_guard_refuses_other_sites_bodies_that_are_no_json_and_unknown_routes(
    web: FlaskClient,
) -> None:
    def problem_of(answer: object, status: int, code: str) -> dict[str, object]:
        assert answer.status_code == status, answer.get_data(as_text=True)  # type: ignore[attr-defined]
        assert answer.mimetype == "application/problem+json"  # type: ignore[attr-defined]
        body = answer.get_json()  # type: ignore[attr-defined]
        assert body["code"] == code and body["status"] == status
        return dict(body)

    foreign = {"Origin": "http://evil.example"}
    problem_of(web.post("/api/v1/jobs", json=JOB, headers=foreign), 403, "cross_site")
    problem_of(web.delete("/api/v1/stop", headers=foreign), 403, "cross_site")
    problem_of(web.post("/api/v1/jobs", data="pickup=1"), 400, "not_json")
    problem_of(
        web.post("/api/v1/jobs", data="[" * 50000, content_type="application/json"), 400, "not_json"
    )
    problem_of(web.post("/api/v1/jobs", json="a string"), 400, "not_json")
    problem_of(web.get("/api/v1/nowhere"), 404, "not_found")
    gone = problem_of(web.put("/api/v1/jobs", json=JOB), 405, "method_not_allowed")
    assert gone["instance"] == "/api/v1/jobs"
    assert "POST" in web.put("/api/v1/jobs", json=JOB).headers["Allow"]
    # The page's own routes keep the page's guard and answers.
    refused = web.post("/api/logout", data="x=1")
    assert refused.status_code == 403 and "error" in refused.get_json()
    assert web.get("/nowhere").mimetype != "application/problem+json"
    # Without accounts only this machine's names reach the API (DNS rebinding).
    rebound = web.get("/api/v1/jobs", headers={"Host": "evil.example:5000"})
    problem_of(rebound, 403, "cross_site")


def test_tokens_and_roles_are_checked_before_anything_reaches_the_fleet() -> None:
    accounts = default_accounts(["unit1"]).with_account(Account("vera", new_password(), "viewer"))
    viewer, _, accounts = issue_token(accounts, "vera")
    dashboard, _, accounts = issue_token(accounts, "dashboard")
    settings = DashboardSettings(broker_ws="ws://127.0.0.1:9", accounts=accounts)
    web = create_app(settings).test_client()
    nobody = web.get("/api/v1/jobs")
    assert nobody.status_code == 401 and nobody.headers["WWW-Authenticate"].startswith("Bearer")
    assert web.get("/api/v1/jobs", headers={"Authorization": "Basic b3A6cHc="}).status_code == 401
    as_viewer = {"Authorization": f"Bearer {viewer}"}
    for method, path, body in (
        ("post", "/api/v1/jobs", JOB),
        ("post", "/api/v1/stop", {"reason": "r"}),
        ("put", "/api/v1/zones/z1", {"first": [0, 0], "last": [1, 1], "reason": "r"}),
        ("post", "/api/v1/units/unit1/control", {"command": "pause"}),
    ):
        answer = getattr(web, method)(path, json=body, headers=as_viewer)
        assert answer.status_code == 403, (path, answer.get_json())
        assert answer.get_json()["code"] == "role"
    for path in ("/api/v1/history", "/api/v1/audit", "/api/v1/history/charges"):
        records = web.get(path, headers=as_viewer)
        assert records.status_code == 403 and records.mimetype == "application/problem+json"
        problem = records.get_json()
        said = "account vera is a viewer account: it may not read the audit or the records"
        assert problem["code"] == "role" and problem["detail"].startswith(said), (path, problem)
    board = web.delete("/api/v1/stop", headers={"Authorization": f"Bearer {dashboard}"})
    assert board.status_code == 403 and "only an operator" in board.get_json()["detail"]


def test_every_refusal_code_of_the_protocol_has_its_status() -> None:
    assert set(get_args(RefusalCode)) <= set(STATUS_OF_CODE)
    assert {
        c: STATUS_OF_CODE[c] for c in ("unknown_job", "conflict", "zone_closed", "too_heavy")
    } == {
        "unknown_job": 404,
        "conflict": 409,
        "zone_closed": 409,
        "too_heavy": 422,
    }
    assert all(400 <= s <= 599 for s in STATUS_OF_CODE.values())


def test_a_key_names_one_job_per_account() -> None:
    one = derived_id("operator", "order-1")
    assert one == derived_id("operator", "order-1") and validate_id(one) == one
    assert len({one, derived_id("operator", "order-2"), derived_id("ann", "order-1")}) == 3
    # No NUL in either (an account is an id, a key printable ASCII): the join is unambiguous.
    assert one.startswith("k-") and len(one) == 22


def test_times_are_taken_as_the_cli_takes_them_but_never_without_a_zone() -> None:
    now = datetime(2026, 11, 26, 12, 0, tzinfo=UTC)
    assert at_moment("24h", now) == now - timedelta(hours=24)
    assert at_moment("90s", now) == now - timedelta(seconds=90)
    assert at_moment("now", now) == now
    assert at_moment("2026-11-26", now) == datetime(2026, 11, 26, tzinfo=UTC)
    assert at_moment("2026-11-26T10:00:00+01:00", now) == datetime(2026, 11, 26, 9, tzinfo=UTC)
    assert at_moment("2026-11-26t10:00:00.123456789z", now).microsecond == 123456
    for bad in ("yesterday", "2026-11-26T10:00:00", "24", "2026-13-01", "0000-01-01", ""):
        with pytest.raises(ValueError, match="time"):
            at_moment(bad, now)


def job(n: int, state: str = "queued", unit: str | None = None) -> JobView:
    return JobView.model_validate(
        {
            "id": f"job-{n}",
            "pickup": [1, 1],
            "dropoff": [2, 2],
            "mass_kg": 1.0,
            "state": state,
            "unit": unit,
        }
    )


def view(*jobs: JobView, finished: tuple[JobView, ...] = ()) -> JobsView:
    return JobsView(header=header("coordinator"), jobs=list(jobs), finished=list(finished))


def test_the_jobs_listing_is_filtered_and_paged_in_the_views_order() -> None:
    listing = view(job(1), job(2, "to_pickup", "u1"), job(3), finished=(job(0, "done", "u1"),))
    first = jobs_page(listing, JobsQuery(limit=2))
    assert [j.id for j in first.jobs] == ["job-1", "job-2"] and first.next_cursor == "2"
    rest = jobs_page(listing, JobsQuery(limit=2, cursor=first.next_cursor))
    assert [j.id for j in rest.jobs] == ["job-3", "job-0"] and rest.next_cursor is None
    assert [j.id for j in jobs_page(listing, JobsQuery(unit="u1")).jobs] == ["job-2", "job-0"]
    assert [j.id for j in jobs_page(listing, JobsQuery(state="done")).jobs] == ["job-0"]
    assert jobs_page(listing, JobsQuery(cursor="99")).jobs == []


def test_events_are_the_changes_after_the_first_views() -> None:
    tracker = ChangeTracker()
    stop = StopView()
    tracker.baseline(view(job(1)), None, stop, None)
    assert tracker.jobs(view(job(1))) == []
    changed = tracker.jobs(view(job(1, "assigned", "u1"), job(2)))
    assert [(k, d.id) for k, d in changed] == [("job", "job-1"), ("job", "job-2")]
    zone = Zone(
        name="aisle-4", first=(0, 0), last=(1, 1), reason="cleaning", closed_at=datetime.now(UTC)
    )
    closed = tracker.zones(ZonesView(header=header("coordinator"), zones=[zone]))
    assert [(k, d.model_dump()["state"]) for k, d in closed] == [("zone", "closed")]
    opened = tracker.zones(ZonesView(header=header("coordinator"), zones=[]))
    assert [d.model_dump() for _, d in opened] == [
        {"name": "aisle-4", "state": "open", "zone": None}
    ]
    stop.apply("estop", None, "t/v1/fleet/estop", b"engaged|ann-page|drill")
    engaged = tracker.stop(stop, None)
    assert len(engaged) == 1 and engaged[0][1].model_dump()["engaged"] is True
    assert tracker.stop(stop, None) == []  # no change, no event


def test_a_stream_resumes_after_an_event_it_holds_else_it_resets() -> None:
    log = EventLog(kept=3)
    assert log.resume_from(None) == 0
    log.add([("job", job(n)) for n in range(5)])  # numbers 1-5, the latest 3 kept
    assert log.resume_from(f"{log.run}-4") == 4
    assert log.resume_from(f"{log.run}-2") == 2  # the one just before the oldest kept
    assert log.resume_from(f"{log.run}-1") is None  # pushed out
    assert log.resume_from(f"{log.run}-9") is None  # never was
    assert log.resume_from("ffffffff-4") is None  # another run's
    assert log.resume_from("nonsense") is None
    assert [e.number for e in log.after(3, wait_s=0)] == [4, 5]
    assert log.after(5, wait_s=0.01) == []
