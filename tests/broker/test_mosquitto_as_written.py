"""Mosquitto run from the files `gridfleet accounts mosquitto` writes, as they are and as a site
runs it (`mosquitto -c DIR/mosquitto.conf`, as root or as the user who wrote them): it reads its
accounts, runs as no root, and keeps the latched stop across a restart (protocol.md §5.1)."""

from __future__ import annotations

import importlib
import os
import pwd
import signal
import stat
import subprocess
import sys
import traceback
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

from gridfleet.accounts import Accounts, default_accounts, write_accounts
from gridfleet.ports import free_port
from gridfleet.protocol import Topics
from gridfleet.system.cli import main

from support.cli import gridfleet
from support.mosquitto import folder_anyone_may_enter, started_from
from support.probe import MqttProbe
from support.security import login
from support.wait import wait_for

ROOT = "aswritten"
LATCH = Topics(ROOT).fleet("estop")
AS_ROOT = os.geteuid() == 0
# Whom Debian's Mosquitto drops to when root starts it (its default `user`).
DROPS_TO = "mosquitto"
# As root, the unprivileged user who writes the files and runs Mosquitto in the second test.
UNPRIVILEGED = "nobody"


@pytest.fixture
def site() -> Iterator[Path]:
    """Where the site keeps its broker's files: a folder anyone may enter."""
    with folder_anyone_may_enter() as folder:
        yield folder


def gridfleet_as(
    user: pwd.struct_passwd, args: list[str], cwd: Path
) -> subprocess.CompletedProcess[str]:
    """`gridfleet ARGS` run by `user` (this process being root), in `cwd`: forked from here,
    since the interpreter may sit where `user` cannot reach (/root/.pyenv)."""
    out, err = cwd / "stdout", cwd / "stderr"
    # Imported before the fork: the child never waits on a module lock another thread held then.
    importlib.import_module("gridfleet.system.accounts_cli")
    pid = os.fork()
    if pid == 0:  # the child: become `user`, then run the command; never returns
        code = 70
        try:
            sys.stdout, sys.stderr = out.open("w"), err.open("w")
            os.setgroups([])
            os.setgid(user.pw_gid)
            os.setuid(user.pw_uid)
            os.chdir(cwd)
            code = main(args)
        except BaseException:
            traceback.print_exc()
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
    ended: list[int] = []

    def reaped() -> bool:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            ended.append(os.waitstatus_to_exitcode(status))
        return bool(done)

    try:
        wait_for(reaped, 60, what=f"gridfleet {args[0]} as {user.pw_name}")
    finally:
        if not ended:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
    return subprocess.CompletedProcess(args, ended[0], out.read_text(), err.read_text())


def write_as(writer: pwd.struct_passwd | None, site: Path, port: int) -> tuple[Accounts, Path]:
    """`gridfleet accounts mosquitto` run by `writer` (None: by this process) into site/broker;
    the accounts and the config it wrote."""
    accounts = default_accounts(["unit1"])
    accounts_file = site / "accounts.toml"
    write_accounts(accounts, accounts_file)
    if writer is not None:  # the writer's own accounts file, in the writer's own folder
        for path in (site, accounts_file):
            os.chown(path, writer.pw_uid, writer.pw_gid)
    args = ["accounts", "mosquitto", "--file", str(accounts_file), "--out", str(site / "broker"),
            "--root", ROOT, "--port", str(port), "--no-ws"]  # fmt: skip
    done = gridfleet(*args, cwd=site) if writer is None else gridfleet_as(writer, args, site)
    assert done.returncode == 0, done.stderr
    assert "note:" not in done.stderr  # nothing Mosquitto could not open
    return accounts, site / "broker" / "mosquitto.conf"


def assert_owned_by(user: pwd.struct_passwd, conf: Path) -> None:
    """passwd, acl and data/ are `user`'s and nobody else's, and the config runs Mosquitto as it."""
    out = conf.parent
    for path, mode in ((out / "passwd", 0o600), (out / "acl", 0o600), (out / "data", 0o700)):
        st = path.stat()
        assert (st.st_uid, st.st_gid, stat.S_IMODE(st.st_mode)) == (
            user.pw_uid,
            user.pw_gid,
            mode,
        ), path
    assert f"\nuser {user.pw_name}\n" in conf.read_text()


