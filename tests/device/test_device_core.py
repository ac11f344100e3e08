"""The virtual device's pure core: LEDs from direction and estop, the stop key, bad input."""

from __future__ import annotations

import pytest

from gridfleet.device.core import DeviceCore
from gridfleet.device.terminal import render_plain
from gridfleet.protocol import EstopSignal, Leds, Topics, encode_estop

from support.effects import header_json, published, stamper

T = Topics("t/logic")
DIR = T.unit("direction", "unit1")
ESTOP = T.fleet("estop")
PRESS = T.device("device_stop", "dev1")


def online_logic() -> DeviceCore:
    logic = DeviceCore(T, "unit1", "dev1", retry_s=1.0)
    logic.connected()
    return logic


@pytest.mark.parametrize("side", ["N", "E", "S", "W"])
def test_each_direction_lights_exactly_its_led(side: str) -> None:
    logic = online_logic()
    assert logic.on_message(DIR, side.encode()) is None
    lit = [s for s in "NESW" if getattr(logic.leds, s)]
    assert lit == [side]
    assert logic.pattern == "direction"


def test_no_move_lights_nothing() -> None:
    logic = online_logic()
    logic.on_message(DIR, b"E")
    logic.on_message(DIR, b"-")
    assert logic.leds == Leds()


def test_stop_wins_over_direction_until_released() -> None:
    logic = online_logic()
    logic.on_message(DIR, b"S")
    logic.on_message(ESTOP, b"engaged|dashboard|operator pressed STOP")
    assert logic.pattern == "stop" and logic.leds == Leds(N=True, E=True, S=True, W=True)
    logic.on_message(DIR, b"W")  # direction changes underneath still do not show
    assert logic.pattern == "stop"
    logic.on_message(ESTOP, b"released|dashboard|checked")
    assert logic.leds == Leds(W=True)


def test_offline_shows_nothing_but_the_stop_still_shows() -> None:
    logic = online_logic()
    logic.on_message(DIR, b"N")
    logic.disconnected()
    assert logic.pattern == "offline" and logic.leds == Leds()
    logic.press()
    assert logic.pattern == "stop"


@pytest.mark.parametrize(
    ("topic", "payload"),
    [
        (DIR, b"X"),
        (DIR, b"NE"),
        (DIR, b""),
        (DIR, b"N" * 100_000),
        (ESTOP, b"stop"),
        (ESTOP, b"released"),
        (ESTOP, b"released||reason"),
        (ESTOP, b"released|a|two\nlines"),
        (ESTOP, b"released|a|\xff\xfe"),
        (ESTOP, b"released|a|" + b"x" * 600),
        (T.unit("direction", "unit2"), b"N"),
        (T.unit("state", "unit1"), b"{}"),
        ("other/v1/fleet/estop", b"released|a|b"),
        (PRESS, b"released|dev1|button"),  # a press cannot release
        (PRESS, b"engaged|dev2|button"),  # nor name another source
        (T.device("device_stop", "dev2"), b"engaged|dev2|button"),
    ],
)
def test_bad_or_unexpected_messages_change_nothing(topic: str, payload: bytes) -> None:
    logic = online_logic()
    logic.on_message(DIR, b"E")
    logic.on_message(ESTOP, b"engaged|dashboard|x")
    before = (logic.direction, logic.estop, logic.leds, logic.pending_stop)
    refusal = logic.on_message(topic, payload)
    assert refusal is not None and refusal.topic == topic and refusal.reason
    assert (logic.direction, logic.estop, logic.leds, logic.pending_stop) == before


def test_press_is_pending_until_its_own_engaged_comes_back() -> None:
    logic = online_logic()
    assert not logic.stop_due(0.0)
    logic.press()
    logic.press()  # a second press while pending is the same stop
    assert logic.stop_due(10.0)
    assert logic.stop_payload == encode_estop(EstopSignal(True, "dev1", "button"))
    logic.stop_sent(10.0)
    assert not logic.stop_due(10.5)
    assert logic.next_stop_in(10.5) == pytest.approx(0.5)
    assert logic.stop_due(11.0)  # not seen yet: send again
    logic.on_message(ESTOP, b"engaged|dashboard|someone else")
    logic.on_message(ESTOP, logic.stop_payload)  # the coordinator's copy in the latch
    assert logic.pending_stop  # only our own press topic confirms the broker has it
    logic.on_message(PRESS, logic.stop_payload)
    assert not logic.pending_stop and not logic.stop_due(99.0)
    assert logic.next_stop_in(99.0) is None


