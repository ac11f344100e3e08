"""The dashboard given a list of brokers (a cluster's): checked item by item, handed to the page."""

from __future__ import annotations

import pytest

from gridfleet.dashboard.app import api_broker, create_app
from gridfleet.dashboard.cli import settings_from
from gridfleet.dashboard.settings import DashboardSettings, browser_broker_url
from gridfleet.errors import ConfigError
from gridfleet.system.cli import build_parser


@pytest.mark.parametrize(
    ("broker_ws", "words"),
    [
        # The item the page cannot speak is named, with the list it is in.
        (
            "ws://127.0.0.1:9001,mqtt://127.0.0.2:1883",
            r"'mqtt://127.0.0.2:1883' \(in the list .*\): the page needs a websocket URL",
        ),
        ("ws://127.0.0.1:9001,ws://127.0.0.1:9001", "ws://127.0.0.1:9001 is in it twice"),
        ("ws://127.0.0.1:9001,,ws://127.0.0.2:9001", "an empty item"),
        ("ws://127.0.0.1:9001,ws://", "broker URL 'ws://': no host"),
        (
            "ws://u:secret-pw@127.0.0.1:9001,ws://u:secret-pw@127.0.0.2:9001",
            r"ws://u@127.0.0.1:9001 \(in the list .*\): no login in the URL",
        ),
    ],
)
def test_a_bad_item_of_the_page_s_list_is_refused_in_one_line_naming_it(
    broker_ws: str, words: str
) -> None:
    with pytest.raises(ConfigError, match=words) as refused:
        DashboardSettings(broker_ws=broker_ws)
    assert "\n" not in str(refused.value)
    assert "secret-pw" not in str(refused.value)


def test_a_bad_audit_broker_list_is_refused_at_the_start() -> None:
    with pytest.raises(ConfigError, match="in it twice"):
        DashboardSettings(audit_broker="mqtt://127.0.0.1:1883,mqtt://127.0.0.1:1883")
    with pytest.raises(ConfigError, match="scheme"):
        DashboardSettings(audit_broker="mqtt://127.0.0.1:1883,http://127.0.0.2:1883")
    # TCP, TLS and websocket URLs mixed: the dashboard's own clients speak them all.
    DashboardSettings(audit_broker="mqtt://127.0.0.1:1883,ws://127.0.0.2:9001")


def test_each_wildcard_broker_of_a_list_is_reached_where_the_page_came_from() -> None:
    listed = "ws://0.0.0.0:9001,wss://10.0.0.2:9443/mqtt,ws://[::]:9002"
    assert browser_broker_url(listed, "fleet.lan:5000") == (
        "ws://fleet.lan:9001,wss://10.0.0.2:9443/mqtt,ws://fleet.lan:9002"
    )
    assert browser_broker_url(listed, None) == listed


def test_the_page_gets_the_whole_list() -> None:
    settings = DashboardSettings(broker_ws="ws://0.0.0.0:9001, ws://127.0.0.1:9002")
    client = create_app(settings).test_client()
    body = client.get("/api/settings", headers={"Host": "127.0.0.1:5000"}).get_json()
    assert body["broker_ws"] == "ws://127.0.0.1:9001,ws://127.0.0.1:9002"


def test_the_dashboard_s_own_clients_take_the_page_s_list_by_default() -> None:
    parser = build_parser(only="dashboard")
    args = parser.parse_args(["dashboard", "--broker-ws", "ws://0.0.0.0:9001,ws://10.0.0.2:9002"])
    settings = settings_from(args, environ={})
    assert api_broker(settings) == "ws://127.0.0.1:9001,ws://10.0.0.2:9002"
    listed = "mqtt://127.0.0.1:1883,mqtt://127.0.0.1:1884"
    args = parser.parse_args(["dashboard", "--audit-broker", listed])
    assert api_broker(settings_from(args, environ={})) == listed
