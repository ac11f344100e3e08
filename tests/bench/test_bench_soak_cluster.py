"""`gridfleet bench soak --cluster`: a one-minute soak on each broker cluster, and its parts alone."""

from __future__ import annotations

import io
import json
import random
from pathlib import Path
from typing import Any

import pytest
from test_bench_soak import soak

from gridfleet.bench.soak import listen as soak_listen
from gridfleet.bench.soak.check import Stop
from gridfleet.bench.soak.cluster import ClusterSoak, via_proxy
from gridfleet.bench.soak.faults import (
    CLUSTER_DEFAULT,
    CLUSTER_FAMILIES,
    KEEP_ALIVE_S,
    LOCAL_FAMILIES,
    NODE_TARGETS,
    main_faults,
)
from gridfleet.bench.soak.run import SoakConfig, spread
from gridfleet.bench.soak.topologies import soak_for
from gridfleet.protocol import Topics

# The benchmark's own runs: in make test, not in make test-fast.
pytestmark = pytest.mark.slow


class NoCluster:
    """A cluster that is never started (the soak's parts alone)."""

    node_urls = ["mqtt://127.0.0.1:1", "mqtt://127.0.0.1:2", "mqtt://127.0.0.1:3"]
    pids: list[int] = []

    def __enter__(self) -> object:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def kill_node(self, i: int) -> None:
        raise AssertionError("never started")

    start_node = pause_node = resume_node = kill_node


def test_node_faults_strike_each_components_node_some_pauses_past_the_keep_alive() -> None:
    faults = [
        f
        for f, _ in zip(
            main_faults(random.Random(4), CLUSTER_FAMILIES, 0.1), range(300), strict=False
        )
    ]
    assert {f.kind for f in faults} == {"kill_node", "pause_node", "cut_node"}
    assert {f.target for f in faults} == set(NODE_TARGETS)
    pauses = [f.hold_s for f in faults if f.kind == "pause_node"]
    # Some past 1.5 keep-alives (the clients give up on the node and move on), most short.
    assert any(h > 1.5 * KEEP_ALIVE_S for h in pauses) and any(h < 5.0 for h in pauses)
    assert all(0.5 <= f.hold_s <= 5.0 for f in faults if f.kind == "cut_node")
    # The plain soak's default schedule has none of them; a cluster's has no embedded broker.
    assert not set(CLUSTER_FAMILIES) & set(LOCAL_FAMILIES)
    assert "broker" not in CLUSTER_DEFAULT and set(CLUSTER_FAMILIES) <= set(CLUSTER_DEFAULT)


def test_spread_is_median_nearest_rank_p99_and_worst() -> None:
    assert spread([3.0, 1.0, 2.0]) == {"n": 3, "median": 2.0, "p99": 3.0, "max": 3.0}
    hundred = [float(n) for n in range(1, 101)]
    assert spread(hundred) == {"n": 100, "median": 50.5, "p99": 99.0, "max": 100.0}


def test_a_components_list_reaches_each_node_through_its_proxy_login_kept() -> None:
    assert via_proxy("mqtt://u:p@10.0.0.1:1883", 4000) == "mqtt://u:p@127.0.0.1:4000"
    assert via_proxy("mqtt://127.0.0.1:31001", 4001) == "mqtt://127.0.0.1:4001"


