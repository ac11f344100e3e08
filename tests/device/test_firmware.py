"""The ESP32 firmware as a person and CI meet it: host tests from a clean checkout, a README that
matches the configuration, the sketch and the PlatformIO project."""

from __future__ import annotations

import configparser
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from support.firmware_libs import compiler_warnings, firmware_libs, make_env
from support.paths import REPO

FW = REPO / "firmware"
README = (FW / "README.md").read_text()
CONFIG = (FW / "esp32_unit" / "config.example.h").read_text()
SKETCH = (FW / "esp32_unit" / "esp32_unit.ino").read_text()
DEFINES = dict(re.findall(r"^#define (GF_\w+) (.+)$", CONFIG, re.MULTILINE))


# The real libraries the firmware builds against on the device, kept beside the repository
# (CI has them; a clone elsewhere may not).
FIRMWARE_LIBS = firmware_libs()


def tracked(under: str) -> list[str]:
    """Files under `under` that a clean clone has: tracked, or new and not git-ignored."""
    out = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard", under],
        cwd=REPO,
        capture_output=True,
        check=True,
        timeout=30,
    )
    return [p for p in out.stdout.decode().split("\0") if p and (REPO / p).exists()]


def copy_checkout(under: str, into: Path) -> None:
    """Copy the files of a clean clone under `under` into `into`, keeping their paths."""
    for name in tracked(under):
        (into / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, into / name)


def have_toolchain() -> bool:
    """g++ and doctest, which `.ci/run` installs."""
    return shutil.which("g++") is not None and Path("/usr/include/doctest/doctest.h").exists()


