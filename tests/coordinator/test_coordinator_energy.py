"""The coordinator's energy policy (coordinator/energy.py, protocol.md §5.9), by what it publishes.

Each test injects units' states with their charge into the pure core and reads the orders, the
energy view, the waits, the events and the charges it returns (support/energy_drive.py: the
units' energy model and the map).
"""

from __future__ import annotations

import json
from typing import Any

import pytest

from gridfleet.coordinator.core import CoordinatorCore
from gridfleet.coordinator.effects import Effects
from gridfleet.coordinator.energy import (
    DETECT_MOVES,
    DETECT_PCT,
    MOVE_SAFETY,
    EnergySettings,
    max_moves,
    need_pct,
    to_charger_pct,
)
from gridfleet.grid import Cell, GridMap
from gridfleet.protocol import Charger, ControlUnit, EnergyModel
from gridfleet.protocol.constants import STATE_HEARTBEAT_STEPS

from support.coordinator_drive import from_unit, orders_in, request
from support.effects import header, header_json, published
from support.energy_drive import (
    C1,
    ENERGY,
    THRESHOLDS,
    acked,
    control,
    energy_view,
    events,
    make,
    meet,
    plans,
    state,
    submit,
)


def test_the_margins_are_the_ones_protocol_md_states() -> None:
    assert MOVE_SAFETY == 1.25
    model = EnergyModel(move_pct=0.5, idle_pct_per_s=0.01, charge_pct_per_s=2.0)
    # 10 squares: 10 x 0.5 x 1.25 driving, standing 10 s more and a minute, at 0.01 %/s.
    assert need_pct(model, 10, 1.0) == pytest.approx(6.25 + 0.7)
    assert max_moves(model, 26.95, 20.0, 1.0) == pytest.approx(10.0)
    assert max_moves(model, 20.5, 20.0, 1.0) == -1.0  # not even the minute's allowance
    # A state may be a heartbeat old (its moves) and a standing unit's a whole percent high.
    assert (DETECT_MOVES, DETECT_PCT) == (STATE_HEARTBEAT_STEPS, 1.0) == (3, 1.0)
    assert to_charger_pct(model, 10, 1.0) == pytest.approx(need_pct(model, 13, 1.0) + 1.0)


def test_an_idle_unit_below_good_goes_to_the_nearest_free_charger_with_charge_set() -> None:
    core = make()
    meet(core, "u1", Cell(1, 1), 40.0)
    effects = core.step(1.0)
    order = orders_in(effects)["u1"]
    assert (order.target, order.charge) == (C1.square, C1.square)
    assert order.released in ([Cell(0, 1)], [Cell(1, 0)])
    assert energy_view(effects) == {
        "thresholds": THRESHOLDS,
        "chargers": [
            {"name": "C1", "square": [0, 0], "unit": "u1", "queue": []},
            {"name": "C2", "square": [5, 0], "unit": None, "queue": []},
        ],
        "units": {
            "u1": {
                "plan": "to_charger",
                "charger": "C1",
                "reason": "below good 50 %; charges up to 80 %",
            }
        },
    }
    assert events(effects) == ["unit u1 sent to charge at C1 (40 %: below good 50 %)"]
    # The view goes out again only when a plan changes, not with every step or % of charge.
    from_unit(core, "state", "u1", state("u1", Cell(1, 1), 39.0, seq=1), 1.5)
    assert [t for t, *_ in published(core.step(2.0))].count(ENERGY) == 0


def test_two_low_units_are_never_sent_to_one_charger() -> None:
    core = make()
    meet(core, "u1", Cell(1, 1), 40.0)
    meet(core, "u2", Cell(2, 1), 40.0)
    orders = orders_in(core.step(1.0))
    # u2 is the more urgent (its critical level covers 3 squares to C1): it goes first; u1's
    # 40 % would not keep critical 20 % on the 5 squares to C2: it waits for C1.
    assert (orders["u1"].charge, orders["u2"].charge) == (None, C1.square)
    assert core.energy.queued == {"u1": "C1"}


