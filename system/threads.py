"""Services in threads of their own, each with its own event loop: how the system runs in-process."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Generic, Protocol, Self, TypeVar

from gridfleet.scenario import Scenario

if TYPE_CHECKING:
    from gridfleet.coordinator.shell import CoordinatorShell
    from gridfleet.robots.fleet import Fleet
    from gridfleet.robots.world import WorldSim

T = TypeVar("T")


class Service(Protocol):
    """What a runnable component offers: `ready` once online, `run` until `stop` is set."""

    ready: asyncio.Event

    async def run(self, shutdown: asyncio.Event) -> None:
        """Run until `stop` is set."""


S = TypeVar("S", bound=Service)


class ServiceThread(Generic[S]):
    """One service in its own thread and event loop; `with` starts it and waits until it is ready."""

    def __init__(self, make: Callable[[], S], name: str) -> None:
        self.name = name
        self._make = make
        self._service: S | None = None
        self._loop = asyncio.new_event_loop()
        self._stop: asyncio.Event | None = None
        self._ready: Future[None] = Future()
        self._done: Future[None] = Future()
        self._thread = threading.Thread(target=self._main, name=name, daemon=True)

    def _main(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._run())
        except BaseException as exc:  # surfaced by stop(), and by start() if it never got ready
            self._done.set_exception(exc)
        else:
            self._done.set_result(None)
        finally:
            self._loop.close()

    @property
    def service(self) -> S:
        """The running service object (made in its own thread: sqlite and loops are per thread)."""
        assert self._service is not None, f"{self.name} not started"
        return self._service

    async def _run(self) -> None:
        self._stop = asyncio.Event()
        self._service = service = self._make()

        async def watch() -> None:
            await service.ready.wait()
            self._ready.set_result(None)

        watcher = asyncio.create_task(watch())
        try:
            await service.run(self._stop)
        finally:
            watcher.cancel()

    def start(self, timeout: float = 30.0) -> Self:
        """Start the service and wait until it says it is ready."""
        self._thread.start()
        wait([self._ready, self._done], timeout, return_when=FIRST_COMPLETED)
        if self._ready.done():
            return self
        if self._done.done():
            self._done.result()  # it died while starting: raise its error here
            raise RuntimeError(f"{self.name} ended before it was ready")
        raise TimeoutError(f"{self.name} not ready after {timeout} s")

    def stop(self, timeout: float = 30.0) -> None:
        """Ask the service to stop cleanly, wait for it, and raise any error it ended with."""
        if self._thread.is_alive() and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise TimeoutError(f"{self.name} did not stop within {timeout} s")
        self._done.result(0)

    def check(self) -> None:
        """Raise the error the service died of, if it has ended while it should be running."""
        if self._done.done():
            self._done.result()
            if self._stop is None or not self._stop.is_set():
                raise RuntimeError(f"{self.name} ended on its own")

    def call(self, fn: Callable[[], T], timeout: float = 10.0) -> T:
        """Run `fn` in the service's own thread and event loop (no races with it); its result."""
        result: Future[T] = Future()

        def run() -> None:
            try:
                result.set_result(fn())
            except BaseException as exc:  # handed to the caller below
                result.set_exception(exc)

        self._loop.call_soon_threadsafe(run)
        return result.result(timeout)

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(
        self, et: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()


def coordinator_thread(
    scenario: Scenario,
    broker_url: str,
    *,
    root: str,
    step_s: float,
    db_path: Path,
    energy_policy: str = "gridfleet",
    **kw: Any,
) -> ServiceThread[CoordinatorShell]:
    """The real coordinator for a scenario's map, chargers, places and [charging] (under its
    energy policy, unless `energy` is given), with its job store at `db_path`."""
    from gridfleet.coordinator.shell import CoordinatorShell

    def make() -> CoordinatorShell:
        from gridfleet.coordinator.cli import site_of
        from gridfleet.coordinator.energy import EnergySettings

        site = site_of(scenario)
        kw.setdefault("energy", EnergySettings.of(scenario.charging, energy_policy))
        return CoordinatorShell(
            broker_url,
            scenario.grid,
            root=root,
            step_s=step_s,
            db_path=db_path,
            chargers=site.chargers,
            places=site.places,
            **kw,
        )

    return ServiceThread(make, "gridfleet-coordinator")


def fleet_thread(
    scenario: Scenario,
    broker_url: str,
    *,
    root: str,
    step_s: float,
    units: Sequence[str] | None = None,
    **kw: Any,
) -> ServiceThread[Fleet]:
    """The scenario's simulated units (all, or a subset) over the real broker."""
    from gridfleet.robots.fleet import Fleet

    def make() -> Fleet:
        return Fleet(scenario, broker_url, root=root, step=step_s, units=units, **kw)

    return ServiceThread(make, "gridfleet-units")


def world_of(fleet: ServiceThread[Fleet]) -> WorldSim:
    """The ground-truth world simulation of a running fleet."""
    from gridfleet.robots.world import WorldSim  # the robots layer, loaded when used (as above)

    service = fleet.service
    assert isinstance(service.world, WorldSim)  # a fleet in a thread is never sharded
    return service.world
