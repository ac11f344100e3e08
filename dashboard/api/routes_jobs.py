"""`/jobs`: submit (idempotent with a key), list with filters and pages, one job, cancel."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from flask import Response

from gridfleet.dashboard.api.context import PREFIX, caller, current
from gridfleet.dashboard.api.fleet import FleetView
from gridfleet.dashboard.api.idempotency import derived_id, reused_words
from gridfleet.dashboard.api.identity import Caller
from gridfleet.dashboard.api.models import JobRequest, JobsPage
from gridfleet.dashboard.api.params import JobPath, JobsQuery, SubmitHeaders
from gridfleet.dashboard.api.problems import ApiProblem, accepted, accepted_page
from gridfleet.dashboard.api.web import also, answer, blueprint
from gridfleet.protocol import JobHistoryEntry, JobsView
from gridfleet.protocol.messages import FINAL_JOB_STATES, JobView

api = blueprint("jobs", "pick-and-deliver jobs: submit, list, read, cancel")
HISTORY_BACK = timedelta(days=3600)  # how far back a job is looked for (a range < ten years)
HISTORY_PAGES = 10  # pages of one job's history read at most


def jobs_page(view: JobsView, query: JobsQuery) -> JobsPage:
    """One page of the view's listing (jobs not finished, then the latest finished), filtered."""
    listed = [
        j
        for j in view.listed()
        if (query.state is None or j.state == query.state)
        and (query.unit is None or j.unit == query.unit)
    ]
    start = 0 if query.cursor is None else int(query.cursor)
    end = start + query.limit
    more = str(end) if end < len(listed) else None
    return JobsPage(jobs=listed[start:end], next_cursor=more, counts=view.counts)


def listed_job(view: FleetView, job_id: str) -> JobView | None:
    """The job as the queue view lists it (None: not listed)."""
    if view.jobs is None:
        return None
    return next((j for j in view.jobs.listed() if j.id == job_id), None)


def from_history(entry: JobHistoryEntry) -> JobView:
    """A job as its latest history entry tells it (a job the queue view no longer lists)."""
    final = entry.state in FINAL_JOB_STATES
    return JobView(
        id=entry.job,
        pickup=entry.pickup,
        dropoff=entry.dropoff,
        mass_kg=entry.mass_kg,
        priority=entry.priority,
        state=entry.state,
        unit=entry.unit,
        reason=entry.reason if final else None,
        submitted_by=entry.submitted_by,
        wait=None if final else entry.wait,
        wait_reason=None if final or entry.wait is None else entry.reason,
        pickup_place=entry.pickup_place,
        dropoff_place=entry.dropoff_place,
    )


async def find_job(view: FleetView, who: Caller, job_id: str, request_s: float) -> JobView:
    """The job from the queue view, else from its history; 404 when neither knows it."""
    found = listed_job(view, job_id)
    if found is not None:
        return found
    if not who.allowed("audit"):
        raise ApiProblem(
            "unknown_job",
            f"job {job_id!r} is not in the queue view (the jobs not finished and the latest "
            "finished), and a viewer account cannot read the job history",
        )
    if view.coordinator is None or view.coordinator.state != "online":
        raise ApiProblem(
            "not_online",
            f"job {job_id!r} is not in the queue view, and no coordinator is "
            "online to read its history from",
        )
    since = datetime.now(UTC) - HISTORY_BACK
    cursor: str | None = None
    last: JobHistoryEntry | None = None
    for _ in range(HISTORY_PAGES):
        page = accepted_page(
            await view.job_history(request_s, since=since, job_id=job_id, limit=1000, cursor=cursor)
        )
        if page.entries:
            last = page.entries[-1]
        cursor = page.next_cursor
        if cursor is None:
            break
    if last is None:
        raise ApiProblem("unknown_job", f"unknown job {job_id!r}", job_id=job_id)
    return from_history(last)


@api.get(
    "/jobs",
    summary="The jobs of the queue view: those not finished, then the latest finished",
    responses={200: JobsPage},
)
def list_jobs(query: JobsQuery) -> Response:
    """Filter by `state` and `unit`; `limit` a page, `cursor` the next (from `next_cursor`)."""
    who = caller("read")

    async def work(view: FleetView) -> JobsPage:
        if view.jobs is None:
            raise ApiProblem(
                "not_online", "no job queue on the broker yet: is the coordinator running?"
            )
        return jobs_page(view.jobs, query)

    return answer(current().run(who, work))


@api.post(
    "/jobs",
    summary="Submit a job; with an Idempotency-Key a retry is the same job, never a second",
    responses={201: JobView, **also(404, 409, 422)},
)
def submit_job(body: JobRequest, header: SubmitHeaders) -> Response:
    """`pickup` and `dropoff` are squares [x, y] or places' names (GET /places)."""
    who = caller("change")
    config = current().config
    key = header.idempotency_key
    derived = None if key is None else derived_id(who.name, key)

    async def work(view: FleetView) -> JobView:
        reply = await view.submit(body, derived, config.request_s)
        conflict = not reply.accepted and reply.code == "conflict"
        if conflict and key is not None and derived is not None:
            raise ApiProblem("idempotency_key_reused", reused_words(key, derived), job_id=derived)
        job_id = accepted(reply).job_id
        if job_id is None:
            raise ApiProblem("no_reply", "the coordinator accepted the job but named none")
        shown = await view.until(lambda: listed_job(view, job_id), config.view_s)
        if shown is not None:
            return shown
        try:
            return await find_job(view, who, job_id, config.request_s)
        except ApiProblem:
            raise ApiProblem(
                "no_reply",
                f"job {job_id} was accepted, but the queue view has not shown it within "
                f"{config.view_s:g} s: GET {PREFIX}/jobs/{job_id}",
                job_id=job_id,
            ) from None

    job = current().run(who, work, online=True)
    return answer(job, 201, {"Location": f"{PREFIX}/jobs/{job.id}"})


@api.get(
    "/jobs/<job_id>",
    summary="One job, from the queue view or its history",
    responses={200: JobView, **also(404, 422)},
)
def get_job(path: JobPath) -> Response:
    """A job the queue view no longer lists is read from the job history (its latest entry)."""
    who = caller("read")
    config = current().config

    async def work(view: FleetView) -> JobView:
        return await find_job(view, who, path.job_id, config.request_s)

    return answer(current().run(who, work))


@api.delete(
    "/jobs/<job_id>",
    summary="Cancel a job: a queued one is deleted, an active one aborted safely",
    responses={200: JobView, **also(404, 409, 422)},
)
def cancel_job(path: JobPath) -> Response:
    """A job already final is refused (409)."""
    who = caller("change")
    config = current().config

    async def work(view: FleetView) -> JobView:
        accepted(await view.cancel_job(path.job_id, config.request_s))

        def final() -> JobView | None:
            job = listed_job(view, path.job_id)
            return job if job is not None and job.state in FINAL_JOB_STATES else None

        shown = await view.until(final, config.view_s)
        return (
            shown if shown is not None else await find_job(view, who, path.job_id, config.request_s)
        )

    return answer(current().run(who, work, online=True))
