"""The page on a cluster (aedes on Redis, RabbitMQ 3.10) when the node it is on dies, kill -9:
with the stop released and jobs under way, then with it engaged. It moves to the next node of its
list, says so, and shows the fleet again: the jobs finishing, the stop as it is, every unit."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from urllib.parse import urlsplit

import pytest
from playwright.sync_api import expect
from test_cluster_node_death import (
    FLEET,
    JOBS,
    ROOT,
    Cluster,
    T,
    Watch,
    cluster_of,
    fleet_on,
    rotated,
)

from support.browser import OpenDashboard
from support.operator_peer import OperatorPeer
from support.probe import MqttProbe
from support.wait import wait_for

UNITS = [unit.id for unit in FLEET.units]
SQUARE = re.compile(r"\[\d+, \d+\]")


def on_node(dash: OpenDashboard, cluster: Cluster, node: int) -> None:
    """The page says it is connected to `node` (its websocket port), and is."""
    url = urlsplit(cluster.node_ws_urls[node])
    conn = dash.page.locator("#conn")
    expect(conn).to_have_text(f"broker: connected to {url.netloc}{url.path}", timeout=60_000)
    expect(conn).to_have_attribute("data-state", "connected")


def every_unit_shown(dash: OpenDashboard) -> None:
    """A row for each unit of the fleet, with a square."""
    for unit in UNITS:
        expect(dash.page.locator(f"#units tr[data-unit='{unit}'] .pos")).to_have_text(SQUARE)


@pytest.mark.slow
@pytest.mark.browser
# A cluster's boot and two node deaths beside a browser: with the cluster soaks (make
# soak-clusters), not in make test's lanes, as test_cluster_node_death.
@pytest.mark.cluster_soak
# 300 s: a RabbitMQ cluster boots in 20-30 s on two shared cores, a killed node takes ~10 s to be
# back, the page's reconnects back off up to a few seconds, and four jobs run to the end.
@pytest.mark.timeout(300)
@pytest.mark.parametrize("kind", ["aedes", "rabbitmq"])
def test_the_page_shows_the_fleet_again_when_its_node_dies(
    kind: str, tmp_path: Path, open_dashboard: Callable[..., OpenDashboard]
) -> None:
    with cluster_of(kind, tmp_path) as cluster, fleet_on(cluster, tmp_path) as (coordinator, fleet):
        watch = Watch(cluster, coordinator, fleet)
        urls = cluster.node_urls
        # The page begins at node 0, the coordinator's (on RabbitMQ the node that holds the
        # retained map and queue view: its store is its own).
        dash = open_dashboard(
            ROOT, via=cluster, broker_ws=rotated(cluster.node_ws_urls, 0), wait_connected=False
        )
        on_node(dash, cluster, 0)
        every_unit_shown(dash)

        # 1. Released, jobs under way: node 0 dies (the page's and the coordinator's).
        with MqttProbe(urls[1]) as probe:
            operator = OperatorPeer(probe, T, "ann")
            ids = []
            for n, (pickup, dropoff) in enumerate(JOBS):
                reply = operator.submit_job(pickup, dropoff, 1.0, job_id=f"job-{n + 1}")
                assert reply.accepted, reply
                ids.append(reply.job_id)
        wait_for(
            lambda: any(s not in ("queued", "done") for s in watch.job_states().values()),
            30,
            what="a job under way",
        )
        for job in ids:  # the page shows them before the death
            expect(dash.page.locator(f"tr[data-job='{job}']")).to_have_count(1)
        assert any(s != "done" for s in watch.job_states().values()), watch.job_states()
        cluster.kill_node(0)
        on_node(dash, cluster, 1)
        every_unit_shown(dash)
        # What changed after the death reaches the page on its new node: every job done.
        for job in ids:
            expect(dash.page.locator(f"#finished tr[data-job='{job}'] .state")).to_have_text(
                "done", timeout=120_000
            )
        body = dash.page.locator("body")
        expect(body).not_to_have_attribute("data-estop", "engaged")  # never engaged yet
        cluster.start_node(0)

        # 2. Engaged: node 1 dies (the page's; the coordinator's too, since node 0's death).
        with MqttProbe(urls[2]) as probe:
            OperatorPeer(probe, T, "ann").engage("STOP before node 1 dies")
        expect(body).to_have_attribute("data-estop", "engaged")
        wait_for(watch.coordinator_stopped, 20, what="the coordinator stopped")
        cluster.kill_node(1)
        on_node(dash, cluster, 2)
        every_unit_shown(dash)
        expect(body).to_have_attribute("data-estop", "engaged")  # a failover releases nothing
        expect(dash.page.locator("#estop-banner")).to_contain_text("engaged by ann")
        assert watch.coordinator_stopped()

        # Released by the operator on the page's node: the page shows it.
        with MqttProbe(urls[2]) as probe:
            OperatorPeer(probe, T, "ann").release("area checked")
        expect(body).to_have_attribute("data-estop", "released")
    assert dash.errors == []
