"""What `pip install .` installs: one top-level package, gridfleet, that runs from where it lands,
outside the checkout: `gridfleet up` with its shipped scenario and its page's MQTT.js."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import sysconfig
import urllib.request
import zipfile
from pathlib import Path
from typing import Any

import pytest

from gridfleet.dashboard.settings import DashboardSettings

from support.output import Output
from support.paths import REPO
from support.wait import wait_for

UNITS = ["unit1", "unit2", "unit3", "unit4"]  # the playfield's
# Neither the checkout nor this venv: a fresh process's environment, with a home of its own.
BARE_PATH = "/usr/bin:/bin"


def _copy_sources(into: Path) -> None:
    """The checkout's files as git sees them (committed, changed, new; not ignored) and the
    MQTT.js bundle npm put in dashboard/node_modules: a build in the checkout itself would leave
    build/ there, whose stale files a later build takes."""
    listed = subprocess.run(
        ["git", "-C", str(REPO), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        capture_output=True, timeout=60, check=True,
    )  # fmt: skip
    bundle = DashboardSettings().mqtt_bundle.relative_to(REPO)
    for name in [*listed.stdout.decode().split("\0"), str(bundle)]:
        source = REPO / name
        if name and source.is_file():
            (into / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, into / name)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The checkout built into a wheel, from a copy of its files."""
    work = tmp_path_factory.mktemp("build")
    _copy_sources(work / "src")
    pip = [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps"]
    pip += ["-w", str(work / "wheel"), str(work / "src")]
    built = subprocess.run(
        [*pip, "--no-build-isolation"], capture_output=True, text=True, timeout=120, check=False
    )
    if built.returncode != 0:  # this venv's setuptools is older than pyproject's (>= 77)
        built = subprocess.run(pip, capture_output=True, text=True, timeout=120, check=False)
    assert built.returncode == 0, built.stderr[-2000:]
    (found,) = (work / "wheel").glob("gridfleet-*.whl")
    return found


@pytest.fixture(scope="module")
def installed(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh venv in a temporary folder with the wheel installed (its `bin/`); the packages
    it depends on are this venv's, by a .pth file (no index needed), which runs no .pth of theirs
    (so not the checkout's editable install)."""
    venv = tmp_path_factory.mktemp("venv")
    subprocess.run(
        [sys.executable, "-m", "venv", "--without-pip", str(venv)], timeout=60, check=True
    )
    python = venv / "bin" / "python"
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet", "--no-deps",
         "--no-index", str(wheel)],
        timeout=120, check=True,
    )  # fmt: skip
    where = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    purelib = subprocess.run(
        [str(python), "-c", where], capture_output=True, text=True, timeout=60, check=True
    ).stdout.strip()
    ours = sysconfig.get_paths()
    dependencies = "".join(f"{p}\n" for p in dict.fromkeys([ours["purelib"], ours["platlib"]]))
    Path(purelib, "dependencies-of-the-test.pth").write_text(dependencies, encoding="utf-8")
    return venv / "bin"


@pytest.fixture
def elsewhere(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A folder outside the checkout to run in, and a bare environment (no PYTHONPATH)."""
    folder = tmp_path / "elsewhere"
    folder.mkdir()
    return folder, {"PATH": BARE_PATH, "HOME": str(folder)}


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_the_wheel_holds_only_gridfleet_and_runs_from_where_it_is_unpacked(
    wheel: Path, tmp_path: Path
) -> None:
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        archive.extractall(tmp_path / "site")
    assert {n.split("/")[0] for n in names} == {
        "gridfleet",
        wheel.name.split("-py")[0] + ".dist-info",
    }
    assert "gridfleet/dashboard/static/index.html" in names  # the page ships with it
    # So do the scenarios with their maps, and MQTT.js from its npm package.
    assert {f"gridfleet/scenarios/playfield.{kind}" for kind in ("toml", "map")} <= set(names)
    assert "gridfleet/dashboard/vendor/mqtt.esm.js" in names
    assert not [n for n in names if "node_modules" in n]
    # Run from the unpacked copy (PYTHONPATH comes before the checkout's editable install).
    code = (
        "import gridfleet.coordinator.core as c, gridfleet.robots.unit as u, gridfleet.system.cli;"
        "print(c.__file__); print(u.__file__)"
    )
    env = {"PYTHONPATH": str(tmp_path / "site"), "PATH": BARE_PATH}
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


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_installed_wheel_simulates_a_shipped_scenario_by_name_outside_the_checkout(
    installed: Path, elsewhere: tuple[Path, dict[str, str]]
) -> None:
    folder, env = elsewhere
    where = "import gridfleet; print(gridfleet.__file__)"
    imported = subprocess.run(
        [str(installed / "python"), "-c", where], capture_output=True, text=True, cwd=folder,
        env=env, timeout=60, check=False,
    )  # fmt: skip
    assert imported.stdout.startswith(str(installed.parent)), imported.stdout + imported.stderr
    ran = subprocess.run(
        [str(installed / "gridfleet"), "simulate", "playfield", "--max-steps", "400"],
        capture_output=True, text=True, cwd=folder, env=env, timeout=90, check=False,
    )  # fmt: skip
    assert ran.returncode == 0, ran.stdout[-2000:] + ran.stderr[-2000:]
    assert "jobs: 4 done of 4" in ran.stdout, ran.stdout[-2000:]
    unknown = subprocess.run(
        [str(installed / "gridfleet"), "simulate", "nowhere"],
        capture_output=True, text=True, cwd=folder, env=env, timeout=60, check=False,
    )  # fmt: skip
    assert unknown.returncode == 2 and unknown.stdout == ""
    assert unknown.stderr == (
        "gridfleet simulate: error: nowhere: no such scenario file, and no shipped scenario of "
        "that name (corridor, crossing, heavy, maze, playfield, playfield-energy, warehouse, "
        "warehouse-energy)\n"
    )


@pytest.mark.slow
@pytest.mark.browser
@pytest.mark.timeout(120)
def test_the_installed_wheel_runs_up_outside_the_checkout_and_its_page_shows_the_units(
    installed: Path, elsewhere: tuple[Path, dict[str, str]], chromium: Any
) -> None:
    folder, env = elsewhere
    proc = subprocess.Popen(
        [str(installed / "gridfleet"), "up", "--mqtt-port", "0", "--ws-port", "0", "--port", "0",
         "--step", "0.1", "--db", str(folder / "jobs.db")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=folder, env=env,
    )  # fmt: skip
    out = Output(proc)
    try:
        url = out.wait(r"gridfleet is running: open (http://127\.0\.0\.1:\d+)", 60).group(1)
        # The page's MQTT.js is the wheel's own copy of the npm package's bundle.
        with urllib.request.urlopen(f"{url}/vendor/mqtt.esm.js", timeout=10) as got:
            assert got.read() == DashboardSettings().mqtt_bundle.read_bytes()
        context = chromium.new_context()
        try:
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(url)
            page.wait_for_selector("#conn[data-state=connected]", timeout=30_000)
            canvas = page.locator("#map")

            def drawn() -> list[str]:
                return [u.split("@")[0] for u in (canvas.get_attribute("data-units") or "").split()]

            wait_for(
                lambda: drawn() == UNITS, 30, interval=0.1, what=f"the page to draw {UNITS}",
                context=drawn,
            )  # fmt: skip
            assert errors == []
        finally:
            context.close()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    out.wait_closed()
    assert proc.returncode == 0, out.text[-3000:]
    assert "Traceback" not in out.text, out.text[-3000:]
