"""Stray items (protocol.md §6.2, §8): a unit carrying the item of a job that is over for it.

Pure. A unit can carry an item no active job of its own accounts for: its job was cancelled after
pick-up, or failed while the unit was away (a restarted units process resumes with the item on
board), or the job store forgot it. Such a unit would never get work again (only empty units get
jobs), so it puts the item back: at the job's pickup when that square is still free, else where it
stands; then it is free.
"""

from __future__ import annotations

from gridfleet.coordinator.jobs import JobBook
from gridfleet.coordinator.world import UnitRecord
from gridfleet.grid import GridMap
from gridfleet.protocol import Action

UNKNOWN_MASS_KG = 0.001  # an item of a forgotten job: the unit drops by job id, not by mass


def stray_items(
    units: list[UnitRecord], active: set[str], jobs: JobBook, grid: GridMap
) -> dict[str, Action]:
    """The put-down action of every active unit carrying an item of no active job of its own."""
    out: dict[str, Action] = {}
    for u in units:
        st = u.state
        if st is None or st.job_id is None or u.id not in active:
            continue
        job = jobs.get(st.job_id)
        if job is None:
            mass = st.load_kg if st.load_kg > 0 else UNKNOWN_MASS_KG
            out[u.id] = Action(kind="drop", job_id=st.job_id, square=st.position, mass_kg=mass)
        elif job.final:
            square = job.pickup if grid.is_free(job.pickup) else st.position
            out[u.id] = Action(kind="drop", job_id=job.id, square=square, mass_kg=job.mass_kg)
    return out
