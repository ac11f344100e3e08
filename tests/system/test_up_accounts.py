"""`gridfleet up` on a network: --listen needs --accounts, and with accounts (and TLS) every
component logs in as its own account and the playfield's jobs get done."""

from __future__ import annotations

import json
import re
import signal
import ssl
import subprocess
import sys
import time
import urllib.request
from http.cookiejar import CookieJar
from pathlib import Path

import pytest

from gridfleet.accounts import Accounts, default_accounts, write_accounts
from gridfleet.broker.certs import make_tls, write_tls
from gridfleet.config import with_ca_file
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol import JobsView, Topics, decode
from gridfleet.scenario import load_scenario
from gridfleet.session_login import session_password_refusal
from gridfleet.system.cli import build_parser
from gridfleet.system.up import spec_from, where_to_open

from support.output import Output, alive
from support.paths import REPO
from support.probe import MqttProbe
from support.security import login
from support.wait import wait_for

PLAYFIELD = REPO / "maps" / "playfield.toml"
UP = [sys.executable, "-m", "gridfleet", "up"]


@pytest.fixture
def accounts() -> Accounts:
    return default_accounts([u.id for u in load_scenario(PLAYFIELD).units])


@pytest.fixture
def accounts_file(accounts: Accounts, tmp_path: Path) -> Path:
    path = tmp_path / "fleet-accounts.toml"
    write_accounts(accounts, path)
    return path


def up_args(*argv: str) -> object:
    return spec_from(build_parser(only="up").parse_args(["up", *argv]))


def test_listen_beyond_loopback_without_accounts_refuses_in_one_line() -> None:
    out = subprocess.run(
        [*UP, "--listen", "0.0.0.0", "--mqtt-port", "0", "--ws-port", "0", "--port", "0"],
        capture_output=True, text=True, timeout=60, check=False, cwd=REPO,
    )  # fmt: skip
    assert out.returncode == 2 and out.stdout == ""  # nothing started, not even the broker
    assert out.stderr.count("\n") == 1, out.stderr
    assert out.stderr.startswith("gridfleet up: error: --listen 0.0.0.0 lets anyone")
    assert "gridfleet accounts init --scenario FILE --out FILE" in out.stderr


def test_mistakes_in_accounts_and_tls_are_named_before_anything_starts(
    tmp_path: Path, accounts_file: Path
) -> None:
    corridor = tmp_path / "corridor-accounts.toml"
    write_accounts(default_accounts(["east", "west"]), corridor)
    with pytest.raises(ConfigError, match=r"no account 'unit1'.*accounts add unit1 --role unit"):
        up_args("--accounts", str(corridor))
    with pytest.raises(ConfigError, match="--tls-cert, --tls-key and --ca-file"):
        up_args("--accounts", str(accounts_file), "--tls-cert", str(tmp_path / "server.pem"))
    with pytest.raises(ConfigError, match="no such TLS certificate"):
        up_args(
            *("--tls-cert", str(tmp_path / "nope.pem"), "--tls-key", str(tmp_path / "k")),
            *("--ca-file", str(accounts_file)),
        )
    spec = up_args("--listen", "0.0.0.0", "--accounts", str(accounts_file))
    assert getattr(spec, "accounts_file") == accounts_file.resolve()  # noqa: B009


class Dashboard:
    """A person's browser session with the dashboard, as plain HTTP."""

    def __init__(self, url: str, ca_file: Path | None = None) -> None:
        self.url = url
        self.cookies = CookieJar()
        https = urllib.request.HTTPSHandler(context=ssl.create_default_context(cafile=ca_file))
        self.opener = urllib.request.build_opener(
            urllib.request.HTTPCookieProcessor(self.cookies), https
        )

    def call(self, path: str, body: dict[str, str] | None = None) -> tuple[int, dict[str, object]]:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(f"{self.url}{path}", data=data)
        request.add_header("Content-Type", "application/json")
        try:
            with self.opener.open(request, timeout=10) as res:
                return res.status, json.loads(res.read())
        except urllib.error.HTTPError as err:
            return err.code, json.loads(err.read())


@pytest.fixture
def tls(tmp_path: Path) -> Path:
    out = tmp_path / "tls"
    out.mkdir()
    write_tls(make_tls(), out)
    return out


@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.parametrize("with_tls", [False, True], ids=["plain", "tls"])
def test_up_with_accounts_runs_the_playfield_each_component_on_its_own_account(
    with_tls: bool, accounts: Accounts, accounts_file: Path, tls: Path, tmp_path: Path
) -> None:
    argv = ["--accounts", str(accounts_file), "--scenario", str(PLAYFIELD), "--step", "0.05"]
    argv += ["--mqtt-port", "0", "--ws-port", "0", "--port", "0", "--db", str(tmp_path / "j.db")]
    if with_tls:
        argv += ["--tls-cert", str(tls / "server.pem"), "--tls-key", str(tls / "server.key")]
        argv += ["--ca-file", str(tls / "ca.pem")]
    proc = subprocess.Popen(
        [*UP, *argv], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO
    )
    out = Output(proc)
    try:
        ready = out.wait(r"listening on (mqtts?://\S+) and (wss?://\S+)", timeout=60)
        url, ws_url = ready.group(1), ready.group(2)
        assert (url.startswith("mqtts://"), ws_url.startswith("wss://")) == (with_tls, with_tls)
        if with_tls:
            url = with_ca_file(url, str(tls / "ca.pem"))
        page = out.wait(r"gridfleet is running: open (https?://\S+), log in as operator", 60)
        # With TLS the page too is served over HTTPS: the login's password is never in clear.
        assert page.group(1).startswith("https://" if with_tls else "http://")
        # The broker lets nobody in without an account (each component got in with its own).
        with pytest.raises(AssertionError, match="Not authorized"):
            MqttProbe(url).connect(timeout=5)
        # The dashboard hands the broker login to a logged-in person only.
        person = Dashboard(page.group(1), tls / "ca.pem" if with_tls else None)
        assert person.call("/api/settings")[0] == 401
        operator = accounts.get("operator")
        assert person.call("/api/login", {"username": "operator", "password": "nope"})[0] == 401
        login_ok = person.call(
            "/api/login", {"username": "operator", "password": operator.password}
        )
        assert login_ok == (200, {"user": "operator"})
        assert [c.secure for c in person.cookies] == [with_tls]  # over HTTPS only, with TLS
        status, settings = person.call("/api/settings")
        assert status == 200 and settings["broker_ws"] == ws_url
        # Not the account's password: one of this session's own, which logout takes back
        # (up runs its own broker with accounts, which checks them: session_login.py).
        handed = settings["mqtt"]
        assert handed["username"] == "operator" and handed["password"] != operator.password
        now = time.time()
        assert (
            session_password_refusal("operator", operator.password, handed["password"], now) is None
        )

        # Every job of the playfield gets done. The broker's rules let each role publish only
        # its own topics: a unit's state only from its account, orders only from the
        # coordinator's, requests only from the people's side: done jobs mean each used its own.
        topics = Topics("gridfleet")
        with MqttProbe(login(url, accounts, "dashboard")) as watcher:
            watcher.subscribe(topics.fleet("jobs"))

            def all_done() -> bool:
                seen = watcher.received(topics.fleet("jobs"))
                jobs = decode(JobsView, seen[-1].payload).listed() if seen else []
                mine = [j for j in jobs if re.match(r"playfield-\d{6}-job-\d$", j.id)]
                return len(mine) == 4 and all(j.state == "done" for j in mine)

            wait_for(all_done, timeout=60, what="the playfield's four jobs done")
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    assert proc.returncode == 0, out.text[-3000:]
    assert "Traceback" not in out.text and "DIED" not in out.text, out.text[-6000:]
    assert not any(a.password in out.text for a in accounts.accounts.values())
    pids = [int(p) for p in re.findall(r"started \(pid (\d+)\)", out.text)]
    assert len(pids) == 5
    wait_for(lambda: not any(alive(p) for p in pids), 10, what="every component to exit")


def test_a_person_is_told_where_to_open_the_dashboard() -> None:
    assert where_to_open("http://127.0.0.1:5000", "127.0.0.1", False) == "http://127.0.0.1:5000"
    assert where_to_open("http://0.0.0.0:5000", "0.0.0.0", True) == (
        "http://127.0.0.1:5000 (from other machines: http://THIS-MACHINE:5000), log in as operator"
    )


@pytest.mark.slow  # `gridfleet up`, the whole system, end to end (as the playfield's above)
@pytest.mark.timeout(180)
def test_up_with_accounts_and_vehicles_a_vehicle_on_its_own_account_does_a_job(
    tmp_path: Path,
) -> None:
    from gridfleet.accounts import VehicleLink
    from gridfleet.robots.vda5050.frame import Frame
    from gridfleet.robots.vda5050.virtual import VirtualSpec
    from gridfleet.robots.vda5050.virtual_shell import VirtualVehicleShell
    from gridfleet.robots.vda5050.wire import Vehicle
    from gridfleet.system.threads import ServiceThread

    from support.operator_peer import OperatorPeer

    vehicle = Vehicle("agv1", "gridfleet", "sn-1", "2.1.0")
    vehicles = tmp_path / "vehicles.toml"
    vehicles.write_text(
        '[maps.hall]\n[[vehicles]]\nunit = "agv1"\nmanufacturer = "gridfleet"\n'
        'serial_number = "sn-1"\nversion = "2.1.0"\nmap = "hall"\n',
        encoding="utf-8",
    )
    units = [u.id for u in load_scenario(PLAYFIELD).units]
    accounts = default_accounts(units, [VehicleLink("agv1", vehicle.prefix)])
    accounts_file = tmp_path / "accounts.toml"
    write_accounts(accounts, accounts_file)
    argv = ["--accounts", str(accounts_file), "--vehicles", str(vehicles), "--no-robots"]
    argv += ["--scenario", str(PLAYFIELD), "--step", "0.2", "--db", str(tmp_path / "j.db")]
    argv += ["--mqtt-port", "0", "--ws-port", "0", "--port", "0"]
    proc = subprocess.Popen(
        [*UP, *argv], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO
    )
    out = Output(proc)
    try:
        url = out.wait(r"listening on (mqtts?://\S+) and", timeout=60).group(1)
        out.wait(r"coordinator online", 60)  # requests before it listens reach nobody
        # The vehicle logs in with its own account and a client id of its vendor's choosing.
        shell = VirtualVehicleShell(
            vehicle,
            VirtualSpec(Frame("hall").position(Cell(5, 0)), "hall", capacity_kg=3.0),
            login(url, accounts, "agv1"),
        )
        with (
            ServiceThread(lambda: shell, "vehicle"),
            MqttProbe(login(url, accounts, "operator"), "operator-vda") as probe,
        ):
            operator = OperatorPeer(probe, Topics("gridfleet"))
            wait_for(
                lambda: (s := operator.last_state("agv1")) is not None and s.status == "idle",
                timeout=30,
                what="agv1 idle as a unit, through the adapter's account",
            )
            job = operator.submit_job(Cell(6, 0), Cell(8, 2), 1.0)
            assert job.accepted, job.reason
            wait_for(lambda: operator.all_final([job.job_id or ""]), 60, what="the job final")
            assert operator.listed_jobs()[job.job_id or ""].state == "done"
            assert any(topic == "order" for topic, _ in shell.received)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    assert proc.returncode == 0, out.text[-3000:]
    assert "Traceback" not in out.text and "DIED" not in out.text, out.text[-6000:]
