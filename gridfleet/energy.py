"""A scenario's batteries and the coordinator's charge thresholds: plain data, and their one rule."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class BatterySpec:
    """A unit's battery: its charge at the start and its energy model, in % of a full charge."""

    start_pct: float = 100.0
    move_pct: float = 0.5  # one move (one square)
    idle_pct_per_s: float = 0.01  # a second standing
    charge_pct_per_s: float = 2.0  # a second on a charger


@dataclass(frozen=True)
class ChargingSpec:
    """The coordinator's charge thresholds for a scenario (openTCS's four; protocol.md §5.9)."""

    critical_pct: float = 20.0
    good_pct: float = 50.0
    sufficient_pct: float = 80.0
    full_pct: float = 95.0
    available_from: str = "sufficient"  # or "full": when a charging unit takes jobs again


def thresholds_problem(spec: ChargingSpec) -> str | None:
    """Why these thresholds cannot work together, or None when they can."""
    c, g, s, f = spec.critical_pct, spec.good_pct, spec.sufficient_pct, spec.full_pct
    if not c < g <= s <= f:
        return (
            "thresholds must rise: critical_pct < good_pct <= sufficient_pct <= full_pct, "
            f"got {c:g} < {g:g} <= {s:g} <= {f:g}"
        )
    if not g < f:  # a unit charged to full and below good at once would go again at once
        return (
            "good_pct must be below full_pct (a unit charged to full would be sent again at "
            f"once), got good_pct {g:g} and full_pct {f:g}"
        )
    return None
