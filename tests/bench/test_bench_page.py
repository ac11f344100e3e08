"""`gridfleet bench page` refuses bad flags in one line, before it starts a fleet or a browser."""

from __future__ import annotations

import subprocess
import sys

import pytest

# The benchmark's own runs: in make test, not in make test-fast.
pytestmark = pytest.mark.slow


@pytest.mark.parametrize(
    ("args", "problem"),
    [
        (["--viewport", "wide"], "'wide' is not WIDTHxHEIGHT"),
        (["--viewport", "100x100"], "at least 320x240"),
        (["--units", "0"], "--units ≥ 1"),
        (["--phases", "0"], "--phases ≥ 1"),
        (["--phase", "1"], "--phase ≥ 5"),
        (["--warmup", "-1"], "--warmup ≥ 0"),
        (["--step", "0"], "step"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(args: list[str], problem: str) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "gridfleet", "bench", "page", *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and problem in out.stderr, out.stderr
    assert "Traceback" not in out.stderr and lines[-1].startswith("gridfleet"), out.stderr
