"""`gridfleet job history --charges`: each charge's start and end, from the coordinator's store,
as a table, CSV or JSON; the job filters are refused for charges."""

from __future__ import annotations

import csv
import io
import json
import subprocess
from collections.abc import Callable
from dataclasses import replace
from datetime import UTC, datetime, timedelta

import pytest

from gridfleet.scenario import load_scenario
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import ServiceThread

from support.cli import gridfleet
from support.paths import MAPS
from support.wait import wait_for


def gridfleet_job(broker: BrokerThread, root: str, *args: str) -> subprocess.CompletedProcess[str]:
    """Run `gridfleet job ARGS` against the session broker, in a process of its own."""
    return gridfleet("job", *args, "--broker", broker.url, "--root", root, timeout=90)


@pytest.mark.slow  # the whole system, end to end
def test_a_charge_made_by_the_fleet_is_in_the_history_as_csv_json_and_table(
    broker: BrokerThread,
    root: str,
    run_system: Callable[..., tuple[ServiceThread, ServiceThread]],
) -> None:
    # The energy playfield without its jobs: unit4 starts at 45 %, below good (50 %), and goes
    # to charge at once; nothing else moves.
    scenario = replace(load_scenario(MAPS / "playfield-energy.toml"), jobs=())
    since = datetime.now(UTC) - timedelta(seconds=1)
    run_system(scenario)

    def rows() -> list[dict[str, str]]:
        got = gridfleet_job(
            broker, root, "history", "--charges", "--since", since.isoformat(), "--csv"
        )
        assert got.returncode == 0, got.stderr
        return list(csv.DictReader(io.StringIO(got.stdout)))

    wait_for(
        lambda: any(r["event"] == "started" for r in rows()),
        timeout=90,
        interval=0.5,
        what="a charge started",
    )
    started = next(r for r in rows() if r["event"] == "started")
    assert started["unit"] == "unit4" and started["charger"] in ("C1", "C2")
    assert 30.0 <= float(started["battery_pct"]) < 50.0 and started["reason"], started
    as_json = json.loads(
        gridfleet_job(
            broker, root, "history", "--charges", "--since", "10m", "--unit", "unit4", "--json"
        ).stdout
    )
    assert {"unit": "unit4", "event": "started"}.items() <= as_json[0].items()
    table = gridfleet_job(broker, root, "history", "--charges", "--since", "10m", "--unit", "unit1")
    assert table.returncode == 0 and table.stdout.splitlines()[-1] == "0 charge entries"
    mixed = gridfleet_job(broker, root, "history", "--charges", "--job", "j1")
    assert (mixed.returncode, mixed.stderr) == (
        2,
        "refused: --job and --state select jobs, not charges\n",
    )
