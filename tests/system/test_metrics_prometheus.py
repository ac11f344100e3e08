"""A real Prometheus server scrapes a running fleet's coordinator on loopback (with the bearer
token, as docs/monitoring.md configures it) and answers PromQL about it."""

from __future__ import annotations

import json
import shutil
import subprocess
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from gridfleet.metrics import MetricsOptions
from gridfleet.ports import free_port
from gridfleet.protocol import Topics
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import coordinator_thread, fleet_thread

from support.coordinator_fakes import PLAYFIELD_JOBS
from support.operator_peer import OperatorPeer
from support.paths import REPO
from support.probe import MqttProbe
from support.wait import wait_for

PROMETHEUS = shutil.which("prometheus")
STEP = 0.05
TOKEN = "test-token-0123456789abcdef"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(PROMETHEUS is None, reason="no prometheus binary (make system-deps)"),
]


def scrape_config(target: str, token_file: Path) -> str:
    """prometheus.yml: the coordinator every second, with its token (as docs/monitoring.md)."""
    return f"""\
global:
  scrape_interval: 1s
  evaluation_interval: 1s
scrape_configs:
  - job_name: gridfleet-coordinator
    authorization:
      type: Bearer
      credentials_file: {token_file}
    static_configs:
      - targets: ["{target}"]
"""


class Prometheus:
    """A Prometheus server of this test's own: its config, storage and free port."""

    def __init__(self, folder: Path, config: str) -> None:
        (folder / "prometheus.yml").write_text(config, encoding="utf-8")
        self.url = f"http://127.0.0.1:{free_port()}"
        self.log = folder / "prometheus.log"
        assert PROMETHEUS is not None
        with self.log.open("wb") as log:
            self.process = subprocess.Popen(
                [
                    PROMETHEUS,
                    f"--config.file={folder / 'prometheus.yml'}",
                    f"--storage.tsdb.path={folder / 'data'}",
                    f"--web.listen-address={self.url.removeprefix('http://')}",
                ],
                stdout=log,
                stderr=subprocess.STDOUT,
            )

    def ready(self) -> bool:
        """Whether it answers `/-/ready` (raises when it has exited)."""
        if self.process.poll() is not None:
            raise AssertionError(f"prometheus exited: {self.log.read_text()[-2000:]}")
        try:
            with urllib.request.urlopen(f"{self.url}/-/ready", timeout=5) as response:
                return bool(response.status == 200)
        except (urllib.error.URLError, OSError):
            return False

    def query(self, promql: str) -> list[dict[str, Any]]:
        """The instant vector `promql` gives now (its `result`)."""
        url = f"{self.url}/api/v1/query?{urllib.parse.urlencode({'query': promql})}"
        with urllib.request.urlopen(url, timeout=10) as response:
            body = json.load(response)
        assert body["status"] == "success", body
        result: list[dict[str, Any]] = body["data"]["result"]
        return result

    def value(self, promql: str) -> float | None:
        """The one value `promql` gives now (None: an empty vector)."""
        result = self.query(promql)
        return float(result[0]["value"][1]) if result else None

    def targets_health(self) -> list[str]:
        """Each active target's health and last error."""
        with urllib.request.urlopen(f"{self.url}/api/v1/targets", timeout=10) as response:
            body = json.load(response)
        return [f"{t['health']} {t['lastError']}" for t in body["data"]["activeTargets"]]

    def stop(self) -> None:
        """Stop it, whatever state it is in."""
        self.process.terminate()
        try:
            self.process.wait(30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(10)


@pytest.fixture
def prometheus_factory(tmp_path: Path) -> Iterator[Callable[[str], Prometheus]]:
    """Start Prometheus with a config; always stopped after the test."""
    started: list[Prometheus] = []

    def start(config: str) -> Prometheus:
        server = Prometheus(tmp_path, config)
        started.append(server)
        return server

    yield start
    for server in started:
        server.stop()


@pytest.mark.timeout(180)
def test_prometheus_scrapes_a_running_fleet_and_answers_promql(
    broker: BrokerThread,
    root: str,
    tmp_path: Path,
    probe_factory: Callable[..., MqttProbe],
    prometheus_factory: Callable[[str], Prometheus],
) -> None:
    scenario = load_scenario(REPO / "maps" / "playfield.toml")
    token_file = tmp_path / "metrics.token"
    token_file.write_text(TOKEN + "\n", encoding="utf-8")
    metrics = MetricsOptions(0, token=TOKEN)
    coordinator = coordinator_thread(
        scenario, broker.url, root=root, step_s=STEP, db_path=tmp_path / "jobs.db", metrics=metrics
    )
    fleet = fleet_thread(scenario, broker.url, root=root, step_s=STEP)
    with coordinator, fleet:
        server = coordinator.service.metrics_server
        assert server is not None
        prometheus = prometheus_factory(scrape_config(f"127.0.0.1:{server.port}", token_file))
        wait_for(prometheus.ready, timeout=60, interval=0.2, what="prometheus ready")

        # Scraped, with the token: the target is up and the fleet's units are there.
        up = 'up{job="gridfleet-coordinator"}'
        wait_for(
            lambda: prometheus.value(up) == 1,
            timeout=60,
            interval=0.5,
            what=up,
            context=lambda: f"targets: {prometheus.targets_health()}",
        )
        units = len(scenario.units)
        wait_for(
            lambda: prometheus.value('sum(gridfleet_units{connection="online"})') == units,
            timeout=60,
            interval=0.5,
            what=f"{units} units online in Prometheus",
        )

        operator = OperatorPeer(probe_factory(), Topics(root), "tester")
        for n, (pickup, dropoff, mass) in enumerate(PLAYFIELD_JOBS[:4]):
            operator.send_submit_job(pickup, dropoff, mass, job_id=f"prom-{n}")
        wait_for(
            lambda: prometheus.query("rate(gridfleet_jobs_done_total[1m]) > 0"),
            timeout=90,
            interval=0.5,
            what="jobs done at a rate above 0 in Prometheus",
        )
        # The figures a dashboard draws are there too.
        p99 = "histogram_quantile(0.99, rate(gridfleet_step_duration_seconds_bucket[1m]))"
        step_p99 = prometheus.value(p99)
        assert step_p99 is not None and 0 < step_p99 < 2.5
        assert prometheus.value('gridfleet_jobs{state="rejected"}') == 0
        assert prometheus.value("gridfleet_estop_engaged") == 0
        received = prometheus.value('gridfleet_messages_received_total{kind="submit_job"}')
        assert received is not None and received >= 1
