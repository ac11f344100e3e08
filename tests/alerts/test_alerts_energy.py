"""The alerts core's energy rules, pure: battery_low, battery_critical and cannot_reach_charger
against the coordinator's thresholds and plans (fleet/energy): exactly what is raised and cleared."""

from __future__ import annotations

from dataclasses import replace

import pytest
from test_alerts_core import SETTINGS, Rig, at, connection, errors, notices, summary, views

from gridfleet.alerts.core import AlertsCore
from gridfleet.alerts.settings import AlertSettings, with_flag
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol import (
    ChargerView,
    EnergyView,
    HeaderStamper,
    Leds,
    Sensors,
    Thresholds,
    Topics,
    UnitEnergy,
    UnitState,
    encode,
)
from gridfleet.protocol.messages import EnergyPlan

T = Topics("site")
# The other unit rules off: these tests send a state only when the battery changes.
ENERGY = replace(
    SETTINGS,
    unit_lost_s=None,
    unit_stuck_s=None,
    battery_low_s=60.0,
    battery_critical_s=10.0,
    cannot_reach_charger_s=5.0,
)
THRESHOLDS = Thresholds(critical_pct=20, good_pct=50, sufficient_pct=80, full_pct=95)


def battery(unit: str, pct: float | None, charging: bool = False) -> bytes:
    """A moving unit's state with its battery (None: it reports no energy)."""
    state = UnitState(
        header=HeaderStamper(unit)("state"),
        step=1,
        position=Cell(3, 4),
        direction="-",
        status="moving",
        leds=Leds(),
        sensors=Sensors(N="free", E="free", S="free", W="free"),
        battery_pct=pct,
        charging=charging,
    )
    return encode(state)


def energy(plans: dict[str, tuple[EnergyPlan, str | None]] | None = None) -> bytes:
    """The energy view: one charger C1, and each unit's plan with its reason."""
    units = {u: UnitEnergy(plan=p, charger="C1", reason=r) for u, (p, r) in (plans or {}).items()}
    view = EnergyView(
        header=HeaderStamper("coordinator")("energy"),
        thresholds=THRESHOLDS,
        chargers=[ChargerView(name="C1", square=Cell(0, 0))],
        units=units,
    )
    return encode(view)


def rig(settings: AlertSettings = ENERGY) -> Rig:
    """A core online with unit1 online; its energy view says nothing of any unit yet."""
    rig = Rig(settings)
    rig.send(0.0, T.unit("connection", "unit1"), connection("unit1", "online"))
    rig.send(0.0, T.fleet("energy"), energy())
    return rig


def test_the_core_follows_the_energy_view() -> None:
    core = rig().core
    assert isinstance(core, AlertsCore)
    assert (T.fleet("energy"), 0) in core.subscriptions()  # every subscription at QoS 0


def test_a_low_battery_left_alone_raises_after_its_threshold_and_clears_once_in_hand() -> None:
    r = rig()
    assert r.send(1.0, T.unit("state", "unit1"), battery("unit1", 38.0)).notices == []
    assert r.send(60.0, T.unit("state", "unit1"), battery("unit1", 37.5)).notices == []
    raised = r.tick(61.5)  # low since t=1: more than 60 s
    text = (
        "unit unit1 battery low: 38 % (below 50 %), neither charging nor on its way to a "
        "charger for 60 s"
    )
    assert notices(raised) == [("raised", "n1-1", f"[WARNING] {text}")]
    (view,) = views(raised)
    assert summary(view) == (
        [("n1-1", "battery_low", "unit1", "warning", at(61.5), None, None)],
        [],
    )
    assert r.tick(90.0).notices == []  # raised once
    # The coordinator sends it to a charger: the policy has it in hand, the alert clears.
    cleared = r.send(91.0, T.fleet("energy"), energy({"unit1": ("to_charger", None)}))
    assert notices(cleared) == [("cleared", "n1-1", f"[CLEARED] {text}")]
    assert r.send(95.0, T.unit("state", "unit1"), battery("unit1", 36.0)).notices == []
    # Charging on its own (the plan gone meanwhile): not low either.
    r.send(96.0, T.fleet("energy"), energy())
    r.send(97.0, T.unit("state", "unit1"), battery("unit1", 36.0, charging=True))
    assert r.tick(400.0).notices == []
    assert r.core.raised_total["battery_low"] == r.core.cleared_total["battery_low"] == 1