async def test_each_component_starts_on_another_node_and_the_soaks_clients_avoid_those_down(
    tmp_path: Path,
) -> None:
    cfg = SoakConfig(minutes=1, units=2, cluster="aedes")
    soak_run = ClusterSoak(cfg, tmp_path, io.StringIO(), cluster=NoCluster())
    soak_run.broker_url = await soak_run._start_broker([])
    urls = await soak_run._links()
    try:
        firsts = [urls[name].split(",")[0] for name in NODE_TARGETS]
        ports = [[p.port for p in soak_run.routes[name]] for name in NODE_TARGETS]
        # The coordinator's list begins at its proxy to node 0, the units' at node 1, the feed's
        # at node 2; every list names all three nodes.
        assert firsts == [f"mqtt://127.0.0.1:{ports[n][n]}" for n in range(3)]
        assert all(len(urls[name].split(",")) == 3 for name in NODE_TARGETS)
        assert soak_run.node_of("robots") is None  # nobody connected yet
        soak_run.down = {0}
        assert soak_run._login("operator").split(",") == [
            "mqtt://127.0.0.1:2",
            "mqtt://127.0.0.1:3",
            "mqtt://127.0.0.1:1",
        ]
    finally:
        for proxy in soak_run.proxies:
            await proxy.close()
    assert type(soak_for(cfg, tmp_path, io.StringIO())) is ClusterSoak


def test_on_a_cluster_the_listener_hears_the_stop_live_never_from_a_nodes_replay() -> None:
    # RabbitMQ keeps retained messages per node: a node the listener moves to may replay an old
    # stop. Live, the stop stands as it was heard.
    topics = Topics("soak")
    listener = soak_listen.SoakListener("mqtt://127.0.0.1:1", topics, "listener", live_only=True)
    listener.take(topics.fleet("estop"), b"engaged|operator|soak", 1.0)
    listener.reconnected()  # moved to another node: what it knew still stands
    assert listener.stopped and not listener.settling
    assert [e for e in listener.events if isinstance(e, Stop)] == [Stop(1.0, True)]


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--cluster", "aedes", "--broker", "mqtt://127.0.0.1:1883"], "no --broker"),
        (["--faults", "units,node"], "need --cluster"),
        (["--cluster", "emqx"], "invalid choice: 'emqx'"),
    ],
)
def test_bad_cluster_arguments_are_one_line(args: list[str], says: str) -> None:
    done = soak(*args, timeout=30)
    assert done.returncode == 2 and says in done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.soak
@pytest.mark.cluster_soak
@pytest.mark.timeout(600)  # a minute of faults, the drain, and three RabbitMQ nodes booting
@pytest.mark.parametrize("kind", ["aedes", "rabbitmq"])
def test_one_minute_soak_on_a_cluster_kills_and_cuts_nodes_and_stays_safe(
    kind: str, tmp_path: Path
) -> None:
    log = tmp_path / "soak.log"
    args = ["--cluster", kind, "--minutes", "1", "--units", "8", "--seed", "3", "--drain", "120"]
    # Not node_pause: a paused aedes instance stalls the fleet past the recovery wait (every
    # component on it; bench/README.md, "Chaos soak on a cluster"), a finding still open.
    args += ["--faults", "node,node_cut,estop", "--json", "--log", str(log)]
    done = soak(*args, timeout=580)
    out: dict[str, Any] = json.loads(done.stdout)
    verdict = "\n".join(out["details"])
    figures = {k: v for k, v in out.items() if k != "details"}
    assert done.returncode == 0, f"{verdict}\n{figures}\n{log.read_text()[-20000:]}"
    assert out["cluster"] == kind and out["units"] == 8
    assert {"kill_node", "cut_node"} <= set(out["faults"]), out["faults"]
    assert out["collisions"] == 0 and out["moved_while_stopped"] == 0
    assert out["jobs_submitted"] > 0 and out["jobs_done"] > 0
    assert out["jobs_lost"] == 0 and out["jobs_duplicated"] == 0
    assert out["units_stranded"] == 0 and out["faults_unrecovered"] == 0
    # From each node's death to the fleet moving again: measured, within the recovery wait.
    deaths = out["node_recovery_s"]["kill_node"]
    assert deaths["n"] == out["faults"]["kill_node"]
    assert 0 < deaths["median"] <= deaths["p99"] <= deaths["max"] < 60
    listed = [line for line in log.read_text().splitlines() if line.startswith("[node       ]")]
    assert len(listed) == out["faults"]["kill_node"] + out["faults"]["cut_node"]
