// The records beside the map (issue 35): the History view's query, CSV and summary, paging by
// cursor, the day's throughput from the history, alerts until acknowledged, the audit's words.
import assert from "node:assert/strict";
import { test } from "node:test";
import { ackRequest, alertCells, alertsKey, alertsOf, alertWhen, moreText, unacknowledged } from "../static/js/alerts.js";
import { auditCells, auditQuery, mayReadAudit } from "../static/js/audit.js";
import {
  csvCell, csvName, DAY_MS, HISTORY_COLUMNS, historyCells, historyCsv, historyQuery, historyRow, historySummary,
  localInputValue, readTime, shortStamp, utcStamp,
} from "../static/js/history.js";
import { PagedQuery } from "../static/js/paging.js";
import { DayThroughput, dayDue, HOUR_MS, hourStart, REFRESH_MS, SOONEST_MS } from "../static/js/throughput.js";

const NOW = Date.parse("2026-11-27T10:30:00Z");
const entry = (job, at, state = "queued", more = {}) => ({
  at, job, state, unit: "unit1", since_submitted_s: 0, pickup: [1, 2], dropoff: [8, 9], mass_kg: 1.5,
  priority: 0, submitted_by: "dash", ...more,
});

test("the history's filters make the request, and a mistake is told before anything is sent", () => {
  const local = localInputValue(NOW - 3600000);
  const { body } = historyQuery({ since: local, until: "", unit: " unit2 ", job: "", state: "done" }, NOW);
  assert.deepEqual(body, {
    kind: "jobs", since: new Date(local).toISOString(), until: null, unit: "unit2", job_id: null, state: "done", limit: 200, cursor: null,
  });
  // An empty since is the last day; a time with its zone is taken as it says.
  assert.equal(historyQuery({ since: "" }, NOW).body.since, new Date(NOW - DAY_MS).toISOString());
  assert.equal(historyQuery({ since: "2026-11-26T14:00:00Z" }, NOW, 1000).body.limit, 1000);
  const error = (fields) => historyQuery(fields, NOW).error;
  assert.equal(error({ since: "2026-11-27T10:00", until: "2026-11-26T10:00" }),
    "since 2026-11-27T10:00 is not before until 2026-11-26T10:00");
  assert.equal(error({ since: "2026-11-27T10:00", until: "2026-11-27T10:00" }),
    "since 2026-11-27T10:00 is not before until 2026-11-27T10:00");
  assert.match(error({ since: "yesterday" }), /^since "yesterday" is not a time/);
  assert.match(error({ since: "2026-13-45T99:99" }), /is not a time/);
  assert.match(error({ since: "", unit: "unit 1" }), /^unit "unit 1": letters, digits/);
  assert.match(error({ since: "", job: "a/b" }), /^job "a\/b": letters/);
  assert.match(error({ since: "", state: "lost" }), /^state "lost" is not one of queued, assigned/);
  assert.equal(readTime("", "since"), null);
});

test("the CSV has the command's columns, its times, its quoting and its empty cells", () => {
  assert.deepEqual(HISTORY_COLUMNS, [
    "at", "job", "state", "unit", "wait", "reason", "since_submitted_s", "pickup_x",
    "pickup_y", "dropoff_x", "dropoff_y", "mass_kg", "priority", "submitted_by",
  ]);
  // The coordinator's microseconds cut to milliseconds, as Python's isoformat writes them.
  assert.equal(utcStamp("2026-11-27T09:59:51.757826Z"), "2026-11-27T09:59:51.757Z");
  assert.equal(utcStamp("2026-11-27T09:59:51+00:00"), "2026-11-27T09:59:51.000Z");
  assert.equal(utcStamp("2026-11-27T10:59:51.5+01:00"), "2026-11-27T09:59:51.500Z");
  const e = entry("j1", "2026-11-27T09:00:00.123456Z", "done", { reason: 'said "no", twice\nthen yes', since_submitted_s: 80.5, unit: null });
  assert.deepEqual(historyRow(e), [
    "2026-11-27T09:00:00.123Z", "j1", "done", "", "", 'said "no", twice\nthen yes', "80.5", "1", "2", "8", "9",
    "1.5", "0", "dash",
  ]);
  assert.equal(csvCell("plain"), "plain");
  assert.equal(csvCell('a "b", c'), '"a ""b"", c"');
  const text = historyCsv([entry("j1", "2026-11-27T09:00:00Z")]);
  assert.equal(text, `${HISTORY_COLUMNS.join(",")}\n2026-11-27T09:00:00.000Z,j1,queued,unit1,,,0,1,2,8,9,1.5,0,dash\n`);
  assert.equal(historyCsv([]), `${HISTORY_COLUMNS.join(",")}\n`);
  assert.equal(csvName({ since: "2026-11-26T10:30:00.000Z", until: null }, NOW),
    "gridfleet-history-2026-11-26T103000Z-2026-11-27T103000Z.csv");
});

