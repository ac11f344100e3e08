"""The soak's oracle on made-up event streams: a clean one passes, each bad one fails its check."""

from __future__ import annotations

from pathlib import Path

from gridfleet.bench.soak.check import (
    Disturbed,
    Event,
    Held,
    JobSeen,
    Released,
    SoakLimits,
    StateSeen,
    Stop,
    Truth,
    check,
)
from gridfleet.bench.soak.run import hall_stops
from gridfleet.protocol import Topics

LIMITS = SoakLimits(step_s=0.1, stranded_s=5.0)
HOME = {"u1": (0, 0), "u2": (5, 5)}


def truth(t: float, pid: int = 1, collisions: int = 0, **moved: tuple[int, int]) -> Truth:
    """A truth sample: both units at home unless moved."""
    return Truth(t, pid, collisions, {**HOME, **moved})


def clean() -> list[Event]:
    """A run where nothing goes wrong: a stop held still, one job done, units idle at the end."""
    return [
        truth(0.0),
        truth(0.1, u1=(1, 0)),
        Stop(1.0, True),
        truth(1.05, u1=(2, 0)),  # within the grace: the unit had not read the stop yet
        truth(1.3, u1=(2, 0)),
        truth(1.9, u1=(2, 0)),
        Stop(2.0, False),
        truth(2.1, u1=(3, 0)),
        JobSeen(0.0, "j1", "queued"),
        JobSeen(0.5, "j1", "to_pickup"),
        JobSeen(3.0, "j1", "done"),
        JobSeen(0.0, "j2", "rejected"),
        StateSeen(0.0, "u1", (0, 0), True),
        StateSeen(3.0, "u1", (3, 0), False),
    ]


def test_a_clean_run_passes() -> None:
    verdict = check(clean(), LIMITS)
    assert verdict.ok, verdict.details
    assert (verdict.jobs_submitted, verdict.jobs_done) == (2, 1)


def test_a_collision_fails_and_every_process_run_counts() -> None:
    # The second units process counts from zero again: 2 + 1, not max.
    events = [*clean(), truth(0.2, pid=1, collisions=2), truth(5.0, pid=2, collisions=1)]
    verdict = check(events, LIMITS)
    assert verdict.collisions == 3 and not verdict.ok


def test_a_move_while_stopped_fails() -> None:
    events = [*clean(), truth(1.6, u1=(2, 0), u2=(5, 6))]
    verdict = check(events, LIMITS)
    assert verdict.moved_while_stopped == 1 and not verdict.ok
    assert "u2 moved" in verdict.details[0]


def test_a_teleport_by_a_restarted_units_process_while_stopped_fails() -> None:
    events = [*clean(), truth(1.6, pid=2, u1=(0, 0))]  # back to its start
    assert check(events, LIMITS).moved_while_stopped == 1


def test_a_stop_still_engaged_at_the_end_lasts() -> None:
    events: list[Event] = [truth(0.0), Stop(1.0, True), truth(1.5), truth(9.0, u1=(0, 1))]
    assert check(events, LIMITS).moved_while_stopped == 1


def test_a_move_after_the_release_the_listener_heard_late_passes() -> None:
    # The 30-minute soak: the listener, behind the whole fleet's traffic, saw the release 1.7 s
    # after the operator gave it; the units moved on it at once.
    events: list[Event] = [
        truth(0.0),
        Stop(1.0, True),
        truth(1.5),
        Released(2.0),
        truth(2.1, u1=(1, 0)),
        truth(3.5, u1=(2, 0)),
        Stop(3.7, False),
    ]
    assert check(events, LIMITS).ok


def test_a_move_before_a_release_given_again_fails() -> None:
    # The first release did not take (a press still held); moves before the second one count.
    events: list[Event] = [
        truth(0.0),
        Stop(1.0, True),
        Released(2.0),
        truth(2.5),
        truth(3.0, u1=(1, 0)),
        Released(7.0),
        truth(7.5, u1=(2, 0)),
        Stop(8.0, False),
    ]
    verdict = check(events, LIMITS)
    assert verdict.moved_while_stopped == 1
    assert "moved [0, 0] -> [1, 0] at 3.00" in verdict.details[0]


def test_a_move_after_the_coordinators_stamped_release_passes_though_released_again() -> None:
    # The aedes soak: the listener sat on a restarted node and heard the release 40 s late; the
    # soak released again and again meanwhile. The coordinator's status, stamped 2.3 and heard
    # late, says when it let the fleet go: the moves after it are no moves in a stop.
    events: list[Event] = [
        truth(0.0),
        Stop(1.0, True),
        truth(1.5),
        Released(2.0),
        Held(2.3, False),
        truth(3.0, u1=(1, 0)),
        Released(7.0),
        truth(7.5, u1=(2, 0)),
        Released(12.0),
        Stop(40.0, False),
    ]
    assert check(events, LIMITS).ok


