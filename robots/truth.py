"""Ground truth for outside checkers: the world's collisions, moves and squares, one JSON line a step."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import time
from pathlib import Path

from gridfleet.robots.world import SimulatedWorld


def truth_line(world: SimulatedWorld) -> str:
    """One JSON line: wall time, this process, the world's collision and move counts, every square."""
    return json.dumps(
        {
            "t": time.time(),
            "pid": os.getpid(),
            "collisions": world.collisions,
            "prevented": world.prevented,
            "moves": sum(world.moves.values()),
            "positions": {uid: [c.x, c.y] for uid, c in sorted(world.positions.items())},
        },
        separators=(",", ":"),
    )


async def write_truth(
    world: SimulatedWorld, path: Path, period_s: float, shutdown: asyncio.Event
) -> None:
    """Append a truth line every `period_s` until `stop`, and one last line then."""
    # Appended and flushed line by line: a process killed with SIGKILL leaves whole lines only,
    # and a restarted one adds to the same file (its pid tells the runs apart).
    with path.open("a", encoding="utf-8") as out:
        while True:
            out.write(truth_line(world) + "\n")
            out.flush()
            if shutdown.is_set():
                return
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(shutdown.wait(), period_s)
