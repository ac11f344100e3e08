"""The typed test peers of tests/support (fleet_peer, operator_peer, peers) on the real broker.

Each message a peer publishes is the protocol's: its model, on its topic, with its kind's QoS and
retain flag; and the operator's requests get their own replies and no one else's.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest

from gridfleet.grid import Cell, Direction, GridMap
from gridfleet.protocol import (
    TOPICS,
    CancelJob,
    Connection,
    CoordinatorStatus,
    ErrorReport,
    EstopSignal,
    Factsheet,
    FleetMap,
    JobsView,
    JobView,
    Leds,
    Reply,
    Routes,
    RouteView,
    SetGoal,
    SubmitJob,
    Topics,
    UnitState,
    decode,
    decode_direction,
    decode_estop,
)
from gridfleet.system.broker_thread import BrokerThread

from support.fleet_peer import CoordinatorPeer, UnitPeer
from support.operator_peer import OperatorPeer
from support.peers import DispatchPeer
from support.probe import MqttProbe
from support.wait import WaitTimeout, wait_for

pytestmark = (
    pytest.mark.every_broker
)  # each kind's QoS and retain flag, as the broker delivers them

Probes = Callable[..., MqttProbe]
GRID = GridMap.from_rows(["....", ".@..", "...."], name="tiny")
REQUESTS: dict[str, type[SubmitJob] | type[CancelJob] | type[SetGoal]] = {
    "submit_job": SubmitJob,
    "cancel_job": CancelJob,
    "set_goal": SetGoal,
}


class RecordingProbe(MqttProbe):
    """A probe that also notes how each message was handed to the broker: topic, QoS, retain.

    (What a subscriber sees says less: amqtt 0.12 delivers a QoS 0 message at the subscription's
    QoS 1, and sets the retain flag only on what it replays from its store.)
    """

    def __init__(self, url: str) -> None:
        super().__init__(url)
        self.sent: list[tuple[str, int, bool]] = []

    def publish(
        self,
        topic: str,
        payload: bytes | str,
        qos: int = 1,
        retain: bool = False,
        timeout: float = 10.0,
    ) -> None:
        self.sent.append((topic, qos, retain))
        super().publish(topic, payload, qos, retain, timeout)


@pytest.fixture
def recording(broker: BrokerThread) -> Iterator[Callable[[], RecordingProbe]]:
    """Make connected RecordingProbes on the session broker; all closed after the test."""
    made: list[RecordingProbe] = []

    def make() -> RecordingProbe:
        probe = RecordingProbe(broker.url)
        probe.connect()
        made.append(probe)
        return probe

    yield make
    for probe in made:
        probe.close()


class Wire:
    """What one probe sent, as a listener under the test's root heard it."""

    def __init__(
        self, sender: RecordingProbe, listener: MqttProbe, topics: Topics, twice_ok: bool = False
    ) -> None:
        self.sender = sender
        self.listener = listener
        self.topics = topics
        # QoS 1 is at least once: a cluster may deliver a message twice (aedes' did, under load)
        self.twice_ok = twice_ok

    def one(self, topic: str) -> bytes:
        """The payload of the one message on `topic`, sent with its kind's QoS and retain flag."""
        kind, _ = self.topics.parse(topic)
        spec = TOPICS[kind]
        assert [(q, r) for t, q, r in self.sender.sent if t == topic] == [
            (spec.qos, spec.retained)
        ], kind
        seen = self.listener.wait(topic)
        heard = self.listener.received(topic)
        if self.twice_ok and spec.qos == 1:  # the same message again, never another
            heard = [h for h in heard if (h.payload, h.retain) != (seen.payload, seen.retain)]
            heard.insert(0, seen)
        assert heard == [seen]
        return seen.payload