def test_a_release_the_coordinator_stamped_before_any_operator_gave_one_is_no_release() -> None:
    # Only an operator's release lets the fleet go: a coordinator letting go before it is a
    # fault the checks must see, not a window's end.
    events: list[Event] = [
        truth(0.0),
        Stop(1.0, True),
        truth(1.5),
        Held(1.8, False),
        truth(3.0, u1=(1, 0)),
        Released(7.0),
        truth(7.5, u1=(2, 0)),
        Stop(8.0, False),
    ]
    verdict = check(events, LIMITS)
    assert verdict.moved_while_stopped == 1
    assert "moved [0, 0] -> [1, 0] at 3.00" in verdict.details[0]


def test_a_bridged_halls_units_are_judged_from_when_its_broker_had_the_stop() -> None:
    # Central stop at 1.0; the hall's broker had it at 1.8 (a thin bridge): a move at 1.5 is the
    # bridge's delay, told apart; a move at 2.5, once the hall had it, fails.
    before = [
        truth(0.0),
        Stop(1.0, True),
        Stop(1.8, True, "hall"),
        truth(1.3),
        truth(1.5, u1=(1, 0)),
    ]
    after = [
        truth(1.9, u1=(1, 0)),
        truth(2.2, u1=(1, 0)),
        Stop(4.0, False),
        Stop(4.2, False, "hall"),
    ]
    verdict = check([*before, *after], LIMITS)
    assert (verdict.moved_while_stopped, verdict.moved_before_the_hall_had_it) == (0, 1)
    assert verdict.ok and verdict.worst_stop_to_hall_s == 0.8
    late = check([*before, *after, truth(2.5, u1=(2, 0))], LIMITS)
    assert (late.moved_while_stopped, late.moved_before_the_hall_had_it) == (1, 1)
    assert not late.ok and "u1 moved [1, 0] -> [2, 0] at 2.50" in late.details[0]


def test_a_lost_job_fails() -> None:
    events = [*clean(), JobSeen(1.0, "j3", "queued"), JobSeen(2.0, "j3", "to_pickup")]
    verdict = check(events, LIMITS)
    assert verdict.jobs_lost == 1 and not verdict.ok
    assert verdict.jobs_submitted == 3


def test_a_job_done_twice_fails() -> None:
    events = [*clean(), JobSeen(4.0, "j1", "to_dropoff"), JobSeen(5.0, "j1", "done")]
    verdict = check(events, LIMITS)
    assert verdict.jobs_duplicated == 1 and not verdict.ok


def test_a_job_that_ends_two_ways_fails() -> None:
    events = [*clean(), JobSeen(4.0, "j1", "cancelled")]
    assert check(events, LIMITS).jobs_duplicated == 1


def test_a_stranded_unit_fails() -> None:
    events = [*clean(), *(StateSeen(4.0 + n, "u2", (5, 5), True) for n in range(7))]
    verdict = check(events, LIMITS)
    assert verdict.units_stranded == 1 and not verdict.ok


def test_standing_still_through_faults_and_stops_is_not_stranded() -> None:
    # 6 s busy on one square, but 2 s of it disturbed by a fault and 1 s stopped: 3 s is fine.
    events = [
        *clean(),
        *(StateSeen(4.0 + n, "u2", (5, 5), True) for n in range(7)),
        Disturbed(5.0, 7.0),
        Stop(8.0, True),
        Stop(9.0, False),
    ]
    assert check(events, LIMITS).units_stranded == 0


def test_an_idle_unit_standing_still_is_not_stranded() -> None:
    events = [*clean(), *(StateSeen(4.0 + n, "u2", (5, 5), False) for n in range(20))]
    assert check(events, LIMITS).units_stranded == 0


def test_the_hall_watchers_lines_give_the_stop_as_the_hall_had_it(tmp_path: Path) -> None:
    # mosquitto_sub -F '%U %t %p' in the hall: a press held, the latch, both gone; junk skipped.
    t = Topics("soak")
    lines = [
        f"100.5 {t.fleet('estop')} released|operator|soak",
        f"101.0 {t.device('device_stop', 'dev1')} engaged|dev1|button",
        "not a line",
        f"102.0 {t.fleet('estop')} engaged|operator|soak",
        f"103.0 {t.device('device_stop', 'dev1')} ",  # the press cleared (empty, retained)
        f"104.0 {t.fleet('estop')} released|operator|soak",
    ]
    watched = tmp_path / "hall-stop.txt"
    watched.write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert hall_stops(watched, t) == [Stop(101.0, True, "hall"), Stop(104.0, False, "hall")]
    assert hall_stops(tmp_path / "none.txt", t) == []
