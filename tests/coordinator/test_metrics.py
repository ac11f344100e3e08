"""The coordinator's metrics in the Prometheus format: names, types, labels and values, as scraped
over HTTP from a coordinator shell on a real broker; the flags; the token; a clean stop."""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import socket
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from prometheus_client import generate_latest

from gridfleet.alerts.metrics import Figures, alerts_registry
from gridfleet.broker.metrics import broker_registry
from gridfleet.broker.stats import BrokerFigures
from gridfleet.coordinator.allocation import capacity_reason, reach_reason
from gridfleet.coordinator.metrics import CoordinatorMetrics, reason_kind
from gridfleet.coordinator.shell import CoordinatorShell
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.maps import load_map
from gridfleet.metrics import MetricsOptions, MetricsServer, read_token
from gridfleet.paths import DistanceFieldCache
from gridfleet.protocol import Topics
from gridfleet.robots.unit import UnitLogic
from gridfleet.scenario import load_scenario
from gridfleet.system.assembly import Assembly, SystemSpec
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.cli import build_parser
from gridfleet.system.up import spec_from

from support.cli import gridfleet
from support.coordinator_drive import make_core
from support.coordinator_fakes import FakeFleet
from support.operator_peer import OperatorPeer
from support.paths import REPO
from support.probe import MqttProbe
from support.scrape import Scrape, get, parse
from support.wait import WaitTimeout

MAP = REPO / "maps" / "playfield.map"
STEP = 0.03
UNITS = [("unit1", (0, 0), 2.0), ("unit2", (9, 0), 5.0), ("unit3", (0, 9), 10.0)]


@dataclass
class Rig:
    """A coordinator serving metrics, three fake units stepped by the test's loop, an operator."""

    coordinator: CoordinatorShell
    fleet: FakeFleet
    op: OperatorPeer

    @property
    def url(self) -> str:
        assert self.coordinator.metrics_server is not None
        return str(self.coordinator.metrics_server.url)

    async def scrape(self) -> Scrape:
        """Over HTTP, from another thread (the coordinator runs on this test's loop)."""
        status, body = await asyncio.to_thread(get, self.url)
        assert status == 200, body
        return parse(body)

    async def scrape_until(self, ok: Callable[[Scrape], bool], what: str) -> Scrape:
        """Scrape until `ok` says yes (generous deadline: a loaded machine); the last scrape."""
        deadline = time.monotonic() + 45
        while True:
            s = await self.scrape()
            if ok(s):
                return s
            if time.monotonic() > deadline:
                raise WaitTimeout(f"timed out waiting for {what}")
            await asyncio.sleep(0.05)


@contextlib.asynccontextmanager
async def rig(broker: BrokerThread, root: str, tmp_path: Path) -> AsyncIterator[Rig]:
    grid = load_map(MAP)
    topics = Topics(root)
    probe = MqttProbe(broker.url, f"tester-{root.rsplit('-', 1)[-1]}").connect()
    op = OperatorPeer(probe, topics, "tester")
    units = [UnitLogic(uid, grid, Cell(*pos), cap, STEP) for uid, pos, cap in UNITS]
    fleet = FakeFleet(broker.url, root, grid, units)
    await fleet.start_all()
    coordinator = CoordinatorShell(
        broker.url,
        grid,
        root=root,
        step_s=STEP,
        db_path=tmp_path / "jobs.db",
        metrics=MetricsOptions(0),
    )
    stop_coord, stop_fleet = asyncio.Event(), asyncio.Event()
    coord_task = asyncio.create_task(coordinator.run(stop_coord))
    await asyncio.wait_for(coordinator.ready.wait(), 30)
    fleet_task = asyncio.create_task(fleet.run(stop_fleet, STEP))
    try:
        yield Rig(coordinator, fleet, op)
    finally:
        stop_fleet.set()
        await fleet_task
        stop_coord.set()
        await coord_task
        await fleet.close()
        op.raw_estop(b"")
        probe.close()


