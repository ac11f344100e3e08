"""`gridfleet job`: an operator drives the real coordinator and units from the command line."""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from gridfleet.grid import Cell
from gridfleet.protocol import Topics, decode_estop
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread, world_of

from support.cli import gridfleet
from support.probe import MqttProbe
from support.wait import wait_for


@pytest.fixture
def job(broker: BrokerThread, root: str) -> Callable[..., subprocess.CompletedProcess[str]]:
    """Run `gridfleet job ARGS --broker URL --root R` (the session broker, this test's root).

    The common flags come after the action, where a new user puts them; `job_before` puts them
    before it.
    """

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return gridfleet("job", *args, "--broker", broker.url, "--root", root)

    return run


@pytest.fixture
def job_before(broker: BrokerThread, root: str) -> Callable[..., subprocess.CompletedProcess[str]]:
    """Run `gridfleet job --broker URL --root R ARGS`."""

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return gridfleet("job", "--broker", broker.url, "--root", root, *args)

    return run


@pytest.mark.slow  # the whole system, end to end: make test, not test-fast
@pytest.mark.timeout(180)  # its own waits (30 s, 60 s) and ten commands: more than 60 s when slow
def test_submit_list_cancel_goal_and_refusal(
    job: Callable[..., subprocess.CompletedProcess[str]],
    job_before: Callable[..., subprocess.CompletedProcess[str]],
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
    playfield: Path,
) -> None:
    _, fleet = run_system(playfield)
    world = world_of(fleet)
    out = job(
        "submit", "--pickup", "1,8", "--dropoff", "8,8", "--mass", "1.5", "--id", "crate",
        "--timeout", "5",
    )  # fmt: skip
    assert (out.returncode, out.stdout.strip()) == (0, "accepted: job crate"), out.stderr
    assert "crate" in job_before("list").stdout  # the flags before the action work as well
    heavy = job("submit", "--pickup", "1,8", "--dropoff", "8,8", "--mass", "500")
    assert heavy.returncode == 1
    assert heavy.stdout.startswith("refused: ") and "capacity" in heavy.stdout
    listed = job("list")
    assert listed.returncode == 0 and "crate" in listed.stdout
    out = job("goal", "unit3", "5,5")
    assert (out.returncode, out.stdout.strip()) == (0, "accepted"), out.stderr
    wait_for(lambda: world.positions["unit3"] == Cell(5, 5), timeout=30, what="unit3 at 5,5")
    wait_for(lambda: "done" in job("list").stdout, timeout=60, interval=0.5, what="crate done")
    negative = job("submit", "--pickup", "1,8", "--dropoff", "8,8", "--mass=-1")
    assert negative.returncode == 2 and "Traceback" not in negative.stderr
    assert "a mass must be more than 0 kg" in negative.stderr.strip().splitlines()[-1]
    cancel = job("cancel", "nonexistent")
    assert cancel.returncode == 1 and "nonexistent" in cancel.stdout
    wall = job("goal", "unit1", "99,99")
    assert wall.returncode == 1 and wall.stdout.startswith("refused: ")
    nobody = job("goal", "nobody", "1,1")
    assert (nobody.returncode, nobody.stdout.strip()) == (1, "refused: unknown unit 'nobody'")
    typo = job("clear-obstacles", "0,9")  # not an obstacle anybody found
    assert typo.returncode == 1 and "is not a discovered obstacle" in typo.stdout, typo.stdout
    everything = job("clear-obstacles", "--all")
    assert (everything.returncode, everything.stdout.strip()) == (0, "accepted"), everything.stderr


@pytest.mark.slow  # the whole system, end to end: make test, not test-fast
def test_units_are_paused_and_taken_out_of_service_and_a_waiting_job_says_why(
    job: Callable[..., subprocess.CompletedProcess[str]],
    broker: BrokerThread,
    root: str,
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
    playfield: Path,
) -> None:
    run_system(playfield)
    assert job("stop", "--reason", "drill").returncode == 0
    out = job("submit", "--pickup", "1,8", "--dropoff", "8,8", "--mass", "1", "--id", "crate")
    assert out.returncode == 0, out.stdout + out.stderr

    def crate() -> str:
        return next(line for line in job("list").stdout.splitlines() if line.startswith("crate"))

    # The wait is the coordinator's next step's; the view right after the submission may precede it.
    wait_for(
        lambda: crate().endswith("waits: the emergency stop is engaged"),
        timeout=20,
        interval=0.5,
        what="the crate's wait listed",
    )
    assert job("release").returncode == 0
    out = job("out-of-service", "unit1")
    assert (out.returncode, out.stdout.strip()) == (0, "accepted"), out.stderr

    def unit1() -> str:
        status = gridfleet("status", "--once", "--broker", broker.url, "--root", root)
        return next(line for line in status.stdout.splitlines() if "unit1" in line)

    wait_for(lambda: "out of service" in unit1(), timeout=20, interval=0.5, what="shown")
    assert job("pause", "unit1").stdout.startswith("refused: ")  # out of service: no pause
    assert job("in-service", "unit1").stdout.strip() == "accepted"
    again = job("in-service", "unit1")
    assert again.returncode == 1 and again.stdout.startswith("refused: ")
    assert (job("pause", "unit2").returncode, job("resume", "unit2").returncode) == (0, 0)
    nobody = job("resume", "nobody")
    assert (nobody.returncode, nobody.stdout.strip()) == (1, "refused: unknown unit 'nobody'")


