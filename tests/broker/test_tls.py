"""TLS: the certificate command, the embedded broker's mqtts and wss listeners, and the clients."""

from __future__ import annotations

import datetime as dt
import ipaddress
import re
import socket
import stat
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiomqtt
import pytest
from cryptography import x509
from cryptography.hazmat.primitives import serialization

from gridfleet.accounts import default_accounts
from gridfleet.broker.certs import make_tls, subject_names, write_tls
from gridfleet.broker.embedded import BrokerSettings, EmbeddedBroker, load_settings
from gridfleet.bus import make_client
from gridfleet.config import parse_broker_url, redacted, with_ca_file, with_credentials
from gridfleet.errors import ConfigError
from gridfleet.system.broker_thread import BrokerThread

from support.cli import gridfleet
from support.probe import MqttProbe
from support.security import check_strangers_are_refused

pytestmark = pytest.mark.every_broker  # the broker's TLS listeners

# A minimal MQTT 3.1.1 CONNECT (client id "x"), sent as plain bytes.
PLAIN_CONNECT = b"\x10\x0d\x00\x04MQTT\x04\x02\x00\x3c\x00\x01x"


@pytest.fixture(scope="module")
def tls(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory with ca.pem, server.pem and server.key for 127.0.0.1 and localhost."""
    out = tmp_path_factory.mktemp("tls")
    write_tls(make_tls(), out)
    return out


def tls_settings(tls: Path, **more: Any) -> BrokerSettings:
    """Broker settings on free loopback ports serving the certificate in `tls`."""
    return BrokerSettings(
        **{"port": 0, "ws_port": 0, **more},
        tls_cert=tls / "server.pem",
        tls_key=tls / "server.key",
    )


@pytest.fixture(scope="module")
def tls_broker(tls: Path) -> Iterator[BrokerThread]:
    """The embedded broker with TLS on both listeners."""
    with BrokerThread(tls_settings(tls)) as running:
        yield running


def trusting(url: str, tls: Path) -> str:
    """`url` trusting the CA in `tls`."""
    return with_ca_file(url, str(tls / "ca.pem"))


def san(cert: x509.Certificate) -> list[object]:
    """The addresses and names a certificate is for."""
    names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    return [*names.get_values_for_type(x509.IPAddress), *names.get_values_for_type(x509.DNSName)]


def test_the_command_makes_a_ca_and_a_server_certificate_signed_by_it(tmp_path: Path) -> None:
    out = tmp_path / "tls"
    done = gridfleet("accounts", "tls", "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert f"--ca-file {out / 'ca.pem'}" in done.stdout
    ca = x509.load_pem_x509_certificate((out / "ca.pem").read_bytes())
    server = x509.load_pem_x509_certificate((out / "server.pem").read_bytes())
    server.verify_directly_issued_by(ca)  # raises unless the CA signed it
    # The address also as a DNS name: the ESP32's mbedTLS 2.x matches only those.
    assert san(server) == [ipaddress.ip_address("127.0.0.1"), "127.0.0.1", "localhost"]
    now = dt.datetime.now(dt.UTC)
    assert server.not_valid_before_utc <= now
    assert server.not_valid_after_utc > now + dt.timedelta(days=365)
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    assert not server.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    key = serialization.load_pem_private_key((out / "server.key").read_bytes(), None)
    assert key.public_key() == server.public_key()
    assert stat.S_IMODE((out / "server.key").stat().st_mode) == 0o600

    again = gridfleet("accounts", "tls", "--out", str(out), "--host", "10.0.0.5")
    assert again.returncode == 2 and "exists; --force" in again.stderr
    assert (out / "server.pem").read_bytes() == server.public_bytes(serialization.Encoding.PEM)

    hosts = ("--host", "10.0.0.5", "--host", "fleet.lan", "--force")
    forced = gridfleet("accounts", "tls", "--out", str(out), *hosts)
    assert forced.returncode == 0, forced.stderr
    new_ca = x509.load_pem_x509_certificate((out / "ca.pem").read_bytes())
    new_server = x509.load_pem_x509_certificate((out / "server.pem").read_bytes())
    assert new_ca != ca
    new_server.verify_directly_issued_by(new_ca)
    assert san(new_server) == [ipaddress.ip_address("10.0.0.5"), "10.0.0.5", "fleet.lan"]


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "bad name", "-x.lan", "http://h"])
def test_a_host_clients_cannot_connect_to_is_refused(host: str) -> None:
    with pytest.raises(ConfigError, match="--host"):
        subject_names([host])


def test_tls_urls_name_their_ca_and_keep_passwords_out_of_messages(tls: Path) -> None:
    ca = str(tls / "ca.pem")
    url = parse_broker_url(with_credentials(with_ca_file("mqtts://h", ca), "op", "s3cret pw"))
    assert (url.scheme, url.port, url.tls, url.transport) == ("mqtts", 8883, True, "tcp")
    assert (url.username, url.password, url.ca_file) == ("op", "s3cret pw", ca)
    assert "s3cret" not in str(url) + repr(url) + redacted(
        str(with_credentials("mqtts://h", "op", "s3cret"))
    )
    ws = parse_broker_url(f"wss://h/mqtt?cafile={ca}")
    assert (ws.port, ws.path, ws.transport, ws.ca_file) == (443, "/mqtt", "websockets", ca)
    assert parse_broker_url("mqtts://h:1").ca_file is None  # the system's trusted CAs


@pytest.mark.parametrize(
    ("url", "problem"),
    [
        ("mqtt://h:1883?cafile={ca}", "a CA file is for TLS"),
        ("mqtts://h?cafile=/no/such/ca.pem", "no such CA file"),
        ("mqtts://h?cafile=", "one non-empty cafile"),
        ("mqtts://h?ca={ca}", "unknown option 'ca'"),
        ("mqtts://h?cafile={ca}&cafile={ca}", "one non-empty cafile"),
    ],
)
def test_bad_tls_urls_are_refused(tls: Path, url: str, problem: str) -> None:
    with pytest.raises(ConfigError, match=problem):
        parse_broker_url(url.format(ca=tls / "ca.pem"))


async def test_a_client_trusting_the_ca_exchanges_messages_over_mqtts_and_wss(
    tls_broker: BrokerThread, tls: Path
) -> None:
    assert tls_broker.url.startswith("mqtts://") and tls_broker.ws_url.startswith("wss://")
    for url in (tls_broker.url, tls_broker.ws_url):
        async with make_client(trusting(url, tls), "tls-client") as client:
            await client.subscribe("tls/echo", qos=1)
            await client.publish("tls/echo", url.encode(), qos=1)
            async for message in client.messages:
                assert message.payload == url.encode()
                break


async def test_clients_that_do_not_trust_its_ca_are_refused(
    tls_broker: BrokerThread, tmp_path: Path
) -> None:
    write_tls(make_tls(), tmp_path)  # another CA, for the same names
    for url in (tls_broker.url, trusting(tls_broker.url, tmp_path)):
        with pytest.raises(aiomqtt.MqttError, match="certificate verify failed"):
            async with make_client(url, "stranger"):
                pass


async def test_the_certificate_must_be_for_the_address_the_client_uses(tmp_path: Path) -> None:
    write_tls(make_tls(["fleet.lan"]), tmp_path)
    async with EmbeddedBroker(tls_settings(tmp_path, ws_port=None)) as other:
        with pytest.raises(aiomqtt.MqttError, match="mismatch"):
            async with make_client(trusting(other.url, tmp_path), "wrong-name"):
                pass


def connack_to_plain_bytes(port: int) -> bytes:
    """What a broker port answers a plain MQTT CONNECT (up to the connection's end)."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(PLAIN_CONNECT)
        return s.recv(64)


def test_plain_mqtt_to_the_tls_port_is_not_answered(
    tls_broker: BrokerThread, broker: BrokerThread
) -> None:
    assert connack_to_plain_bytes(broker.port)[:2] == b"\x20\x02"  # the bytes are a CONNECT
    assert not connack_to_plain_bytes(tls_broker.port).startswith(b"\x20")


def test_paho_over_wss_and_mosquitto_clients_with_the_ca(
    tls_broker: BrokerThread, tls: Path
) -> None:
    with MqttProbe(trusting(tls_broker.ws_url, tls)) as paho:
        paho.publish("tls/from-paho", b"over wss", retain=True)
    where = ["-h", "127.0.0.1", "-p", str(tls_broker.port), "--cafile", str(tls / "ca.pem")]
    out = subprocess.run(
        ["mosquitto_sub", *where, "-t", "tls/from-paho", "-C", "1", "-W", "10"],
        capture_output=True,
        text=True,
        timeout=15,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "over wss"


def test_accounts_log_in_over_tls_also_after_a_restart(tls: Path) -> None:
    accounts = default_accounts(["unit1"])
    with BrokerThread(tls_settings(tls, ws_port=None, accounts=accounts)) as running:
        check_strangers_are_refused(trusting(running.url, tls), accounts, "operator")
        running.restart()
        check_strangers_are_refused(trusting(running.url, tls), accounts, "operator")


def test_a_config_file_names_the_certificate_next_to_it(tls: Path) -> None:
    config = tls / "broker.toml"
    config.write_text('[broker]\ntls_cert = "server.pem"\ntls_key = "server.key"\n')
    settings = load_settings(config)
    assert (settings.tls_cert, settings.tls_key) == (tls / "server.pem", tls / "server.key")
    assert settings.amqtt_config()["listeners"]["ws"]["ssl"] is True


def test_the_broker_command_serves_mqtts_and_wss(tls: Path) -> None:
    files = ["--tls-cert", str(tls / "server.pem"), "--tls-key", str(tls / "server.key")]
    proc = subprocess.Popen(
        [sys.executable, "-m", "gridfleet", "broker", "--port", "0", "--ws-port", "0", *files],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        match = re.search(r"listening on (mqtts://\S+) and (wss://\S+)$", line.strip())
        assert match, line
        with (
            MqttProbe(trusting(match.group(1), tls)) as tcp,
            MqttProbe(trusting(match.group(2), tls)) as ws,
        ):
            tcp.publish("cli/tls", b"1", retain=True)
            ws.subscribe("cli/tls")
            assert ws.wait("cli/tls").payload == b"1"
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=15)
    assert proc.returncode == 0, err


@pytest.mark.parametrize(
    ("args", "problem"),
    [
        (["broker", "--tls-cert", "{tls}/server.pem"], "needs both a certificate and its key"),
        (
            ["broker", "--tls-cert", "/no/cert.pem", "--tls-key", "{tls}/server.key"],
            "/no/cert.pem: no such TLS certificate file",
        ),
        (
            ["broker", "--tls-cert", "{tls}/server.pem", "--tls-key", "{tls}/ca.pem"],
            "not a PEM certificate and its private key",
        ),
        (
            ["job", "--broker", "mqtts://127.0.0.1:1", "--ca-file", "/no/ca.pem", "list"],
            "/no/ca.pem: no such CA file",
        ),
        (["job", "--ca-file", "{tls}/ca.pem", "list"], "a CA file is for TLS"),
    ],
)
def test_tls_mistakes_are_one_clear_line(tls: Path, args: list[str], problem: str) -> None:
    done = gridfleet(*(a.format(tls=tls) for a in args))
    assert done.returncode == 2
    assert problem in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr


@pytest.mark.parametrize(
    "command",
    [
        ["coordinator", "--map", "m.map"],
        ["robots", "--scenario", "s.toml"],
        ["device", "--unit", "unit1"],
        ["job", "list"],
        ["feed", "--scenario", "s.toml"],
        ["simulate", "s.toml"],
    ],
)
def test_every_client_command_takes_the_ca_file(tls: Path, command: list[str]) -> None:
    from gridfleet.system.cli import build_parser

    ca = str(tls / "ca.pem")
    name, *rest = command
    for flags in (
        ["--ca-file", ca, "--broker", "mqtts://h"],
        ["--broker", "mqtts://h", "--ca-file", ca],
    ):
        args = build_parser(only=name).parse_args([name, *flags, *rest])
        assert parse_broker_url(args.broker).ca_file == ca