@pytest.fixture
def wire(
    recording: Callable[[], RecordingProbe], probe_factory: Probes, topics: Topics, broker_kind: str
) -> Wire:
    """A recording sender, and a listener that hears everything under this test's root."""
    listener = probe_factory()
    listener.subscribe(f"{topics.prefix}/#", qos=1)
    return Wire(recording(), listener, topics, twice_ok=broker_kind in ("aedes", "rabbitmq"))


def test_a_unit_peer_publishes_the_protocols_messages(wire: Wire, topics: Topics) -> None:
    unit = UnitPeer(wire.sender, topics, "unit1")
    connection = unit.connection("online")
    factsheet = unit.factsheet(2.0, "#d32f2f", step_period_s=0.05)
    moving = unit.state(Cell(1, 0), Direction.E, "moving", job_id="job-1", load_kg=1.5)
    direction = unit.direction(Direction.E)

    assert decode(Connection, wire.one(topics.unit("connection", "unit1"))) == connection
    assert connection.state == "online" and connection.header.sender == "unit1"
    assert decode(Factsheet, wire.one(topics.unit("factsheet", "unit1"))) == factsheet
    assert (factsheet.capacity_kg, factsheet.color, factsheet.step_period_s) == (
        2.0,
        "#d32f2f",
        0.05,
    )
    state = decode(UnitState, wire.one(topics.unit("state", "unit1")))
    assert state == moving
    assert (state.position, state.direction, state.status) == ((1, 0), "E", "moving")
    assert (state.job_id, state.load_kg, state.leds) == ("job-1", 1.5, Leds(E=True))
    letter = wire.one(topics.unit("direction", "unit1"))
    assert letter == direction == b"E" and decode_direction(letter) is Direction.E


def test_unit_states_count_steps_and_light_the_leds_protocol_md_says(
    probe_factory: Probes, topics: Topics
) -> None:
    unit = UnitPeer(probe_factory(), topics, "unit2")
    still = unit.state(Cell(0, 0))
    north = unit.state(Cell(0, 0), Direction.N, "moving")
    stopped = unit.state(Cell(0, 0), Direction.N, "stopped", estop=True)
    waiting = unit.state(Cell(0, 0), None, "waiting", step=9, wait_reason="blocked")
    assert [s.step for s in (still, north, stopped, waiting)] == [0, 1, 2, 9]
    assert [s.header.seq for s in (still, north, stopped, waiting)] == [0, 1, 2, 3]
    assert (still.direction, still.leds) == ("-", Leds())
    assert north.leds == Leds(N=True)
    assert stopped.leds == Leds(N=True, E=True, S=True, W=True)
    assert (waiting.direction, waiting.leds, waiting.wait_reason) == ("-", Leds(), "blocked")


def test_a_coordinator_peer_publishes_the_protocols_messages(wire: Wire, topics: Topics) -> None:
    coordinator = CoordinatorPeer(wire.sender, topics)
    jobs = [
        JobView(id="job-1", pickup=Cell(0, 0), dropoff=Cell(3, 2), mass_kg=1.5, state="queued"),
        JobView(id="job-2", pickup=Cell(0, 0), dropoff=Cell(3, 0), mass_kg=2.0, state="queued"),
        JobView(
            id="job-3",
            pickup=Cell(2, 0),
            dropoff=Cell(0, 2),
            mass_kg=50.0,
            state="rejected",
            reason="too heavy",
        ),
    ]
    sent = [
        coordinator.map(GRID, obstacles=[Cell(3, 0)]),
        coordinator.jobs(jobs),
        coordinator.routes({"unit1": RouteView(released=[Cell(1, 0)], target=Cell(2, 0))}, step=7),
        coordinator.status(step=3, step_period_s=0.05),
        coordinator.reply("dash", "r-1", False, "pickup [9, 9] is off the 4x3 map"),
        coordinator.error(topics.request("set_goal"), "target [1, 1] is a wall", "r-2"),
    ]

    fleet_map = decode(FleetMap, wire.one(topics.fleet("map")))
    assert fleet_map == sent[0]
    assert (fleet_map.name, fleet_map.rows, fleet_map.obstacles) == (
        "tiny",
        ["....", ".@..", "...."],
        [(3, 0)],
    )
    view = decode(JobsView, wire.one(topics.fleet("jobs")))
    assert view == sent[1] and view.listed() == jobs and view.counts == {"queued": 2, "rejected": 1}
    assert [j.id for j in view.finished] == ["job-3"]  # the final ones apart, as the coordinator
    routes = decode(Routes, wire.one(topics.fleet("routes")))
    assert routes == sent[2] and routes.step == 7 and routes.routes["unit1"].released == [(1, 0)]
    status = decode(CoordinatorStatus, wire.one(topics.fleet("coordinator")))
    assert status == sent[3] and (status.state, status.step, status.estop) == ("online", 3, False)
    reply = decode(Reply, wire.one(topics.reply("dash")))
    assert reply == sent[4] and (reply.request_id, reply.accepted) == ("r-1", False)
    error = decode(ErrorReport, wire.one(topics.fleet("errors")))
    assert error == sent[5] and error.request_id == "r-2"
    assert {m.header.sender for m in sent} == {"coordinator"}


