"""The one place the system is put together: what each mode refuses, and threads end to end."""

from __future__ import annotations

from pathlib import Path

import pytest

from gridfleet.accounts import default_accounts
from gridfleet.errors import ConfigError
from gridfleet.scenario import load_scenario
from gridfleet.system.assembly import Assembly, SystemSpec
from gridfleet.system.broker_thread import BrokerThread
from gridfleet.system.threads import world_of

from support.paths import MAPS


@pytest.mark.parametrize(
    ("mode", "settings", "words"),
    [
        ("threads", {"dashboard_port": 0}, "only as processes"),
        ("threads", {"feed": True}, "only as processes"),
        ("processes", {"seed": 3}, "only in threads"),
        ("processes", {"sensors_see_units": False}, "only in threads"),
        ("processes", {"accounts": default_accounts(["east"])}, "processes take accounts_file"),
        ("threads", {"listen": "0.0.0.0"}, "only as processes"),
        ("threads", {"tls_cert": Path("server.pem")}, "only as processes"),
    ],
)
def test_settings_of_the_other_mode_are_refused(
    mode: str, settings: dict[str, object], words: str
) -> None:
    spec = SystemSpec(load_scenario(MAPS / "corridor.toml"), **settings)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=words):
        Assembly(spec, mode)  # type: ignore[arg-type]


def test_threads_with_a_broker_of_its_own_start_and_stop_cleanly() -> None:
    spec = SystemSpec(load_scenario(MAPS / "corridor.toml"), step_s=0.05, ws_port=None)
    assembly = Assembly(spec, "threads")
    system = assembly.start_threads()
    try:
        assert system.url.startswith("mqtt://127.0.0.1:") and system.ws_url is None
        assert sorted(world_of(system.fleet).positions) == ["east", "west"]
    finally:
        assembly.stop()
    assert system.threads == {} and system.broker_thread is None


def test_threads_on_a_given_broker_leave_it_running(broker: BrokerThread, root: str) -> None:
    spec = SystemSpec(load_scenario(MAPS / "corridor.toml"), broker=broker.url, root=root)
    assembly = Assembly(spec, "threads")
    system = assembly.start_threads()
    assembly.stop()
    assert system.url == broker.url and system.broker_thread is None
    assert broker.port  # still there for the rest of the session