test("the table shows how long each job took and the summary the jobs that ended", () => {
  const clock = (iso) => iso.slice(11, 19);
  const done = entry("j1", "2026-11-27T09:01:20Z", "done", { since_submitted_s: 80 });
  assert.deepEqual(historyCells(done, clock), [
    ["09:01:20", "at"], ["j1", "job"], ["done", "state"], ["unit1", "unit"], ["1 min 20 s", "took final"], ["", "reason"],
  ]);
  const under = entry("j2", "2026-11-27T09:00:05Z", "to_pickup", { since_submitted_s: 5, reason: "waits for unit3" });
  assert.deepEqual(historyCells(under, clock).slice(4), [["+5 s", "took"], ["waits for unit3", "reason"]]);
  const entries = [
    entry("j1", "a"), entry("j1", "b", "done", { since_submitted_s: 10 }), entry("j2", "c", "done", { since_submitted_s: 30 }),
    entry("j3", "d", "done", { since_submitted_s: 20 }), entry("j4", "e", "cancelled", { since_submitted_s: 3 }),
  ];
  assert.equal(historySummary(entries, false), "5 changes — jobs ended: done 3 · cancelled 1 — done took 20 s (median), 30 s at most");
  assert.equal(historySummary(entries.slice(0, 1), true), "1 changes (more to load)");
  assert.equal(historySummary([], false), "no change in this range");
});

test("a paged query goes on from each page's cursor and takes only its own pages", () => {
  const q = new PagedQuery();
  assert.equal(q.more(), null);
  const first = q.begin({ since: "s", limit: 200, cursor: "stale" });
  assert.equal(first.cursor, null);
  q.sent("r-1");
  assert.ok(q.busy);
  assert.equal(q.more(), null, "one page at a time");
  assert.equal(q.take({ request_id: "r-0", accepted: true, entries: [1], next_cursor: "9" }), false);
  assert.ok(q.take({ request_id: "r-1", accepted: true, entries: [1, 2], next_cursor: "2" }));
  assert.deepEqual(q.entries, [1, 2]);
  assert.deepEqual(q.more(1000), { since: "s", limit: 1000, cursor: "2" });
  q.sent("r-2");
  assert.equal(q.take({ request_id: "r-1", accepted: true, entries: [1, 2], next_cursor: "2" }), false, "a page again");
  assert.ok(q.take({ request_id: "r-2", accepted: true, entries: [3], next_cursor: null }));
  assert.ok(q.complete);
  assert.deepEqual(q.entries, [1, 2, 3]);
  // A refusal is kept in words; a new query forgets the old one's pages.
  q.begin({ since: "t", limit: 5 });
  q.sent("r-3");
  assert.ok(q.take({ request_id: "r-3", accepted: false, reason: "since … is not before until …" }));
  assert.equal(q.error, "since … is not before until …");
  assert.deepEqual(q.entries, []);
  assert.ok(!q.complete);
  q.begin({ since: "u" });
  q.sent("r-4");
  q.gaveUp("no reply");
  assert.ok(!q.busy);
  assert.equal(q.error, "no reply");
});

test("the day's chart counts done jobs in their clock hour, once each, and asks only for what is new", () => {
  const day = new DayThroughput();
  const first = hourStart(NOW) - 23 * HOUR_MS;
  const asked = day.query(NOW);
  assert.deepEqual(asked, {
    since: new Date(first).toISOString(), until: null, unit: null, job_id: null, state: "done", limit: 1000, cursor: null,
  });
  const at = (ms) => new Date(ms).toISOString();
  day.add([
    entry("a", at(first + 10), "done"), entry("b", at(first + HOUR_MS + 5), "done"),
    entry("c", at(NOW - 60000), "done"), entry("d", at(NOW - 1000), "done"),
    entry("e", at(NOW - 500), "queued"), // not done: not counted
  ]);
  const counts = day.perHour(NOW);
  assert.equal(counts.length, 24);
  assert.deepEqual([counts[0], counts[1], counts[23]], [1, 1, 2]);
  assert.equal(counts.reduce((a, b) => a + b), 4);
  // The next question starts a little before the newest done entry; a job seen again counts once.
  assert.equal(day.query(NOW).since, at(NOW - 1000 - 5000));
  day.add([entry("d", at(NOW - 1000), "done")]);
  assert.equal(day.perHour(NOW)[23], 2);
  // An hour later the oldest hour has left the chart, and its jobs are forgotten.
  const later = day.perHour(NOW + HOUR_MS);
  assert.deepEqual([later[0], later[22], later[23]], [1, 2, 0]);
  assert.ok(!day.done.has("a"));
});

