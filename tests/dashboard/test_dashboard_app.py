"""The dashboard's Flask app, settings, server thread and CLI, without a browser."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from gridfleet.dashboard.app import create_app
from gridfleet.dashboard.cli import settings_from
from gridfleet.dashboard.server import DashboardServer
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.errors import ConfigError, GridfleetError, ProtocolError
from gridfleet.ports import free_port
from gridfleet.scenario import load_scenario
from gridfleet.system.cli import build_parser

from support.paths import REPO
from support.wait import wait_for


def get(url: str) -> tuple[int, str, bytes]:
    """Status, content type and body of a GET (errors included)."""
    try:
        with urllib.request.urlopen(url, timeout=5) as res:
            return res.status, res.headers.get_content_type(), res.read()
    except urllib.error.HTTPError as err:
        return err.code, err.headers.get_content_type(), err.read()


def test_settings_endpoint_carries_broker_root_and_map(playfield: Path) -> None:
    scenario = load_scenario(playfield)
    settings = DashboardSettings(
        broker_ws="ws://127.0.0.1:9999",
        root="lab/a",
        map=scenario.grid,
        colors={"unit1": "#d32f2f"},
    )
    body = create_app(settings).test_client().get("/api/settings").get_json()
    assert body["broker_ws"] == "ws://127.0.0.1:9999"
    assert (body["root"], body["prefix"], body["client_prefix"]) == (
        "lab/a",
        "lab/a/v1",
        "dashboard",
    )
    assert body["map"]["width"] == 10 and body["map"]["rows"] == scenario.grid.rows()
    assert body["colors"] == {"unit1": "#d32f2f"}


def test_page_static_files_and_bundle_are_served() -> None:
    client = create_app(DashboardSettings()).test_client()
    page = client.get("/")
    assert page.status_code == 200 and b'src="/static/js/main.js"' in page.data
    # Its icon is in the page: a browser asks for no /favicon.ico (a 404 on every load before).
    assert b'<link rel="icon" href="data:image/svg+xml,' in page.data
    for path in ("/static/js/main.js", "/static/js/model.js", "/static/style.css"):
        assert client.get(path).status_code == 200, path
    bundle = client.get("/vendor/mqtt.esm.js")
    if not DashboardSettings().mqtt_bundle.is_file():
        pytest.skip("MQTT.js is not installed here (npm ci in dashboard/)")
    assert bundle.status_code == 200 and bundle.mimetype == "text/javascript"
    assert b"export default" in bundle.data


def test_missing_bundle_says_how_to_install(tmp_path: Path) -> None:
    client = create_app(DashboardSettings(node_modules=tmp_path)).test_client()
    body = client.get("/api/settings").get_json()
    assert body["mqtt_js"]["available"] is False
    assert "npm ci" in body["mqtt_js"]["hint"]
    bundle = client.get("/vendor/mqtt.esm.js")
    assert bundle.status_code == 503 and b"npm ci" in bundle.data


@pytest.mark.parametrize(
    ("kwargs", "error", "words"),
    [
        ({"broker_ws": "mqtt://127.0.0.1:1883"}, ConfigError, "websocket URL"),
        ({"broker_ws": "http://x"}, ConfigError, "scheme"),
        ({"root": "a/+/b"}, ProtocolError, "topic root"),
        ({"client_prefix": "no/slash"}, ProtocolError, "client id prefix"),
    ],
)
def test_bad_settings_are_refused(
    kwargs: dict[str, str], error: type[Exception], words: str
) -> None:
    with pytest.raises(error, match=words):
        DashboardSettings(**kwargs)  # type: ignore[arg-type]


def test_cli_flags_build_settings(playfield: Path) -> None:
    parser = build_parser(only="dashboard")
    args = parser.parse_args(
        [
            "dashboard",
            "--broker-ws",
            "ws://127.0.0.1:9002",
            "--root",
            "x",
            "--scenario",
            str(playfield),
        ]
    )
    settings = settings_from(args)
    assert settings.broker_ws == "ws://127.0.0.1:9002" and settings.root == "x"
    assert settings.map is not None and settings.map.width == 10
    assert settings.colors["unit4"] == "#f9a825"
    with pytest.raises(SystemExit):
        parser.parse_args(["dashboard", "--scenario", "a", "--map", "b"])
    bad = parser.parse_args(["dashboard", "--map", str(playfield.parent / "nope.map")])
    with pytest.raises(GridfleetError, match=r"nope\.map"):
        settings_from(bad)


def test_server_thread_serves_and_stops() -> None:
    server = DashboardServer(create_app(DashboardSettings(root="srv"))).start()
    try:
        status, kind, body = get(f"{server.url}/api/settings")
        assert (status, kind) == (200, "application/json")
        assert json.loads(body)["root"] == "srv"
        port = server.port
    finally:
        server.stop()
    with socket.socket() as s:
        # As a server binds (werkzeug too): the connection the server closed may linger in
        # TIME_WAIT on that port, which only a listener still there should make fail.
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
        s.listen()  # nobody listens there any more


def test_gridfleet_dashboard_command_serves_the_page(playfield: Path) -> None:
    port = free_port()
    cmd = [sys.executable, "-m", "gridfleet", "dashboard", "--port", str(port)]
    proc = subprocess.Popen([*cmd, "--scenario", str(playfield)], cwd=REPO, stderr=subprocess.PIPE)
    try:

        def up() -> bool:
            try:
                return get(f"http://127.0.0.1:{port}/healthz")[0] == 200
            except OSError:
                return False

        wait_for(up, timeout=20, what="gridfleet dashboard to answer")
        status, _, body = get(f"http://127.0.0.1:{port}/api/settings")
        assert status == 200 and json.loads(body)["map"]["name"] == "playfield"
    finally:
        proc.terminate()
        proc.wait(10)


def test_serving_beyond_loopback_without_accounts_is_refused_in_one_line() -> None:
    # Like the broker: a page anyone on the network can open must ask who they are.
    cmd = [sys.executable, "-m", "gridfleet", "dashboard", "--host", "0.0.0.0", "--port", "0"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2, done.stderr
    assert "without --accounts lets anyone on that network drive the fleet" in done.stderr
    assert "Traceback" not in done.stderr
