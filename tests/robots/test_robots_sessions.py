"""A unit tells every new coordinator session who it is (protocol.md §5.5): exact messages.

A coordinator learns capacities from the units' retained `connection` and `factsheet`, and not
every broker gives them to it (RabbitMQ's retained messages are each node's and never reach a
wildcard subscription; a broker restarted empty). A unit that reads the first `online` of a
coordinator session says `online`, its factsheet and its state again, fresh headers, once per
session. Exact messages, as tests/robots/test_robots_effects.py pins them.
"""

from __future__ import annotations

from typing import Literal

from test_robots_effects import ROOT, ready, state
from test_vda5050_core import TOPICS as VDA_TOPICS
from test_vda5050_core import connection as vehicle_connection
from test_vda5050_core import core as vehicle_core
from test_vda5050_core import online as vehicle_online

from gridfleet.protocol import CoordinatorStatus, Header, encode
from gridfleet.robots.core import UnitCore

from support.effects import FIXED, Published, header, header_json, published

STATUS = ROOT + "coordinator/status"
Said = Literal["online", "offline", "broken"]


def status(seq: int, said: Said = "online", sender: str = "coordinator") -> bytes:
    """A coordinator status (seq 0: a core's first; a process's first `online` is seq 1)."""
    return encode(CoordinatorStatus(header=header(sender, seq), state=said, step_period_s=0.1))


def announced(connection_seq: int, factsheet_seq: int, state_seq: int) -> list[Published]:
    """u1 telling a coordinator who it is: `online`, the factsheet, the state, in that order."""
    core = ready()
    factsheet = {
        "header": header_json("u1", factsheet_seq),
        "capacity_kg": 5.0,
        "step_period_s": 0.1,
        "sensors": ["N", "E", "S", "W"],
        "color": "#d32f2f",
        "model": "gridfleet-sim",
        "map_id": core.logic.grid.map_id(),
        "energy": None,
    }
    online = {"header": header_json("u1", connection_seq), "state": "online"}
    return [
        ("units/u1/connection", online, 1, True),
        ("units/u1/factsheet", factsheet, 1, True),
        state(state_seq),
    ]


def read(core: UnitCore, payload: bytes, now: float, retained: bool = False) -> list[Published]:
    return published(core.on_message(STATUS, payload, now, retained=retained), ROOT)


def test_a_coordinator_started_after_the_unit_is_told_again_once() -> None:
    core = ready()  # its will seq 0, `online` 1, factsheet 0, states 0 and 1
    # A coordinator process's first `online` (its will took seq 0), heard live.
    assert read(core, status(1), 0.3) == announced(2, 1, 2)
    assert core.announcements == 1
    # The same status again (QoS 1 redelivered), and the later ones of that session: no news.
    assert read(core, status(1), 0.31) == []
    assert read(core, status(2), 0.4) == []
    assert read(core, status(7), 5.0) == []
    assert core.announcements == 1


def test_the_retained_status_found_on_subscribing_is_no_new_session() -> None:
    core = ready()
    # That coordinator was subscribed before the unit connected: it heard the connect's word.
    assert read(core, status(9), 0.3, retained=True) == []
    assert read(core, status(10), 5.0) == []
    assert core.announcements == 0


def test_a_restarted_coordinator_is_told_again_with_or_without_its_will() -> None:
    core = ready()
    read(core, status(4), 0.3, retained=True)
    # It died: its will (stamped when it connected), then the new process's `online`.
    assert read(core, status(3, "broken"), 0.5) == []
    assert read(core, status(1), 0.6) == announced(2, 1, 2)
    # Stopped cleanly and started again: `offline`, then a new `online`.
    assert read(core, status(5, "offline"), 1.0) == []
    assert read(core, status(1), 1.2) == announced(3, 2, 3)
    # Its goodbye lost: a counter that began again (lower seq) tells the restart ...
    assert read(core, status(6), 2.0) == []
    assert read(core, status(1), 2.2) == announced(4, 3, 4)
    # ... and so does the same seq with another header (a core driven without a will: seq 0).
    read(core, status(0), 3.0)
    later = encode(
        CoordinatorStatus(
            header=Header(seq=0, timestamp=FIXED.replace(minute=5), sender="coordinator"),
            state="online",
            step_period_s=0.1,
        )
    )
    assert [t for t, *_ in read(core, later, 3.5)] == [
        "units/u1/connection",
        "units/u1/factsheet",
        "units/u1/state",
    ]
    assert core.announcements == 5


