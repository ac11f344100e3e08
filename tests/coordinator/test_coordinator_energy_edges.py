"""The energy policy at its edges (coordinator/energy.py, protocol.md §5.9): where a low unit may
be sent, a charger that does not charge, units that cannot make way, a restart while units charge,
a charge not known, an empty battery, jobs on chargers, and the one rule every step keeps (each
unit with a battery either has a limit or takes no job).

Most tests drive the pure policy with batteries on an open plane (Manhattan distances); those
that concern what the core hands it (positions of units that cannot make way, states, requests)
drive the core (support/energy_drive.py).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gridfleet.coordinator.chargers import ChargerBook
from gridfleet.coordinator.energy import (
    CHARGE_START_MIN_S,
    CHARGE_START_STEPS,
    Battery,
    EnergyPolicy,
    EnergySettings,
    to_charger_pct,
)
from gridfleet.energy import ChargingSpec, thresholds_problem
from gridfleet.errors import ScenarioError
from gridfleet.grid import Cell
from gridfleet.protocol import Charger, Connection, EnergyModel
from gridfleet.scenario import load_scenario

from support.coordinator_drive import from_unit, orders_in
from support.effects import header
from support.energy_drive import C1, C2, acked, control, events, make, meet, plans, state, submit

M = EnergyModel(move_pct=1.0, idle_pct_per_s=0.0, charge_pct_per_s=5.0)
IDLE = EnergyModel(move_pct=1.0, idle_pct_per_s=0.01, charge_pct_per_s=5.0)


def plane(a: Cell, b: Cell) -> int:
    """Squares between `a` and `b` on an open plane."""
    return abs(a.x - b.x) + abs(a.y - b.y)


def policy(*chargers: tuple[str, Cell], **thresholds: float) -> EnergyPolicy:
    """The gridfleet policy over `chargers` (name, square), a step a second."""
    book = ChargerBook([Charger(name=n, square=sq) for n, sq in chargers])
    return EnergyPolicy(EnergySettings(**thresholds), book, 1.0)  # type: ignore[arg-type]


# ---- 1. a low unit goes only to a charger its charge reaches ----------------------------------


def test_a_low_unit_is_not_sent_to_a_free_charger_its_charge_does_not_reach() -> None:
    p = policy(("C1", Cell(0, 0)), ("C2", Cell(62, 0)))
    p.plan([Battery("a", Cell(1, 0), 40.0, M)], plane, 0.0)  # below good: C1
    charging = Battery("a", Cell(0, 0), 60.0, M, charging=True)
    low = Battery("b", Cell(2, 0), 21.0, M)  # below good; C2 is 60 squares off, it has 21 %
    step = p.plan([charging, low], plane, 1.0)
    assert "b" not in step.targets and p.queued == {"b": "C1"}
    assert "b" in step.limits  # not urgent: it may do a job it can finish while it waits
    urgent = Battery("c", Cell(2, 0), 5.0, M)
    step = p.plan([charging, urgent], plane, 2.0)
    assert "c" not in step.targets and "c" in step.unavailable and p.queued == {"c": "C1"}


def test_a_farther_free_charger_is_taken_when_the_unit_keeps_critical_on_its_way() -> None:
    p = policy(("C1", Cell(0, 0)), ("C2", Cell(20, 0)))
    p.plan([Battery("a", Cell(1, 0), 40.0, M)], plane, 0.0)
    charging = Battery("a", Cell(0, 0), 60.0, M, charging=True)
    # 18 squares to C2 need 1.25 x (18 + 3) + 1 = 27.25 %: 48 % keeps critical 20 % there.
    assert 48.0 - to_charger_pct(M, 18, 1.0) >= 20.0
    step = p.plan([charging, Battery("b", Cell(2, 0), 48.0, M)], plane, 1.0)
    assert step.targets["b"] == Cell(20, 0)
    p2 = policy(("C1", Cell(0, 0)), ("C2", Cell(20, 0)))
    p2.plan([Battery("a", Cell(1, 0), 40.0, M)], plane, 0.0)
    step = p2.plan([charging, Battery("b", Cell(2, 0), 47.0, M)], plane, 1.0)  # 19.75 % left
    assert "b" not in step.targets and p2.queued == {"b": "C1"}


def test_a_unit_at_critical_displaces_only_a_charging_unit_within_its_reach() -> None:
    p = policy(("C1", Cell(0, 0)), ("C2", Cell(40, 0)))
    p.plan([Battery("a", Cell(1, 0), 40.0, M), Battery("x", Cell(39, 0), 40.0, M)], plane, 0.0)
    p.force("a")  # charging to full for an operator: not to be displaced
    a = Battery("a", Cell(0, 0), 85.0, M, charging=True)
    x = Battery("x", Cell(40, 0), 85.0, M, charging=True)  # above sufficient, 37 squares off
    b = Battery("b", Cell(3, 0), 9.0, M)  # critical, 3 squares from C1
    step = p.plan([a, x, b], plane, 1.0)
    assert "b" not in step.targets and p.queued == {"b": "C1"} and "b" in step.unavailable
    assert p.chargers.holder("C2") == "x"


def test_a_unit_that_makes_way_at_its_charger_gets_its_limit_that_step() -> None:
    p = policy(("C1", Cell(0, 0)), available_from="full")  # type: ignore[arg-type]
    p.plan([Battery("a", Cell(1, 0), 40.0, M)], plane, 0.0)
    a = Battery("a", Cell(0, 0), 85.0, M, charging=True)  # above sufficient, below full
    step = p.plan([a, Battery("b", Cell(3, 0), 9.0, M)], plane, 1.0)
    assert step.targets == {"b": Cell(0, 0)}
    assert "a" in step.limits and "a" not in step.unavailable


# ---- 2. a charger that does not charge ---------------------------------------------------------


def stand(p: EnergyPolicy, unit: Battery, steps: int, start: float = 1.0) -> list[float]:
    """`unit` stands `steps` steps (a second each) from `start`; the times."""
    times = [start + n for n in range(steps)]
    for t in times:
        p.plan([unit], plane, t)
    return times


def test_a_unit_on_a_charger_that_never_charges_frees_it_and_is_stranded_in_words() -> None:
    p = policy(("C1", Cell(0, 0)))
    p.plan([Battery("a", Cell(2, 0), 40.0, IDLE)], plane, 0.0)
    on = Battery("a", Cell(0, 0), 39.0, IDLE)  # arrived; its state never says it charges
    grace = max(CHARGE_START_STEPS, int(CHARGE_START_MIN_S)) + 1
    stand(p, on, grace - 1)
    assert p.last.standing == {"a"} and p.chargers.holder("C1") == "a"  # within the grace
    p.take_news()
    step = p.plan([on], plane, float(grace + 1))
    assert p.chargers.holder("C1") is None and "a" not in step.standing
    (news,) = p.take_news()
    assert (news.event, news.reason) == ("cancelled", "charger C1 does not charge it")
    assert p.units_view()["a"].plan == "stranded"
    assert p.stranded == {
        "a": "charger C1 does not charge it; no other charger can be reached from [0, 0]"
    }
    assert "a" in step.limits and step.limits["a"].stranded
    assert p.cannot_charge("a", Cell(0, 0), 39.0, plane) is None  # `charge` is not refused:
    p.force("a")  # an operator's `charge` tries it again
    assert p.plan([on], plane, float(grace + 2)).targets == {"a": Cell(0, 0)}


def test_a_unit_whose_charger_does_not_charge_it_tries_another_once() -> None:
    p = policy(("C1", Cell(0, 0)), ("C2", Cell(3, 0)))
    p.plan([Battery("a", Cell(0, 1), 40.0, IDLE)], plane, 0.0)
    on = Battery("a", Cell(0, 0), 39.0, IDLE)
    times = stand(p, on, 40)
    assert p.last.targets == {"a": Cell(3, 0)}  # the same step C1 gave up: to C2
    assert p.refused == {"a": {"C1"}}
    p.plan([Battery("a", Cell(3, 0), 38.0, IDLE, charging=True)], plane, times[-1] + 1)
    assert p.refused == {} and p.last.standing == {"a"}  # it charges: C1 may be tried again


def test_a_unit_that_stops_charging_by_itself_below_full_leaves_its_charger() -> None:
    p = policy(("C1", Cell(0, 0)))
    p.plan([Battery("a", Cell(0, 0), 40.0, IDLE)], plane, 0.0)
    p.plan([Battery("a", Cell(0, 0), 41.0, IDLE, charging=True)], plane, 1.0)
    stand(p, Battery("a", Cell(0, 0), 85.0, IDLE), 40, start=2.0)
    ended = [n for n in p.take_news() if n.event == "ended"]
    assert [(n.reason, n.pct) for n in ended] == [("it stopped charging by itself at 85 %", 85.0)]
    assert p.chargers.holder("C1") is None and "a" in p.last.limits


# ---- 3. every unit with a battery: a limit, or no job ------------------------------------------


def test_a_unit_whose_charger_cannot_be_reached_any_more_gets_its_limit_that_step() -> None:
    p = policy(("C1", Cell(0, 0)), ("C2", Cell(5, 0)))
    p.plan([Battery("a", Cell(1, 0), 40.0, M)], plane, 0.0)

    def walled(a: Cell, b: Cell) -> int:  # C1 walled off now
        return 2**31 - 1 if Cell(0, 0) in (a, b) else plane(a, b)

    from gridfleet.paths import UNREACHABLE

    assert walled(Cell(1, 0), Cell(0, 0)) == UNREACHABLE
    step = p.plan([Battery("a", Cell(1, 0), 90.0, M)], walled, 1.0)
    assert "a" in step.limits and "a" not in step.unavailable and p.charges == {}


batteries = st.lists(
    st.builds(
        Battery,
        id=st.sampled_from(["a", "b", "c", "d", "e"]),
        position=st.builds(Cell, st.integers(0, 8), st.integers(0, 2)),
        pct=st.floats(0.0, 100.0),
        model=st.just(M),
        charging=st.booleans(),
        free=st.booleans(),
        job=st.booleans(),
        carrying=st.booleans(),
        held=st.booleans(),
        goal=st.booleans(),
        out_of_service=st.booleans(),
    ),
    max_size=5,
    unique_by=lambda b: b.id,
)


@settings(max_examples=120, deadline=None, derandomize=True, database=None)
@given(st.lists(batteries, min_size=1, max_size=6), st.sampled_from(["gridfleet", "naive"]))
def test_every_battery_is_limited_or_kept_from_jobs_and_no_charger_given_twice(
    steps: list[list[Battery]], name: str
) -> None:
    book = ChargerBook(
        [Charger(name="C1", square=Cell(0, 0)), Charger(name="C2", square=Cell(8, 2))]
    )
    p = EnergyPolicy(EnergySettings(policy=name), book, 1.0)  # type: ignore[arg-type]
    for n, units in enumerate(steps):
        step = p.plan(units, plane, float(n * 40))
        for b in units:
            assert (b.id in step.limits) != (b.id in step.unavailable), (b, step)
        holders = [book.holder(c.name) for c in book.chargers]
        held = [h for h in holders if h is not None]
        assert len(held) == len(set(held))
        assert set(held) == set(p.charges)
        assert set(step.standing) <= set(step.targets)


# ---- 4. a charger a unit that cannot make way stands on ----------------------------------------


def test_a_charger_a_paused_unit_stands_on_is_not_handed_out() -> None:
    core = make()
    meet(core, "u2", C1.square, None)
    core.directives.set_control("u2", "paused")
    meet(core, "u1", Cell(1, 1), 40.0)  # C1 is 2 squares off, C2 5: it reaches C2, critical
    assert orders_in(core.step(1.0))["u1"].charge == C2.square
    assert core.energy.chargers.holder("C1") is None
    only = make(chargers=(C1,))
    meet(only, "u2", C1.square, None)
    only.directives.set_control("u2", "paused")
    meet(only, "u1", Cell(1, 1), 40.0)
    assert orders_in(only.step(1.0))["u1"].charge is None
    assert only.energy.stranded == {
        "u1": "no charger is free to reach from [1, 1]: C1 is taken by u2, which cannot make way"
    }


def test_a_unit_sent_to_a_charger_a_lost_unit_now_stands_on_goes_elsewhere() -> None:
    core = make()
    meet(core, "u1", Cell(1, 1), 40.0)
    assert orders_in(core.step(1.0))["u1"].charge == C1.square
    meet(core, "u2", C1.square, None)  # put there by hand, then its link goes
    offline = Connection(header=header("u2"), state="offline")
    from_unit(core, "connection", "u2", offline, 1.5)
    from_unit(core, "state", "u1", state("u1", Cell(1, 1), 39.0, seq=1, **acked(core, "u1")), 1.5)
    effects = core.step(2.0)
    assert orders_in(effects)["u1"].charge != C1.square
    assert core.energy.chargers.holder("C1") is None
    assert (
        "unit u1 no longer sent to charge at C1: charger C1 is taken: u2 stands on it and "
        "cannot make way" in events(effects)
    )


# ---- 5. a lost unit's charge ends at its last known charge -------------------------------------


def test_a_charge_of_a_unit_no_longer_heard_ends_at_its_last_known_charge() -> None:
    p = policy(("C1", Cell(0, 0)))
    p.plan([Battery("a", Cell(0, 0), 40.0, M)], plane, 0.0)
    p.plan([Battery("a", Cell(0, 0), 41.0, M, charging=True)], plane, 1.0)
    p.plan([Battery("a", Cell(0, 0), 47.0, M, charging=True)], plane, 2.0)
    p.plan([], plane, 3.0)
    last = p.take_news()[-1]
    assert (last.event, last.pct, last.reason) == (
        "ended",
        47.0,
        "it no longer reports its charge",
    )


# ---- 6. an operator's charge -------------------------------------------------------------------


def test_an_operators_charge_for_a_unit_not_heard_this_step_is_kept_until_it_is() -> None:
    p = policy(("C1", Cell(0, 0)))
    p.force("a")
    p.plan([], plane, 0.0)
    assert "a" in p.plan([Battery("a", Cell(2, 0), 90.0, M)], plane, 1.0).targets


def test_control_unit_charge_is_refused_for_a_lost_unit_and_one_that_reaches_no_charger() -> None:
    core = make()
    meet(core, "u1", Cell(1, 1), 90.0)
    from_unit(core, "connection", "u1", Connection(header=header("u1"), state="offline"), 0.2)
    assert control(core, "u1") == (False, "unit u1 is not heard from")
    empty = make()
    meet(empty, "u1", Cell(2, 1), 0.0)
    empty.step(1.0)
    assert control(empty, "u1", now=1.5) == (
        False,
        "unit u1 cannot be sent to charge: battery empty at [2, 1]: cannot move; "
        "bring it to a charger",
    )


# ---- 7. good below full -------------------------------------------------------------------------


def test_good_equal_to_full_is_refused_so_a_charged_unit_is_not_sent_again_at_once() -> None:
    spec = ChargingSpec(critical_pct=20, good_pct=90, sufficient_pct=90, full_pct=90)
    assert thresholds_problem(spec) == (
        "good_pct must be below full_pct (a unit charged to full would be sent again at once), "
        "got good_pct 90 and full_pct 90"
    )
    with pytest.raises(ValueError, match="good_pct must be below full_pct"):
        make(settings=EnergySettings(critical_pct=20, good_pct=90, sufficient_pct=90, full_pct=90))
    assert thresholds_problem(ChargingSpec(20, 90, 90, 91)) is None


# ---- 9. a restart while units charge ------------------------------------------------------------


def test_after_a_restart_a_charging_unit_keeps_its_charger_and_none_is_sent_there() -> None:
    core = make()
    meet(core, "u1", C1.square, 60.0)
    from_unit(core, "state", "u1", state("u1", C1.square, 60.0, seq=1, charging=True), 0.1)
    meet(core, "u2", Cell(1, 0), 40.0)  # below good, nearest C1
    effects = core.step(1.0)
    orders = orders_in(effects)
    assert orders["u1"].charge == C1.square and orders["u2"].charge != C1.square
    assert core.energy.chargers.holder("C1") == "u1"
    assert plans(core)["u1"] == "charging"
    (started,) = effects.charges
    assert (started.unit, started.event, started.reason) == (
        "u1",
        "started",
        "found charging there",
    )


def test_a_unit_heard_charging_late_takes_its_charger_from_one_on_its_way() -> None:
    core = make()
    meet(core, "u2", Cell(1, 1), 40.0)
    assert orders_in(core.step(1.0))["u2"].charge == C1.square
    meet(core, "u1", C1.square, 60.0)
    from_unit(core, "state", "u1", state("u1", C1.square, 60.0, seq=1, charging=True), 1.2)
    orders = orders_in(core.step(2.0))
    assert orders["u1"].charge == C1.square and orders["u2"].charge != C1.square
    assert core.energy.chargers.holder("C1") == "u1"


# ---- 10. a charge not known ---------------------------------------------------------------------


def test_a_unit_with_energy_but_no_charge_in_its_state_takes_no_job_and_says_why() -> None:
    core = make()
    meet(core, "u1", Cell(1, 1), 50.0)
    from_unit(core, "state", "u1", state("u1", Cell(1, 1), None, seq=1), 0.1)
    submit(core, Cell(3, 1), Cell(4, 1))
    assert orders_in(core.step(1.0))["u1"].action is None
    job = core.jobs.jobs["j1"]
    assert (job.state, job.wait, job.wait_reason) == (
        "queued",
        "no_unit_free",
        "no unit that can carry 1.0 kg is free (u1 its charge is not known: its state reports none)",
    )
    from_unit(core, "state", "u1", state("u1", Cell(1, 1), 90.0, 2, **acked(core, "u1")), 1.5)
    assert orders_in(core.step(2.0))["u1"].action is not None


# ---- 11. an empty battery -----------------------------------------------------------------------


def test_an_empty_unit_on_a_charger_not_its_own_charges_where_it_stands() -> None:
    p = policy(("C1", Cell(0, 0)), ("C2", Cell(4, 0)))
    p.plan([Battery("a", Cell(2, 0), 30.0, M)], plane, 0.0)  # to C1 (ties: the first listed)
    assert p.charges["a"].charger == "C1"
    step = p.plan([Battery("a", Cell(4, 0), 0.0, M)], plane, 1.0)  # empty, on C2
    assert step.targets == {"a": Cell(4, 0)} and step.standing == {"a"}
    assert p.charges["a"].charger == "C2" and p.chargers.holder("C1") is None


def test_an_empty_unit_off_any_charger_is_stranded_and_frees_the_charger_it_was_sent_to() -> None:
    p = policy(("C1", Cell(0, 0)))
    p.plan([Battery("a", Cell(3, 0), 30.0, M)], plane, 0.0)
    step = p.plan([Battery("a", Cell(2, 0), 0.0, M)], plane, 1.0)
    assert step.targets == {} and p.chargers.holder("C1") is None
    assert p.stranded == {"a": "battery empty at [2, 0]: cannot move; bring it to a charger"}


# ---- 12. jobs on chargers -----------------------------------------------------------------------


def test_a_job_whose_pickup_or_dropoff_is_a_charger_is_refused_at_submission() -> None:
    core = make()
    meet(core, "u1", Cell(1, 1), 90.0)
    assert submit(core, C1.square, Cell(3, 1)) == (
        False,
        "pickup [0, 0] is charger C1: a unit charging there would block it",
    )
    assert submit(core, Cell(3, 1), C2.square, "j2") == (
        False,
        "dropoff [5, 0] is charger C2: a unit charging there would block it",
    )
    assert core.jobs.jobs == {}


def test_a_scenario_refuses_a_job_on_a_charger_and_allows_a_unit_to_start_on_one(
    tmp_path: Path,
) -> None:
    (tmp_path / "m.map").write_text("type octile\nheight 2\nwidth 4\nmap\n....\n....\n")
    body = (
        'map = "m.map"\n[[units]]\nid = "u1"\nstart = [0, 0]\ncapacity = 5.0\n'
        "[[chargers]]\nsquare = [0, 0]\n"
    )
    ok = tmp_path / "ok.toml"
    ok.write_text(body)
    assert load_scenario(ok).units[0].start == Cell(0, 0)
    bad = tmp_path / "bad.toml"
    bad.write_text(body + "[[jobs]]\npickup = [2, 1]\ndropoff = [0, 0]\nmass = 1.0\n")
    with pytest.raises(ScenarioError) as info:
        load_scenario(bad)
    assert "job #1: dropoff [0, 0] is charger 'C1': a unit charging there would block it" in str(
        info.value
    )


# ---- 13. the seconds charged --------------------------------------------------------------------


def test_the_seconds_charged_count_the_charges_under_way_and_never_fall() -> None:
    p = policy(("C1", Cell(0, 0)))
    p.plan([Battery("a", Cell(0, 0), 40.0, M)], plane, 0.0)
    p.plan([Battery("a", Cell(0, 0), 41.0, M, charging=True)], plane, 10.0)
    p.plan([Battery("a", Cell(0, 0), 60.0, M, charging=True)], plane, 14.0)
    assert p.charged_s == pytest.approx(4.0)
    p.plan([Battery("a", Cell(0, 0), 96.0, M, charging=True)], plane, 20.0)  # full: ended
    assert p.charged_s == pytest.approx(10.0) and p.charges == {}
    with pytest.raises(TypeError):
        p.pcts["a"] = 1.0  # type: ignore[index]
