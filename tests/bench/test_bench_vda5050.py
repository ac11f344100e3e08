"""`gridfleet bench vda5050`: the mixed fleet's benchmark runs and reports every figure."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from support.paths import REPO

pytestmark = pytest.mark.slow


@pytest.mark.timeout(180)
def test_a_short_mixed_fleet_bench_reports_jobs_and_stops() -> None:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "gridfleet",
            "--log-level",
            "ERROR",
            "bench",
            "vda5050",
            "--minutes",
            "0.15",
            "--stops",
            "3",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=170,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    figures = json.loads(done.stdout)
    assert (figures["units"], figures["vehicles"], figures["stops_timed"]) == (2, 2, 3)
    assert figures["jobs_done"] > 0 and figures["latest_done"] > 0
    assert figures["stop_to_all_paused_ms_p50"] <= figures["stop_to_all_paused_ms_max"]


def test_a_bench_of_too_many_units_says_so_in_one_line() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "gridfleet", "bench", "vda5050", "--units", "5"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )
    assert done.returncode == 2
    assert (
        done.stderr.strip()
        .splitlines()[-1]
        .endswith("--units 1 to 4 (the playfield's), --vehicles 1 to 20")
    )