async def test_a_running_fleet_shows_in_the_metrics(
    broker: BrokerThread, root: str, tmp_path: Path
) -> None:
    async with rig(broker, root, tmp_path) as r:
        s = await r.scrape_until(
            lambda s: s.total("gridfleet_units", connection="online") == 3, "3 units online"
        )
        assert s.types["gridfleet_units"] == "gauge"
        assert s.labels_of("gridfleet_units", "connection") == {
            "online",
            "offline",
            "broken",
            "unknown",
        }
        assert s.labels_of("gridfleet_units", "status") == {
            "idle",
            "moving",
            "waiting",
            "stopped",
            "holding",
            "unknown",
        }
        assert s.value("gridfleet_coordinator_connected") == 1
        assert s.value("gridfleet_step_period_seconds") == STEP

        # One job a unit can do, one too heavy for all, and two that are not requests at all.
        r.op.send_submit_job(Cell(1, 1), Cell(8, 8), 1.5, job_id="light")
        heavy = r.op.send_submit_job(Cell(1, 1), Cell(8, 8), 50.0, job_id="heavy")
        r.op.raw_request("submit_job", b"{not json")
        r.op.raw_request("cancel_job", b"[]")
        # The heavy job is rejected once the coordinator has heard the fleet long enough to know
        # that no unit it has not heard yet could carry it (coordinator/world.py).
        s = await r.scrape_until(
            lambda s: (
                s.value("gridfleet_jobs_done_total") == 1
                and s.value("gridfleet_jobs", state="rejected") == 1
            ),
            "the light job done, the heavy one rejected",
        )
        assert s.types["gridfleet_jobs_done"] == "counter"
        assert s.value("gridfleet_jobs_rejected_total", reason="over_capacity") == 1
        assert s.total("gridfleet_jobs_rejected_total") == 1
        assert s.value("gridfleet_jobs", state="done") == 1
        assert s.value("gridfleet_jobs", state="rejected") == 1
        assert s.value("gridfleet_jobs", state="queued") == 0
        assert s.types["gridfleet_job_duration_seconds"] == "histogram"
        assert s.value("gridfleet_job_duration_seconds_count", state="done") == 1
        assert 0 < s.value("gridfleet_job_duration_seconds_sum", state="done") < 45
        # Once, or again after a re-queue (a unit late enough on a loaded machine to be lost).
        assert s.value("gridfleet_job_queue_wait_seconds_count") >= 1
        # Refused: the bad payloads (invalid), and the heavy job if it came after the coordinator
        # knew the fleet (a refusal with a reason; before, it was queued, and rejected later).
        (answer,) = [a for a in r.op.replies() if a.request_id == heavy.request_id]
        refused_heavy = 0 if answer.accepted else 1
        assert s.value("gridfleet_messages_refused_total", kind="submit_job") == 1 + refused_heavy
        assert s.value("gridfleet_messages_refused_total", kind="cancel_job") == 1
        assert s.value("gridfleet_messages_received_total", kind="submit_job") == 3
        assert s.value("gridfleet_messages_received_total", kind="state") > 10
        assert s.value("gridfleet_messages_sent_total", kind="order") > 0
        assert s.value("gridfleet_messages_sent_total", kind="reply") == 2
        assert s.value("gridfleet_messages_sent_total", kind="errors") == 2 + refused_heavy
        assert s.types["gridfleet_step_duration_seconds"] == "histogram"
        assert s.value("gridfleet_step_duration_seconds_count") > 5
        assert s.value("gridfleet_steps_total") >= s.value("gridfleet_step_duration_seconds_count")
        assert s.value("gridfleet_planner_duration_seconds_count") > 0
        assert s.value("gridfleet_estop_engaged") == 0

        # The stop: engaged by the latch, every unit reports itself stopped, the latency is timed.
        r.op.engage("metrics test")
        s = await r.scrape_until(
            lambda s: s.value("gridfleet_estop_stopped_seconds_count") == 1, "the stop's latency"
        )
        assert s.value("gridfleet_estop_engaged") == 1
        assert s.value("gridfleet_estop_sources", source="latch") == 1
        assert s.value("gridfleet_estop_sources", source="unit") == 0
        assert 0 < s.value("gridfleet_estop_stopped_seconds_sum") < 30
        await r.scrape_until(
            lambda s: s.total("gridfleet_units", connection="online", status="stopped") == 3,
            "every unit stopped in the metrics",
        )
        r.op.release("metrics test")

        # A unit dies: lost, and counted. (A loaded machine may have made a unit late enough to
        # be lost for a moment before: each such loss was followed by its recovery.)
        await r.fleet.kill("unit3")
        # The gauge reads the world at the scrape; the loss is counted at the coordinator's next
        # step (a will on Mosquitto comes at once, and a scrape can fall in between).
        s = await r.scrape_until(
            lambda s: (
                s.value("gridfleet_units_lost") == 1 and s.value("gridfleet_unit_losses_total") >= 1
            ),
            "unit3 lost, and counted",
        )
        assert (
            s.value("gridfleet_unit_recoveries_total") == s.value("gridfleet_unit_losses_total") - 1
        )
        assert s.value("gridfleet_estop_engaged") == 0