def test_with_every_charger_taken_a_low_unit_waits_in_the_queue() -> None:
    core = make(chargers=(C1,))
    meet(core, "u1", Cell(1, 1), 40.0)
    meet(core, "u2", Cell(1, 0), 45.0)
    effects = core.step(1.0)
    orders = orders_in(effects)
    assert orders["u1"].charge == C1.square
    assert orders["u2"].charge is None and orders["u2"].target is None
    view = energy_view(effects)
    assert view["chargers"] == [{"name": "C1", "square": [0, 0], "unit": "u1", "queue": ["u2"]}]
    assert view["units"]["u2"] == {
        "plan": "queued",
        "charger": "C1",
        "reason": "waiting for charger C1: every one is busy",
    }


def test_a_unit_at_critical_takes_no_job_and_goes_at_once() -> None:
    core = make()
    meet(core, "u1", Cell(1, 1), 15.0)
    submit(core, Cell(3, 1), Cell(4, 1))
    effects = core.step(1.0)
    order = orders_in(effects)["u1"]
    assert (order.target, order.charge, order.action) == (C1.square, C1.square, None)
    job = core.jobs.jobs["j1"]
    assert (job.state, job.wait, job.wait_reason) == (
        "queued",
        "unit_charging",
        "every unit that can carry 1.0 kg is charging (u1 on its way to charge at C1 (15 %))",
    )


def test_a_job_given_but_not_picked_up_goes_back_when_its_unit_falls_to_critical() -> None:
    core = make()
    meet(core, "u1", Cell(2, 1), 90.0)
    submit(core, Cell(3, 1), Cell(4, 1))
    assert orders_in(core.step(1.0))["u1"].action is not None
    from_unit(core, "state", "u1", state("u1", Cell(2, 1), 18.0, seq=1), 1.5)
    effects = core.step(2.0)
    assert orders_in(effects)["u1"].charge == C1.square
    job = core.jobs.jobs["j1"]
    assert (job.state, job.unit) == ("queued", None)
    assert job.reason == "unit u1 sent to charge: battery critical (18 %)"


def test_the_critical_level_is_raised_to_cover_the_way_to_the_nearest_charger() -> None:
    core = make(chargers=(C1,))
    meet(core, "u1", Cell(5, 1), 55.0)  # 6 squares from C1: 9 x 6.25 + 1 = 57.25 % with the lag
    submit(core, Cell(4, 1), Cell(3, 1))
    effects = core.step(1.0)
    order = orders_in(effects)["u1"]
    assert (order.charge, order.action) == (C1.square, None)
    assert events(effects)[0] == (
        "unit u1 sent to charge at C1 (55 %: at or below its critical level 57 %)"
    )


def test_a_job_goes_to_the_unit_that_can_finish_it_not_to_the_nearer_one() -> None:
    core = make()
    # u1 is nearer, but 2 + 4 + 2 squares to C2 after the dropoff need 20 + 50 = 70 %.
    meet(core, "u1", Cell(2, 1), 55.0)
    meet(core, "u2", Cell(4, 1), 95.0)  # 4 + 4 + 2: 82.5 %
    submit(core, Cell(0, 1), Cell(3, 0))
    orders = orders_in(core.step(1.0))
    assert orders["u2"].action is not None and orders["u2"].action.job_id == "j1"
    assert orders["u1"].action is None and orders["u1"].charge is None
    assert core.jobs.jobs["j1"].unit == "u2"


def test_a_job_no_unit_has_the_charge_for_waits_battery_low() -> None:
    core = make(chargers=(C1,))
    meet(core, "u1", Cell(1, 0), 70.0)
    submit(core, Cell(5, 1), Cell(5, 0))
    core.step(1.0)
    job = core.jobs.jobs["j1"]
    assert (job.state, job.wait, job.wait_reason) == (
        "queued",
        "battery_low",
        "battery too low for this job (u1 has 70 %, needs 89 %)",
    )


