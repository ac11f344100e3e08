"""The coordinator restarts while a site's system uses the API: requests get 503 (safe to retry),
and a retry with its Idempotency-Key gives exactly one job, whether or not the first one had
reached the coordinator before it went."""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from gridfleet.dashboard.api.idempotency import derived_id
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, coordinator_thread

from support.api_client import job_ids, online, problem, serving
from support.probe import MqttProbe
from support.wait import wait_for

RunSystem = Callable[..., tuple[ServiceThread, ServiceThread]]
STEP = 0.05


def order(n: int) -> dict[str, object]:
    """The WMS's n-th order (each to its own dropoff, so none is another's body)."""
    return {"pickup": "A1", "dropoff": ["P1", "P2", "P3", "P4"][n % 4], "mass_kg": 1.0 + n}


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
def test_a_coordinator_restart_mid_use_gives_503_and_the_retry_one_job(
    broker: BrokerThread,
    root: str,
    run_system: RunSystem,
    playfield: Path,
    tmp_path: Path,
    probe_factory: Callable[..., MqttProbe],
) -> None:
    coordinator, _ = run_system(playfield, step_s=STEP)
    requests = probe_factory()
    requests.subscribe(f"{root}/v1/requests/submit_job")
    with serving(broker.url, root) as served, served.client() as api:
        online(api)
        first = api.post("/jobs", json=order(1), headers={"Idempotency-Key": "order-1"})
        assert first.status_code == 201, first.text

        # Gone (a clean stop says offline): changes get 503 at once, saying to retry; the
        # retained views still read.
        coordinator.stop()
        down = problem(
            api.post("/jobs", json=order(2), headers={"Idempotency-Key": "order-2"}),
            503,
            "not_online",
        )
        assert "not online" in str(down["detail"])
        assert int(api.post("/jobs", json=order(2)).headers["Retry-After"]) >= 1
        problem(api.delete(f"/jobs/{first.json()['id']}"), 503, "not_online")
        assert api.get("/jobs").status_code == 200
        assert api.get("/coordinator").json()["state"] == "offline"

        # Back, from its store: the retries with their keys, each one job.
        scenario = load_scenario(playfield)
        again = coordinator_thread(
            scenario, broker.url, root=root, step_s=STEP, db_path=tmp_path / "jobs.db"
        )
        again.start()
        try:
            online(api)
            retried = api.post("/jobs", json=order(2), headers={"Idempotency-Key": "order-2"})
            assert retried.status_code == 201, retried.text
            assert retried.json()["id"] == derived_id("", "order-2")
            before_restart = api.post(
                "/jobs", json=order(1), headers={"Idempotency-Key": "order-1"}
            )
            assert (
                before_restart.status_code == 201
                and before_restart.json()["id"] == first.json()["id"]
            )

            # Mid-request: the coordinator stops the moment the request is on the broker. The
            # first answer may be the job (it was handled in time) or a 503 (it was not).
            seen = len(requests.messages[f"{root}/v1/requests/submit_job"])
            answers: list[httpx.Response] = []
            sending = threading.Thread(
                target=lambda: answers.append(
                    api.post("/jobs", json=order(3), headers={"Idempotency-Key": "order-3"})
                )
            )
            sending.start()
            wait_for(
                lambda: len(requests.messages[f"{root}/v1/requests/submit_job"]) > seen,
                timeout=10,
                what="the submit on the broker",
            )
            again.stop()
            sending.join(30)
            assert answers and answers[0].status_code in (201, 503), answers
        finally:
            again.stop()
        third = coordinator_thread(
            scenario, broker.url, root=root, step_s=STEP, db_path=tmp_path / "jobs.db"
        )
        with third:
            online(api)
            retried = api.post("/jobs", json=order(3), headers={"Idempotency-Key": "order-3"})
            assert retried.status_code == 201, retried.text
            assert retried.json()["id"] == derived_id("", "order-3")
            # Exactly one job per key: nothing doubled, nothing lost.
            ids = job_ids(api)
            keyed = [derived_id("", f"order-{n}") for n in (1, 2, 3)]
            assert sorted(i for i in ids if i.startswith("k-")) == sorted(keyed), ids
            assert all(ids.count(k) == 1 for k in keyed)
