"""What `pip install .` installs: one top-level package, gridfleet, that runs from where it lands."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from support.paths import REPO


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_the_wheel_holds_only_gridfleet_and_runs_from_where_it_is_unpacked(tmp_path: Path) -> None:
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps",
         "-w", str(tmp_path / "wheel"), str(REPO)],
        capture_output=True, text=True, timeout=170, check=False,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr[-2000:]
    (wheel,) = (tmp_path / "wheel").glob("gridfleet-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        archive.extractall(tmp_path / "site")
    assert {n.split("/")[0] for n in names} == {
        "gridfleet",
        wheel.name.split("-py")[0] + ".dist-info",
    }
    assert "gridfleet/dashboard/static/index.html" in names  # the page ships with it
    # Run from the unpacked copy (PYTHONPATH comes before the checkout's editable install).
    code = (
        "import gridfleet.coordinator.core as c, gridfleet.robots.unit as u, gridfleet.system.cli;"
        "print(c.__file__); print(u.__file__)"
    )
    env = {"PYTHONPATH": str(tmp_path / "site"), "PATH": "/usr/bin:/bin"}
    ran = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env,
        timeout=60, check=False,
    )  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    assert all(line.startswith(str(tmp_path / "site")) for line in ran.stdout.split())
    helped = subprocess.run(
        [sys.executable, "-m", "gridfleet", "--help"], capture_output=True, text=True,
        cwd=tmp_path, env=env, timeout=60, check=False,
    )  # fmt: skip
    assert helped.returncode == 0 and "usage: gridfleet" in helped.stdout, helped.stderr
