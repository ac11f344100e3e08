"""`gridfleet bench logins`: its mistakes are one line, and a small run reports every figure."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

# The benchmark's own runs: in make test, not in make test-fast.
pytestmark = pytest.mark.slow


def bench(*args: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "gridfleet", "bench", "logins", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--flood", "0"], "--units, --stops, --phases and --flood must be positive"),
        (["--units", "-1"], "must be positive"),
        (["--broker", "mqtt://127.0.0.1:1"], "--broker and --accounts go together"),
        (["--from", "10.0.0.2"], "--from 10.0.0.2: not a loopback IPv4 address"),
        (["--seconds", "0"], "--seconds and --repeat must be positive"),
        (
            ["--broker", "mqtt://127.0.0.1:1", "--accounts", "a.toml", "--tree", "."],
            "--tree starts brokers of its own: not with --broker",
        ),
    ],
)
def test_mistakes_are_one_line(args: list[str], words: str) -> None:
    done = bench(*args)
    assert done.returncode == 2 and done.stderr.strip() == done.stderr.strip().splitlines()[0]
    assert words in done.stderr


def test_a_small_run_reports_a_quiet_and_a_flood_phase() -> None:
    done = bench(
        *("--units", "3", "--stops", "2", "--phases", "1", "--flood", "20", "--seconds", "3"),
        *("--from", "127.0.0.2", "--names", "operator,coordinator", "--json"),
    )
    assert done.returncode == 0, done.stderr[-2000:]
    quiet, flood = json.loads(done.stdout)
    assert quiet["flood_per_s"] == 0 and flood["flood_per_s"] > 0
    assert flood["refused"] > 0  # every wrong login is refused, at once or after its budget
    for phase in (quiet, flood):  # the stop reached every unit (60 s stands for never)
        assert phase["stop_max_ms"] < 60_000, phase
        assert phase["tree"] == "this checkout" and phase["run"] == 0
    assert (quiet["kind"], flood["kind"]) == ("quiet", "flood")
    # Each role logged in with its right password from 127.0.0.1, about 2 a second for 3 s, and
    # was let in every time: the flood's wrong guesses for operator and coordinator came from
    # 127.0.0.2 and counted against that address alone.
    for phase in (quiet, flood):
        logins = phase["logins"]
        assert set(logins) == {"operator", "coordinator", "dashboard", "unit", "device"}, logins
        assert logins["unit"]["account"] == "u003" and logins["device"]["account"] == "device-u003"
        for role, got in logins.items():
            assert got["tried"] >= 4 and got["ok"] == got["tried"], (phase["kind"], role, got)
            assert 0 < got["slowest_ms"] < 10_000, (role, got)
