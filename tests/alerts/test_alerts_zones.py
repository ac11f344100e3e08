"""The alerts core's zone_wait rule, pure: a job held up by closed zones (its wait zone_closed or
unreachable, protocol.md §5.3) for longer than its threshold raises a warning, cleared once it no
longer waits for them; such a job is not told by job_queued as well."""

from __future__ import annotations

import argparse
from dataclasses import replace

import pytest
from test_alerts_core import SETTINGS, Rig, notices

from gridfleet.alerts.cli import add_arguments, settings_from
from gridfleet.alerts.settings import AlertSettings, with_flag
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol import HeaderStamper, JobsView, JobView, Topics, encode

T = Topics("site")
CLOSED = ("zone_closed", "zone aisle-4 closed: cleaning")
CUT = ("unreachable", "zone aisle-4 (closed: cleaning) cuts every way to its pickup [1, 1]")
BUSY = ("no_unit_free", "every unit that can carry 1.0 kg is busy (unit2)")


def jobs(*listed: tuple[str, str, tuple[str, str] | None]) -> bytes:
    """The queue view: (id, state, (wait, words) or None) each."""
    views = [
        JobView(
            id=ident,
            pickup=Cell(1, 1),
            dropoff=Cell(4, 4),
            mass_kg=1.0,
            state=state,  # type: ignore[arg-type]
            unit=None if state == "queued" else "unit2",
            wait=None if wait is None else wait[0],  # type: ignore[arg-type]
            wait_reason=None if wait is None else wait[1],
        )
        for ident, state, wait in listed
    ]
    return encode(JobsView(header=HeaderStamper("coordinator")("jobs"), jobs=views))


def test_a_job_waiting_on_a_zone_too_long_raises_a_warning_and_clears_when_it_goes_on() -> None:
    rig = Rig(replace(SETTINGS, zone_wait_s=300.0))
    rig.send(0.0, T.fleet("jobs"), jobs(("j1", "queued", CLOSED)))
    assert notices(rig.tick(299.0)) == []
    # Closed, then cut off: the same wait for closed zones, counted from its start.
    rig.send(200.0, T.fleet("jobs"), jobs(("j1", "queued", CUT)))
    assert notices(rig.tick(300.5)) == [
        (
            "raised",
            "n1-1",
            "[WARNING] job j1 held up by closed zones for 5.0 min: zone aisle-4 (closed: "
            "cleaning) cuts every way to its pickup [1, 1]",
        )
    ]
    cleared = rig.send(400.0, T.fleet("jobs"), jobs(("j1", "assigned", None)))
    assert [n[:2] for n in notices(cleared)] == [("cleared", "n1-1")]


def test_a_job_under_way_waiting_on_a_zone_counts_too() -> None:
    rig = Rig(replace(SETTINGS, zone_wait_s=60.0))
    rig.send(0.0, T.fleet("jobs"), jobs(("j1", "loaded", CLOSED)))
    raised = rig.tick(61.0)
    assert [(n[0], n[2]) for n in notices(raised)] == [
        (
            "raised",
            "[WARNING] job j1 held up by closed zones for 1.0 min: zone aisle-4 closed: cleaning",
        )
    ]
    assert rig.core.active[("zone_wait", "j1")].severity == "warning"
    assert [n[0] for n in notices(rig.send(70.0, T.fleet("jobs"), jobs()))] == ["cleared"]


def test_a_job_waiting_on_a_zone_is_not_told_by_job_queued_as_well() -> None:
    rig = Rig(replace(SETTINGS, job_queued_s=600.0, zone_wait_s=900.0))
    rig.send(0.0, T.fleet("jobs"), jobs(("j1", "queued", CLOSED), ("j2", "queued", BUSY)))
    raised = rig.tick(601.0)
    assert [n[2] for n in notices(raised)] == [
        "[WARNING] job j2 queued for 10.0 min: every unit that can carry 1.0 kg is busy (unit2)"
    ]
    assert [n[2].split(":")[0] for n in notices(rig.tick(901.0))] == [
        "[WARNING] job j1 held up by closed zones for 15.0 min"
    ]


def test_with_zone_wait_off_job_queued_tells_such_a_job() -> None:
    rig = Rig(replace(SETTINGS, job_queued_s=600.0, zone_wait_s=None))
    rig.send(0.0, T.fleet("jobs"), jobs(("j1", "queued", CLOSED)))
    assert [n[2] for n in notices(rig.tick(601.0))] == [
        "[WARNING] job j1 queued for 10.0 min: zone aisle-4 closed: cleaning"
    ]


def test_zone_wait_defaults_to_job_queueds_threshold_and_takes_its_flag() -> None:
    assert AlertSettings().zone_wait_s == AlertSettings().job_queued_s == 600.0
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert settings_from(parser.parse_args(["--zone-wait-s", "120"])).zone_wait_s == 120.0
    assert settings_from(parser.parse_args(["--zone-wait-s", "off"])).zone_wait_s is None
    assert with_flag(AlertSettings(), "zone_wait_s=30").zone_wait_s == 30.0
    with pytest.raises(ConfigError, match=r"--zone-wait-s: zone_wait_s -5.0: give a number"):
        settings_from(parser.parse_args(["--zone-wait-s", "-5"]))