def test_only_the_retained_kinds_reach_a_late_subscriber(
    probe_factory: Probes, topics: Topics
) -> None:
    publisher = probe_factory()
    unit, coordinator = UnitPeer(publisher, topics, "unit1"), CoordinatorPeer(publisher, topics)
    operator = OperatorPeer(probe_factory(), topics)
    unit.connection("online")
    unit.factsheet(2.0)
    unit.state(Cell(0, 0))
    unit.direction(None)
    coordinator.map(GRID)
    coordinator.jobs([])
    coordinator.routes({})
    coordinator.events([])
    coordinator.status()
    coordinator.reply("dash", "r-1", True)
    coordinator.error(topics.request("submit_job"), "malformed JSON")
    operator.engage("test")

    late = probe_factory()
    late.subscribe(f"{topics.prefix}/#", qos=1)
    # The peers send no presses, device messages or a vehicle's condition (units and devices of
    # their own do, and the VDA 5050 adapter), nor the alerts process's view, nor the energy view
    # (the coordinator's, for a fleet with chargers or batteries), nor the zones view (the
    # coordinator's: tests/coordinator/test_coordinator_zones.py).
    retained = {k for k, spec in TOPICS.items() if spec.retained} - {
        "device_connection",
        "device_stop",
        "stop",
        "vehicle",
        "alerts",
        "energy",
        "zones",
    }
    wanted = {
        topics.unit(kind, "unit1")
        if kind in ("connection", "factsheet", "state", "direction")
        else topics.fleet(kind)
        for kind in retained
    }
    wait_for(
        lambda: all(late.received(topic) for topic in wanted),
        what=f"the retained {sorted(retained)}",
    )
    assert all([m.retain for m in late.received(topic)] == [True] for topic in wanted)
    # The reply and the error report are not retained: gone for whoever was not listening.
    assert late.received(topics.reply("dash")) == late.received(topics.fleet("errors")) == []


AnyRequest = SubmitJob | CancelJob | SetGoal


@contextmanager
def answering(
    listener: MqttProbe, topics: Topics, answer: Callable[[AnyRequest], None]
) -> Iterator[list[AnyRequest]]:
    """The coordinator's side, in a thread: `answer` each request `listener` hears, in order."""
    heard: list[AnyRequest] = []
    stop = threading.Event()

    def run() -> None:
        while not stop.wait(0.005):
            arrived = sorted(
                (m for kind in REQUESTS for m in listener.received(topics.request(kind))),
                key=lambda m: m.at,
            )
            for seen in arrived[len(heard) :]:
                kind, _ = topics.parse(seen.topic)
                heard.append(decode(REQUESTS[kind], seen.payload))
                answer(heard[-1])

    thread = threading.Thread(target=run, name="answering", daemon=True)
    thread.start()
    try:
        yield heard
    finally:
        stop.set()
        thread.join(5)


