"""What one system bench run measured, and the medians over repeated runs."""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

from gridfleet.bench.system.procs import ProcessFigures


@dataclass(frozen=True)
class SystemResult:
    """One run of `gridfleet bench system`: figures of the measured window and the stop trials."""

    units: int
    step_s: float
    broker: str  # "embedded amqtt" or the URL given
    deploy: str  # "processes" (as deployed) or "threads"
    window: int  # squares a unit could be released ahead (the coordinator's --window)
    unit_workers: int  # processes the units ran in
    map_size: tuple[int, int]
    free_squares: int
    duration_s: float  # the measured window as it really lasted
    messages: int
    messages_per_s: float
    per_kind_per_s: dict[str, float]
    steps: int
    step_rate: float  # achieved coordinator steps per second
    nominal_step_rate: float
    moves_per_unit_s: float
    jobs_done: int
    jobs_submitted: int
    state_latency_ms_p50: float | None
    state_latency_ms_p99: float | None
    estop_ms: tuple[float | None, ...]  # publish → the monitor saw every unit stopped; None: never
    estop_ms_p99: float | None  # over every engagement; None when any was never shown
    estop_applied_ms: tuple[float | None, ...]  # publish → the last unit's state was made
    moved_while_stopped: int  # world moves after every unit showed the stop (must be 0)
    collisions: int  # the world simulation's ground truth (must be 0)
    prevented: int  # moves the world refused (a unit tried a blocked square)
    processes: tuple[ProcessFigures, ...] = ()  # each process: CPU % of a core, peak RSS

    @property
    def estop_ms_median(self) -> float | None:
        """Median stop latency over the engagements that completed."""
        done = [v for v in self.estop_ms if v is not None]
        return statistics.median(done) if done else None

    def as_json(self) -> dict[str, Any]:
        """Plain JSON types only."""
        data = asdict(self)
        data["map_size"] = list(self.map_size)
        data["estop_ms"] = list(self.estop_ms)
        data["estop_applied_ms"] = list(self.estop_applied_ms)
        data["processes"] = [asdict(p) for p in self.processes]
        data["estop_ms_median"] = self.estop_ms_median
        return data


SUMMARY_FIELDS = (
    "messages_per_s",
    "step_rate",
    "moves_per_unit_s",
    "jobs_done",
    "state_latency_ms_p50",
    "state_latency_ms_p99",
    "estop_ms_median",
    "estop_ms_p99",
    "collisions",
    "prevented",
    "moved_while_stopped",
)


def summarise(runs: Sequence[SystemResult]) -> dict[str, Any]:
    """Median, min and max of each figure over repeated runs of one unit count."""
    out: dict[str, Any] = {
        "units": runs[0].units,
        "window": runs[0].window,
        "runs": len(runs),
        "nominal_step_rate": runs[0].nominal_step_rate,
    }
    for name in SUMMARY_FIELDS:
        values = [v for v in (getattr(r, name) for r in runs) if v is not None]
        if name in ("collisions", "moved_while_stopped"):
            out[name] = sum(values)  # totals: any one is a failure, not to be hidden by a median
            continue
        out[name] = (
            {"median": statistics.median(values), "min": min(values), "max": max(values)}
            if values
            else None
        )
    return out
