"""free_port: under pytest-xdist, each worker's ports come from a band of its own."""

from __future__ import annotations

import socket

import pytest

from gridfleet import ports


@pytest.fixture
def worker(monkeypatch: pytest.MonkeyPatch) -> None:
    # The last band: no worker of a run of fewer than twelve uses it (their servers would be
    # passed over in it, as a port somebody holds is).
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw11")
    monkeypatch.setattr(ports, "_band", None)


@pytest.mark.usefixtures("worker")
def test_a_worker_is_handed_distinct_ports_of_its_own_band() -> None:
    handed = [ports.free_port() for _ in range(50)]
    assert len(set(handed)) == 50
    assert all(31000 <= p < 32000 for p in handed)


@pytest.mark.usefixtures("worker")
def test_a_port_somebody_holds_is_passed_over() -> None:
    first = ports.free_port()
    with socket.socket() as held:
        held.bind(("127.0.0.1", first + 1 if first + 1 < 32000 else 31000))
        taken = held.getsockname()[1]
        handed = [ports.free_port() for _ in range(100)]
    assert taken not in handed
    assert len(set(handed)) == 100


def test_a_run_beside_the_workers_takes_the_band_it_names(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)
    monkeypatch.setenv(ports.PORT_BAND_ENV, "10")
    monkeypatch.setattr(ports, "_band", None)
    handed = [ports.free_port() for _ in range(20)]
    assert len(set(handed)) == 20
    assert all(30000 <= p < 31000 for p in handed)


def test_a_second_run_of_workers_takes_the_bands_from_the_one_it_names(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw1")
    monkeypatch.setenv(ports.PORT_BAND_ENV, "6+")
    monkeypatch.setattr(ports, "_band", None)
    handed = [ports.free_port() for _ in range(20)]
    assert len(set(handed)) == 20
    assert all(27000 <= p < 28000 for p in handed)  # band 7: after 6, as worker gw1


def test_outside_xdist_the_os_picks(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)
    monkeypatch.delenv(ports.PORT_BAND_ENV, raising=False)
    port = ports.free_port()
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))  # free, as promised