def test_stop_and_release_are_latched_on_the_fleet_topic(
    job: Callable[..., subprocess.CompletedProcess[str]],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
) -> None:
    out = job("stop", "--reason", "spill in aisle 3")
    assert (out.returncode, out.stdout) == (0, "emergency stop ENGAGED\n"), out.stderr
    late = probe_factory()  # retained: a client that connects later sees it
    late.subscribe(topics.fleet("estop"))
    signal = decode_estop(late.wait(topics.fleet("estop"), lambda m: m.retain).payload)
    assert signal.engaged and signal.reason == "spill in aisle 3"
    again = job("stop", "--reason", "second thoughts")
    assert again.returncode == 0
    assert again.stdout == (
        f"the emergency stop was already engaged (latched by {signal.by}: spill in aisle 3); "
        "left as it was\n"
    )
    out = job("release")
    assert out.returncode == 0
    assert (
        out.stdout == f"emergency stop released (it was engaged by {signal.by}: spill in aisle 3)\n"
    )
    later = probe_factory()
    later.subscribe(topics.fleet("estop"))
    assert not decode_estop(later.wait(topics.fleet("estop")).payload).engaged
    assert [m.payload for m in late.received(topics.fleet("estop"))] == [
        f"engaged|{signal.by}|spill in aisle 3".encode(),  # the second stop left it as it was
        later.received(topics.fleet("estop"))[0].payload,
    ]


def test_release_when_nothing_was_engaged_says_so_and_changes_nothing(
    job: Callable[..., subprocess.CompletedProcess[str]],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
) -> None:
    watcher = probe_factory()
    watcher.subscribe(topics.fleet("estop"))
    out = job("release")
    assert (out.returncode, out.stdout, out.stderr) == (
        0,
        "nothing to release: the emergency stop was not engaged\n",
        "",
    )
    assert job("stop").returncode == 0 and job("release").returncode == 0
    again = job("release")  # released is not engaged either
    assert again.stdout == "nothing to release: the emergency stop was not engaged\n"
    # A marker published after every command has finished arrives after all they sent.
    probe_factory().publish(topics.fleet("estop"), b"released|sync-marker|x")
    watcher.wait(topics.fleet("estop"), lambda m: b"sync-marker" in m.payload)
    signals = [decode_estop(m.payload) for m in watcher.received(topics.fleet("estop"))]
    assert [(s.engaged, s.by == "sync-marker") for s in signals] == [
        (True, False),
        (False, False),
        (False, True),
    ]


def test_a_held_press_without_a_coordinator_is_named_and_not_released(
    job: Callable[..., subprocess.CompletedProcess[str]],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
) -> None:
    unit = probe_factory()
    unit.publish(topics.unit("stop", "unit2"), "engaged|unit2|bumper hit", retain=True)
    out = job("release")
    assert out.returncode == 1
    assert out.stdout == (
        "not released: the press of unit2 (bumper hit) holds the fleet, and no coordinator is "
        "online to clear it (it clears the presses when an operator releases the latch): release "
        "once one runs\n"
    )
    stop = job("stop")
    assert stop.returncode == 0
    assert stop.stdout == (
        "emergency stop ENGAGED: it was already engaged by the press of unit2 (bumper hit); now it "
        "is latched too\n"
    )
    released = job("release")
    assert released.returncode == 1  # the press still holds the fleet
    assert "the press of unit2 (bumper hit) still holds the fleet" in released.stdout
    unit.publish(topics.unit("stop", "unit2"), b"", retain=True)
    unit.publish(topics.fleet("estop"), b"", retain=True)


