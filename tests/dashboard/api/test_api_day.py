"""A warehouse system's day against the HTTP API, with a real HTTP client and a real fleet
(broker, coordinator, simulated units): by place names, a retry with its key, a list with a
filter, one job, a cancel, the history as CSV, the audit."""

from __future__ import annotations

import csv
import io
from collections.abc import Callable
from pathlib import Path

import pytest

from gridfleet.console.job import HISTORY_COLUMNS
from gridfleet.dashboard.api.idempotency import derived_id
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.api_client import job_ids, online, problem, serving
from support.wait import wait_for

RunSystem = Callable[..., tuple[ServiceThread, ServiceThread]]
# Its verdict rests on what the broker keeps (retained views) and passes (requests, replies):
# asked for both, it runs on Mosquitto too.
pytestmark = pytest.mark.every_broker


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
def test_a_warehouse_systems_day(
    broker: BrokerThread, root: str, run_system: RunSystem, playfield: Path
) -> None:
    run_system(playfield)
    with serving(broker.url, root) as served, served.client() as api:
        online(api)
        places = {p["name"]: p for p in api.get("/places").json()["places"]}
        assert places["A1"] == {"name": "A1", "square": [1, 1], "kinds": ["pickup"]}
        assert "dropoff" in places["P1"]["kinds"]

        # The morning's first order, by place names, with the WMS's own order number as key.
        order = {"pickup": "A1", "dropoff": "P1", "mass_kg": 1.5, "priority": 10}
        first = api.post("/jobs", json=order, headers={"Idempotency-Key": "wms-order-1001"})
        assert first.status_code == 201, first.text
        job = first.json()
        assert job["id"] == derived_id("", "wms-order-1001")  # no accounts: the dashboard's own
        assert (job["pickup"], job["dropoff"]) == ([1, 1], [8, 8])
        assert (job["pickup_place"], job["dropoff_place"]) == ("A1", "P1")
        assert job["priority"] == 10 and job["state"] in ("queued", "assigned", "to_pickup")
        assert first.headers["Location"] == f"/api/v1/jobs/{job['id']}"

        # Its answer was lost: the WMS sends it again, the same, with the same key.
        again = api.post("/jobs", json=order, headers={"Idempotency-Key": "wms-order-1001"})
        assert again.status_code == 201 and again.json()["id"] == job["id"]
        assert job_ids(api).count(job["id"]) == 1
        # The same key for another order is a mistake, refused, changing nothing.
        other = {**order, "mass_kg": 2.0}
        reused = api.post("/jobs", json=other, headers={"Idempotency-Key": "wms-order-1001"})
        body = problem(reused, 422, "idempotency_key_reused")
        assert body["job_id"] == job["id"] and "wms-order-1001" in str(body["detail"])
        assert api.get(f"/jobs/{job['id']}").json()["mass_kg"] == 1.5

        # Squares work too; and a job without a key gets the coordinator's own id.
        second = api.post(
            "/jobs",
            json={"pickup": [8, 1], "dropoff": [1, 8], "mass_kg": 4.0},
            headers={"Idempotency-Key": "wms-order-1002"},
        )
        assert second.status_code == 201, second.text
        third = api.post("/jobs", json={"pickup": "A3", "dropoff": "P3", "mass_kg": 8.0})
        assert third.status_code == 201, third.text
        assert third.json()["id"].startswith("job-")
        ids = [job["id"], second.json()["id"], third.json()["id"]]
        assert sorted(job_ids(api)) == sorted(ids)

        # A list with a filter, and a page at a time.
        listed = api.get("/jobs", params={"limit": 1})
        assert listed.status_code == 200 and len(listed.json()["jobs"]) == 1
        assert listed.json()["next_cursor"] == "1"
        rest = api.get("/jobs", params={"limit": 5, "cursor": listed.json()["next_cursor"]})
        assert [j["id"] for j in listed.json()["jobs"] + rest.json()["jobs"]] == job_ids(api)
        cancelled_none = api.get("/jobs", params={"state": "cancelled"})
        assert cancelled_none.json()["jobs"] == []

        # One job; a cancel; a second cancel of a job already final is a conflict.
        one = api.get(f"/jobs/{ids[1]}")
        assert one.status_code == 200 and one.json()["dropoff"] == [1, 8]
        cancel = api.delete(f"/jobs/{ids[1]}")
        assert cancel.status_code == 200, cancel.text
        assert cancel.json()["state"] == "cancelled"
        assert [
            j["id"] for j in api.get("/jobs", params={"state": "cancelled"}).json()["jobs"]
        ] == [ids[1]]
        twice = problem(api.delete(f"/jobs/{ids[1]}"), 409, "conflict")
        assert twice["detail"] == f"job {ids[1]} is already cancelled"

        # The day goes on: the others are delivered.
        def delivered() -> bool:
            return all(api.get(f"/jobs/{i}").json()["state"] == "done" for i in (ids[0], ids[2]))

        wait_for(delivered, timeout=60, interval=0.25, what="both jobs delivered")
        done_by = api.get(f"/jobs/{ids[0]}").json()["unit"]
        mine = api.get("/jobs", params={"unit": done_by}).json()["jobs"]
        assert mine and all(j["unit"] == done_by for j in mine)

        # The evening: the day's history as CSV, in `gridfleet job history --csv`'s columns.
        export = api.get("/history", params={"since": "1h", "format": "csv"})
        assert export.status_code == 200, export.text
        assert export.headers["content-type"].startswith("text/csv")
        rows = list(csv.reader(io.StringIO(export.text)))
        assert tuple(rows[0]) == HISTORY_COLUMNS
        lives = {i: [r[2] for r in rows[1:] if r[1] == i] for i in ids}
        assert lives[ids[0]][0] == "queued" and lives[ids[0]][-1] == "done", lives
        assert lives[ids[1]][-1] == "cancelled", lives
        assert len(rows) - 1 == sum(len(v) for v in lives.values())  # our jobs alone
        as_json = api.get("/history", params={"since": "1h", "job": ids[0]}).json()
        assert [e["state"] for e in as_json["entries"]] == lives[ids[0]]
        assert as_json["next_cursor"] is None
        # A page at a time, the next one's address in a Link header.
        paged = api.get("/history", params={"since": "1h", "limit": 2})
        assert paged.status_code == 200 and len(paged.json()["entries"]) == 2
        link = paged.headers["Link"]
        assert link.startswith("</api/v1/history?") and link.endswith('>; rel="next"')
        following = api.get(link[1 : link.index(">")].removeprefix("/api/v1"))
        assert following.status_code == 200
        assert following.json()["entries"][0] != paged.json()["entries"][-1]

        # Every act is in the audit, with who did it.
        trail = api.get("/audit", params={"since": "1h"}).json()["entries"]
        acts = [(e["act"], e["target"], e["outcome"]) for e in trail]
        assert ("submit_job", ids[0], "accepted") in acts
        assert ("cancel_job", ids[1], "accepted") in acts
        trail_csv = api.get("/audit", params={"since": "1h", "format": "csv"}).text
        assert trail_csv.splitlines()[0] == "at,actor,verified,via,act,target,detail,outcome,reason"
