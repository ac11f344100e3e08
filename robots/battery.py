"""A unit's battery, pure: its charge in % of a full one, drained and charged step by step.

Time is the unit's steps, never the wall clock: a step with a move costs `move_pct`, a step
standing `idle_pct_per_s` x the step period, a step charging adds `charge_pct_per_s` x the step
period (and costs nothing), never below 0 nor above 100 (protocol.md §4.3). A simulated run is
therefore the same every time. It also keeps what a run reports of it: its lowest charge, how
many charges it made (a charge: a spell of charging steps), how many steps it charged, and
whether it ever ran empty.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from gridfleet.protocol.constants import DEFAULT_STEP_S
from gridfleet.protocol.messages import EnergyModel

if TYPE_CHECKING:  # a pure core: the scenario loader (files, TOML) is not loaded with it
    from gridfleet.energy import BatterySpec

FULL_PCT = 100.0
# A simulated unit lives in simulated time: each of its steps is this long a life of its battery
# (the course's step period), whatever the step period it runs at; `--step 0.02` runs it faster.
SIMULATED_STEP_S = DEFAULT_STEP_S
SHOWN_DECIMALS = 1  # the state's `battery_pct`: a tenth of a percent is all anyone reads
EMPTY_BELOW_PCT = 0.05  # what the state shows as 0.0: empty, the unit cannot move


class Battery:
    """One battery: its model, its charge now, and what it went through."""

    def __init__(self, model: EnergyModel, start_pct: float = FULL_PCT) -> None:
        if not 0.0 <= start_pct <= FULL_PCT:
            raise ValueError(f"start_pct {start_pct} is not 0..100")
        self.model = model
        self.pct = float(start_pct)
        self.lowest_pct = self.pct
        self.charges = 0  # spells of charging steps begun
        self.charging_steps = 0  # steps spent charging, all spells together
        self.standing_steps = 0  # steps it neither moved nor charged
        self.reached_empty = self.empty
        self._charging = False  # the last step charged

    @classmethod
    def from_spec(cls, spec: BatterySpec, simulated_step_s: float | None = None) -> Battery:
        """The battery a scenario gives a unit, living in real time (a Webots unit's).

        With `simulated_step_s` (the step period a simulated unit runs at), in simulated time:
        a step drains and charges as SIMULATED_STEP_S seconds would, and the model (what its
        factsheet says) states the rates per second of the run, so the coordinator's forecasts
        hold: at `--step 0.02` a charge of 2 % a second is 100 % a second of the run.
        """
        scale = 1.0 if simulated_step_s is None else SIMULATED_STEP_S / simulated_step_s
        model = EnergyModel(
            move_pct=spec.move_pct,
            idle_pct_per_s=spec.idle_pct_per_s * scale,
            charge_pct_per_s=spec.charge_pct_per_s * scale,
        )
        return cls(model, spec.start_pct)

    @property
    def empty(self) -> bool:
        """Too little left to move: what its state shows as 0.0 %."""
        return self.pct < EMPTY_BELOW_PCT

    @property
    def shown_pct(self) -> float:
        """The charge as the state reports it, to a tenth of a percent."""
        return round(self.pct, SHOWN_DECIMALS)

    @property
    def whole_pct(self) -> int:
        """The whole percent of its charge (a state goes out when it changes)."""
        return int(self.pct)

    def step(self, *, moved: bool, charging: bool, step_s: float) -> None:
        """One step of the unit: it moved, charged, or stood."""
        m = self.model
        if charging:
            self.pct = min(FULL_PCT, self.pct + m.charge_pct_per_s * step_s)
            self.charging_steps += 1
            if not self._charging:
                self.charges += 1
        elif moved:
            self.pct = max(0.0, self.pct - m.move_pct)
        else:
            self.pct = max(0.0, self.pct - m.idle_pct_per_s * step_s)
            self.standing_steps += 1
        self._charging = charging
        self.lowest_pct = min(self.lowest_pct, self.pct)
        self.reached_empty = self.reached_empty or self.empty