def test_a_low_spell_that_ends_starts_afresh() -> None:
    r = rig()
    r.send(1.0, T.unit("state", "unit1"), battery("unit1", 40.0))
    r.send(50.0, T.unit("state", "unit1"), battery("unit1", 40.0, charging=True))  # ended
    r.send(51.0, T.unit("state", "unit1"), battery("unit1", 49.0))  # low again from 51
    assert r.tick(70.0).notices == []
    assert r.tick(111.0).notices == []  # 60 s since 51, not more
    assert [n[0] for n in notices(r.tick(111.5))] == ["raised"]


def test_a_critical_battery_raises_critical_after_its_own_threshold() -> None:
    r = rig()
    r.send(1.0, T.unit("state", "unit1"), battery("unit1", 20.0))  # at critical
    raised = r.tick(11.5)
    text = "unit unit1 battery critical: 20 % (at or below 20 %), not charging for 10 s"
    assert notices(raised) == [("raised", "n1-1", f"[CRITICAL] {text}")]
    (view,) = views(raised)
    assert [a.rule for a in view.active] == ["battery_critical"]
    # On its way to a charger it is still critical; once charging, it clears.
    r.send(12.0, T.fleet("energy"), energy({"unit1": ("to_charger", None)}))
    assert r.tick(30.0).notices == []
    cleared = r.send(31.0, T.unit("state", "unit1"), battery("unit1", 21.0, charging=True))
    assert notices(cleared) == [("cleared", "n1-1", f"[CLEARED] {text}")]
    # Charged above critical and off the charger below good, in hand: nothing more.
    r.send(40.0, T.unit("state", "unit1"), battery("unit1", 45.0))
    assert r.tick(200.0).notices == []


LOW_38 = (
    "unit unit1 battery low: 38 % (below 50 %), neither charging nor on its way to a charger "
    "for 60 s"
)


def test_a_low_battery_falling_to_critical_keeps_low_in_force_beside_critical() -> None:
    # The walkthrough's unit: low at 38 %, left alone, falls on to 19 %. battery_low cleared
    # then (its cleared entry still said 38 %) and nothing was in force for 10 s: it read as if
    # the battery had recovered.
    r = rig()
    r.send(1.0, T.unit("state", "unit1"), battery("unit1", 38.0))
    assert notices(r.tick(61.5)) == [("raised", "n1-1", f"[WARNING] {LOW_38}")]
    fell = r.send(62.0, T.unit("state", "unit1"), battery("unit1", 19.0))
    assert fell.notices == []  # nothing cleared: still low, and critical from now
    assert r.tick(72.0).notices == []  # critical for 10 s, not more
    critical = r.tick(72.5)
    critical_text = "unit unit1 battery critical: 19 % (at or below 20 %), not charging for 10 s"
    assert notices(critical) == [("raised", "n1-2", f"[CRITICAL] {critical_text}")]
    (view,) = views(critical)
    assert [(a.id, a.rule) for a in view.active] == [
        ("n1-1", "battery_low"),
        ("n1-2", "battery_critical"),
    ]
    # At 0 % too, both hold; nothing more is raised.
    assert r.send(80.0, T.unit("state", "unit1"), battery("unit1", 0.0)).notices == []
    assert r.tick(200.0).notices == []
    # Sent to a charger: the policy has it in hand, so it is no longer "low and left alone";
    # critical it still is, on its way.
    on_its_way = r.send(201.0, T.fleet("energy"), energy({"unit1": ("to_charger", None)}))
    assert notices(on_its_way) == [("cleared", "n1-1", f"[CLEARED] {LOW_38}")]
    assert r.tick(300.0).notices == []
    charging = r.send(301.0, T.unit("state", "unit1"), battery("unit1", 1.0, charging=True))
    assert notices(charging) == [("cleared", "n1-2", f"[CLEARED] {critical_text}")]
    assert r.core.raised_total["battery_low"] == r.core.cleared_total["battery_low"] == 1