def test_a_reconnect_of_the_coordinator_after_its_will_and_another_coordinator_are_told() -> None:
    core = ready()
    read(core, status(4), 0.3, retained=True)
    # The same process reconnects (a failover: its will seq 4 published, its `online` counts on).
    assert read(core, status(4, "broken"), 0.5) == []
    assert read(core, status(7), 0.7) == announced(2, 1, 2)
    # Another coordinator (another sender) takes over.
    assert [t for t, *_ in read(core, status(12, sender="coordinator-b"), 1.0)][:2] == [
        "units/u1/connection",
        "units/u1/factsheet",
    ]
    assert core.announcements == 2


def test_nothing_is_told_while_disconnected_nor_on_the_way_out_and_each_connection_anew() -> None:
    core = ready()
    core.offline()  # its clean stop's goodbye is made
    assert read(core, status(1), 0.3) == []
    core.on_disconnect(0.4)
    assert read(core, status(1), 0.45) == []  # (nothing arrives unconnected; nothing goes)
    core.will()
    core.on_connect(0.5)  # its own connect tells whoever listens: will seq 3, `online` 4
    # The retained status of that coordinator, read on subscribing: no news.
    assert read(core, status(1), 0.55, retained=True) == []
    # A coordinator started since: told, with fresh headers.
    assert [(t, p["header"]["seq"]) for t, p, *_ in read(core, status(0), 0.7)][:2] == [
        ("units/u1/connection", 5),
        ("units/u1/factsheet", 2),
    ]


def test_a_bad_or_cleared_status_tells_nothing() -> None:
    core = ready()
    assert read(core, b"", 0.3) == []
    ((topic, report, _, _),) = read(core, b"{", 0.31)
    assert topic == "errors" and report["reason"].startswith("CoordinatorStatus: malformed JSON")
    assert core.announcements == 0


def test_a_vda_5050_unit_is_told_again_to_a_new_coordinator_once_announced() -> None:
    c = vehicle_core()
    topic = VDA_TOPICS.fleet("coordinator")
    assert (topic, 0) in c.fleet_subscriptions()

    def status_of(seq: int, said: Said = "online") -> bytes:
        return encode(
            CoordinatorStatus(header=header("coordinator", seq), state=said, step_period_s=0.5)
        )

    # Not announced yet: its announcement, when it comes, tells the coordinator anyway.
    assert c.on_fleet(topic, status_of(1), 0.0) == []
    outs = vehicle_online(c)
    connection = VDA_TOPICS.unit("connection", "agv1")
    factsheet = VDA_TOPICS.unit("factsheet", "agv1")
    assert [o.topic for o in outs if o.topic in (connection, factsheet)] == [connection, factsheet]
    assert c.on_fleet(topic, status_of(2), 1.0) == []  # the same session
    # The coordinator restarted: its will, then its new `online`.
    assert c.on_fleet(topic, status_of(2, "broken"), 1.5) == []
    again = c.on_fleet(topic, status_of(1), 2.0)
    assert [(o.topic, o.qos, o.retain) for o in again] == [
        (connection, 1, True),
        (factsheet, 1, True),
        (VDA_TOPICS.unit("state", "agv1"), 0, True),
    ]
    said = [published([o])[0][1] for o in again[:2]]
    assert said[0]["state"] == "online" and said[0]["header"]["seq"] == 1  # fresh headers
    assert said[1]["capacity_kg"] == 20.0 and said[1]["header"]["seq"] == 1
    assert c.on_fleet(topic, status_of(1), 2.1) == []  # once per session
    # The vehicle gone: its unit is not announced, and a new coordinator is told nothing.
    c.on_vehicle("connection", vehicle_connection("CONNECTIONBROKEN"), 3.0)
    c.on_fleet(topic, status_of(3, "offline"), 3.5)
    assert c.on_fleet(topic, status_of(1), 4.0) == []