test("alerts stay as notifications until acknowledged, in force or cleared", () => {
  const a = (id, more) => ({ id, rule: "unit_lost", subject: "u1", severity: "warning", text: `alert ${id}`, raised_at: "2026-11-27T10:00:00Z", ...more });
  const view = alertsOf({
    active: [a("1"), a("2", { severity: "critical", raised_at: "2026-11-27T10:05:00Z" }), a("3", { acked_by: "ann", acked_at: "2026-11-27T10:06:00Z" })],
    cleared: [a("4", { cleared_at: "2026-11-27T10:02:00Z", raised_at: "2026-11-27T09:00:00Z" }), { id: 5 }, null],
  });
  assert.equal(view.cleared.length, 1, "malformed entries are left out");
  assert.deepEqual(unacknowledged(view).map((x) => x.id), ["2", "4", "1"]); // critical first, then oldest
  assert.deepEqual(alertsOf(null), { active: [], cleared: [] });
  const clock = (iso) => iso.slice(11, 16);
  assert.equal(alertWhen(view.active[0], clock), "raised 10:00 · in force");
  assert.equal(alertWhen(view.cleared[0], clock), "raised 09:00 · cleared 10:02");
  assert.equal(moreText(4), "");
  assert.equal(moreText(7), "+ 3 more not acknowledged: see Alerts");
  assert.deepEqual(ackRequest(view.active[0]), { what: "acknowledge unit_lost 1", body: { alert_id: "1" } });
  assert.deepEqual(alertCells(view.active[2], clock).map(([t]) => t), ["warning", "alert 3", "10:00", "in force", "ann 10:06"]);
  assert.notEqual(alertsKey(view), alertsKey(alertsOf({ ...view, active: [a("1", { acked_by: "bob" })] })));
});

test("the audit's filters and rows; who may read it", () => {
  assert.equal(mayReadAudit({ audit: true }), true);
  assert.equal(mayReadAudit({ audit: false }), false);
  assert.equal(mayReadAudit({}), true, "a dashboard that does not say: the coordinator judges");
  const { body } = auditQuery({ since: "", until: "", actor: "ann" }, NOW);
  assert.deepEqual(body, { since: new Date(NOW - DAY_MS).toISOString(), until: null, actor: "ann", limit: 200, cursor: null });
  assert.match(auditQuery({ since: "", actor: "no one" }, NOW).error, /^account "no one": letters/);
  assert.equal(auditQuery({ since: "2026-11-27T10:00", until: "2026-11-27T09:00" }, NOW).error,
    "since 2026-11-27T10:00 is not before until 2026-11-27T09:00");
  const clock = (iso) => iso.slice(11, 19);
  const refused = { at: "2026-11-21T14:06:10.500Z", actor: "operator", verified: false, act: "pause", target: "unit9", outcome: "refused", reason: "unknown unit 'unit9'" };
  assert.deepEqual(auditCells(refused, clock), [
    ["14:06:10", "at"], ["operator?", "actor"], ["pause", "act"], ["unit9", "target"], ["", "detail"],
    ["refused: unknown unit 'unit9'", "outcome refused"],
  ]);
});

test("short times name the day only when it is not today", () => {
  const today = new Date(NOW);
  const iso = new Date(today.getFullYear(), today.getMonth(), today.getDate(), 8, 5, 9).toISOString();
  assert.equal(shortStamp(iso, NOW), "08:05:09");
  const before = new Date(today.getFullYear(), today.getMonth(), today.getDate() - 1, 23, 59).toISOString();
  assert.match(shortStamp(before, NOW), /^\d\d-\d\d 23:59$/);
  assert.equal(shortStamp("nonsense", NOW), "");
});

test("the day's chart asks again once a minute, or sooner once more jobs are done", () => {
  assert.equal(dayDue(null, 3, NOW), true, "never asked");
  const last = { at: NOW, done: 3 };
  assert.equal(dayDue(last, 3, NOW + SOONEST_MS), false, "nothing new done");
  assert.equal(dayDue(last, 4, NOW + SOONEST_MS - 1), false, "not that soon");
  assert.equal(dayDue(last, 4, NOW + SOONEST_MS), true);
  assert.equal(dayDue(last, undefined, NOW + SOONEST_MS), false, "no count from the coordinator yet");
  assert.equal(dayDue(last, 3, NOW + REFRESH_MS), true, "a minute: a new hour may have begun");
});
