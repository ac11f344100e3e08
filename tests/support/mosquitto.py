"""A real Mosquitto for tests: on a free loopback port, with the config a test gives it."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from broker.mosquitto import mosquitto_conf, write_files
from gridfleet.accounts import Accounts
from gridfleet.protocol import Topics

from support.wait import wait_for

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"


def free_port() -> int:
    """A loopback port nobody listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def running_mosquitto(
    directory: Path, conf: Callable[[int], str], port: int | None = None
) -> Iterator[int]:
    """Mosquitto with the config `conf(port)` written into `directory` (on `port`, else a free
    one); yields its port."""
    if not Path(MOSQUITTO).exists():
        pytest.fail("mosquitto is not installed: make test installs it (apt-get install mosquitto)")
    port = port or free_port()
    path = directory / "mosquitto.conf"
    # Started as root, Mosquitto drops to user mosquitto, who cannot read owner-only (0600) files.
    as_root = "user root\n" if os.geteuid() == 0 else ""
    path.write_text(conf(port) + as_root)
    proc = subprocess.Popen(
        [MOSQUITTO, "-c", str(path)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )

    def listening() -> bool:
        assert proc.poll() is None, f"mosquitto exited: {proc.stderr.read() if proc.stderr else ''}"
        with socket.socket() as probe:
            return probe.connect_ex(("127.0.0.1", port)) == 0

    try:
        wait_for(listening, 10, what="mosquitto listening")
        yield port
    finally:
        proc.terminate()
        proc.wait(10)


@contextmanager
def mosquitto_with_accounts(accounts: Accounts, topics: Topics, directory: Path) -> Iterator[str]:
    """Mosquitto with the files and config 'gridfleet accounts mosquitto' writes; its URL."""
    passwd, acl = write_files(accounts, topics, directory)
    with running_mosquitto(
        directory, lambda port: mosquitto_conf(passwd, acl, port=port, ws_port=None)
    ) as port:
        yield f"mqtt://127.0.0.1:{port}"