def test_an_idle_unit_above_good_too_low_for_the_job_that_waits_for_it_charges_for_it() -> None:
    core = make(chargers=(C1,))
    meet(core, "u1", Cell(1, 0), 70.0)  # above good (50 %): alone it would idle
    submit(core, Cell(5, 1), Cell(5, 0))
    core.step(1.0)  # the job waits: battery too low (needs 89 %)
    effects = core.step(2.0)
    orders = orders_in(effects)
    assert orders["u1"].charge == C1.square and orders["u1"].target == C1.square
    assert orders["u1"].action is None
    view = energy_view(effects)
    assert view["units"]["u1"]["plan"] == "to_charger"
    assert "a job waits for it to have 89 %" in view["units"]["u1"]["reason"]
    assert "charges up to 90 %" in view["units"]["u1"]["reason"]  # its need, a point spare


def charging_on_c1(core: CoordinatorCore, pct: float, seq: int = 1, now: float = 1.5) -> Effects:
    """u1, sent to C1 and standing on it, says it charges with `pct` %; the next step."""
    st = state("u1", C1.square, pct, seq=seq, charging=True, **acked(core, "u1"))
    from_unit(core, "state", "u1", st, now)
    return core.step(now + 0.5)


def test_a_charge_starts_and_ends_in_the_events_and_the_history() -> None:
    core = make()
    meet(core, "u1", C1.square, 40.0)
    effects = core.step(1.0)
    order = orders_in(effects)["u1"]
    assert (order.released, order.target, order.charge) == ([], C1.square, C1.square)
    effects = charging_on_c1(core, 40.0)
    assert events(effects) == ["unit u1 charging at C1 (40 %)"]
    (started,) = effects.charges
    assert (started.unit, started.charger, started.event, started.battery_pct) == (
        "u1",
        "C1",
        "started",
        40.0,
    )
    assert plans(core) == {"u1": "charging"}
    effects = charging_on_c1(core, 96.0, seq=2, now=11.5)
    (ended,) = effects.charges
    assert (ended.event, ended.battery_pct, ended.reason) == ("ended", 96.0, "full (95 %)")
    assert events(effects) == ["unit u1 charged at C1: 40 % to 96 % in 10.0 s (full (95 %))"]
    assert orders_in(effects)["u1"].charge is None
    assert plans(core) == {}


def test_a_charging_unit_stands_while_another_passes() -> None:
    grid = GridMap.from_rows(["...", "@.@"])
    chargers = (Charger(name="C1", square=Cell(1, 0)),)
    core = make(chargers=chargers, grid=grid)
    meet(core, "u1", Cell(1, 0), 40.0)
    meet(core, "u2", Cell(1, 1), None)
    core.step(1.0)
    from_unit(core, "state", "u1", state("u1", Cell(1, 0), 41.0, seq=1, charging=True), 1.5)
    submit(core, Cell(0, 0), Cell(2, 0))  # u2 must pass C1's square: u1 is not moved away
    for n in range(2, 6):
        orders = orders_in(core.step(float(n)))
        assert orders["u1"].released == [] and orders["u1"].charge == Cell(1, 0)


def test_a_charging_unit_leaves_at_sufficient_for_a_job_it_can_finish() -> None:
    core = make()
    meet(core, "u1", C1.square, 40.0)
    core.step(1.0)
    charging_on_c1(core, 40.0)
    st = state("u1", C1.square, 85.0, seq=2, charging=True, **acked(core, "u1"))
    from_unit(core, "state", "u1", st, 3.0)
    submit(core, Cell(1, 0), Cell(2, 0))
    effects = core.step(4.0)
    order = orders_in(effects)["u1"]
    assert (order.charge, order.target) == (None, Cell(1, 0))
    assert order.action is not None and order.action.job_id == "j1"
    assert "unit u1 charged at C1: 40 % to 85 % in 2.0 s (left for job j1)" in events(effects)


