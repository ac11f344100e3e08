"""Plan validator, the oracle of every planner test: continuity, walls, vertex, swap, rotation;
released windows, checked like a plan: contiguous, on free squares, nobody else's; and closed
zones: nobody outside one stands on or holds a square of it."""

from __future__ import annotations

from collections.abc import Container, Sequence
from dataclasses import dataclass

from gridfleet.grid import Cell, GridMap


@dataclass(frozen=True)
class Violation:
    """One broken rule: at which step (transition t → t+1), which kind, which agents, and how."""

    step: int
    # "continuity" | "wall" | "vertex" | "swap" | "rotation"; windows: "occupied" | "overlap" |
    # "length"; closed zones: "zone"
    kind: str
    agents: tuple[int, ...]
    detail: str


def validate_plan(grid: GridMap, plan: Sequence[Sequence[Cell]]) -> list[Violation]:
    """Every violation in `plan` (plan[t][i] is agent i's square at time t); empty when clean."""
    out: list[Violation] = []
    for t, row in enumerate(plan):
        out.extend(_check_squares(grid, t, row))
    for t in range(len(plan) - 1):
        out.extend(validate_step(grid, plan[t], plan[t + 1], t, check_squares=False))
    return out


def _check_squares(grid: GridMap, t: int, row: Sequence[Cell]) -> list[Violation]:
    out: list[Violation] = []
    seen: dict[Cell, int] = {}
    for i, c in enumerate(row):
        if not grid.is_free(c):
            out.append(Violation(t, "wall", (i,), f"agent {i} on blocked square {list(c)}"))
        if c in seen:
            out.append(
                Violation(t, "vertex", (seen[c], i), f"agents {seen[c]} and {i} on {list(c)}")
            )
        else:
            seen[c] = i
    return out


def validate_step(
    grid: GridMap,
    before: Sequence[Cell],
    after: Sequence[Cell],
    step: int = 0,
    check_squares: bool = True,
) -> list[Violation]:
    """Violations of one transition `before` → `after` (same agent order)."""
    out: list[Violation] = []
    if len(before) != len(after):
        return [Violation(step, "continuity", (), "agent count changed")]
    if check_squares:
        out.extend(_check_squares(grid, step, before))
        out.extend(_check_squares(grid, step + 1, after))
    for i, (a, b) in enumerate(zip(before, after, strict=True)):
        if a != b and a.manhattan(b) != 1:
            out.append(
                Violation(step, "continuity", (i,), f"agent {i} jumps {list(a)} -> {list(b)}")
            )
    occupant = {c: i for i, c in enumerate(before)}
    # Edge "i moves into the square j vacates": a 2-cycle is a swap, a longer one a rotation.
    follows: dict[int, int] = {}
    for i, (a, b) in enumerate(zip(before, after, strict=True)):
        j = occupant.get(b)
        if a != b and j is not None and j != i:
            follows[i] = j
    reported: set[frozenset[int]] = set()
    for start in follows:
        path = [start]
        k = follows[start]
        while k in follows and k not in path and len(path) <= len(before):
            path.append(k)
            k = follows[k]
        if k == start:
            key = frozenset(path)
            if key in reported:
                continue
            reported.add(key)
            kind = "swap" if len(path) == 2 else "rotation"
            out.append(
                Violation(step, kind, tuple(sorted(path)), f"{kind} of agents {sorted(path)}")
            )
    return out


def validate_windows(
    grid: GridMap,
    positions: Sequence[Cell],
    windows: Sequence[Sequence[Cell]],
    bound: int | None = None,
) -> list[Violation]:
    """Every violation in released windows (windows[i]: what agent i may still drive, in order).

    A window starts next to its agent and goes on square by square (continuity), on free squares
    (wall), never onto a square another agent stands on (occupied) or another window holds
    (overlap), and is at most `bound` squares long (length): then no two agents can ever meet,
    whatever their clocks, since each drives only its own window.
    """
    out: list[Violation] = []
    if len(positions) != len(windows):
        return [Violation(0, "continuity", (), "agent count and window count differ")]
    out.extend(_check_squares(grid, 0, positions))
    occupant = {c: i for i, c in enumerate(positions)}
    holder: dict[Cell, int] = {}
    for i, window in enumerate(windows):
        if bound is not None and len(window) > bound:
            out.append(Violation(0, "length", (i,), f"agent {i}: {len(window)} > {bound} squares"))
        before = positions[i]
        for c in window:
            if before.manhattan(c) != 1:
                detail = f"agent {i}: {list(c)} is not next to {list(before)}"
                out.append(Violation(0, "continuity", (i,), detail))
            before = c
            if not grid.is_free(c):
                out.append(Violation(0, "wall", (i,), f"agent {i}: window on blocked {list(c)}"))
            j = occupant.get(c)
            if j is not None and j != i:
                detail = f"agent {i}'s window holds {list(c)}, where agent {j} stands"
                out.append(Violation(0, "occupied", (i, j), detail))
            k = holder.setdefault(c, i)
            if k != i:
                detail = f"agents {k} and {i} both hold {list(c)}"
                out.append(Violation(0, "overlap", (k, i), detail))
    return out


def validate_zones(
    positions: Sequence[Cell],
    windows: Sequence[Sequence[Cell]],
    closed: Container[Cell],
    inside: Container[int] = (),
) -> list[Violation]:
    """Every violation of closed zones (coordinator/zones.py): an agent not `inside` (those that
    stood in a closed zone, or held squares of one, when it closed, and have not left it since)
    on a `closed` square, or with one in its window (windows[i]: what agent i may still drive).
    """
    out: list[Violation] = []
    for i, (here, window) in enumerate(zip(positions, windows, strict=True)):
        if i in inside:
            continue
        if here in closed:
            out.append(Violation(0, "zone", (i,), f"agent {i} stands on closed {list(here)}"))
        for c in window:
            if c in closed:
                detail = f"agent {i}'s window holds closed {list(c)}"
                out.append(Violation(0, "zone", (i,), detail))
    return out
