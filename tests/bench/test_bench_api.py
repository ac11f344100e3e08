"""`gridfleet bench api`: a short run answers its requests with no server error while the fleet
steps, its summary reads the phases it measured, and bad flags are refused in one line."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from gridfleet.bench.api import ApiResult, Phase


def test_the_summary_is_the_medians_of_each_kind_of_phase() -> None:
    result = ApiResult(units=4, step_s=0.1, clients=2, rate=None)
    for idle, loaded, rps in ((10.0, 8.0, 100.0), (9.0, 9.0, 140.0), (10.0, 7.0, 120.0)):
        result.phases.append(Phase(False, 20.0, idle, 3.0))
        result.phases.append(
            Phase(
                True,
                20.0,
                loaded,
                60.0,
                requests=int(rps * 20),
                requests_per_s=rps,
                statuses={"200": 9, "404": 1},
                latency_ms={"jobs": {"p50": rps / 10, "p99": rps}},
            )
        )
    summary = result.summary()
    assert summary["requests_per_s"] == 120.0
    assert (summary["steps_per_s_idle"], summary["steps_per_s_loaded"]) == (10.0, 8.0)
    assert summary["loaded_over_idle"] == 0.8
    assert summary["statuses"] == {"200": 27, "404": 3}
    assert summary["latency_ms_p50"] == {"jobs": 12.0}
    assert summary["latency_ms_p99"] == {"jobs": 120.0}


@pytest.mark.slow  # a whole `gridfleet up` for two short phases
def test_a_short_run_answers_every_request_while_the_fleet_steps() -> None:
    flags = ["--units", "6", "--jobs", "12", "--clients", "2", "--phase", "5", "--phases", "1"]
    out = subprocess.run(
        [sys.executable, "-m", "gridfleet", "bench", "api", *flags, "--warmup", "0", "--json"],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout)
    idle, loaded = result["phases"]
    assert not idle["loaded"] and loaded["loaded"]
    assert idle["steps_per_s"] > 0 and loaded["steps_per_s"] > 0
    assert loaded["requests"] > 0
    # every kind of request was sent, and none was answered with a server error
    assert {"jobs", "units", "submit"} <= set(loaded["latency_ms"]), loaded
    assert all(not s.startswith("5") for s in loaded["statuses"]), loaded["statuses"]
    assert loaded["statuses"].get("201", 0) > 0, loaded["statuses"]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "problem"),
    [
        (["--clients", "0"], "--clients ≥ 1"),
        (["--rate", "0"], "--rate > 0"),
        (["--phase", "1"], "--phase ≥ 5"),
        (["--step", "0"], "step"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(args: list[str], problem: str) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "gridfleet", "bench", "api", *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and problem in out.stderr, out.stderr
    assert "Traceback" not in out.stderr and lines[-1].startswith("gridfleet"), out.stderr
