"""`gridfleet bench soak`: a one-minute chaos soak through the CLI, and its parts alone."""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import random
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from gridfleet.bench.soak import listen as soak_listen
from gridfleet.bench.soak.check import Stop
from gridfleet.bench.soak.faults import (
    BRIDGED_HOSTS,
    KEEP_ALIVE_S,
    LOCAL_FAMILIES,
    MOSQUITTO_WILL_SLACK_S,
    NETWORK_HOSTS,
    main_faults,
    parse_families,
    stop_faults,
)
from gridfleet.bench.soak.proxy import FaultyProxy
from gridfleet.bench.soak.run import SoakConfig
from gridfleet.bench.soak.topologies import BridgeSoak, NetworkSoak, PlainSoak, soak_for
from gridfleet.protocol import Topics
from gridfleet.robots.truth import write_truth
from gridfleet.robots.world import WorldSim
from gridfleet.scenario import load_scenario

from support.paths import REPO

# The benchmark's own runs: in make test, not in make test-fast.
pytestmark = pytest.mark.slow


def soak(*args: str, timeout: float) -> subprocess.CompletedProcess[str]:
    """Run `python -m gridfleet bench soak ARGS` and capture its output."""
    return subprocess.run(
        [sys.executable, "-m", "gridfleet", "bench", "soak", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
    )


@pytest.mark.soak
@pytest.mark.timeout(420)
def test_one_minute_soak_is_green_and_reports_every_figure(tmp_path: Path) -> None:
    log = tmp_path / "soak.log"
    args = ["--minutes", "1", "--units", "6", "--seed", "1", "--drain", "120", "--json"]
    done = soak(*args, "--log", str(log), timeout=400)
    out: dict[str, Any] = json.loads(done.stdout)
    # On a failure: the whole verdict and its figures (a string: pytest would cut a tuple's repr),
    # then the components' last words and (after a stall) where every task waited.
    verdict = "\n".join(out["details"])
    figures = {k: v for k, v in out.items() if k != "details"}
    assert done.returncode == 0, f"{verdict}\n{figures}\n{log.read_text()[-20000:]}"
    assert out["minutes"] == 1
    for family in ("units", "coordinator", "broker", "pause", "cut", "delay"):
        assert any(family in kind for kind in out["faults"]), (family, out["faults"])
    assert out["faults"].get("estop_operator", 0) + out["faults"].get("estop_device", 0) >= 2
    assert out["collisions"] == 0 and out["moved_while_stopped"] == 0
    assert out["jobs_submitted"] > 0 and out["jobs_done"] > 0
    assert out["jobs_lost"] == 0 and out["jobs_duplicated"] == 0
    assert out["units_stranded"] == 0 and out["faults_unrecovered"] == 0
    assert out["max_recovery_s"] is not None and out["max_recovery_s"] > 0
    # The log lists every main-lane fault it counted, to read a verdict against.
    listed = [line for line in log.read_text().splitlines() if line.startswith("[fault      ]")]
    main_lane = sum(n for kind, n in out["faults"].items() if not kind.startswith("estop_"))
    assert len(listed) == main_lane, listed


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--minutes", "0"], "--minutes 0"),
        (["--units", "0"], "--units 0"),
        (["--faults", "units,meteor"], "meteor"),
        (["--broker", "http://nowhere"], "http://nowhere"),
        (["--faults", "units,silent"], "need --network"),
        (["--network", "--broker", "mqtt://127.0.0.1:1883"], "no --broker"),
        (["--bridge"], "give --network too"),
    ],
)
def test_bad_arguments_are_one_line(args: list[str], says: str) -> None:
    done = soak(*args, timeout=30)
    assert done.returncode == 2 and says in done.stderr
    assert "Traceback" not in done.stderr


