"""Runs on one broker do not see each other (issue 18), and `gridfleet clean` clears a root."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.ports import free_port
from gridfleet.protocol import Routes, Topics, decode
from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.cli import gridfleet
from support.mosquitto import running_mosquitto
from support.paths import MAPS
from support.probe import MqttProbe
from support.wait import wait_for

pytestmark = (
    pytest.mark.every_broker
)  # retained messages of several runs on one broker, and clearing them


def jobs_done(scenario: str, broker: str) -> list[str]:
    """Run `scenario` to the end on `broker`; the ids of the jobs done."""
    out = gridfleet("simulate", str(MAPS / scenario), "--broker", broker, "--json", timeout=240)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    result: dict[str, Any] = json.loads(out.stdout)
    assert result["finished"] and result["collisions"] == 0
    return sorted(j["id"] for j in result["jobs"] if j["state"] == "done")


def can_be_done(scenario: str) -> list[str]:
    """The jobs of `scenario` some unit can carry: what a run on a fresh broker does."""
    s = load_scenario(MAPS / scenario)
    largest = max(u.capacity for u in s.units)
    ids = [j.id or f"{s.name}-job-{n}" for n, j in enumerate(s.jobs, start=1) if j.mass <= largest]
    return sorted(ids)


@pytest.fixture
def mosquitto_url(tmp_path: Path) -> Iterator[str]:
    conf = "listener {port} 127.0.0.1\nallow_anonymous true\nset_tcp_nodelay true\n"
    with running_mosquitto(tmp_path, lambda port: conf.format(port=port)) as port:
        yield f"mqtt://127.0.0.1:{port}"


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize("kind", ["mosquitto", "embedded"])
def test_playfield_maze_playfield_on_one_broker_each_do_what_a_fresh_broker_does(
    kind: str, request: pytest.FixtureRequest
) -> None:
    # Reported: after a playfield run, a warehouse run on the same Mosquitto never finished: the
    # playfield's retained units (another map, `offline`) sat in its coordinator's world. The
    # maze is another map too, and its unit1..unit3 are the playfield's ids (unit4 is not).
    url = (
        request.getfixturevalue("mosquitto_url")
        if kind == "mosquitto"
        else request.getfixturevalue("fresh_broker").url
    )
    for scenario in ("playfield.toml", "maze.toml", "playfield.toml"):
        assert jobs_done(scenario, url) == can_be_done(scenario), scenario


def test_clean_clears_a_root_and_leaves_the_others(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    probe = probe_factory()
    for topic in ("units/u1/state", "units/u1/connection", "fleet/estop"):
        probe.publish(f"{root}/v1/{topic}", b"x", retain=True, qos=1)
    probe.publish(f"{root}-other/v1/fleet/estop", b"kept", retain=True, qos=1)
    out = gridfleet("clean", "--broker", broker.url, "--root", root, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"cleared 3 retained messages under {root!r}"
    late = probe_factory()
    late.subscribe(f"{root}/#")
    late.subscribe(f"{root}-other/#")
    seen = late.wait(f"{root}-other/v1/fleet/estop")
    assert seen.payload == b"kept"
    assert late.received(f"{root}/v1/fleet/estop") == []


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--root", "a/+/b"], "--root: topic root 'a/+/b' is not valid"),
        (["--broker", "http://x"], "http://x"),
    ],
)
def test_clean_refuses_bad_input_in_one_line(args: list[str], says: str) -> None:
    out = gridfleet("clean", *args, timeout=60)
    assert out.returncode == 2 and says in out.stderr and "Traceback" not in out.stderr


def test_clean_says_when_the_broker_is_not_there() -> None:
    out = gridfleet("clean", "--broker", f"mqtt://127.0.0.1:{free_port()}", timeout=60)
    assert out.returncode == 2 and "error: MQTT with" in out.stderr
    assert "Traceback" not in out.stderr


def test_client_ids_name_the_root_but_for_the_default_one() -> None:
    assert Topics().client_id("coordinator") == "coordinator"
    assert Topics("lab/a").client_id("coordinator") == "coordinator@lab.a"
    long = Topics("/".join(["x" * 30] * 4)).client_id("coordinator")
    assert len(long) <= 64 and long.startswith("coordinator@xxx")
    assert long != Topics("/".join(["x" * 30] * 3 + ["y" * 30])).client_id("coordinator")


def test_two_fleets_on_one_broker_keep_their_coordinators_connected(
    broker: BrokerThread, tmp_path: Path, root: str
) -> None:
    # Both coordinators were MQTT client `coordinator`: each connection took the other's over,
    # for ever (on Mosquitto as on the embedded broker).
    grid = load_scenario(MAPS / "playfield.toml").grid
    roots = (f"{root}/a", f"{root}/b")
    probe = MqttProbe(broker.url).connect()
    for r in roots:
        probe.subscribe(Topics(r).fleet("routes"), qos=0)

    def coordinator(n: int) -> ServiceThread:
        db = tmp_path / f"{n}.db"
        return ServiceThread(
            lambda: CoordinatorShell(broker.url, grid, root=roots[n], step_s=0.05, db_path=db),
            f"coordinator-{n}",
        )

    def steps(r: str) -> int:
        seen = probe.received(Topics(r).fleet("routes"))
        return decode(Routes, seen[-1].payload).step if seen else 0

    try:
        with coordinator(0) as first, coordinator(1) as second:
            # 40 steps each (2 s) side by side: a takeover reconnects within 0.1 s.
            wait_for(lambda: min(steps(r) for r in roots) >= 40, timeout=30, what="40 steps each")
            connects = [s.service.endpoint.connects for s in (first, second)]
    finally:
        probe.close()
    assert connects == [1, 1]