def test_a_charging_unit_stays_for_a_job_it_could_not_finish() -> None:
    core = make(chargers=(C1,))
    meet(core, "u1", C1.square, 40.0)
    core.step(1.0)
    charging_on_c1(core, 40.0)
    st = state("u1", C1.square, 85.0, seq=2, charging=True, **acked(core, "u1"))
    from_unit(core, "state", "u1", st, 3.0)
    submit(core, Cell(5, 1), Cell(5, 0))  # 6 + 1 + 5 squares: 95 % with the margins
    order = orders_in(core.step(4.0))["u1"]
    assert (order.charge, order.action) == (C1.square, None)
    assert core.jobs.jobs["j1"].wait == "battery_low"


def test_below_sufficient_a_charging_unit_is_charging_for_the_waits() -> None:
    core = make()
    meet(core, "u1", C1.square, 40.0)
    core.step(1.0)
    charging_on_c1(core, 62.0)
    submit(core, Cell(1, 0), Cell(2, 0))
    core.step(3.0)
    assert core.jobs.jobs["j1"].wait_reason == (
        "every unit that can carry 1.0 kg is charging (u1 charging: 62 % of 80 %)"
    )


def test_a_unit_at_critical_takes_the_charger_of_one_charged_enough() -> None:
    core = make(chargers=(C1,))
    meet(core, "u1", C1.square, 40.0)
    core.step(1.0)
    charging_on_c1(core, 85.0)
    meet(core, "u2", Cell(3, 1), 10.0)
    effects = core.step(3.0)
    orders = orders_in(effects)
    assert orders["u2"].charge == C1.square
    assert orders["u1"].charge is None
    assert "unit u1 charged at C1: 85 % to 85 % in 1.0 s (made way for u2)" in events(effects)
    assert energy_view(effects)["chargers"][0]["unit"] == "u2"


def test_a_unit_that_cannot_reach_a_charger_is_stranded_and_given_no_job_it_cannot_finish() -> None:
    grid = GridMap.from_rows(["..@...", "..@..."])
    core = make(chargers=(C1,), grid=grid)
    meet(core, "u1", Cell(4, 1), 30.0)
    submit(core, Cell(5, 1), Cell(3, 0))  # 1 + 3 squares: 25 % + 20 %, it has 30 %
    effects = core.step(1.0)
    assert energy_view(effects)["units"] == {
        "u1": {
            "plan": "stranded",
            "charger": None,
            "reason": "no charger can be reached from [4, 1]",
        }
    }
    assert orders_in(effects)["u1"].action is None
    assert core.jobs.jobs["j1"].wait == "battery_low"


def test_control_unit_charge_sends_a_unit_to_charge_to_full_and_refuses_in_words() -> None:
    core = make()
    meet(core, "u1", Cell(1, 1), 90.0)
    meet(core, "u2", Cell(4, 1), None)
    assert control(core, "nobody") == (False, "unknown unit 'nobody'")
    assert control(core, "u2") == (False, "unit u2 reports no energy: it has nothing to charge")
    assert control(core, "u1") == (True, None)
    effects = core.step(2.0)  # (the views went out with the first request, at 0.5 s)
    assert orders_in(effects)["u1"].charge == C1.square
    assert energy_view(effects)["units"]["u1"] == {
        "plan": "to_charger",
        "charger": "C1",
        "reason": "an operator asked it to charge; charges up to 95 %",
    }
    again = ControlUnit(
        header=header("op"), request_id="c2", reply_to="op", unit="u1", command="charge"
    )
    (entry,) = request(core, "control_unit", again, 2.5).audit.entries
    assert (entry.act, entry.target, entry.outcome) == ("charge", "u1", "accepted")
    bare = make(chargers=())
    meet(bare, "u1", Cell(1, 1), 90.0)
    assert control(bare, "u1") == (False, "the map has no chargers")


