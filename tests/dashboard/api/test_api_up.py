"""`gridfleet up` serves the HTTP API beside the page: a site's system reaches the fleet at once,
through the dashboard's own way to the broker."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from gridfleet.system.broker_thread import BrokerThread

from support.api_client import online
from support.output import Output

pytestmark = pytest.mark.slow  # a whole `gridfleet up`, as processes


@pytest.mark.timeout(240)
def test_up_serves_the_api_and_it_drives_the_fleet(
    broker: BrokerThread, root: str, tmp_path: Path, playfield: Path
) -> None:
    proc = subprocess.Popen(
        [
            *(sys.executable, "-m", "gridfleet", "up", "--broker", broker.url),
            *("--broker-ws", broker.ws_url, "--root", root, "--port", "0", "--step", "0.05"),
            *("--db", str(tmp_path / "jobs.db"), "--scenario", str(playfield)),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    out = Output(proc)
    try:
        out.wait(r"gridfleet is running: open http://127\.0\.0\.1:\d+", timeout=90)
        found = re.search(r"open (http://127\.0\.0\.1:\d+)", out.text)
        assert found is not None, out.text
        with httpx.Client(base_url=f"{found.group(1)}/api/v1", timeout=30) as api:
            online(api, timeout=60)
            job = api.post(
                "/jobs",
                json={"pickup": "A2", "dropoff": "P2", "mass_kg": 3.0},
                headers={"Idempotency-Key": "up-1"},
            )
            assert job.status_code == 201, job.text
            assert job.json()["pickup_place"] == "A2"
            assert api.get(f"/jobs/{job.json()['id']}").json()["dropoff"] == [1, 8]
            assert {u["id"] for u in api.get("/units").json()["units"]} >= {"unit1", "unit4"}
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    assert proc.returncode == 0, out.text[-3000:]
    assert "Traceback" not in out.text, out.text[-3000:]