@pytest.fixture(scope="module")
def clean_build(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[Path, subprocess.CompletedProcess[str]]:
    """The firmware folder of a clean clone, built and tested with the real libraries: the
    folder and what `make test` said."""
    into = tmp_path_factory.mktemp("checkout")
    copy_checkout("firmware", into)
    out = subprocess.run(
        ["make", "-C", str(into / "firmware"), "-j2", "test", f"FIRMWARE_LIBS={FIRMWARE_LIBS}"],
        capture_output=True,
        text=True,
        timeout=180,
        env=make_env(),
    )
    return into / "firmware", out


needs_toolchain = pytest.mark.skipif(
    not have_toolchain(), reason="needs g++ and doctest-dev (.ci/run installs them)"
)


@needs_toolchain
@pytest.mark.slow  # make test-fast: `make firmware-test` builds and runs the same host tests
@pytest.mark.firmware  # make test runs it beside the soak and the static checks
@pytest.mark.timeout(240)  # a cold g++ build of the host tests, with its own 180 s limit
def test_host_tests_pass_from_a_clean_checkout(
    clean_build: tuple[Path, subprocess.CompletedProcess[str]],
) -> None:
    assert "firmware/esp32_unit/config.h" not in tracked("firmware")  # never committed
    _, out = clean_build
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    results = re.findall(r"test cases:\s+(\d+) \|\s+(\d+) passed \|\s+(\d+) failed", out.stdout)
    # The logic tests, the sketch on stand-ins, and (with the real libraries) the sketch on the
    # real PubSubClient and ArduinoCore-API in arduino-esp32 2.x's and 3.x's layouts.
    assert len(results) == (4 if FIRMWARE_LIBS.is_dir() else 2), out.stdout[-2000:]
    for total, passed, failed in results:
        assert int(total) > 0 and total == passed and failed == "0"
    assert int(results[0][0]) >= 20  # the logic suite, not an empty shell
    # None from the project's code (g++ says `FILE:LINE:COL: warning:`; make's own jobserver
    # notes under a parallel make are not the code's).
    assert compiler_warnings(out.stdout + out.stderr) == []


# In the clean checkout built above: the stand-in tests need nothing of the real libraries, so
# make runs the programs it built there (a second cold build of them cost the lane ~50 s of g++).
@needs_toolchain
@pytest.mark.slow
@pytest.mark.firmware
@pytest.mark.timeout(240)  # the clean build, when this runs first
def test_without_the_real_libraries_the_stand_in_tests_run_and_say_so_in_one_line(
    clean_build: tuple[Path, subprocess.CompletedProcess[str]],
) -> None:
    firmware, _ = clean_build
    out = subprocess.run(
        ["make", "-C", str(firmware), "-j2", "test", "FIRMWARE_LIBS=/nonexistent/firmware-libs"],
        capture_output=True,
        text=True,
        timeout=110,
        env=make_env(),
    )
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    said = [line for line in out.stdout.splitlines() if "/nonexistent/firmware-libs" in line]
    assert said == [
        "firmware: /nonexistent/firmware-libs not found: the sketch is not built against the "
        "real PubSubClient and ArduinoCore-API here (FIRMWARE_LIBS=DIR gives them)"
    ]
    assert len(re.findall(r"Status: SUCCESS", out.stdout)) == 2


def test_readme_and_comments_say_the_press_is_confirmed_on_the_devices_own_stop_topic() -> None:
    # The device confirms its press when it comes back on <root>/v1/devices/<id>/stop, which it
    # subscribes to; the fleet's latch (fleet/estop) carries the coordinator's copy instead.
    never_lost = README[README.index("**Never lost, never sent twice.**") :]
    never_lost = never_lost[: never_lost.index("\n\n")]
    assert "`<root>/v1/devices/<device id>/stop`" in never_lost
    assert "estop topic" not in never_lost
    timing = (FW / "esp32_unit" / "src" / "timing.h").read_text()
    pending = timing[timing.index("class PendingStop") - 600 : timing.index("class PendingStop")]
    assert "devices/<id>/stop" in pending and "estop topic" not in pending


def test_make_test_runs_the_host_tests_and_installs_their_compiler() -> None:
    out = subprocess.run(
        ["make", "-n", "test"], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    # make test builds and runs them from a clean checkout (the test above), once.
    assert re.search(r"pytest -q -m firmware$", out.stdout, re.M), out.stdout
    assert '-m "not soak and not firmware and not cluster_soak"' in out.stdout
    # `make test` installs its own Debian packages (system-deps), and CI runs just that.
    makefile = (REPO / "Makefile").read_text()
    packages = re.search(r"^DEBIAN_PACKAGES := (.*)$", makefile, re.MULTILINE)
    assert packages is not None and {"g++", "doctest-dev"} <= set(packages[1].split())
    assert re.search(r"^test: system-deps ", makefile, re.MULTILINE)
    assert "make test" in (REPO / ".ci" / "run").read_text()


def test_the_real_config_is_git_ignored_and_the_example_is_tracked() -> None:
    ignored = subprocess.run(
        ["git", "check-ignore", "-q", "firmware/esp32_unit/config.h"], cwd=REPO, timeout=30
    )
    assert ignored.returncode == 0
    assert "firmware/esp32_unit/config.example.h" in tracked("firmware")
    assert "cp config.example.h config.h" in README


def test_every_setting_is_documented_and_used_by_the_sketch() -> None:
    assert len(DEFINES) >= 12
    configure = README[README.index("## Configure") : README.index("## Build and flash")]
    for name in DEFINES:
        documented = name in configure or (name.startswith("GF_PIN_") and "`GF_PIN_*`" in configure)
        assert documented, f"{name} is not explained in firmware/README.md's Configure section"
        assert name in SKETCH, f"{name} is set in config.h but the sketch never uses it"


def test_wiring_table_and_diagram_match_the_default_pins() -> None:
    wiring = README[README.index("## Wiring") : README.index("## Configure")]
    table = dict(re.findall(r"^\| (LED [NESW]|button) \| GPIO (\d+) \|", wiring, re.MULTILINE))
    pins = {f"LED {s}": DEFINES[f"GF_PIN_LED_{s}"] for s in "NESW"}
    pins["button"] = DEFINES["GF_PIN_BUTTON"]
    assert table == pins
    for what, pin in pins.items():
        # The diagram shows each pin; every LED goes through a series resistor.
        line = next((x for x in wiring.splitlines() if f"GPIO{pin} " in x), None)
        assert line is not None, f"GPIO{pin} ({what}) is missing from the diagram"
        if what.startswith("LED"):
            assert "R]--|>|" in line and what in line
    assert "BUTTON" in wiring and "GND" in wiring and "pull-up" in wiring
    assert "INPUT_PULLUP" in SKETCH and "FALLING" in SKETCH  # as the README says


def test_platformio_project_builds_the_sketch_for_esp32dev_with_pubsubclient() -> None:
    ini = configparser.ConfigParser()
    ini.read(FW / "platformio.ini")
    env = ini["env:esp32dev"]
    assert (env["platform"], env["board"], env["framework"]) == (
        "espressif32",
        "esp32dev",
        "arduino",
    )
    assert "PubSubClient" in env["lib_deps"]
    src = FW / ini["platformio"]["src_dir"]
    # arduino-cli and the IDE need the sketch file named after its folder.
    assert (src / f"{src.name}.ino").is_file()
    for include in re.findall(r'#include "(src/[^"]+)"', SKETCH):
        assert (src / include).is_file(), include


def test_readme_explains_how_to_build_and_flash_and_says_no_esp32_build_happened() -> None:
    build = README[README.index("## Build and flash") : README.index("## How it works")]
    for needle in (
        "PubSubClient",
        "arduino-cli compile --fqbn esp32:esp32:esp32 esp32_unit",
        "arduino-cli upload",
        "pio run -t upload",
        "ESP32 Dev Module",
    ):
        assert needle in build, needle
    assert "has **not** been compiled for the ESP32" in README