def test_the_schedule_is_seeded_and_covers_every_family_each_round() -> None:
    first = [
        f.kind
        for f, _ in zip(main_faults(random.Random(3), LOCAL_FAMILIES, 0.1), range(12), strict=False)
    ]
    again = [
        f.kind
        for f, _ in zip(main_faults(random.Random(3), LOCAL_FAMILIES, 0.1), range(12), strict=False)
    ]
    assert first == again
    round_one = {k.split("_")[-1] for k in first[:6]}
    assert round_one == {"units", "coordinator", "broker", "cut", "delay"} | (
        round_one - {"units", "coordinator", "broker", "cut", "delay"}
    )
    pauses = [
        f for f, _ in zip(main_faults(random.Random(0), ["pause"], 0.1), range(5), strict=False)
    ]
    assert all(f.hold_s > 5 * 0.1 for f in pauses)  # past the staleness timeout
    stops = {
        f.kind
        for f, _ in zip(stop_faults(random.Random(0), ["estop", "press"]), range(20), strict=False)
    }
    assert stops == {"estop_operator", "estop_device"}
    assert parse_families("units, cut") == ["units", "cut"]
    with pytest.raises(ValueError, match="meteor"):
        parse_families("meteor")


def test_the_network_schedule_cuts_stalls_and_narrows_both_hosts_some_cuts_past_the_keep_alive() -> (
    None
):
    families = ["silent", "stall", "narrow"]
    faults = [
        f for f, _ in zip(main_faults(random.Random(1), families, 0.1), range(300), strict=False)
    ]
    assert {f.target for f in faults} == set(NETWORK_HOSTS)
    kinds = {f.kind for f in faults}
    assert kinds == {
        f"{k}_{h}" for k in ("silent", "silent_long", "stall", "narrow") for h in NETWORK_HOSTS
    }
    long_cuts = [f for f in faults if f.kind.startswith("silent_long_")]
    # Long enough for the broker to give up (1.5 keep-alives) and send the will.
    assert all(f.hold_s > 1.5 * KEEP_ALIVE_S for f in long_cuts)
    assert all(f.hold_s < 1.5 * KEEP_ALIVE_S for f in faults if f not in long_cuts)
    assert all(f.kbit > 0 for f in faults if f.kind.startswith("narrow_"))


def test_with_a_bridge_the_network_faults_strike_the_halls_link_and_the_coordinators() -> None:
    faults = [
        f
        for f, _ in zip(
            main_faults(random.Random(1), ["silent", "stall"], 0.1, BRIDGED_HOSTS),
            range(100),
            strict=False,
        )
    ]
    assert {f.target for f in faults} == {"hall", "office"}
    assert "silent_long_hall" in {f.kind for f in faults}  # past the bridge's keep-alive too


def test_on_mosquitto_a_long_cut_lasts_past_its_coarser_keep_alive_check() -> None:
    schedule = main_faults(random.Random(2), ["silent"], 0.1, BRIDGED_HOSTS, MOSQUITTO_WILL_SLACK_S)
    long_cuts = [f for f, _ in zip(schedule, range(200), strict=False) if "long" in f.kind]
    assert long_cuts and all(f.hold_s >= 1.5 * KEEP_ALIVE_S + 8 for f in long_cuts)


