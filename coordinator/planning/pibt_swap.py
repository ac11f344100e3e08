"""Swap emulation for PIBT: two agents that must pass each other in a corridor.

Plain PIBT lets the more urgent agent push the other down the corridor ahead of it, possibly to
its end and back. Instead the one in front backs off and pulls the other along, until a side
square lets them pass: the swap technique of Okumura's LaCAM3 ("Engineering LaCAM*", 2024).
`coordinator.planning.pibt` asks `swap_partner` before each agent's move.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gridfleet.coordinator.planning.pibt import PIBT, Index


def swap_partner(s: PIBT, i: int, best: Index) -> int | None:
    """The unplanned agent `i` must swap places with to get to `best`, if any."""
    here = s.pos[i]
    if best == here:
        return None
    j = s.occupant.get(best)
    if (
        j is not None
        and not s.planned(j)
        and _swap_required(s, i, j, here, best)
        and _swap_possible(s, best, here)
    ):
        return j
    # Or a neighbour that must pass `i` the other way (as if it stood on `here` and `i` on `best`).
    for u in s.nbrs[here]:
        k = s.occupant.get(u)
        if k is None or u == best or s.planned(k):
            continue
        if _swap_required(s, k, i, here, best) and _swap_possible(s, best, here):
            return k
    return None


def _swap_required(s: PIBT, pusher: int, puller: int, v_pusher: Index, v_puller: Index) -> bool:
    """Would pushing `puller` only drive it down a corridor with no room to step aside?"""
    # Then the two can pass only if the pusher backs off instead.
    dist = s.dist
    guard = 0
    while dist(pusher, v_puller) < dist(pusher, v_pusher) and guard < len(s.nbrs):
        guard += 1
        ways = _ways_on(s, v_pusher, v_puller)
        if len(ways) >= 2:
            return False
        if not ways:
            break
        v_pusher, v_puller = v_puller, ways[0]
    return dist(puller, v_pusher) < dist(puller, v_puller) and (
        dist(pusher, v_pusher) == 0 or dist(pusher, v_puller) < dist(pusher, v_pusher)
    )


def _swap_possible(s: PIBT, v_pusher: Index, v_puller: Index) -> bool:
    """Is there a side square somewhere behind, so that backing off lets the two pass?"""
    start = v_pusher
    guard = 0
    while v_puller != start and guard < len(s.nbrs):
        guard += 1
        ways = _ways_on(s, v_pusher, v_puller)
        if len(ways) >= 2:
            return True
        if not ways:
            return False
        v_pusher, v_puller = v_puller, ways[0]
    return False


def _ways_on(s: PIBT, v_back: Index, v_front: Index) -> list[Index]:
    """The squares one can go on to from `v_front`, coming from `v_back`."""
    return [u for u in s.nbrs[v_front] if u != v_back and not _held_dead_end(s, u)]


def _held_dead_end(s: PIBT, square: Index) -> bool:
    """A dead end held by a unit on its own target: closed, that unit need not move."""
    k = s.occupant.get(square)
    return len(s.nbrs[square]) == 1 and k is not None and s.goal[k] == square
