"""The stop the coordinator holds across a failover to another broker: exactly what it publishes.

protocol.md §5.1, "Across a broker's death": a broker that shares nothing with the one before (or
a cluster node whose retained messages are its own, RabbitMQ's) may hold a stale `released`, or
no latch at all. Neither releases the fleet the coordinator holds stopped: it puts the latch back
(retained, QoS 1) and an operator releases again. A live release is taken as ever.
"""

from __future__ import annotations

import logging

import pytest
from test_coordinator_effects import ESTOP, GRID, PRESS, STATUS, state, status, under_way

from gridfleet.coordinator.core import CoordinatorCore

from support.coordinator_drive import TOPICS, from_unit, make_core, meet, orders_in
from support.effects import published

STALE = b"released|operator-cli-1|checked, long ago"
HELD = b"engaged|ann-page-1|STOP pressed on the page"
LINE = (
    "emergency stop held: the retained latch on the broker failed over to says released by "
    "operator-cli-1, which is no release; re-asserted (ann-page-1)"
)


@pytest.fixture
def core() -> CoordinatorCore:
    """Connected, unit1 online at [0, 0] and under way, then the stop engaged at 1.5 s."""
    c = make_core(GRID)
    c.on_connect()
    meet(c, state(), capacity_kg=5.0)
    under_way(c)
    c.on_message(ESTOP, HELD, 1.5)
    assert c.estop
    return c


def latch(core: CoordinatorCore, payload: bytes, now: float, *, retained: bool) -> object:
    return core.on_message(ESTOP, payload, now, retained=retained)


def test_a_stale_released_latch_on_the_broker_failed_over_to_is_re_asserted_not_taken(
    core: CoordinatorCore,
) -> None:
    core.on_connect(10.0, moved=True)
    effects = core.on_message(ESTOP, STALE, 10.1, retained=True)
    assert published(effects) == [(ESTOP, HELD.decode(), 1, True)]  # nothing else: no release
    assert effects.log == ((logging.WARNING, LINE),)
    assert core.estop
    back = state(seq=1, status="stopped")  # unit1 is back on this broker, and stopped
    from_unit(core, "state", "unit1", back, 10.3)
    assert [o.released for o in orders_in(core.step(10.5)).values()] == [[]]
    # The copy it put back comes to it live: idempotent. Nothing is re-asserted a second time.
    assert published(core.on_message(ESTOP, HELD, 10.2)) == []
    assert ESTOP not in [o.topic for o in core.step(12.0).publish]
    # An operator's release on this broker, live, releases as ever.
    released = core.on_message(ESTOP, b"released|operator-cli-2|area checked", 13.0)
    assert published(released)[-1] == (
        STATUS,
        status(2, "online", step=3, estop=False, achieved=9.5),
        1,
        True,
    )
    assert not core.estop


def test_the_same_stale_latch_on_a_reconnect_to_the_same_broker_is_an_operators_release(
    core: CoordinatorCore,
) -> None:
    # One broker: what it kept is the fleet's latch (an operator released it while we were away).
    core.on_connect(10.0, moved=False)
    effects = core.on_message(ESTOP, STALE, 10.1, retained=True)
    assert ESTOP not in [o.topic for o in effects.publish] and not core.estop


def test_a_live_release_right_after_a_failover_is_taken(core: CoordinatorCore) -> None:
    # The broker had no latch (not retained: nothing replayed); an operator releases at once.
    core.on_connect(10.0, moved=True)
    core.on_message(ESTOP, b"released|operator-cli-2|area checked", 10.1, retained=False)
    assert not core.estop


def test_only_the_first_latch_of_a_failover_session_is_read_as_the_brokers_kept_one(
    core: CoordinatorCore,
) -> None:
    # A broker that marked live messages retained must not keep a release from ever being taken.
    core.on_connect(10.0, moved=True)
    core.on_message(ESTOP, HELD, 10.1, retained=True)  # agrees: taken, and the latch is answered
    core.on_message(ESTOP, b"released|operator-cli-2|area checked", 11.0, retained=True)
    assert not core.estop


def test_a_retained_engaged_latch_after_a_failover_is_taken_whoever_it_names(
    core: CoordinatorCore,
) -> None:
    core.on_connect(10.0, moved=True)
    effects = core.on_message(ESTOP, b"engaged|dev1|button", 10.1, retained=True)
    assert ESTOP not in [o.topic for o in effects.publish] and core.estop
    assert ESTOP not in [o.topic for o in core.step(12.0).publish]


def test_a_stale_latch_after_a_failover_with_only_a_press_holding_latches_the_press() -> None:
    c = make_core(GRID)
    c.on_connect()
    c.on_message(ESTOP, b"released|operator-cli-1|earlier", 1.0)
    press = c.on_message(PRESS, b"engaged|dev1|button", 1.5)  # mirrored into the latch ...
    assert published(press)[0] == (ESTOP, "engaged|dev1|button", 1, True)
    c.on_connect(10.0, moved=True)  # ... on the broker that died before the mirror came back
    effects = c.on_message(ESTOP, STALE, 10.1, retained=True)
    assert published(effects) == [(ESTOP, "engaged|dev1|button", 1, True)]
    assert c.estop


@pytest.mark.parametrize("moved", [True, False], ids=["failover", "same broker"])
def test_a_broker_that_answers_with_no_latch_gets_the_held_latch_again(
    core: CoordinatorCore, moved: bool
) -> None:
    # The broker answers (the coordinator's own status comes back: it is no dead link) but
    # has no latch: one that never saw it (a failover), or one that lost it.
    core.on_connect(10.0, moved=moved)
    own = core.status("online")
    core.on_message(own.topic, own.payload, 10.05, retained=True)
    core.on_message(TOPICS.unit("state", "unit1"), b"", 10.06, retained=True)  # cleared: nothing
    assert ESTOP not in [o.topic for o in core.step(10.5).publish]  # it may still arrive
    effects = core.step(11.0)
    assert published(effects)[0] == (ESTOP, HELD.decode(), 1, True)
    assert (logging.WARNING, "emergency stop re-asserted on the broker (ann-page-1)") in effects.log
    assert core.estop
    assert ESTOP not in [o.topic for o in core.step(12.0).publish]  # once


def test_a_press_replayed_by_the_broker_failed_over_to_keeps_the_fleet_stopped() -> None:
    c = make_core(GRID)
    c.on_connect()
    c.on_message(ESTOP, b"released|operator-cli-1|earlier", 1.0)
    c.on_connect(10.0, moved=True)
    c.on_message(ESTOP, b"released|operator-cli-1|earlier", 10.1, retained=True)  # agrees
    effects = c.on_message(PRESS, b"engaged|dev1|button", 10.2, retained=True)
    assert published(effects)[0] == (ESTOP, "engaged|dev1|button", 1, True)
    assert c.estop
    assert [m[0] for m in published(effects)][1:] == [STATUS]  # no unit yet: no halt order


def test_the_coordinators_own_time_off_the_broker_is_no_units_silence() -> None:
    # Everyone's broker died: the units' states stopped while the coordinator was off it too.
    c = make_core(GRID)
    c.on_connect()
    meet(c, state(), capacity_kg=5.0)
    c.on_connect(10.0, moved=True)  # back after 10 s on the next broker, unit1 not heard yet
    assert set(orders_in(c.step(10.5))) == {"unit1"}  # not lost: its timeout counts from 10 s
    timeout = c.world.stale_after_s(c.world.units["unit1"])
    assert orders_in(c.step(10.0 + timeout + 0.1)) == {}  # silent that long since: lost
