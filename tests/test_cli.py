"""The command line reads well and answers user mistakes with one line, never a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gridfleet.config import parse_broker_url
from gridfleet.errors import ConfigError
from system.cli import COMMANDS, main


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "system.cli", *args], capture_output=True, text=True, timeout=60
    )


def test_help_lists_every_subcommand() -> None:
    out = run_cli("--help")
    assert out.returncode == 0
    for name in (
        "up",
        "broker",
        "coordinator",
        "robots",
        "dashboard",
        "device",
        "job",
        "simulate",
        "bench",
    ):
        assert name in out.stdout
    assert set(COMMANDS) >= {"up", "broker", "simulate"}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_each_subcommand_has_help(command: str) -> None:
    out = run_cli(command, "--help")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"usage: gridfleet {command}")


def test_unknown_command_is_one_line_error() -> None:
    out = run_cli("fly")
    assert out.returncode == 2 and "invalid choice" in out.stderr and "Traceback" not in out.stderr


def test_broker_config_error_is_one_line(tmp_path: Path) -> None:
    out = run_cli("broker", "--config", str(tmp_path / "absent.toml"))
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        f"gridfleet broker: error: {tmp_path / 'absent.toml'}: no such broker config file"
    ]


def test_no_command_prints_help(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == 2
    assert "usage: gridfleet" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("mqtt://127.0.0.1:1883", ("mqtt", "127.0.0.1", 1883, "tcp")),
        ("mqtt://broker.local", ("mqtt", "broker.local", 1883, "tcp")),
        ("ws://127.0.0.1:9001/mqtt", ("ws", "127.0.0.1", 9001, "websockets")),
    ],
)
def test_broker_urls_parse(url: str, expected: tuple[str, str, int, str]) -> None:
    b = parse_broker_url(url)
    assert (b.scheme, b.host, b.port, b.transport) == expected


@pytest.mark.parametrize("url", ["http://x:1", "127.0.0.1:1883", "mqtt://:1883", "mqtt://h:99999"])
def test_bad_broker_urls_are_refused(url: str) -> None:
    with pytest.raises(ConfigError, match="broker URL"):
        parse_broker_url(url)