def test_a_held_press_shows_the_stop_until_an_operator_release_clears_it() -> None:
    logic = online_logic()
    logic.on_message(DIR, b"E")
    logic.press()
    logic.on_message(PRESS, logic.stop_payload)
    assert logic.pattern == "stop"  # held, even before (or without) the coordinator's latch
    logic.on_message(ESTOP, b"released|dashboard|checked")  # released, but not yet cleared
    assert logic.pattern == "stop"
    logic.on_message(PRESS, b"")  # the coordinator clears the press after the release
    assert logic.pattern == "direction" and logic.leds == Leds(E=True)


def test_press_while_offline_is_sent_on_the_next_session() -> None:
    logic = online_logic()
    logic.disconnected()
    logic.press()
    assert not logic.stop_due(0.0)
    logic.connected()
    assert logic.stop_due(0.0)
    logic.stop_sent(0.0)
    logic.disconnected()
    logic.connected()
    assert logic.stop_due(0.1)  # a new session sends at once


def test_plain_rendering() -> None:
    logic = online_logic()
    logic.on_message(DIR, b"E")
    assert render_plain(logic) == "leds=.#.. direction=E estop=unknown link=online"
    logic.press()
    assert render_plain(logic) == ("leds=#### direction=E estop=unknown link=online stop=pending")


def test_bad_ids_are_refused() -> None:
    with pytest.raises(Exception, match="unit id"):
        DeviceCore(T, "unit/1", "dev1")
    with pytest.raises(Exception, match="device id"):
        DeviceCore(T, "unit1", "")


# ---- exactly what the core publishes for each input (no broker) ------------------------------


def stamped_logic() -> DeviceCore:
    """An online device whose headers carry a fixed time, so payloads can be compared whole."""
    logic = DeviceCore(T, "unit1", "dev1", retry_s=1.0, stamp=stamper("dev1"))
    logic.connected()
    return logic


def report(seq: int, topic: str, reason: str) -> dict[str, object]:
    return {
        "header": header_json("dev1", seq),
        "topic": topic,
        "reason": reason,
        "request_id": None,
    }


def test_session_messages_are_exact() -> None:
    logic = stamped_logic()
    conn = T.device("device_connection", "dev1")
    assert logic.subscriptions() == [(DIR, 0), (ESTOP, 0), (PRESS, 0)]  # every one at QoS 0
    assert published([logic.connection(s) for s in ("online", "offline", "broken")]) == [
        (conn, "online", 1, True),
        (conn, "offline", 1, True),
        (conn, "broken", 1, True),
    ]


def test_good_direction_and_stop_publish_nothing() -> None:
    logic = stamped_logic()
    assert logic.receive(DIR, b"E") == []
    assert logic.receive(ESTOP, b"engaged|dashboard|x") == []
    assert logic.refused == []


@pytest.mark.parametrize(
    ("topic", "payload", "reason"),
    [
        (ESTOP, b"released", "estop"),
        (DIR, b"Q", "direction"),
        (DIR, b"N" * 100, "too long"),
        (T.unit("state", "unit1"), b"{}", "does not expect messages on state"),
        ("elsewhere/x", b"", "elsewhere/x"),
    ],
)
def test_each_refused_message_is_reported_once_on_errors(
    topic: str, payload: bytes, reason: str
) -> None:
    logic = stamped_logic()
    before = logic.leds
    out = published(logic.receive(topic, payload))
    assert len(out) == 1
    where, body, qos, retain = out[0]
    assert (where, qos, retain) == (T.fleet("errors"), 1, False)
    assert isinstance(body, dict) and reason in str(body["reason"])
    assert body == report(0, topic, str(body["reason"]))
    assert logic.leds == before and len(logic.refused) == 1


def test_a_press_is_sent_at_once_then_every_retry_until_it_comes_back() -> None:
    logic = stamped_logic()
    stop = (PRESS, "engaged|dev1|button", 1, True)
    assert logic.due(0.0) == []  # nothing pending
    logic.press()
    assert published(logic.due(10.0)) == [stop]
    assert logic.due(10.5) == []
    assert published(logic.due(11.0)) == [stop]
    logic.disconnected()
    assert logic.due(11.5) == []  # nothing can be sent while offline
    logic.connected()
    assert published(logic.due(11.6)) == [stop]  # a new session sends it at once
    assert logic.receive(PRESS, b"engaged|dev1|button") == []
    assert logic.due(20.0) == []  # confirmed: no more sends


def test_a_press_cleared_while_offline_is_not_shown_after_reconnecting() -> None:
    logic = online_logic()
    logic.on_message(DIR, b"E")
    logic.press()
    logic.on_message(PRESS, logic.stop_payload)
    logic.disconnected()  # meanwhile an operator releases and the press is cleared
    logic.connected()
    logic.on_message(ESTOP, b"released|operator|checked")  # retained; no press is replayed
    assert logic.pattern == "direction" and logic.leds == Leds(E=True)
