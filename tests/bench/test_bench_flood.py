"""`gridfleet bench flood`: its mistakes are one line, and a tiny run reports every figure."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

# The benchmark's own runs: in make test, not in make test-fast.
pytestmark = pytest.mark.slow


def bench(*args: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "gridfleet", "bench", "flood", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=150)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--flood", "0"], "--flood, --units and --repeat must be positive"),
        (["--quiet", "0"], "--warmup, --quiet, --deadline and --probe-every must be positive"),
        (["--tree", "/nonexistent-tree"], "--tree /nonexistent-tree: no pyproject.toml there"),
    ],
)
def test_mistakes_are_one_line(args: list[str], words: str) -> None:
    done = bench(*args)
    assert done.returncode == 2, done.stderr
    assert words in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_a_tiny_run_reports_a_quiet_and_a_flood_phase() -> None:
    done = bench(
        "--flood", "200", "--units", "3", "--warmup", "1", "--quiet", "4",
        "--deadline", "40", "--settle", "2", "--stops", "1", "--probe-every", "1", "--json",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(done.stdout)
    (one,) = report["runs"]
    assert one["imports"].endswith("coordinator/__init__.py") and one["broker_dropping"] == []
    quiet, flood = one["phases"]["quiet"], one["phases"]["flood"]
    for phase in (quiet, flood):
        assert phase["moves_per_s"] > 0, phase  # the fleet moved: the feeder keeps it busy
        assert 0.1 < phase["step_s"] < 2, phase  # the coordinator stepped (its metrics)
        assert len(phase["stop_ms"]) == 1 and 0 < phase["stop_ms"][0] < 20_000, phase
        submits = phase["operator2_submit_job"]
        assert submits["sent"] >= 1 and submits["answered"] == submits["sent"], submits
    # Every request of the tiny flood was answered (accepted, or refused with its reason).
    answers = flood["flood"]
    assert answers["sent"] == answers["answered"] == 200, answers
    assert answers["accepted"] + answers["refused"] == 200
    assert sum(answers["refused_why"].values()) <= answers["refused"]
    assert 0 < answers["p50_ms"] <= answers["p99_ms"] <= answers["max_ms"]
    assert answers["all_answered_s"] is not None and answers["all_answered_s"] <= 40
    assert flood["jobs_views"] >= 1 and flood["jobs_views_mb"] >= 0
    assert [row["phase"] for row in report["summary"]] == ["quiet", "flood"]
