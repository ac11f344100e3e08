"""Where the real PubSubClient and ArduinoCore-API sources are (used in place, never copied)."""

from __future__ import annotations

import os
import re
from pathlib import Path

from support.paths import REPO

# Beside the repository (`../shared`); CI may clone elsewhere, and the development machines
# keep the shared data at /work/shared. GRIDFLEET_FIRMWARE_LIBS names another place.
CANDIDATES = [REPO.parent / "shared" / "firmware-libs", Path("/work/shared/firmware-libs")]


def firmware_libs() -> Path:
    """The first place that has them (else the first candidate, for the message that says so)."""
    named = os.environ.get("GRIDFLEET_FIRMWARE_LIBS")
    if named:
        return Path(named)
    return next((p for p in CANDIDATES if p.is_dir()), CANDIDATES[0])


def make_env() -> dict[str, str]:
    """This environment without a parent make's jobserver (`make test` runs the tests under
    `make -j4`): the firmware's own `make -j2` then runs as it would from a shell."""
    return {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}


def compiler_warnings(output: str) -> list[str]:
    """The lines where g++ warned (`FILE:LINE:COL: warning: ...`)."""
    return re.findall(r"^\S+:\d+:\d+: warning:.*$", output, re.MULTILINE)