def test_each_request_gets_its_own_id_and_the_reply_carrying_it(
    wire: Wire, probe_factory: Probes, topics: Topics
) -> None:
    coordinator = CoordinatorPeer(probe_factory(), topics)

    def accept(request: AnyRequest) -> None:
        job = request.job_id if isinstance(request, SubmitJob | CancelJob) else None
        coordinator.reply(request.reply_to or "nobody", request.request_id, True, job_id=job)

    op = OperatorPeer(wire.sender, topics, "op1")
    with answering(wire.listener, topics, accept) as heard:
        submitted = op.submit_job(Cell(0, 0), Cell(3, 2), 1.5, priority=5, job_id="job-9")
        cancelled = op.cancel_job("job-9")
        goal = op.set_goal("unit1", Cell(2, 0))
        cleared = op.set_goal("unit1", None)

    replies = [submitted, cancelled, goal, cleared]
    assert all(r.accepted for r in replies) and submitted.job_id == "job-9"
    assert [r.request_id for r in replies] == [q.request_id for q in heard]
    assert len({r.request_id for r in replies}) == 4
    assert all(q.reply_to == "op1" and q.header.sender == "op1" for q in heard)
    job, cancel, to_square, clear = heard
    assert isinstance(job, SubmitJob) and (job.pickup, job.dropoff, job.mass_kg) == (
        (0, 0),
        (3, 2),
        1.5,
    )
    assert (job.priority, job.job_id) == (5, "job-9")
    assert isinstance(cancel, CancelJob) and cancel.job_id == "job-9"
    assert isinstance(to_square, SetGoal) and (to_square.unit, to_square.target) == (
        "unit1",
        (2, 0),
    )
    assert isinstance(clear, SetGoal) and clear.target is None
    # Requests go at QoS 1, not retained (a stale request must not be replayed to a newcomer).
    assert [q for t, q, r in wire.sender.sent if "/requests/" in t] == [1, 1, 1, 1]
    assert not any(r for t, q, r in wire.sender.sent if "/requests/" in t)


def test_a_reply_to_another_request_is_not_taken_as_ours(
    wire: Wire, probe_factory: Probes, topics: Topics
) -> None:
    coordinator = CoordinatorPeer(probe_factory(), topics)

    def other_first(request: AnyRequest) -> None:
        # One publisher, one topic, QoS 1: the stranger's reply arrives first.
        coordinator.reply("op1", f"not-{request.request_id}", False, "not yours")
        coordinator.reply("op1", request.request_id, True)

    op = OperatorPeer(probe_factory(), topics, "op1")
    with answering(wire.listener, topics, other_first):
        reply = op.set_goal("unit1", Cell(2, 0))
    assert reply.accepted and reply.request_id == "op1-1"
    assert [(r.request_id, r.accepted) for r in op.replies()] == [
        ("not-op1-1", False),
        ("op1-1", True),
    ]


def test_no_reply_with_our_id_is_a_timeout_even_when_others_come(
    wire: Wire, probe_factory: Probes, topics: Topics
) -> None:
    coordinator = CoordinatorPeer(probe_factory(), topics)

    def only_others(request: AnyRequest) -> None:
        coordinator.reply("op1", f"not-{request.request_id}", True)

    op = OperatorPeer(probe_factory(), topics, "op1")
    with answering(wire.listener, topics, only_others), pytest.raises(WaitTimeout):
        op.cancel_job("job-1", timeout=1.0)
    stranger = wait_for(op.replies, what="the other request's reply")
    assert [r.request_id for r in stranger] == ["not-op1-1"]