def test_units_that_report_no_energy_are_allocated_as_before_and_never_sent_to_charge() -> None:
    core = make()
    meet(core, "u1", Cell(1, 1), None)
    submit(core, Cell(3, 1), Cell(4, 1))
    order = orders_in(core.step(1.0))["u1"]
    assert (order.target, order.charge) == (Cell(3, 1), None)
    assert core.energy.units_view() == {}


def test_without_chargers_or_energy_no_energy_view_goes_out() -> None:
    core = make(chargers=())
    meet(core, "u1", Cell(1, 1), None)
    topics = [t for t, *_ in published(core.on_connect()) + published(core.step(1.0))]
    assert ENERGY not in topics
    map_payload = json.loads(core.say.fleet_map(make().world).payload)
    assert map_payload["chargers"] == [
        {"name": "C1", "square": [0, 0]},
        {"name": "C2", "square": [5, 0]},
    ]


def test_the_naive_policy_charges_only_at_critical_and_checks_no_job() -> None:
    core = make(settings=EnergySettings(policy="naive"))
    meet(core, "u1", Cell(2, 1), 40.0)  # below good: the gridfleet policy would send it
    submit(core, Cell(5, 1), Cell(4, 0))  # more than its charge can drive
    order = orders_in(core.step(1.0))["u1"]
    assert order.action is not None and order.charge is None
    naive = make(settings=EnergySettings(policy="naive"))
    meet(naive, "u1", Cell(2, 1), 19.0)
    assert orders_in(naive.step(1.0))["u1"].charge == C1.square


@pytest.mark.parametrize(
    ("settings", "problem"),
    [
        (
            EnergySettings(critical_pct=60.0),
            "thresholds must rise: critical_pct < good_pct <= sufficient_pct <= full_pct, "
            "got 60 < 50 <= 80 <= 95",
        ),
        (
            EnergySettings(full_pct=120.0),
            "full_pct must be a number from 0 to 100 (% of a full charge), got 120.0",
        ),
        (
            EnergySettings(good_pct=-1.0),
            "good_pct must be a number from 0 to 100 (% of a full charge), got -1.0",
        ),
        (
            EnergySettings(policy="fast"),  # type: ignore[arg-type]
            "energy policy must be one of gridfleet, naive, got 'fast'",
        ),
    ],
)
def test_bad_thresholds_are_refused_in_one_line(settings: EnergySettings, problem: str) -> None:
    assert settings.problem() == problem
    with pytest.raises(ValueError, match="charging thresholds: "):
        make(settings=settings)


def test_the_energy_view_has_a_header_like_every_view() -> None:
    core = make()
    meet(core, "u1", Cell(1, 1), 40.0)
    (out,) = [o for o in core.step(1.0).publish if o.topic == ENERGY]
    assert (out.qos, out.retain) == (1, True)
    assert json.loads(out.payload)["header"] == header_json("coordinator", 0)


def test_a_charge_entry_is_stored_and_paged_as_the_history_kind_charges(tmp_path: Any) -> None:
    from datetime import timedelta

    from gridfleet.coordinator.history_store import HistoryStore
    from gridfleet.protocol import JobHistoryQuery
    from gridfleet.protocol.messages import ChargeEntry

    from support.effects import FIXED

    store = HistoryStore(tmp_path / "h.db")
    entries = [
        ChargeEntry(at=FIXED, unit="u1", charger="C1", event="started", battery_pct=35.0),
        ChargeEntry(
            at=FIXED + timedelta(seconds=24),
            unit="u1",
            charger="C1",
            event="ended",
            battery_pct=82.0,
            reason="left for job j7",
        ),
        ChargeEntry(at=FIXED, unit="u2", charger="C2", event="started", battery_pct=15.0),
    ]
    store.add_charges(entries)
    query = JobHistoryQuery(
        header=header("op"),
        request_id="h",
        reply_to="op",
        kind="charges",
        since=FIXED - timedelta(hours=1),
        unit="u1",
    )
    page, cursor = store.query(query, FIXED + timedelta(hours=1))
    assert (page, cursor) == (entries[:2], None)
    jobs, _ = store.query(query.model_copy(update={"kind": "jobs"}), FIXED + timedelta(hours=1))
    assert jobs == []
    assert store.prune(FIXED + timedelta(days=500)) == 3
    store.close()


