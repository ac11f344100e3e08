"""Making way: where an idle unit standing on another unit's target goes to wait instead.

Pure. PIBT moves an idle unit only when pushed, and a pushed unit that has nowhere to go but the
pusher's square (the end of a dead end, a one-wide pocket) stays: the unit that needs that square
waits forever. So an idle unit on a square another unit is heading for gets a target of its own,
a parking square, and leaves before the other arrives (the corridor swap lets the two pass).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Collection, Iterator, Sequence

Index = int  # a square as a flat index: y * width + x
OPEN = 4  # free neighbours of a square on open floor, where a waiting unit is easily passed


def parking_square(
    nbrs: Sequence[tuple[Index, ...]],
    start: Index,
    avoid: Collection[Index],
    occupied: Collection[Index],
) -> Index | None:
    """The nearest square off every target and free of units, on open floor if any is reachable.

    Not a junction of one-wide aisles: a unit parked there stood in every aisle's way at once
    (warehouse runs jammed for minutes 1 time in 20 with junctions, not in 40 with open floor).
    """
    fallback: Index | None = None
    for here in nearest_first(nbrs, start):
        if here != start and here not in avoid and here not in occupied:
            if len(nbrs[here]) >= OPEN:
                return here
            if fallback is None:
                fallback = here
    return fallback


def nearest_first(nbrs: Sequence[tuple[Index, ...]], start: Index) -> Iterator[Index]:
    """Every square reachable from `start`, nearest first (`start` itself first)."""
    seen = {start}
    queue = deque([start])
    while queue:
        here = queue.popleft()
        yield here
        for n in nbrs[here]:
            if n not in seen:
                seen.add(n)
                queue.append(n)
