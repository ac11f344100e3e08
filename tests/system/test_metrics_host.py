"""A loopback metrics endpoint answers only requests that name loopback as their Host (a DNS-
rebinding page names its own), and a token file must hold a token worth guessing."""

from __future__ import annotations

import http.client
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from gridfleet.coordinator.metrics import CoordinatorMetrics
from gridfleet.errors import ConfigError
from gridfleet.maps import load_map
from gridfleet.metrics import MIN_TOKEN_CHARS, MetricsOptions, MetricsServer, guarded, read_token

from support.cli import gridfleet
from support.coordinator_drive import make_core
from support.paths import REPO

MAP = REPO / "maps" / "playfield.map"
TOKEN = "0123456789abcdef-token"


def get(port: int, host: str | None, token: str | None = None) -> tuple[int, str]:
    """GET /metrics on 127.0.0.1:`port` with this Host header (None: none at all)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.putrequest("GET", "/metrics", skip_host=True, skip_accept_encoding=True)
        if host is not None:
            conn.putheader("Host", host)
        if token is not None:
            conn.putheader("Authorization", f"Bearer {token}")
        conn.endheaders()
        response = conn.getresponse()
        return response.status, response.read().decode()
    finally:
        conn.close()


@pytest.fixture(params=[None, TOKEN], ids=["no-token", "token"])
def served(request: pytest.FixtureRequest) -> Iterator[tuple[MetricsServer, str | None]]:
    """A loopback metrics server of an idle coordinator core, with or without a token."""
    metrics = CoordinatorMetrics(make_core(load_map(MAP)))
    server = MetricsServer(metrics.registry, MetricsOptions(0, token=request.param)).start()
    yield server, request.param
    server.stop()


def test_a_loopback_endpoint_refuses_a_host_that_is_not_loopback(
    served: tuple[MetricsServer, str | None],
) -> None:
    # As found: a page on http://rebound.example:<port>, its name resolved to 127.0.0.1, read
    # the fleet's figures (the browser sends its own name as Host).
    server, token = served
    port = server.port
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", "127.0.0.1", f"[::1]:{port}"):
        status, body = get(port, host, token)
        assert status == 200 and "# TYPE gridfleet_units gauge" in body, host
    strangers: tuple[str | None, ...] = (
        f"rebound.example:{port}",
        "10.0.0.7",
        "localhost.evil.example",
        "",
        "[::1",  # no host at all, to a URL parser
        None,  # no Host at all
    )
    for stranger in strangers:
        status, body = get(port, stranger, token)
        assert status == 403, stranger
        assert "loopback" in body and "gridfleet_units" not in body, stranger


def test_beyond_loopback_any_host_name_is_let_through_to_the_token_check() -> None:
    # Scrapers on a LAN name the machine as they know it; there the token is what keeps out.
    seen: list[str] = []

    def app(environ: dict[str, Any], start_response: Any) -> list[bytes]:
        seen.append(environ["HTTP_HOST"])
        start_response("200 OK", [])
        return [b"ok"]

    check = guarded(app, TOKEN, loopback_only=False)
    environ = {"HTTP_HOST": "metrics.hall.lan:9100", "HTTP_AUTHORIZATION": f"Bearer {TOKEN}"}
    assert check(environ, lambda *a: None) == [b"ok"] and seen == ["metrics.hall.lan:9100"]


def test_a_token_shorter_than_the_minimum_is_refused(tmp_path: Path) -> None:
    # As found: a token file holding "x" was taken.
    assert MIN_TOKEN_CHARS == 16
    short = tmp_path / "short.token"
    for token in ("x", "a" * (MIN_TOKEN_CHARS - 1)):
        short.write_text(token + "\n", encoding="utf-8")
        with pytest.raises(ConfigError) as refused:
            read_token(short)
        assert str(refused.value) == (
            f"--metrics-token-file {short}: the token is {len(token)} characters, give at least "
            f"{MIN_TOKEN_CHARS} (e.g. from 'openssl rand -hex 32')"
        )
    short.write_text("a" * MIN_TOKEN_CHARS, encoding="utf-8")
    assert read_token(short) == "a" * MIN_TOKEN_CHARS


def closed_port() -> int:
    """A loopback port nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("command", ["coordinator", "broker"])
def test_a_short_token_stops_the_start_in_one_line(tmp_path: Path, command: str) -> None:
    short = tmp_path / "metrics.token"
    short.write_text("x\n", encoding="utf-8")
    if command == "coordinator":
        where = ["--map", str(MAP), "--broker", f"mqtt://127.0.0.1:{closed_port()}"]
    else:
        where = ["--port", "0", "--no-ws"]
    flags = ["--metrics", "0", "--metrics-token-file", str(short)]
    done = gridfleet(command, *where, *flags, timeout=20)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert str(short) in lines[0] and f"at least {MIN_TOKEN_CHARS}" in lines[0]