def uid_of(proc: subprocess.Popen[bytes]) -> int:
    """The real user id process `proc` runs as."""
    status = Path(f"/proc/{proc.pid}/status").read_text()
    return int(next(line for line in status.splitlines() if line.startswith("Uid:")).split()[1])


def stop(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM, as a service manager stops it: Mosquitto saves its retained messages, then ends."""
    proc.terminate()
    proc.wait(10)


def engage(url: str, accounts: Accounts, reason: str) -> bytes:
    """The operator engages the latch (retained, QoS 1), the broker has it; its payload."""
    payload = f"engaged|operator|{reason}".encode()
    with MqttProbe(login(url, accounts, "operator")) as operator:
        operator.subscribe(LATCH)
        operator.publish(LATCH, payload, retain=True)
        operator.wait(LATCH, lambda m: m.payload == payload)
    return payload


def retained_latch(url: str, accounts: Accounts) -> bytes:
    """The retained latch a client connecting now is given."""
    with MqttProbe(login(url, accounts, "coordinator")) as coordinator:
        coordinator.subscribe(LATCH)
        seen = coordinator.wait(LATCH)
        assert seen.retain
        return seen.payload


def assert_quiet(log: Path) -> None:
    """Mosquitto neither failed to save nor warned of its files' owner or mode."""
    said = log.read_text()
    assert "Error saving" not in said and "Warning: File" not in said, said


def test_mosquitto_from_the_files_as_written_keeps_the_latch_across_restarts(site: Path) -> None:
    port = free_port()
    url = f"mqtt://127.0.0.1:{port}"
    accounts, conf = write_as(None, site, port)
    runs_as = pwd.getpwnam(DROPS_TO) if AS_ROOT else pwd.getpwuid(os.geteuid())
    assert_owned_by(runs_as, conf)
    log = site / "mosquitto.log"
    mosquitto = started_from(conf, log, port)  # as root here: it drops to user mosquitto
    try:
        assert uid_of(mosquitto) == runs_as.pw_uid  # never root
        before_restart = engage(url, accounts, "before a restart")
        stop(mosquitto)
        mosquitto = started_from(conf, log, port)
        assert retained_latch(url, accounts) == before_restart
        # A kill -9 loses what was not saved yet (autosave_interval 60 in the config); saved
        # (SIGUSR1 saves at once), the latch outlives it too.
        before_kill = engage(url, accounts, "before a kill -9")
        mosquitto.send_signal(signal.SIGUSR1)
        db = conf.parent / "data" / "mosquitto.db"
        wait_for(lambda: before_kill in db.read_bytes(), 10, what="the latch saved")
        mosquitto.kill()
        mosquitto.wait(10)
        mosquitto = started_from(conf, log, port)
        assert retained_latch(url, accounts) == before_kill
        assert_quiet(log)
    finally:
        stop(mosquitto)


def test_files_an_unprivileged_user_wrote_serve_mosquitto_run_by_it_or_by_root(
    site: Path,
) -> None:
    # Not root, the files are the writer's and Mosquitto run by it stays it (it drops nothing);
    # root starting that config drops to the writer ('user' in it), not to user mosquitto.
    port = free_port()
    url = f"mqtt://127.0.0.1:{port}"
    writer = pwd.getpwnam(UNPRIVILEGED) if AS_ROOT else pwd.getpwuid(os.geteuid())
    accounts, conf = write_as(writer if AS_ROOT else None, site, port)
    assert_owned_by(writer, conf)
    as_writer: Sequence[str] = (
        ("setpriv", f"--reuid={writer.pw_uid}", f"--regid={writer.pw_gid}", "--clear-groups")
        if AS_ROOT
        else ()
    )
    log = site / "mosquitto.log"
    mosquitto = started_from(conf, log, port, as_writer)
    try:
        assert uid_of(mosquitto) == writer.pw_uid
        latch = engage(url, accounts, "by the writer's broker")
        stop(mosquitto)
        mosquitto = started_from(conf, log, port)  # as root here: it drops to the writer
        assert uid_of(mosquitto) == writer.pw_uid
        assert retained_latch(url, accounts) == latch
        assert_quiet(log)
    finally:
        stop(mosquitto)
