"""`gridfleet robots`: one-line errors for user mistakes, and a clean stop on SIGTERM."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from gridfleet.protocol import Connection, Topics, decode
from gridfleet.system.broker_thread import BrokerThread

from support.cli import gridfleet
from support.probe import MqttProbe
from support.wait import wait_for


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return gridfleet("robots", *args)


@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        (["--units", "unit1,unit9"], "unknown unit 'unit9'"),
        (["--step", "0"], "--step 0: the step period must be in (0, 60] seconds"),
        (["--broker", "http://x"], "scheme must be mqtt://, mqtts://, ws:// or wss://"),
        (["--workers", "0"], "--workers 0: give at least 1"),
        (["--workers", "2", "--units", "unit1"], "--workers shards every unit of the scenario"),
        (["--workers", "2", "--step", "-1"], "--step -1"),
        (["--workers", "2", "--broker", "http://x"], "scheme must be mqtt://"),
    ],
)
def test_user_mistakes_are_one_line_errors(
    playfield: Path, extra: list[str], expected: str
) -> None:
    out = cli("--scenario", str(playfield), *extra)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert (
        len(lines) == 1 and expected in lines[0] and lines[0].startswith("gridfleet robots: error:")
    )


def test_bad_scenario_is_a_one_line_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('map = "nowhere.map"\n')
    out = cli("--scenario", str(bad))
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1
    assert "nowhere.map" in out.stderr and "Traceback" not in out.stderr


def test_sigterm_stops_every_unit_with_offline(
    broker: BrokerThread, root: str, topics: Topics, playfield: Path
) -> None:
    with MqttProbe(broker.url) as probe:
        probe.subscribe(topics.all_units("connection"))
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "gridfleet.system.cli",
                "robots",
                "--broker",
                broker.url,
                "--root",
                root,
                "--scenario",
                str(playfield),
                "--units",
                "unit1,unit3",
                "--step",
                "0.05",
            ],
            stderr=subprocess.PIPE,
            text=True,
        )
        try:

            def states(uid: str) -> list[str]:
                seen = probe.received(topics.unit("connection", uid))
                return [decode(Connection, m.payload).state for m in seen]

            wait_for(lambda: states("unit1") == ["online"] and states("unit3") == ["online"], 20)
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(20) == 0
            wait_for(lambda: states("unit1")[-1] == "offline" and states("unit3")[-1] == "offline")
            assert states("unit2") == [] and states("unit4") == []
        finally:
            if proc.poll() is None:
                proc.kill()
            _, err = proc.communicate()
        assert "Traceback" not in err


def test_a_scenario_without_units_is_a_one_line_error_naming_it(tmp_path: Path) -> None:
    (tmp_path / "m.map").write_text("type octile\nheight 1\nwidth 3\nmap\n...\n")
    (tmp_path / "empty.toml").write_text('map = "m.map"\n')
    out = cli("--scenario", str(tmp_path / "empty.toml"))
    assert out.returncode == 2
    assert out.stderr.strip() == (
        f"gridfleet robots: error: {tmp_path / 'empty.toml'}: no units to run (add [[units]] tables)"
    )
