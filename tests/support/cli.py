"""Running `gridfleet` as a person does: a process of its own, its output as text."""

from __future__ import annotations

import subprocess
import sys


def gridfleet(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """Run `gridfleet ARGS` in a process of its own; its exit code is the caller's to check."""
    return subprocess.run(
        [sys.executable, "-m", "gridfleet", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )
