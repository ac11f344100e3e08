"""The same accounts on Mosquitto: its password and ACL files refuse strangers and forgeries."""

from __future__ import annotations

import os
import pwd
import stat
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from gridfleet.accounts import Account, Accounts, default_accounts, new_password, write_accounts
from gridfleet.broker.mosquitto import RunAs, blocked, password_hash, runs_as
from gridfleet.protocol import Topics

from support.cli import gridfleet
from support.mosquitto import folder_anyone_may_enter, mosquitto_with_accounts
from support.security import (
    VEHICLES,
    check_a_bridge_carries_only_the_halls_topics,
    check_a_unit_cannot_forge,
    check_a_vehicle_cannot_forge,
    check_only_operators_write_the_latch,
    check_strangers_are_refused,
    check_wills_obey_the_publish_rules,
)

pytestmark = pytest.mark.every_broker  # each broker enforces the accounts and their rules itself

T = Topics("mosq")


def test_password_hashes_are_mosquittos_own_format() -> None:
    made = password_hash("correct horse", salt=b"\x00" * 12)
    assert made.startswith("$7$101$AAAAAAAAAAAAAAAA$") and len(made.split("$")) == 5
    assert password_hash("correct horse") != password_hash("correct horse")  # salted


@pytest.fixture(scope="module")
def accounts() -> Accounts:
    hall = Account("hall1", new_password(), "bridge")
    return default_accounts(["unit1", "unit2"], VEHICLES).with_account(hall)


@pytest.fixture(scope="module")
def mosquitto(accounts: Accounts, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """Mosquitto with the config 'gridfleet accounts mosquitto' writes; its URL (no login)."""
    with mosquitto_with_accounts(accounts, T, tmp_path_factory.mktemp("mosquitto")) as url:
        yield url


def test_strangers_and_wrong_passwords_are_refused(mosquitto: str, accounts: Accounts) -> None:
    check_strangers_are_refused(mosquitto, accounts, "operator")


def test_a_unit_cannot_forge_another_unit_or_an_order(mosquitto: str, accounts: Accounts) -> None:
    check_a_unit_cannot_forge(mosquitto, accounts, T)


def test_a_device_or_unit_cannot_write_the_latch_or_another_press(
    mosquitto: str, accounts: Accounts
) -> None:
    check_only_operators_write_the_latch(mosquitto, accounts, T)


def test_a_will_outside_the_accounts_rules_is_heard_by_nobody(
    mosquitto: str, accounts: Accounts
) -> None:
    # Mosquitto takes the CONNECT and drops the will when it would be sent (its ACL check).
    check_wills_obey_the_publish_rules(mosquitto, accounts, T)


def test_the_command_writes_private_files_for_mosquitto(tmp_path: Path) -> None:
    accounts_file = tmp_path / "accounts.toml"
    write_accounts(default_accounts(["unit1"]), accounts_file)
    out = tmp_path / "mosq"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "gridfleet",
            "accounts",
            "mosquitto",
            "--file",
            str(accounts_file),
            "--out",
            str(out),
            "--root",
            "lab",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert "allow_anonymous false" in done.stdout
    conf = (out / "mosquitto.conf").read_text()
    assert f"password_file {out.resolve() / 'passwd'}" in conf and "listener 1883 127.0.0.1" in conf
    assert f"persistence_location {out.resolve() / 'data'}/" in conf  # the latched stop survives
    assert "set_tcp_nodelay true" in conf  # small packets at once (docs/brokers.md)
    for name in ("passwd", "acl"):
        assert stat.S_IMODE((out / name).stat().st_mode) == 0o600
    acl = (out / "acl").read_text()
    assert "user unit1\ntopic write lab/v1/units/unit1/connection" in acl
    assert (out / "passwd").read_text().startswith("coordinator:$7$101$")


def test_a_vehicle_cannot_forge_orders_states_or_the_latch(
    mosquitto: str, accounts: Accounts
) -> None:
    check_a_vehicle_cannot_forge(mosquitto, accounts, T)


def test_a_halls_bridge_carries_only_what_a_hall_may_say_and_read(
    mosquitto: str, accounts: Accounts
) -> None:
    check_a_bridge_carries_only_the_halls_topics(mosquitto, accounts, T, "hall1")


def accounts_mosquitto(*args: str) -> subprocess.CompletedProcess[str]:
    """`gridfleet accounts mosquitto ARGS`, its output captured."""
    return gridfleet("accounts", "mosquitto", *args)


def test_a_halls_broker_gets_a_bridge_carrying_the_protocols_topics(tmp_path: Path) -> None:
    accounts_file, out = tmp_path / "accounts.toml", tmp_path / "hall"
    hall1 = Account("hall1", new_password(), "bridge")
    write_accounts(default_accounts(["unit1"]).with_account(hall1), accounts_file)
    done = accounts_mosquitto(
        *("--file", str(accounts_file), "--out", str(out), "--root", "lab"),
        *("--bridge-to", "10.0.0.5:1883", "--bridge-account", "hall1"),
    )
    assert done.returncode == 0, done.stderr
    conf = (out / "mosquitto.conf").read_text()
    bridge = conf[conf.index("connection hall1") :]
    assert "address 10.0.0.5:1883\n" in bridge and f"remote_password {hall1.password}\n" in bridge
    # The password is Mosquitto's alone: root's, readable by its group, as root; else 600.
    st = (out / "mosquitto.conf").stat()
    owner = runs_as()
    if os.geteuid() == 0 and owner is not None:
        assert (st.st_uid, st.st_gid, stat.S_IMODE(st.st_mode)) == (0, owner.gid, 0o640)
    else:
        assert (st.st_uid, stat.S_IMODE(st.st_mode)) == (os.geteuid(), 0o600)
    assert "cleansession false\n" in bridge  # queued both ways across a cut
    topics = [line.split()[1:] for line in bridge.splitlines() if line.startswith("topic ")]
    assert ["lab/v1/units/+/state", "both", "0"] in topics
    assert ["lab/v1/fleet/estop", "in", "1"] in topics
    assert ["lab/v1/devices/+/stop", "both", "1"] in topics
    assert not any(t[0].endswith(("jobs", "map", "routes", "events")) for t in topics)
    # On the central broker, the bridge account may say there what the hall's units may.
    acl = (out / "acl").read_text()
    assert "user hall1\ntopic write lab/v1/units/+/connection" in acl
    assert "topic read lab/v1/units/+/order" in acl[acl.index("user hall1") :]


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--bridge-to", "10.0.0.5:1883"], "both --bridge-to HOST:PORT and --bridge-account"),
        (["--bridge-to", "10.0.0.5", "--bridge-account", "hall1"], "give the central broker as"),
        (["--bridge-to", "h:1883", "--bridge-account", "unit1"], "a unit account; make one with"),
        (["--bridge-to", "h:1883", "--bridge-account", "nobody"], "no account 'nobody'"),
        (["--bridge-ca", "ca.pem"], "--bridge-ca is for a bridge"),
        (
            ["--bridge-to", "h:8883", "--bridge-account", "hall1", "--bridge-ca", "/nope.pem"],
            "--bridge-ca /nope.pem: no such file",
        ),
    ],
)
def test_a_bridge_asked_for_wrongly_is_one_line_and_writes_nothing(
    tmp_path: Path, args: list[str], says: str
) -> None:
    accounts_file, out = tmp_path / "accounts.toml", tmp_path / "hall"
    hall1 = Account("hall1", new_password(), "bridge")
    write_accounts(default_accounts(["unit1"]).with_account(hall1), accounts_file)
    done = accounts_mosquitto("--file", str(accounts_file), "--out", str(out), *args)
    assert done.returncode == 2 and says in done.stderr, done.stderr
    assert done.stderr.count("\n") == 1 and not out.exists()


def test_blocked_names_the_folder_a_user_cannot_enter_or_the_file_it_cannot_read() -> None:
    me = pwd.getpwuid(os.geteuid()).pw_name
    stranger = RunAs("gridfleet-test-stranger", os.geteuid() + 54321, os.getegid() + 54321)
    with folder_anyone_may_enter() as site:
        closed, shared, private = site / "closed", site / "ca.pem", site / "server.key"
        closed.mkdir(mode=0o700)
        (closed / "passwd").write_text("")
        for path, mode in ((shared, 0o644), (private, 0o600)):
            path.write_text("")
            path.chmod(mode)
        assert (
            blocked(stranger, closed / "passwd") == f"cannot enter {closed} (owner {me}, mode 700)"
        )
        assert blocked(stranger, private) == f"cannot read {private} (owner {me}, mode 600)"
        assert blocked(stranger, shared) is None
        assert (
            blocked(stranger, site, write=True) == f"cannot write in {site} (owner {me}, mode 755)"
        )
        owner = RunAs(me, os.geteuid(), os.getegid())
        assert all(blocked(owner, p) is None for p in (closed / "passwd", private, shared))


def test_the_command_names_a_tls_key_mosquitto_could_not_read(tmp_path: Path) -> None:
    accounts_file = tmp_path / "accounts.toml"
    write_accounts(default_accounts(["unit1"]), accounts_file)
    as_root = os.geteuid() == 0
    with folder_anyone_may_enter() as site:
        cert, key = site / "server.pem", site / "server.key"
        cert.write_text("")
        key.write_text("")
        key.chmod(0o600 if as_root else 0o200)  # root's alone; or not even readable by its owner
        done = accounts_mosquitto(
            *("--file", str(accounts_file), "--out", str(site / "m")),
            *("--tls-cert", str(cert), "--tls-key", str(key)),
        )
    assert done.returncode == 0, done.stderr
    runs_as = "mosquitto" if as_root else pwd.getpwuid(os.geteuid()).pw_name
    fix = f"chown mosquitto: {key}" if as_root else f"chmod u+r {key}"
    assert done.stderr == (
        f"note: user {runs_as}, whom Mosquitto runs as, cannot read {key} (owner "
        f"{pwd.getpwuid(os.geteuid()).pw_name}, mode {600 if as_root else 200}): {fix}\n"
    )
    assert f"run 'mosquitto -c {site / 'm' / 'mosquitto.conf'}'" in done.stdout


def test_tls_files_that_are_not_there_are_refused_in_one_line(tmp_path: Path) -> None:
    accounts_file = tmp_path / "accounts.toml"
    write_accounts(default_accounts(["unit1"]), accounts_file)
    done = accounts_mosquitto(
        *("--file", str(accounts_file), "--out", str(tmp_path / "m")),
        *("--tls-cert", str(tmp_path / "server.pem"), "--tls-key", str(tmp_path / "server.key")),
    )
    assert done.returncode == 2 and "--tls-cert" in done.stderr and "no such file" in done.stderr
    assert done.stderr.count("\n") == 1 and not (tmp_path / "m").exists()


def test_persistence_in_the_configs_own_folder_is_refused(tmp_path: Path) -> None:
    # Mosquitto's user owns its data folder: holding mosquitto.conf, it could rewrite what root
    # reads at the next start.
    accounts_file, out = tmp_path / "accounts.toml", tmp_path / "m"
    write_accounts(default_accounts(["unit1"]), accounts_file)
    for keep in (out, tmp_path):
        done = accounts_mosquitto("--file", str(accounts_file), "--out", str(out),
                                  "--persistence", str(keep))  # fmt: skip
        assert done.returncode == 2 and "it holds mosquitto.conf" in done.stderr, done.stderr
        assert done.stderr.count("\n") == 1 and not out.exists()