async def test_the_metrics_port_closes_when_the_coordinator_stops(
    broker: BrokerThread, root: str, tmp_path: Path
) -> None:
    coordinator = CoordinatorShell(
        broker.url,
        load_map(MAP),
        root=root,
        step_s=STEP,
        db_path=tmp_path / "jobs.db",
        metrics=MetricsOptions(0),
    )
    stop = asyncio.Event()
    task = asyncio.create_task(coordinator.run(stop))
    await asyncio.wait_for(coordinator.ready.wait(), 30)
    assert coordinator.metrics_server is not None
    port = coordinator.metrics_server.port
    status, body = await asyncio.to_thread(get, f"http://127.0.0.1:{port}/metrics")
    assert status == 200 and "gridfleet_units" in body
    stop.set()
    await task
    with pytest.raises(ConnectionRefusedError), socket.create_connection(("127.0.0.1", port), 5):
        pass


# ---- without a broker ---------------------------------------------------------------------


def test_reason_kinds_follow_the_cores_sentences() -> None:
    grid = load_map(MAP)
    cache = DistanceFieldCache(grid)
    assert reason_kind(capacity_reason(30.0, [2.0, 5.0])) == "over_capacity"
    walled = grid.with_blocked({Cell(1, 0), Cell(0, 1)})  # square 0,0 walled in
    walled_cache = DistanceFieldCache(walled)
    reach = reach_reason(walled_cache, Cell(0, 0), Cell(5, 5), 1.0, [(Cell(9, 9), 2.0)])
    assert reason_kind(reach) == "unreachable"
    assert reason_kind(reach_reason(cache, Cell(0, 0), Cell(5, 5), 1.0, [(Cell(9, 9), 2.0)])) == (
        "other"  # reachable: no reason at all
    )
    assert reason_kind("unit u1 was lost carrying the item, last seen at [3, 4]") == "unit_lost"
    assert reason_kind("unit u1 no longer carries the item (at [3, 4])") == "item_lost"
    assert reason_kind("something new") == "other"


def test_two_coordinators_in_one_process_keep_their_own_metrics() -> None:
    grid = load_map(MAP)
    first, second = CoordinatorMetrics(make_core(grid)), CoordinatorMetrics(make_core(grid))
    first.received_one("gridfleet/v1/units/u1/state", refused=False)
    one = parse(generate_latest(first.registry).decode())
    two = parse(generate_latest(second.registry).decode())
    assert one.value("gridfleet_messages_received_total", kind="state") == 1
    assert two.total("gridfleet_messages_received_total") == 0


@pytest.fixture
def served() -> Iterator[MetricsServer]:
    """A metrics server of an idle coordinator core that wants a token."""
    metrics = CoordinatorMetrics(make_core(load_map(MAP)))
    server = MetricsServer(metrics.registry, MetricsOptions(0, token="s3cret-token")).start()
    yield server
    server.stop()


def test_a_scrape_without_the_right_token_gets_401(served: MetricsServer) -> None:
    assert get(served.url)[0] == 401
    assert get(served.url, "wrong")[0] == 401
    assert get(served.url, "s3cret-token-and-more")[0] == 401
    status, body = get(served.url, "s3cret-token")
    assert status == 200 and "# TYPE gridfleet_units gauge" in body


def test_beyond_loopback_the_metrics_need_a_token() -> None:
    with pytest.raises(ConfigError, match="--metrics-token-file"):
        MetricsOptions(9100, "0.0.0.0")
    assert MetricsOptions(9100, "0.0.0.0", "t").token == "t"
    assert MetricsOptions(9100, "::1").token is None


@pytest.mark.parametrize("port", [-1, 65536])
def test_a_port_out_of_range_is_refused(port: int) -> None:
    with pytest.raises(ConfigError, match=f"--metrics {port}: give a port from 1 to 65535"):
        MetricsOptions(port)


def test_a_port_in_use_is_one_line() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        server = MetricsServer(
            CoordinatorMetrics(make_core(load_map(MAP))).registry, MetricsOptions(port)
        )
        with pytest.raises(ConfigError, match=f"cannot listen on 127.0.0.1:{port}"):
            server.start()


def test_a_token_file_must_hold_one_token(tmp_path: Path) -> None:
    good = tmp_path / "good"
    good.write_text("  abc123-0123456789\n", encoding="utf-8")
    assert read_token(good) == "abc123-0123456789"
    for bad in ("", "two words", "naïve"):
        (tmp_path / "bad").write_text(bad, encoding="utf-8")
        with pytest.raises(ConfigError, match="give one token"):
            read_token(tmp_path / "bad")
    with pytest.raises(ConfigError, match="cannot read it"):
        read_token(tmp_path / "absent")


def _cli(*args: str) -> tuple[int, list[str]]:
    done = gridfleet("coordinator", "--map", str(MAP), *args)
    return done.returncode, done.stderr.strip().splitlines()