@pytest.mark.slow  # the naive baseline runs its 2,000 steps: make test, not test-fast
def test_on_the_energy_playfield_no_unit_runs_empty_and_every_job_is_done() -> None:
    from gridfleet.scenario import load_scenario
    from gridfleet.system.lockstep import Lockstep

    from support.paths import REPO

    scenario = load_scenario(REPO / "maps" / "playfield-energy.toml")
    lowest: dict[str, dict[str, float]] = {}
    for policy in ("gridfleet", "naive"):
        sim = Lockstep(scenario, 0.5, seed=0, policy=policy)
        sim.start()
        sim.submit_scenario()
        low = lowest.setdefault(policy, {})
        while sim.core.step_no < 2000 and not sim.finished():
            sim.step()
            for u in sim.core.world.units.values():
                if u.state is not None and u.state.battery_pct is not None:
                    low[u.id] = min(low.get(u.id, 100.0), u.state.battery_pct)
        if policy == "gridfleet":
            assert sim.finished()
            assert {j.state for j in sim.core.jobs.jobs.values()} == {"done"}
            assert sim.core.energy.started > 0
    assert min(lowest["gridfleet"].values()) > 5.0, lowest
    assert min(lowest["naive"].values()) == 0.0, lowest  # the baseline strands units


def test_the_command_line_takes_a_scenario_and_refuses_thresholds_that_do_not_rise() -> None:
    import argparse

    from gridfleet.coordinator.cli import add_arguments, energy_settings, load_site
    from gridfleet.errors import ConfigError

    from support.paths import MAPS

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    site = load_site(str(MAPS / "playfield-energy.toml"))
    assert (site.grid.width, [c.name for c in site.chargers]) == (10, ["C1", "C2"])
    charging = site.charging
    args = parser.parse_args(["--map", "x.toml", "--good-pct", "90", "--energy-policy", "naive"])
    with pytest.raises(ConfigError, match="charging thresholds: thresholds must rise"):
        energy_settings(args, charging)
    args = parser.parse_args(["--map", "x.toml", "--full-pct", "100"])
    assert energy_settings(args, charging) == EnergySettings(full_pct=100.0)
    assert load_site(str(MAPS / "playfield.map")).chargers == ()


def test_a_shipped_scenario_by_name_gives_the_coordinator_its_chargers() -> None:
    from gridfleet.coordinator.cli import load_site
    from gridfleet.errors import MapError

    site = load_site("warehouse-energy")  # no such map: the scenario
    assert (site.grid.width, [c.name for c in site.chargers]) == (16, ["C1", "C2", "C3"])
    assert load_site("warehouse").chargers == ()  # the map of that name wins
    with pytest.raises(MapError, match="no shipped map of that name"):
        load_site("nowhere")


def test_units_on_batteries_on_a_map_without_chargers_are_stranded_saying_so() -> None:
    core = make(chargers=())
    meet(core, "u1", Cell(1, 0), 30.0)  # below good: it would go to charge
    view = energy_view(core.step(1.0))
    assert view["chargers"] == []
    assert view["units"]["u1"] == {
        "plan": "stranded",
        "charger": None,
        "reason": "the map has no chargers: add [[chargers]] to the scenario",
    }
