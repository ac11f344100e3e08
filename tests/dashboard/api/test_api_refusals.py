"""Bad input of every kind, over HTTP against a real fleet: each gets its status and its words as
a problem (RFC 9457), the coordinator's reason verbatim, and changes nothing."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import httpx

from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.api_client import job_ids, online, problem, serving

RunSystem = Callable[..., tuple[ServiceThread, ServiceThread]]
JOB = {"pickup": "A1", "dropoff": "P1", "mass_kg": 1.5}


def zones(api: httpx.Client) -> list[str]:
    return [z["name"] for z in api.get("/zones").json()["zones"]]


def test_bad_input_of_every_kind_gets_its_problem_and_changes_nothing(
    broker: BrokerThread, root: str, run_system: RunSystem, playfield: Path
) -> None:
    run_system(playfield)
    with serving(broker.url, root) as served, served.client() as api:
        online(api)
        kept = api.post("/jobs", json=JOB, headers={"Idempotency-Key": "kept"})
        assert kept.status_code == 201, kept.text
        before = job_ids(api)

        # 400: not JSON, not an object, not the schema.
        problem(
            api.post("/jobs", content=b"pickup=A1", headers={"Content-Type": "text/plain"}),
            400,
            "not_json",
        )
        problem(
            api.post("/jobs", content=b"{not json", headers={"Content-Type": "application/json"}),
            400,
            "not_json",
        )
        problem(api.post("/jobs", json=[JOB]), 400, "not_json")
        for bad in (
            {"pickup": "A1", "dropoff": "P1"},  # no mass
            {**JOB, "mass_kg": "1.5"},  # a string is no mass
            {**JOB, "mass_kg": 0},
            {**JOB, "mass_kg": -1},
            {**JOB, "priority": True},
            {**JOB, "priority": 101},
            {**JOB, "priority": 1.5},
            {**JOB, "pickup": [1]},
            {**JOB, "pickup": [-1, 2]},
            {**JOB, "pickup": [1, 2, 3]},
            {**JOB, "pickup": "not a place!"},
            {**JOB, "unit": "unit1"},  # no such field
        ):
            body = problem(api.post("/jobs", json=bad), 400, "bad_request")
            assert body["errors"], body
        missing = problem(
            api.post("/jobs", json={"pickup": "A1", "dropoff": "P1"}), 400, "bad_request"
        )
        assert "mass_kg" in str(missing["detail"])
        key = problem(
            api.post("/jobs", json=JOB, headers={"Idempotency-Key": "k" * 201}), 400, "bad_request"
        )
        assert "Idempotency-Key" in str(key["errors"])

        # 422: what the coordinator refuses, in its own words.
        unknown = problem(api.post("/jobs", json={**JOB, "pickup": "Q9"}), 422, "unknown_place")
        assert str(unknown["detail"]).startswith("unknown place 'Q9': the places are A1, A2, A3")
        kind = problem(api.post("/jobs", json={**JOB, "pickup": "P1"}), 422, "bad_square")
        assert kind["detail"] == "place P1 is not a pickup (it is: dropoff)"
        off = problem(api.post("/jobs", json={**JOB, "pickup": [12, 3]}), 422, "bad_square")
        assert off["detail"] == "pickup [12, 3] is off the 10x10 map"
        problem(api.post("/jobs", json={**JOB, "dropoff": [2, 2]}), 422, "bad_square")  # a wall
        assert job_ids(api) == before
        heavy = problem(api.post("/jobs", json={**JOB, "mass_kg": 50.0}), 422, "too_heavy")
        assert heavy["detail"] == "mass 50.0 kg exceeds every unit's capacity (largest 20.0 kg)"
        # ... listed as rejected, as the protocol lists a job no unit can carry (§6.1).
        rejected = api.get(f"/jobs/{heavy['job_id']}").json()
        assert rejected["state"] == "rejected" and rejected["reason"] == heavy["detail"]

        # 409: a zone closed over a pickup; a zone closed again with another rectangle.
        closed = api.put(
            "/zones/aisle-a", json={"first": [0, 0], "last": [2, 1], "reason": "cleaning"}
        )
        assert closed.status_code == 200, closed.text
        assert closed.json()["first"] == [0, 0] and closed.json()["reason"] == "cleaning"
        inside = problem(api.post("/jobs", json=JOB), 409, "zone_closed")
        assert str(inside["detail"]).endswith("[1, 1] is in zone aisle-a, closed: cleaning")
        same = api.put(
            "/zones/aisle-a", json={"first": [2, 1], "last": [0, 0], "reason": "cleaning"}
        )
        assert same.status_code == 200  # the same again: accepted, no change
        problem(
            api.put("/zones/aisle-a", json={"first": [0, 0], "last": [3, 3], "reason": "cleaning"}),
            409,
            "conflict",
        )
        problem(
            api.put("/zones/aisle-b", json={"first": [0, 0], "last": [1, 1], "reason": ""}),
            400,
            "bad_request",
        )
        problem(
            api.put("/zones/aisle-b", json={"first": [0, 0], "last": [99, 1], "reason": "x"}),
            422,
            "bad_square",
        )
        assert zones(api) == ["aisle-a"]
        assert api.delete("/zones/aisle-a").status_code == 200
        gone = problem(api.delete("/zones/aisle-a"), 404, "unknown_zone")
        assert "aisle-a" in str(gone["detail"])

        # 404: what the path names does not exist; 400: it cannot be a name.
        problem(api.get("/jobs/job-999"), 404, "unknown_job")
        problem(api.delete("/jobs/job-999"), 404, "unknown_job")
        problem(api.get("/units/unit9"), 404, "unknown_unit")
        problem(api.post("/units/unit9/control", json={"command": "pause"}), 404, "unknown_unit")
        problem(api.get("/jobs/bad%20id!"), 400, "bad_request")
        problem(api.post("/units/unit1/control", json={"command": "dance"}), 400, "bad_request")
        problem(api.post("/units/unit1/control", json={"command": "resume"}), 409, "conflict")
        problem(api.get("/nothing/here"), 404, "not_found")
        not_allowed = problem(api.patch("/jobs", json=JOB), 405, "method_not_allowed")
        assert not_allowed["instance"] == "/api/v1/jobs"

        # Queries: a time that is none, a range the coordinator refuses, bounds, strangers.
        problem(api.get("/history", params={"since": "yesterday"}), 400, "bad_request")
        problem(api.get("/history", params={"since": "2026-11-26T10:00:00"}), 400, "bad_request")
        backwards = problem(
            api.get("/history", params={"since": "1h", "until": "2h"}), 422, "invalid"
        )
        assert "is not before until" in str(backwards["detail"])
        problem(api.get("/jobs", params={"limit": 0}), 400, "bad_request")
        problem(api.get("/jobs", params={"limit": 501}), 400, "bad_request")
        problem(api.get("/jobs", params={"colour": "red"}), 400, "bad_request")
        problem(api.get("/history", params={"format": "xml"}), 400, "bad_request")

        # Another site's page in a browser; a body too large.
        foreign = api.post("/jobs", json=JOB, headers={"Origin": "http://evil.example"})
        problem(foreign, 403, "cross_site")
        problem(
            api.delete(f"/jobs/{kept.json()['id']}", headers={"Origin": "http://evil.example"}),
            403,
            "cross_site",
        )
        problem(
            api.post(
                "/jobs",
                content=b"{" + b" " * 70_000 + b"}",
                headers={"Content-Type": "application/json"},
            ),
            413,
            "payload_too_large",
        )

        # Nothing of all that changed anything: the same jobs (and the one rejected), no zone.
        assert set(job_ids(api)) - {heavy["job_id"]} == set(before)
        assert api.get(f"/jobs/{kept.json()['id']}").json()["state"] != "cancelled"
        assert zones(api) == []
