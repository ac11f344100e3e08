"""The command line reads well and answers user mistakes with one line, never a traceback."""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
from pathlib import Path

import pytest

from gridfleet.config import DEFAULT_MQTT_URL, parse_broker_url, with_ca_file
from gridfleet.errors import ConfigError
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.system.cli import COMMANDS, build_parser, main

from support.cli import gridfleet


def test_help_lists_every_subcommand() -> None:
    out = gridfleet("--help")
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
    out = gridfleet(command, "--help")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"usage: gridfleet {command}")


def test_unknown_command_is_one_line_error() -> None:
    out = gridfleet("fly")
    assert out.returncode == 2 and "invalid choice" in out.stderr and "Traceback" not in out.stderr


def test_a_coordinator_window_out_of_range_is_one_line() -> None:
    out = gridfleet("coordinator", "--map", "maps/playfield.map", "--window", "0")
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        "gridfleet coordinator: error: --window 0: give 1 to 32 squares"
    ]


def test_broker_config_error_is_one_line(tmp_path: Path) -> None:
    out = gridfleet("broker", "--config", str(tmp_path / "absent.toml"))
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


URL = "mqtt://10.0.0.7:1884"
PICKUP = ["--pickup", "1,1", "--dropoff", "2,2", "--mass", "1"]


@pytest.mark.parametrize(
    "argv",
    [
        ["job", "list", "--broker", URL, "--root", "R", "--timeout", "5"],
        ["job", "--broker", URL, "list", "--root", "R", "--timeout", "5"],
        ["job", "--broker", URL, "--root", "R", "--timeout", "5", "list"],
        ["job", "--timeout", "5", "--root", "R", "list", "--broker", URL],
        ["job", "submit", *PICKUP, "--broker", URL, "--timeout", "5", "--root", "R"],
        ["job", "--root", "R", "submit", "--broker", URL, *PICKUP, "--timeout", "5"],
        [
            "job",
            "--root",
            "X",
            "--timeout",
            "9",
            "cancel",
            "j1",
            "--root",
            "R",
            "--timeout",
            "5",
            "--broker",
            URL,
        ],
    ],
)
def test_job_takes_its_flags_before_or_after_the_action(argv: list[str]) -> None:
    args = build_parser(only="job").parse_args(argv)
    assert (args.broker, args.root, args.timeout) == (URL, "R", 5.0)


def test_job_flags_left_out_after_the_action_keep_their_defaults() -> None:
    args = build_parser(only="job").parse_args(["job", "list"])
    assert (args.broker, args.root, args.timeout) == (DEFAULT_MQTT_URL, DEFAULT_ROOT, 10.0)
    assert (args.ca_file, args.accounts, args.account) == (None, None, None)
    args = build_parser(only="job").parse_args(
        ["job", "--accounts", "f.toml", "stop", "--account", "ann"]
    )
    assert (args.accounts, args.account) == ("f.toml", "ann")


@pytest.mark.parametrize(
    ("before", "after"),
    [
        (["--ca-file", "ca.pem", "--broker", URL], []),
        ([], ["--broker", URL, "--ca-file", "ca.pem"]),
        ([], ["--ca-file", "ca.pem", "--broker", URL]),
        (["--ca-file", "ca.pem"], ["--broker", URL]),
        (["--broker", URL], ["--ca-file", "ca.pem"]),
    ],
)
def test_the_ca_file_reaches_the_broker_url_wherever_the_two_flags_are(
    before: list[str], after: list[str]
) -> None:
    args = build_parser(only="job").parse_args(["job", *before, "list", *after])
    assert args.broker == with_ca_file(URL, "ca.pem")


def test_negative_squares_reach_the_square_type() -> None:
    """`-1,3` is a value (refused in words), not an unknown flag: argparse never sees it as one."""
    parser = build_parser(only="job")
    for argv in (
        ["job", "submit", "--pickup", "-1,3", "--dropoff", "2,2", "--mass", "1"],
        ["job", "goal", "u1", "-1,2"],
    ):
        with pytest.raises(SystemExit), contextlib.redirect_stderr(io.StringIO()) as err:
            parser.parse_args(argv)
        assert "squares start at 0,0" in err.getvalue().splitlines()[-1]


def test_a_bench_whose_extra_is_missing_says_what_to_install() -> None:
    # psutil is in the bench extra, not the base install: without it the other benches still run.
    code = (
        "import sys; sys.modules['psutil'] = None\n"
        "from gridfleet.system.cli import main\n"
        "sys.exit(main(['bench', 'system', '--units', '4']))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "gridfleet bench: error: bench system needs psutil, of the bench extra: "
        "pip install 'gridfleet[bench]' (in a checkout, make install has it)"
    ]
    planner = subprocess.run(
        [sys.executable, "-c", "import sys; sys.modules['psutil'] = None\n"
         "from gridfleet.system.cli import main\nsys.exit(main(['bench', 'planner', '--help']))"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert planner.returncode == 0 and "--suite" in planner.stdout, planner.stderr


@pytest.mark.parametrize(
    ("vehicles", "says"),
    [
        (None, "no such vehicles file"),
        ("[[vehicles]]\nunit = 'agv1'\n", "vehicles #1: manufacturer: missing"),
        ("", "no [[vehicles]]: nothing to carry"),
    ],
)
def test_a_vda5050_adapter_with_a_bad_vehicles_file_says_what_in_one_line(
    tmp_path: Path, vehicles: str | None, says: str
) -> None:
    path = tmp_path / "vehicles.toml"
    if vehicles is not None:
        path.write_text(vehicles, encoding="utf-8")
    out = gridfleet("vda5050", "--vehicles", str(path), "--map", "maps/playfield.map")
    assert out.returncode == 2
    (line,) = out.stderr.strip().splitlines()
    assert line.startswith("gridfleet vda5050: error: ") and says in line, line