def test_the_operator_reads_units_the_coordinator_and_the_stop(
    probe_factory: Probes, topics: Topics
) -> None:
    publisher = probe_factory()
    op = OperatorPeer(probe_factory(), topics, "op1")
    assert op.last_state("unit1") is None and op.coordinator_status() is None
    unit, coordinator = UnitPeer(publisher, topics, "unit1"), CoordinatorPeer(publisher, topics)
    sent = [unit.state(Cell(0, 0)), unit.state(Cell(0, 0), Direction.S, "moving")]
    sent.append(unit.state(Cell(0, 1), None, "idle"))
    unit.direction(Direction.S)
    unit.direction(None)
    coordinator.status(step=4, estop=True)

    wait_for(lambda: len(op.states("unit1")) == 3, what="three states")
    assert op.states("unit1") == sent and op.last_state("unit1") == sent[-1]
    wait_for(lambda: len(op.directions("unit1")) == 2, what="two directions")
    assert op.directions("unit1") == [Direction.S, None]
    status = wait_for(op.coordinator_status, what="the coordinator's status")
    assert status is not None and (status.step, status.estop) == (4, True)

    engaged = op.engage("test")
    released = op.release("area checked", by="dashboard")
    wait_for(lambda: len(op.estop_signals()) == 2, what="both stop signals")
    assert op.estop_signals() == [engaged, released]
    assert released == EstopSignal(False, "dashboard", "area checked")
    # Retained at QoS 1: a newcomer learns the latest value from the broker.
    late = probe_factory()
    late.subscribe(topics.fleet("estop"), qos=1)
    seen = late.wait(topics.fleet("estop"))
    assert (seen.retain, seen.qos, decode_estop(seen.payload)) == (True, 1, released)


def test_the_operator_reads_the_queue_view_connections_and_error_reports(
    probe_factory: Probes, topics: Topics
) -> None:
    publisher = probe_factory()
    op = OperatorPeer(probe_factory(), topics, "op1")
    assert op.listed_jobs() == {} and op.job_state("job-1") is None
    unit, coordinator = UnitPeer(publisher, topics, "unit1"), CoordinatorPeer(publisher, topics)
    queued = JobView(id="job-1", pickup=Cell(0, 0), dropoff=Cell(3, 2), mass_kg=1.5, state="queued")
    done = queued.model_copy(update={"state": "done", "unit": "unit1"})
    coordinator.jobs([queued])
    coordinator.jobs([done])
    unit.connection("online")
    publisher.publish(topics.unit("connection", "unit1"), b"", retain=True)  # a cleared value
    unit.connection("broken")
    report = coordinator.error(topics.request("submit_job"), "malformed JSON", "r-1")

    wait_for(lambda: len(op.job_views()) == 2, what="two queue views")
    assert [v.listed() for v in op.job_views()] == [[queued], [done]]
    assert op.listed_jobs() == {"job-1": done} and op.job_state("job-1") == "done"
    assert op.all_final(["job-1"]) and not op.all_final(["job-1", "job-2"])
    wait_for(lambda: len(op.probe.received(topics.unit("connection", "unit1"))) == 3, what="all 3")
    assert op.connections("unit1") == ["online", "broken"]
    assert wait_for(op.errors, what="the error report") == [report]


def test_a_unit_peer_reads_its_own_orders_and_acknowledges_them(
    probe_factory: Probes, topics: Topics
) -> None:
    unit = UnitPeer(probe_factory(), topics, "unit1")
    unit.follow_orders()
    coordinator = DispatchPeer(probe_factory(), topics, step_period_s=None)
    other = coordinator.order("unit2", "o9", 1, [])
    sent = coordinator.order("unit1", "o1", 2, [Cell(1, 0)], planned=[Cell(2, 0)])
    wait_for(lambda: unit.orders(), what="unit1's order")
    assert unit.orders() == [sent] and other not in unit.orders()
    ack = unit.state(Cell(0, 0), order_id=sent.order_id, order_update_id=sent.update_id)
    wait_for(lambda: coordinator.states("unit1"), what="the acknowledging state")
    assert coordinator.states("unit1") == [ack]
    assert (ack.order_id, ack.order_update_id) == ("o1", 2)