@pytest.mark.parametrize(
    ("plan", "pct", "charging"),
    [("queued", 15.0, False), (None, 15.0, True), (None, 50.0, False)],
    ids=["queued", "charging", "back at good"],
)
def test_low_and_critical_clear_as_each_rule_says(
    plan: EnergyPlan | None, pct: float, charging: bool
) -> None:
    r = rig()
    r.send(1.0, T.unit("state", "unit1"), battery("unit1", 38.0))
    r.tick(61.5)
    r.send(62.0, T.unit("state", "unit1"), battery("unit1", 15.0))
    (view,) = views(r.tick(73.0))
    assert [a.rule for a in view.active] == ["battery_low", "battery_critical"]
    if plan is not None:
        r.send(74.0, T.fleet("energy"), energy({"unit1": (plan, None)}))
    r.send(75.0, T.unit("state", "unit1"), battery("unit1", pct, charging=charging))
    r.tick(76.0)
    # Queued for a charger: no longer low and left alone, still critical until it charges.
    assert [rule for rule, _ in r.core.active] == (["battery_critical"] if plan else [])
    assert r.core.cleared_total["battery_low"] == 1


def test_a_stranded_unit_raises_cannot_reach_charger_with_the_coordinators_words() -> None:
    r = rig()
    r.send(1.0, T.unit("state", "unit1"), battery("unit1", 42.0))
    why = "no charger within 42 % of charge: the nearest, C1, needs 55 %"
    r.send(2.0, T.fleet("energy"), energy({"unit1": ("stranded", why)}))
    assert r.tick(7.0).notices == []  # 5 s, not more
    raised = r.tick(7.5)
    text = f"unit unit1 cannot reach any charger: {why} for 6 s"
    assert notices(raised) == [("raised", "n1-1", f"[CRITICAL] {text}")]
    # Stranded is not in hand: below good, it is low as well, after its own threshold.
    low = r.tick(61.5)
    assert [n[0] for n in notices(low)] == ["raised"]
    (view,) = views(low)
    assert [a.rule for a in view.active] == ["cannot_reach_charger", "battery_low"]
    cleared = r.send(70.0, T.fleet("energy"), energy({"unit1": ("to_charger", None)}))
    assert sorted(n[2] for n in notices(cleared)) == sorted(
        [
            f"[CLEARED] {text}",
            "[CLEARED] unit unit1 battery low: 42 % (below 50 %), neither charging nor on its "
            "way to a charger for 60 s",
        ]
    )


def test_no_energy_view_or_no_battery_or_offline_raises_nothing() -> None:
    # Without the coordinator's thresholds nothing is judged; a unit without energy never is.
    bare = Rig(ENERGY)
    bare.send(1.0, T.unit("state", "unit1"), battery("unit1", 5.0))
    assert bare.tick(500.0).notices == []
    r = rig()
    r.send(1.0, T.unit("state", "unit2"), battery("unit2", None))
    r.send(1.0, T.unit("state", "unit1"), battery("unit1", 5.0))
    r.send(2.0, T.unit("connection", "unit1"), connection("unit1", "offline"))
    assert r.tick(500.0).notices == []


def test_the_energy_view_cleared_clears_its_alerts_and_a_bad_one_changes_nothing() -> None:
    r = rig()
    r.send(1.0, T.unit("state", "unit1"), battery("unit1", 10.0))
    assert [n[0] for n in notices(r.tick(12.0))] == ["raised"]
    bad = r.send(13.0, T.fleet("energy"), b'{"thresholds": {"critical_pct": 200}}')
    assert len(errors(bad)) == 1 and errors(bad)[0].startswith("EnergyView: ") and not bad.notices
    assert r.tick(14.0).notices == []  # still raised: the last good view stands
    cleared = r.send(15.0, T.fleet("energy"), b"")  # `gridfleet clean`: no thresholds known
    assert [n[0] for n in notices(cleared)] == ["cleared"] and errors(cleared) == []


def test_the_energy_rules_are_settings_like_the_others() -> None:
    defaults = AlertSettings()
    assert (defaults.battery_low_s, defaults.battery_critical_s) == (60.0, 10.0)
    assert defaults.cannot_reach_charger_s == 5.0
    off = with_flag(with_flag(ENERGY, "battery_low_s=off"), "battery_critical_s=30")
    assert (off.battery_low_s, off.battery_critical_s) == (None, 30.0)
    with pytest.raises(
        ConfigError, match=r"cannot_reach_charger_s -1\.0: give a number of seconds"
    ):
        with_flag(ENERGY, "cannot_reach_charger_s=-1")
    r = rig(off)
    r.send(1.0, T.unit("state", "unit1"), battery("unit1", 30.0))  # low, but that rule is off
    assert r.tick(500.0).notices == []
