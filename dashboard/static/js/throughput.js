// The day's throughput: jobs done in each of the last 24 clock hours, read from the coordinator's
// job history (protocol.md §6.10, its `done` entries), so it tells yesterday afternoon as well as
// the last minutes. Pure: no DOM, no network, no clock (callers pass `now` in ms).
//
// The page asks once for the whole day, then once a minute (sooner when jobs were done, at most
// every SOONEST_MS) only for what is new since: a busy fleet's day is thousands of entries, and
// asking for all of them each time would cost the coordinator and the page for nothing.

import { EXPORT_PAGE } from "./history.js";

export const HOURS = 24;
export const HOUR_MS = 3600 * 1000;
export const REFRESH_MS = 60 * 1000; // how often the page asks for the newest done jobs
// Sooner when the coordinator's queue view counts more jobs done than at the last question (the
// chart would otherwise say "none" for up to a minute), but not more often than this.
export const SOONEST_MS = 15 * 1000;

/** Whether to ask the history again at `now` (ms): {at, done} of the last question, `done` now. */
export function dayDue(last, done, now) {
  if (!last) return true;
  const waited = now - last.at;
  return waited >= REFRESH_MS || (waited >= SOONEST_MS && Number.isInteger(done) && done !== last.done);
}
// Entries are stamped when the coordinator made the change: one stamped a moment before the last
// one seen may still arrive; asking again from a little earlier catches it (a job counts once).
// Only the coordinator's own stamps move `through`: the page's clock may differ from its clock.
const OVERLAP_MS = 5000;

/** The start of the clock hour `ms` lies in (the page's own time zone's hours). */
export function hourStart(ms) {
  const d = new Date(ms);
  d.setMinutes(0, 0, 0);
  return d.getTime();
}

export class DayThroughput {
  constructor() {
    this.done = new Map(); // job id -> when it was done (ms): each job counts once
    this.through = null; // every done entry up to here (ms) is in
  }

  /** The first hour the chart shows: 23 hours before the current one. */
  firstHour(now) {
    return hourStart(now) - (HOURS - 1) * HOUR_MS;
  }

  /** The job_history request for what is not in yet: the whole day first, then what is new. */
  query(now) {
    const first = this.firstHour(now);
    const since = this.through == null ? first : Math.max(first, this.through - OVERLAP_MS);
    return { since: new Date(since).toISOString(), until: null, unit: null, job_id: null, state: "done", limit: EXPORT_PAGE, cursor: null };
  }

  /** A page's entries: their done jobs counted in their hour. */
  add(entries) {
    for (const e of entries) {
      if (e?.state !== "done" || typeof e.job !== "string") continue;
      const t = Date.parse(e.at);
      if (Number.isNaN(t)) continue;
      this.done.set(e.job, t);
      this.through = this.through == null ? t : Math.max(this.through, t);
    }
  }

  /** Jobs done in each of the last 24 clock hours at `now`, oldest first, the current hour last. */
  perHour(now) {
    const first = this.firstHour(now);
    const counts = new Array(HOURS).fill(0);
    for (const [job, t] of this.done) {
      if (t < first) { this.done.delete(job); continue; } // out of the day: forgotten
      const i = Math.floor((t - first) / HOUR_MS);
      if (i < HOURS) counts[i] += 1;
    }
    return counts;
  }
}
