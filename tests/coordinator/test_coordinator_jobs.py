"""The queue view stays small: jobs under way, the latest finished, counts of all, done per minute."""

from __future__ import annotations

from gridfleet.coordinator.jobs import Job, JobBook
from gridfleet.grid import Cell
from gridfleet.protocol import encode
from gridfleet.protocol.constants import MAX_OPEN_JOBS, MAX_VIEW_BYTES
from gridfleet.protocol.messages import CHART_MINUTES, FINISHED_LISTED

from support.effects import header


def book_with(done: int, queued: int = 3) -> JobBook:
    """`done` jobs done one step apart (steps 1..done), then `queued` jobs waiting."""
    book = JobBook()
    for n in range(done + queued):
        book.add(Job(f"job-{n + 1}", Cell(0, 0), Cell(1, 1), 1.0, created_step=n))
    for n in range(done):
        book.set(book.jobs[f"job-{n + 1}"], "done", done_step=n + 1)
    return book


def test_the_view_lists_the_jobs_under_way_and_only_the_latest_finished_newest_first() -> None:
    book = book_with(done=50)
    view = book.view(header("coordinator"), step_no=50, step_period_s=1.0)
    assert [j.id for j in view.jobs] == ["job-51", "job-52", "job-53"]
    assert [j.id for j in view.finished] == [
        f"job-{n}" for n in range(50, 50 - FINISHED_LISTED, -1)
    ]
    assert view.counts == {"done": 50, "queued": 3}


def test_its_size_does_not_grow_with_the_jobs_that_finished() -> None:
    def size(done: int) -> int:
        view = book_with(done).view(header("coordinator"), step_no=done, step_period_s=1.0)
        return len(encode(view))

    # Both list 3 waiting and 20 finished: only longer ids and counts differ (900 more finished
    # jobs listed would be about 200 kB).
    assert size(100) < 8000
    assert size(1000) - size(100) < 300


def test_jobs_done_per_minute_count_back_from_the_current_step() -> None:
    book = JobBook()
    # 0.5 s a step: 120 steps a minute. Done at steps 0, 100, 119, 120, 130 and 1300.
    for n, at in enumerate([0, 100, 119, 120, 130, 1300]):
        job = book.add(Job(f"j{n}", Cell(0, 0), Cell(1, 1), 1.0))
        book.set(job, "done", done_step=at)
    cancelled = book.add(Job("c", Cell(0, 0), Cell(1, 1), 1.0))
    book.set(cancelled, "cancelled", done_step=125)
    counts = book.done_per_minute(step_no=1319, step_period_s=0.5)
    assert len(counts) == CHART_MINUTES
    # Step 1319 is in minute 10 (steps 1200..1319 are 0 minutes ago); 1300 is there, the others
    # more than 9 minutes ago (1319 - 130 = 1189 steps: minute 9 ago, the oldest shown).
    assert counts == [2, 0, 0, 0, 0, 0, 0, 0, 0, 1]
    assert book.done_per_minute(step_no=5000, step_period_s=0.5) == [0] * CHART_MINUTES


def test_a_restarted_book_lists_the_same_finished_jobs_and_counts() -> None:
    book = book_with(done=30)
    again = JobBook(list(book.jobs.values()))
    stamp = header("coordinator")
    assert again.view(stamp, 30, 1.0) == book.view(stamp, 30, 1.0)


def test_a_units_job_follows_it_through_the_life_cycle_and_is_forgotten_when_final() -> None:
    book = book_with(done=5, queued=2)
    first, second = book.jobs["job-6"], book.jobs["job-7"]
    assert book.of_unit("u1") is None
    book.set(first, "assigned", unit="u1")
    book.set(second, "assigned", unit="u2")
    book.set(first, "to_pickup")
    assert (book.of_unit("u1"), book.of_unit("u2")) == (first, second)
    assert book.active() == [first, second] and book.queued() == []
    book.set(second, "queued", unit=None)  # handed back, e.g. its unit went away
    assert book.of_unit("u2") is None and book.queued() == [second]
    book.set(first, "done", done_step=9)
    assert book.of_unit("u1") is None and book.active() == []
    assert [j.id for j in book.view(header("coordinator")).jobs] == ["job-7"]


def test_a_restored_book_knows_which_unit_works_on_what() -> None:
    book = book_with(done=3, queued=2)
    book.set(book.jobs["job-5"], "loaded", unit="u9")
    restored = JobBook([Job.from_dict(j.to_dict()) for j in book.jobs.values()])
    assert restored.of_unit("u9") == book.jobs["job-5"]
    assert [j.id for j in restored.queued()] == ["job-4"]


def test_a_full_queue_of_the_longest_jobs_fits_in_the_view() -> None:
    longest = "j" * 64
    book = JobBook()
    for n in range(MAX_OPEN_JOBS):
        job = Job(f"{n}{longest}"[:64], Cell(4095, 4095), Cell(4095, 4095), 1e9, priority=100)
        job.submitted_by, job.created_step = "s" * 64, 10**9
        book.add(job)
        book.explain(job, ("unit_stuck", "w" * 500))
        book.set(job, "to_pickup", unit="u" * 64)
    for n in range(FINISHED_LISTED):
        done = book.add(Job(f"done-{n}", Cell(0, 0), Cell(1, 1), 1.0))
        book.set(done, "failed", reason="r" * 500, done_step=10**9)
    view = book.view(header("coordinator"), step_no=10**9, step_period_s=0.001)
    assert len(encode(view)) <= MAX_VIEW_BYTES
