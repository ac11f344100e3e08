"""A unit sets its own `connection` right (protocol.md §4.1): exact messages, no broker.

A clustered broker leaves the last wills of a node that dies to a survivor, which may publish
them seconds to minutes later, when the unit is online on another node: the old session's
`broken` would then stand as the unit's record. While connected, a unit that reads its own
`connection` saying anything but `online` says `online` again; never in a loop, never on its way
out. Exact messages, as tests/robots/test_robots_effects.py pins them.
"""

from __future__ import annotations

from typing import Literal

from test_robots_effects import ROOT, error, make, ready
from test_vda5050_core import TOPICS as VDA_TOPICS
from test_vda5050_core import connection as vehicle_connection
from test_vda5050_core import core as vehicle_core
from test_vda5050_core import online as vehicle_online

from gridfleet.protocol import Connection, encode

from support.effects import header, header_json, published

CONNECTION = ROOT + "units/u1/connection"
Link = Literal["online", "offline", "broken"]


def said(state: Link, seq: int = 0, sender: str = "u1") -> bytes:
    """A `connection` payload of u1's (seq 0: the will of its first connection, say)."""
    return encode(Connection(header=header(sender, seq), state=state))


def online(seq: int) -> tuple[str, object, int, bool]:
    """u1's `online`, retained at QoS 1, with a header of its own stamper."""
    return ("units/u1/connection", {"header": header_json("u1", seq), "state": "online"}, 1, True)


def test_a_unit_follows_its_own_connection_in_either_mode() -> None:
    own = ("gf/v1/units/u1/connection", 0)
    assert own in make().subscriptions() and own in make("standalone").subscriptions()


def test_a_stale_will_read_while_connected_is_answered_with_online_and_a_fresh_header() -> None:
    core = ready()  # its will seq 0, its `online` seq 1
    # The old session's will (seq 0), published late by a surviving node of the cluster.
    assert published(core.on_message(CONNECTION, said("broken"), 0.3), ROOT) == [online(2)]
    assert core.connection_corrections == 1
    # Its own `online` read back changes nothing: no loop.
    assert core.on_message(CONNECTION, said("online", 2), 0.31) == []
    # A second late will (another node's copy) is set right again, the header fresh again.
    assert published(core.on_message(CONNECTION, said("broken"), 0.4), ROOT) == [online(3)]
    assert core.connection_corrections == 2


def test_a_retained_offline_or_broken_found_on_subscribing_is_set_right() -> None:
    for state in ("offline", "broken"):
        core = ready()
        # What the broker kept from an earlier run of the unit, replayed after its `online`.
        assert published(core.on_message(CONNECTION, said(state, 7), 0.25), ROOT) == [online(2)]


def test_nothing_is_set_right_while_disconnected_or_on_the_way_out() -> None:
    core = ready()
    core.on_disconnect(0.3)
    assert core.on_message(CONNECTION, said("broken"), 0.35) == []  # the next connect says it
    core.will()
    core.on_connect(0.4)  # will seq 2, online seq 3
    goodbye = core.offline()  # its clean stop: `offline`, seq 4, read back as it disconnects
    assert published([goodbye], ROOT)[0][1]["header"]["seq"] == 4
    assert core.on_message(CONNECTION, goodbye.payload, 0.45) == []
    assert core.connection_corrections == 0
    core.on_connect(0.5)  # a new session sets right again
    assert published(core.on_message(CONNECTION, said("broken"), 0.55), ROOT) == [online(6)]


def test_a_cleared_record_is_left_alone_and_a_bad_one_reported() -> None:
    core = ready()
    assert core.on_message(CONNECTION, b"", 0.3) == []  # a removed unit's clear (§6.11)
    assert published(core.on_message(CONNECTION, b"{", 0.31), ROOT) == [
        error(
            0,
            "units/u1/connection",
            "Connection: malformed JSON (Invalid JSON: EOF while parsing an object at line 1 "
            "column 1)",
        )
    ]
    assert core.connection_corrections == 0


def test_another_units_connection_is_none_of_its_business() -> None:
    core = ready()
    assert core.on_message(ROOT + "units/u2/connection", said("broken", sender="u2"), 0.3) == []


def test_a_vda_5050_vehicles_unit_sets_its_connection_right_while_announced() -> None:
    c = vehicle_core()
    topic = VDA_TOPICS.unit("connection", "agv1")
    assert (topic, 0) in c.fleet_subscriptions()
    stale = encode(Connection(header=header("agv1"), state="broken"))
    assert c.on_fleet(topic, stale, 0.0) == []  # not announced yet: nothing to set right
    outs = vehicle_online(c)
    assert [o.topic for o in outs if o.topic == topic] == [topic]  # announced `online`
    again = c.on_fleet(topic, stale, 1.0)
    assert [(o.topic, o.qos, o.retain) for o in again] == [(topic, 1, True)]
    assert c.on_fleet(topic, again[0].payload, 1.1) == []  # its own `online` read back
    # The vehicle gone: its unit's own `broken`, read back, is not set right.
    (gone,) = c.on_vehicle("connection", vehicle_connection("CONNECTIONBROKEN"), 2.0)
    assert c.on_fleet(topic, gone.payload, 2.1) == []
