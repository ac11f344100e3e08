"""The fleet runner: the units of a scenario (or a subset) in one process, one MQTT client each."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Mapping, Sequence

from gridfleet.accounts import Accounts
from gridfleet.config import check_step, parse_broker_url, with_credentials
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol import Topics
from gridfleet.protocol.constants import DEFAULT_ROOT, DEFAULT_STEP_S
from gridfleet.scenario import Scenario, with_units
from robots.runner import UnitRunner
from robots.unit import Mode, UnitLogic
from robots.world import WorldSim


class Fleet:
    """Runs the local units of a scenario against one world; units elsewhere are seen by state."""

    def __init__(
        self,
        scenario: Scenario,
        broker_url: str,
        *,
        root: str = DEFAULT_ROOT,
        units: Sequence[str] | None = None,
        step: float = DEFAULT_STEP_S,
        mode: Mode = "coordinated",
        goals: Mapping[str, Cell] | None = None,
        reconnect_s: float = 0.1,
        sensors_see_units: bool = True,
        accounts: Accounts | None = None,
    ) -> None:
        parse_broker_url(broker_url)  # a bad URL is a clear error now, not a retry loop later
        known = [u.id for u in with_units(scenario).units]
        local = list(known if units is None else units)
        for uid in local:
            if uid not in known:
                raise ConfigError(
                    f"unknown unit {uid!r}: scenario {scenario.name!r} has {', '.join(known) or 'none'}"
                )
        if not local:
            raise ConfigError("units: give at least one unit id")
        check_step(step)
        self.scenario = scenario
        self.topics = Topics(root)
        self.world = WorldSim.from_scenario(scenario, sensors_see_units=sensors_see_units)
        for spec in scenario.units:
            if spec.id not in local:
                self.world.place(spec.id, spec.start)  # best guess until its state arrives
        wanted = {g.unit: g.target for g in scenario.goals} if mode == "standalone" else {}
        wanted.update(goals or {})
        self.runners: dict[str, UnitRunner] = {}
        for spec in scenario.units:
            if spec.id not in local:
                continue
            logic = UnitLogic(
                spec.id,
                scenario.grid,
                spec.start,
                spec.capacity,
                step,
                mode=mode,
                goal=wanted.get(spec.id),
            )
            url = broker_url
            if accounts is not None:  # each unit logs in as itself
                account = accounts.get(spec.id)
                url = with_credentials(broker_url, account.name, account.password)
            self.runners[spec.id] = UnitRunner(
                logic,
                self.world,
                url,
                self.topics,
                color=spec.color,
                watch_remote=not self.runners and len(local) < len(known),
                reconnect_s=reconnect_s,
            )
        self.ready = asyncio.Event()  # set once every local unit is online

    @property
    def logic(self) -> dict[str, UnitLogic]:
        """The pure core of every local unit."""
        return {uid: r.logic for uid, r in self.runners.items()}

    async def run(self, stop: asyncio.Event) -> None:
        """Run every local unit until `stop` is set; each says "offline" before it returns."""
        tasks = [asyncio.create_task(r.run(stop), name=uid) for uid, r in self.runners.items()]
        watcher = asyncio.create_task(self._watch_ready(stop))
        try:
            await asyncio.gather(*tasks)
        finally:
            watcher.cancel()
            for t in tasks:
                t.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.gather(*tasks, watcher, return_exceptions=True)

    async def _watch_ready(self, stop: asyncio.Event) -> None:
        while not stop.is_set():
            await asyncio.gather(*(r.online.wait() for r in self.runners.values()))
            self.ready.set()
            return
