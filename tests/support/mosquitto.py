"""A real Mosquitto for tests: on a free loopback port, with the config a test gives it."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import pytest

from gridfleet.accounts import Accounts
from gridfleet.broker.embedded import BrokerSettings
from gridfleet.broker.limits import MAX_QUEUED_BYTES
from gridfleet.broker.mosquitto import MOSQUITTO_QUEUED_MESSAGES, mosquitto_conf, write_files
from gridfleet.ports import free_port
from gridfleet.protocol import Topics
from gridfleet.system.broker_thread import BrokerThread

from support.wait import wait_for

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"


def _popen(conf: Path, log: Path, on: Sequence[str] = ()) -> subprocess.Popen[bytes]:
    """Mosquitto on `conf`, its log into `log`: a pipe nobody reads fills up (64 KiB, a few hundred
    connections logged) and Mosquitto then blocks writing to it, accepting nobody. `on`: the
    command that runs it elsewhere (`ip netns exec NS`: a host of a test LAN)."""
    with log.open("ab") as out:
        return subprocess.Popen([*on, MOSQUITTO, "-c", str(conf)], stdout=out, stderr=out)


@contextmanager
def folder_anyone_may_enter() -> Iterator[Path]:
    """A new folder under the system's temporary one that every user may enter, as /etc/mosquitto
    is (pytest's own are their owner's only: Mosquitto dropped to its user could not reach files
    there); removed after."""
    made = Path(tempfile.mkdtemp(prefix="gridfleet-mosquitto-")).resolve()
    made.chmod(0o755)
    try:
        yield made
    finally:
        shutil.rmtree(made)


def started_from(
    conf: Path, log: Path, port: int, on: Sequence[str] = ()
) -> subprocess.Popen[bytes]:
    """Mosquitto on `conf` as it is (nothing added, as a site runs it), run by the command `on`
    (default: this user), once it listens on loopback `port`; its log into `log`."""
    if not Path(MOSQUITTO).exists():
        pytest.fail("mosquitto is not installed: make test installs it (apt-get install mosquitto)")
    proc = _popen(conf, log, on)

    def listening() -> bool:
        assert proc.poll() is None, f"mosquitto exited: {log.read_text()}"
        with socket.socket() as probe:
            return probe.connect_ex(("127.0.0.1", port)) == 0

    try:
        wait_for(listening, 10, what="mosquitto listening")
    except BaseException:
        proc.kill()
        proc.wait(10)
        raise
    return proc


@contextmanager
def running_mosquitto(
    directory: Path,
    conf: Callable[[int], str],
    port: int | None = None,
    host: str = "127.0.0.1",
    on: Sequence[str] = (),
    inside: Callable[[Callable[[], bool]], bool] = lambda look: look(),
) -> Iterator[int]:
    """Mosquitto with the config `conf(port)` written into `directory` (on `port`, else a free
    one), listening on `host`, run by the command `on` (default: here); yields its port.
    `inside` runs the look at its port where `host` is reached (a test LAN's `call`)."""
    if not Path(MOSQUITTO).exists():
        pytest.fail("mosquitto is not installed: make test installs it (apt-get install mosquitto)")
    port = port or free_port()
    path = directory / "mosquitto.conf"
    # Started as root, Mosquitto drops to user mosquitto, who cannot read owner-only (0600) files.
    as_root = "user root\n" if os.geteuid() == 0 else ""
    path.write_text(conf(port) + as_root)
    log = directory / "mosquitto.log"
    proc = _popen(path, log, on)

    def connects() -> bool:
        with socket.socket() as probe:
            return probe.connect_ex((host, port)) == 0

    def listening() -> bool:
        assert proc.poll() is None, f"mosquitto exited: {log.read_text()}"
        return inside(connects)

    try:
        wait_for(listening, 10, what="mosquitto listening")
        yield port
    finally:
        proc.terminate()
        proc.wait(10)


@contextmanager
def mosquitto_with_accounts(
    accounts: Accounts, topics: Topics, directory: Path, host: str = "127.0.0.1"
) -> Iterator[str]:
    """Mosquitto with the files and config 'gridfleet accounts mosquitto' writes, listening on
    `host`; its URL."""
    passwd, acl = write_files(accounts, topics, directory)
    with running_mosquitto(
        directory,
        lambda port: mosquitto_conf(passwd, acl, host=host, port=port, ws_port=None),
        host=host,
    ) as port:
        yield f"mqtt://{host}:{port}"


class MosquittoBroker:
    """Debian's Mosquitto as the suite's broker (GRIDFLEET_TEST_BROKER): TCP and
    websockets on free loopback ports, anonymous, the interface of BrokerThread the tests use."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.port = free_port()
        self.ws_port = free_port()
        self._proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        """TCP URL, e.g. mqtt://127.0.0.1:41234."""
        return f"mqtt://127.0.0.1:{self.port}"

    @property
    def ws_url(self) -> str:
        """Websocket URL for the dashboard, e.g. ws://127.0.0.1:41235."""
        return f"ws://127.0.0.1:{self.ws_port}"

    def config(self) -> str:
        """As docs/brokers.md says to run it, minus accounts (tests keep apart by topic root)."""
        return "\n".join(
            [
                "per_listener_settings false",
                "allow_anonymous true",
                "set_tcp_nodelay true",
                "persistence false",
                f"listener {self.port} 127.0.0.1",
                f"listener {self.ws_port} 127.0.0.1",
                "protocol websockets",
                # As gridfleet writes it: past a late reader's retained replay (docs/brokers.md).
                f"max_queued_messages {MOSQUITTO_QUEUED_MESSAGES}",
                f"max_queued_bytes {MAX_QUEUED_BYTES}",
                "",
            ]
        )

    def start(self, timeout: float = 10.0) -> None:
        """Start Mosquitto and wait until both listeners accept connections."""
        if not Path(MOSQUITTO).exists():
            pytest.fail(
                "mosquitto is not installed: make test installs it (apt-get install mosquitto)"
            )
        path = self.directory / "mosquitto.conf"
        path.write_text(self.config())
        log = self.directory / "mosquitto.log"
        self._proc = proc = _popen(path, log)

        def listening() -> bool:
            assert proc.poll() is None, f"mosquitto exited: {log.read_text()}"
            for port in (self.port, self.ws_port):
                with socket.socket() as probe:
                    if probe.connect_ex(("127.0.0.1", port)) != 0:
                        return False
            return True

        wait_for(listening, timeout, what="mosquitto listening")

    def stop(self, timeout: float = 5.0) -> None:
        """Stop it (every client is disconnected); retained messages are gone with it."""
        if self._proc is not None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout)
            except subprocess.TimeoutExpired:  # still flushing to clients: as a crash would
                self._proc.kill()
                self._proc.wait(timeout)
            self._proc = None

    def restart(self) -> None:
        """Stop and start again on the same ports."""
        self.stop()
        self.start()

    def allow_origins(self, *origins: str, timeout: float = 10.0) -> None:
        """As BrokerThread's; nothing to do: Mosquitto checks no origin (protocol.md section 10)."""

    def __enter__(self) -> MosquittoBroker:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


@contextmanager
def broker_with_accounts(
    kind: str, accounts: Accounts, root: str, directory: Path
) -> Iterator[tuple[str, bool]]:
    """(URL without a login, whether the broker vouches for senders) of a broker with `accounts`
    under `root`: the embedded amqtt (`kind` "amqtt") or Mosquitto."""
    if kind == "amqtt":
        settings = BrokerSettings(port=0, ws_port=None, accounts=accounts, root=root)
        with BrokerThread(settings) as running:
            yield running.url, True
    elif kind == "aedes":
        from support.aedes import aedes_with_accounts  # (imports this module)

        with aedes_with_accounts(accounts, Topics(root), directory) as cluster:
            yield cluster.url, False
    elif kind == "rabbitmq":
        from support.rabbitmq import rabbitmq_with_accounts  # only when a run asks for it

        with rabbitmq_with_accounts(accounts, Topics(root), directory) as running:
            yield running.url, False
    else:
        with mosquitto_with_accounts(accounts, Topics(root), directory) as url:
            yield url, False
