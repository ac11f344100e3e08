"""The fleet runner: the units of a scenario (or a subset) in one process, one MQTT client each."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Mapping, Sequence
from pathlib import Path

from gridfleet.accounts import Accounts
from gridfleet.config import check_step, parse_brokers, with_credentials
from gridfleet.errors import ConfigError
from gridfleet.grid import Cell
from gridfleet.protocol import Topics
from gridfleet.protocol.constants import DEFAULT_ROOT, DEFAULT_STEP_S
from gridfleet.robots.battery import Battery
from gridfleet.robots.saved import Saved, SavedUnits
from gridfleet.robots.shell import UnitShell
from gridfleet.robots.unit import Mode, UnitLogic
from gridfleet.robots.world import SimulatedWorld, WorldSim
from gridfleet.scenario import Scenario, with_units

# A process's units step in groups of at most this many, spread over the step period: each unit
# keeps a clock of its own, as a real one does, so a process's states do not all leave in one
# burst (50 units at once kept the last state 15 ms behind its stamp; 250 at once, 60 ms), and
# the process does not wake up for every unit on its own.
STEP_GROUP = 12


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
        state_path: Path | None = None,
        world: SimulatedWorld | None = None,
    ) -> None:
        parse_brokers(broker_url)  # a bad URL or list: a clear error now, not a retry loop later
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
        # A world shared with the other processes of a sharded fleet holds every unit already.
        shared = world is not None
        self.world: SimulatedWorld = world or WorldSim.from_scenario(
            scenario, sensors_see_units=sensors_see_units
        )
        # Where the local units stood and what they carried when this process last ran.
        self.saved = None if state_path is None else SavedUnits(state_path)
        resumed = {} if self.saved is None else self.saved.load(scenario.grid, local)
        _check_resumed(scenario, local, resumed, state_path)
        for uid, was in resumed.items():
            self.world.resume(uid, was.position)
        for spec in scenario.units:
            if spec.id not in local and isinstance(self.world, WorldSim):
                self.world.place(spec.id, spec.start)  # best guess until its state arrives
        wanted = {g.unit: g.target for g in scenario.goals} if mode == "standalone" else {}
        wanted.update(goals or {})
        self.shells: dict[str, UnitShell] = {}
        groups = -(-len(local) // STEP_GROUP)
        chargers = frozenset(c.square for c in scenario.chargers)  # where this world charges
        for spec in scenario.units:
            if spec.id not in local:
                continue
            was = resumed.get(spec.id, Saved(spec.start))
            battery = None if spec.battery is None else Battery.from_spec(spec.battery, step)
            if battery is not None and was.battery_pct is not None:
                battery = Battery(battery.model, was.battery_pct)  # as it was when it stopped
            logic = UnitLogic(
                spec.id,
                scenario.grid,
                was.position,
                spec.capacity,
                step,
                mode=mode,
                goal=wanted.get(spec.id),
                battery=battery,
                chargers=chargers,
            )
            logic.job_id, logic.load_kg = was.job_id, was.load_kg
            url = broker_url
            if accounts is not None:  # each unit logs in as itself
                account = accounts.get(spec.id)
                url = with_credentials(broker_url, account.name, account.password)
            self.shells[spec.id] = UnitShell(
                logic,
                self.world,
                url,
                self.topics,
                color=spec.color,
                watch_remote=not shared and not self.shells and len(local) < len(known),
                reconnect_s=reconnect_s,
                on_step=None if self.saved is None else self._save,
                phase_s=step * (len(self.shells) % groups) / groups,
            )
            if self.saved is not None:
                self._save(logic)
        self.ready = asyncio.Event()  # set once every local unit is online

    def _save(self, logic: UnitLogic) -> None:
        assert self.saved is not None
        # The charge to a tenth: a unit standing still writes a row every few hundred steps.
        battery = None if logic.battery is None else logic.battery.shown_pct
        self.saved.save(logic.unit_id, Saved(logic.position, logic.job_id, logic.load_kg, battery))

    @property
    def logic(self) -> dict[str, UnitLogic]:
        """The pure core of every local unit."""
        return {uid: r.logic for uid, r in self.shells.items()}

    async def run(self, shutdown: asyncio.Event) -> None:
        """Run every local unit until `stop` is set; each says "offline" before it returns."""
        tasks = [asyncio.create_task(r.run(shutdown), name=uid) for uid, r in self.shells.items()]
        watcher = asyncio.create_task(self._watch_ready(shutdown))
        try:
            await asyncio.gather(*tasks)
        finally:
            watcher.cancel()
            for t in tasks:
                t.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.gather(*tasks, watcher, return_exceptions=True)
            if self.saved is not None:
                self.saved.close()

    async def _watch_ready(self, shutdown: asyncio.Event) -> None:
        while not shutdown.is_set():
            await asyncio.gather(*(r.online.wait() for r in self.shells.values()))
            self.ready.set()
            return


def _check_resumed(
    scenario: Scenario, local: Sequence[str], resumed: Mapping[str, Saved], path: Path | None
) -> None:
    """Saved squares and loads must fit the scenario: one local unit a square, within capacity."""
    seen: dict[Cell, str] = {}
    for spec in scenario.units:
        if spec.id not in local:
            continue
        was = resumed.get(spec.id, Saved(spec.start))
        if was.load_kg > spec.capacity:
            raise ConfigError(
                f"{path}: unit {spec.id} carries {was.load_kg} kg, over its capacity "
                f"{spec.capacity} kg"
            )
        other = seen.setdefault(was.position, spec.id)
        if other != spec.id:
            raise ConfigError(
                f"{path}: units {other} and {spec.id} would both stand on {list(was.position)}"
            )