def test_the_coordinators_metrics_flags_answer_mistakes_in_one_line(tmp_path: Path) -> None:
    assert _cli("--metrics", "70000") == (
        2,
        [
            "gridfleet coordinator: error: --metrics 70000: give a port from 1 to 65535 (0: a free one)"
        ],
    )
    code, lines = _cli("--metrics", "9100", "--metrics-listen", "0.0.0.0")
    assert code == 2 and len(lines) == 1
    assert lines[0].startswith("gridfleet coordinator: error: serving metrics on 0.0.0.0 lets")
    code, lines = _cli("--metrics-listen", "0.0.0.0")
    assert (code, lines) == (
        2,
        [
            "gridfleet coordinator: error: --metrics-listen and --metrics-token-file need --metrics PORT"
        ],
    )
    code, lines = _cli("--metrics", "9100", "--metrics-token-file", str(tmp_path / "absent"))
    assert code == 2 and len(lines) == 1 and "cannot read it" in lines[0]


# ---- the docs: every name they use is served, every metric served is documented -------------


def idle_text() -> str:
    """The exposition of an idle coordinator core's metrics (its achieved step period known),
    then of an idle broker's, then of an idle alerts process's (with its webhook)."""
    core = make_core(load_map(MAP))
    core.pace.achieved_step_s = 0.5  # absent until measured: here so that it shows
    coordinator = generate_latest(CoordinatorMetrics(core).registry).decode()
    figures = BrokerFigures(0, 0, 0, 0, 0, 0, 0, 0, 0, {})
    broker = generate_latest(broker_registry(lambda: figures)).decode()
    alerts = Figures(webhook=(0, 0, 0, 0))
    return coordinator + broker + generate_latest(alerts_registry(lambda: alerts)).decode()


def idle_scrape() -> Scrape:
    """idle_text, parsed."""
    return parse(idle_text())


def servable(scrape: Scrape) -> set[str]:
    """Every sample name the families can have (a labelled counter has none before its first)."""
    suffixes = {"counter": ("_total",), "histogram": ("_bucket", "_sum", "_count")}
    names = {name for name, _ in scrape.samples}
    for name, kind in scrape.types.items():
        names |= {name + suffix for suffix in suffixes.get(kind, ("",))}
    return names


def test_no_two_families_share_a_name() -> None:
    # The parser merges them silently; Prometheus would refuse the scrape.
    typed = re.findall(r"^# TYPE (\S+) ", idle_text(), re.MULTILINE)
    assert len(typed) > 20 and len(typed) == len(set(typed))


def test_the_grafana_dashboard_uses_only_served_names() -> None:
    dashboard = json.loads((REPO / "docs" / "grafana-gridfleet.json").read_text(encoding="utf-8"))
    exprs = [t["expr"] for panel in dashboard["panels"] for t in panel["targets"]]
    used = {name for expr in exprs for name in re.findall(r"gridfleet_\w+", expr)}
    assert len(used) > 15 and used - servable(idle_scrape()) == set()


def test_the_monitoring_doc_lists_every_metric_and_uses_only_served_names() -> None:
    doc = (REPO / "docs" / "monitoring.md").read_text(encoding="utf-8")
    scrape = idle_scrape()
    families = {
        f"{name}_total" if kind == "counter" else name
        for name, kind in scrape.types.items()
        if not name.endswith("_created")
    }
    listed = set(re.findall(r"^\| `(gridfleet_\w+)`", doc, re.MULTILINE))
    assert listed == families
    assert set(re.findall(r"gridfleet_\w+", doc)) - servable(scrape) - families == set()


def test_up_hands_its_metrics_port_to_the_coordinator() -> None:
    parser = build_parser(only="up")
    assert spec_from(parser.parse_args(["up", "--metrics", "9464"])).metrics_port == 9464
    assert spec_from(parser.parse_args(["up"])).metrics_port is None
    with pytest.raises(ConfigError, match="--metrics 70000: give a port"):
        spec_from(parser.parse_args(["up", "--metrics", "70000"]))


def test_an_assembled_coordinator_serves_its_metrics(
    broker: BrokerThread, root: str, tmp_path: Path
) -> None:
    scenario = load_scenario(REPO / "maps" / "corridor.toml")
    spec = SystemSpec(
        scenario,
        broker=broker.url,
        root=root,
        step_s=0.05,
        db_path=tmp_path / "jobs.db",
        metrics_port=0,
    )
    assembly = Assembly(spec, "threads")
    try:
        server = assembly.start_threads().coordinator.service.metrics_server
        assert server is not None and server.options.listen == "127.0.0.1"
        status, body = get(server.url)
        assert status == 200 and "# TYPE gridfleet_units gauge" in body
    finally:
        assembly.stop()