async def test_the_proxy_forwards_cuts_and_delays() -> None:
    async def echo(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while data := await reader.read(100):
            writer.write(data)
            await writer.drain()
        writer.close()

    server = await asyncio.start_server(echo, "127.0.0.1", 0)
    proxy = FaultyProxy("127.0.0.1", server.sockets[0].getsockname()[1])
    port = await proxy.start()
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(b"ping")
        assert await asyncio.wait_for(reader.readexactly(4), 5) == b"ping"
        proxy.latency_s = 0.2
        t0 = time.monotonic()
        writer.write(b"slow")
        assert await asyncio.wait_for(reader.readexactly(4), 5) == b"slow"
        assert time.monotonic() - t0 >= 0.4  # both ways
        proxy.latency_s = 0.0
        assert proxy.cut() == 1
        assert await asyncio.wait_for(reader.read(100), 5) == b""  # the client sees it close
        writer.close()
        proxy.refusing = True
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        assert await asyncio.wait_for(reader.read(100), 5) == b""  # the link is down
        writer.close()
    finally:
        await proxy.close()
        server.close()


async def test_truth_lines_carry_the_world(tmp_path: Path) -> None:
    world = WorldSim.from_scenario(load_scenario(REPO / "maps" / "playfield.toml"))
    stop = asyncio.Event()
    path = tmp_path / "truth.jsonl"
    writer = asyncio.create_task(write_truth(world, path, 0.01, stop))
    deadline = time.monotonic() + 10
    while not path.exists() or len(path.read_text().splitlines()) < 2:
        assert time.monotonic() < deadline
        await asyncio.sleep(0.01)  # polling the file, with a deadline
    stop.set()
    await writer
    line = json.loads(path.read_text().splitlines()[-1])
    assert line["collisions"] == 0 and line["moves"] == 0
    assert set(line["positions"]) == set(world.positions)


def test_a_soak_that_injects_nothing_says_where_it_waits(tmp_path: Path) -> None:
    log = io.StringIO()
    soak = PlainSoak(SoakConfig(minutes=1, units=2), tmp_path, log)
    asyncio.run(asyncio.wait_for(soak._watchdog(quiet_s=0.2), 10))
    assert "no progress for 0.2 s; where each task waits:" in log.getvalue()
    assert "_watchdog" in log.getvalue()  # the stacks themselves
    assert soak.unrecovered == ["the soak itself stalled: no progress for 0.2 s"]


def test_a_stalled_soak_is_ended_by_its_watchdog_not_left_hanging(tmp_path: Path) -> None:
    soak = PlainSoak(SoakConfig(minutes=1, units=2), tmp_path, io.StringIO())

    async def stalled_run() -> bool:
        work = asyncio.create_task(asyncio.Event().wait())  # a lane that waits for ever
        await soak._watchdog(quiet_s=0.2, work=work)
        with contextlib.suppress(asyncio.CancelledError):
            await work
        return work.cancelled()

    assert asyncio.run(asyncio.wait_for(stalled_run(), 10))
    assert soak.stalled


def test_the_listener_reads_the_stop_afresh_after_a_broker_restart(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The 30-minute soak reported "stop not released" 5 times: a broker restarted without
    # persistence had lost a device's press, and the listener held on to it for ever.
    monkeypatch.setattr(soak_listen, "RETAINED_S", 0.01)
    topics = Topics("soak")
    listener = soak_listen.SoakListener("mqtt://127.0.0.1:1", topics, "listener")
    press = topics.device("device_stop", "dev")
    listener.take(press, b"engaged|dev|button", 1.0)
    assert listener.stopped
    listener.reconnected()
    listener.take(topics.fleet("estop"), b"released|operator|soak", 2.0)  # the replay
    assert [e for e in listener.events if isinstance(e, Stop)] == [Stop(1.0, True)]
    asyncio.run(listener._settle())  # nothing replayed the press: it is gone
    assert not listener.stopped
    stops = [e for e in listener.events if isinstance(e, Stop)]
    assert stops[:1] == [Stop(1.0, True)] and len(stops) == 2 and stops[1].engaged is False


def test_the_listener_keeps_a_stop_the_replay_confirms() -> None:
    topics = Topics("soak")
    listener = soak_listen.SoakListener("mqtt://127.0.0.1:1", topics, "listener")
    listener.take(topics.fleet("estop"), b"engaged|operator|soak", 1.0)
    listener.reconnected()
    listener.take(topics.fleet("estop"), b"engaged|operator|soak", 2.0)  # the replay
    listener.settling = False
    listener._note_stop(2.5)
    assert [e for e in listener.events if isinstance(e, Stop)] == [Stop(1.0, True)]


def test_each_topology_is_a_soak_of_its_own(tmp_path: Path) -> None:
    log = io.StringIO()
    for name in ("plain", "lan", "hall"):
        (tmp_path / name).mkdir()
    plain = soak_for(SoakConfig(minutes=1, units=2), tmp_path / "plain", log)
    network = soak_for(SoakConfig(minutes=1, units=2, network=True), tmp_path / "lan", log)
    bridge = soak_for(
        SoakConfig(minutes=1, units=2, network=True, bridge=True), tmp_path / "hall", log
    )
    assert (type(plain), type(network), type(bridge)) == (PlainSoak, NetworkSoak, BridgeSoak)
    assert not plain.NETWORK_FAULTS and network.NETWORK_FAULTS and bridge.NETWORK_FAULTS
    # The bridge's brokers are Mosquittos the soak does not restart; the others' is embedded.
    assert plain.RESTARTS_BROKER and network.RESTARTS_BROKER and not bridge.RESTARTS_BROKER
    assert plain._client_id("x") == f"{plain.root}-x"
    assert network._client_id("x", device=True) == f"soak-dev-{network.root}-x"