@pytest.mark.slow  # the whole system, end to end: make test, not test-fast
def test_release_names_the_press_that_held_the_fleet_and_the_coordinator_clears_it(
    job: Callable[..., subprocess.CompletedProcess[str]],
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
    probe_factory: Callable[..., MqttProbe],
    topics: Topics,
    playfield: Path,
) -> None:
    run_system(playfield)
    bumper = probe_factory()
    bumper.subscribe(topics.fleet("estop"))
    bumper.subscribe(topics.all_units("stop"))
    bumper.publish(topics.unit("stop", "unit2"), "engaged|unit2|bumper hit", retain=True)
    bumper.wait(topics.fleet("estop"), lambda m: m.payload == b"engaged|unit2|bumper hit")
    stop = job("stop")
    assert stop.stdout == (
        "the emergency stop was already engaged (latched by unit2: bumper hit); left as it was\n"
    )
    out = job("release")
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout == (
        "emergency stop released (it was engaged by unit2: bumper hit)\n"
        "the press of unit2 (bumper hit) held it too: releasing the latch clears it\n"
    )
    # The coordinator clears the press (an empty retained message), so a restart reads no stop.
    press = topics.unit("stop", "unit2")
    bumper.wait(press, lambda m: m.payload == b"")
    late = probe_factory()
    late.subscribe(topics.all_units("stop"))
    late.subscribe(topics.fleet("estop"))  # replayed after the presses: once here, so are they
    late.wait(topics.fleet("estop"))
    assert late.received(press) == []


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["submit", "--pickup", "1;1", "--dropoff", "2,2", "--mass", "1"], "not a square"),
        (["submit", "--pickup=-1,3", "--dropoff", "2,2", "--mass", "1"], "squares start at 0,0"),
        (["submit", "--pickup", "-1,3", "--dropoff", "2,2", "--mass", "1"], "squares start at 0,0"),
        (
            ["submit", "--pickup", "1,1", "--dropoff", "-2,-2", "--mass", "1"],
            "squares start at 0,0",
        ),
        (["goal", "unit1", "-1,2"], "'-1,2': squares start at 0,0"),
        (["submit", "--pickup", "4096,1", "--dropoff", "2,2", "--mass", "1"], "up to 4095"),
        (["submit", "--pickup", "1,1", "--dropoff", "2,2", "--mass", "nan"], "more than 0 kg"),
        (["submit", "--pickup", "1,1", "--dropoff", "2,2", "--mass", "1e400"], "too large"),
        (
            ["submit", "--pickup", "1,1", "--dropoff", "2,2", "--mass", "1", "--priority", "500"],
            "'500': a priority is a whole number from 0 to 100",
        ),
        (
            ["submit", "--pickup", "1,1", "--dropoff", "2,2", "--mass", "1", "--priority", "-3"],
            "'-3': a priority is a whole number from 0 to 100",
        ),
        (
            ["submit", "--pickup", "1,1", "--dropoff", "2,2", "--mass", "1", "--id", "crate 7"],
            "job id 'crate 7' is not a valid id: 1-64 characters of letters, digits",
        ),
        (["cancel", "a/b"], "job id 'a/b' is not a valid id: 1-64 characters"),
        (["cancel", "x" * 65], "is not a valid id: 1-64 characters"),
        (["goal", "unit 1", "1,1"], "unit id 'unit 1' is not a valid id"),
        (["goal", "unit1"], "goal unit1: give the square to send it to, X,Y, or --clear"),
        (
            ["stop", "--reason", "x" * 201],
            "has 201 characters: a reason is one line of at most 200",
        ),
        (["--timeout", "1", "list"], "is the coordinator running?"),
        (["--timeout", "1", "cancel", "j1"], "the coordinator is not online"),
        (["stop", "--reason", "two\nlines"], "one line"),
        (["--timeout", "0", "list"], "--timeout 0: give a positive number of seconds"),
        (["clear-obstacles"], "clear-obstacles: name the squares, X,Y ..., or give --all"),
        (["clear-obstacles", "1,-1"], "'1,-1'"),
    ],
)
def test_mistakes_are_one_line(
    job: Callable[..., subprocess.CompletedProcess[str]], args: list[str], message: str
) -> None:
    out = job(*args)
    assert out.returncode == 2
    assert "Traceback" not in out.stderr and message in out.stderr.strip().splitlines()[-1]
    for leak in ("Input should", "String should", "pattern", "^[", "expected one argument"):
        assert leak not in out.stderr


def test_flags_after_the_action_are_used(broker: BrokerThread, root: str) -> None:
    """`job list --broker URL --root R --timeout 1`: the refusal names what it was given."""
    out = gridfleet("job", "list", "--broker", broker.url, "--root", root, "--timeout", "1")
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        f"gridfleet job: error: no job queue on {broker.url} under root {root!r} within 1 s: "
        "is the coordinator running?"
    ]


def test_unreachable_broker_is_one_line() -> None:
    out = gridfleet("job", "--broker", "mqtt://127.0.0.1:1", "list")
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        "gridfleet job: error: MQTT with mqtt://127.0.0.1:1: [Errno 111] Connection refused"
    ]
