"""A real Mosquitto with a TLS listener and the certificate from `gridfleet accounts tls` accepts
gridfleet's own client (aiomqtt, through a `gridfleet` command with --ca-file)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from gridfleet.broker.certs import make_tls, write_tls
from gridfleet.config import with_ca_file

from support.cli import gridfleet
from support.mosquitto import running_mosquitto
from support.probe import MqttProbe
from support.wait import wait_for

pytestmark = pytest.mark.every_broker  # the broker's TLS listeners


@pytest.fixture(scope="module")
def tls(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """ca.pem, server.pem and server.key for 127.0.0.1 and localhost."""
    out = tmp_path_factory.mktemp("tls")
    write_tls(make_tls(), out)
    return out


@pytest.fixture(scope="module")
def mosquitto_tls(tls: Path) -> Iterator[str]:
    """Mosquitto with only a TLS listener on a free loopback port; its mqtts:// URL."""

    def conf(port: int) -> str:
        return (
            f"allow_anonymous true\npersistence false\nlistener {port} 127.0.0.1\n"
            f"certfile {tls / 'server.pem'}\nkeyfile {tls / 'server.key'}\n"
        )

    with running_mosquitto(tls, conf) as port:
        yield f"mqtts://127.0.0.1:{port}"


def test_a_gridfleet_command_with_the_ca_file_talks_to_mosquitto(
    mosquitto_tls: str, tls: Path
) -> None:
    ca = str(tls / "ca.pem")
    cmd = ["job", "--broker", mosquitto_tls, "--ca-file", ca]
    done = gridfleet(*cmd, "--root", "tlsq", "stop", "--reason", "over tls")
    assert done.returncode == 0, done.stderr
    with MqttProbe(with_ca_file(mosquitto_tls, ca)) as probe:
        probe.subscribe("tlsq/#")  # the stop is retained: it is there for a later reader
        found = wait_for(lambda: [m for t in list(probe.messages) for m in probe.received(t)])
        assert b"over tls" in found[0].payload


def test_without_the_ca_file_the_command_is_refused(mosquitto_tls: str) -> None:
    done = gridfleet("job", "--broker", mosquitto_tls, "stop")
    assert done.returncode == 2
    assert "certificate verify failed" in done.stderr
