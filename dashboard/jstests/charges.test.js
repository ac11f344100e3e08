// The History tab's charges (issue 54): the query of kind "charges" its switch makes, each charge
// entry checked before it is shown (a bad one is left out, counted), its cells, summary and CSV.
import assert from "node:assert/strict";
import { test } from "node:test";
import {
  CHARGE_COLUMNS, chargeCells, chargeRow, chargeSummary, csvName, historyCsv, historyEntriesOf, historyQuery,
  isChargeEntry, isHistoryEntry, isJobEntry,
} from "../static/js/history.js";
import { PagedQuery } from "../static/js/paging.js";

const NOW = Date.parse("2026-11-27T10:30:00Z");
const charge = (more = {}) => ({
  at: "2026-11-27T09:00:00.123456Z", unit: "u03", charger: "C1", event: "started", battery_pct: 35,
  reason: "battery at 35 % (below 40 %)", ...more,
});
const job = (more = {}) => ({
  at: "2026-11-27T09:00:00Z", job: "j1", state: "queued", unit: null, since_submitted_s: 0,
  pickup: [1, 2], dropoff: [8, 9], mass_kg: 1.5, priority: 0, submitted_by: "dash", ...more,
});

test("the charges' query takes the range and the unit, never the job or state filters", () => {
  const fields = { kind: "charges", since: "2026-11-27T09:00:00Z", until: "", unit: " u03 ", job: "j1", state: "done" };
  assert.deepEqual(historyQuery(fields, NOW).body, {
    kind: "charges", since: "2026-11-27T09:00:00.000Z", until: null, unit: "u03", job_id: null, state: null,
    limit: 200, cursor: null,
  });
  // Even a job or state the jobs' query would refuse is no matter: those filters are the jobs'.
  assert.ok(historyQuery({ ...fields, job: "a/b", state: "lost" }, NOW).body);
  assert.equal(historyQuery({ ...fields, kind: "" }, NOW).body.kind, "jobs");
  assert.equal(historyQuery({ ...fields, kind: "jobs" }, NOW).body.state, "done");
  const error = (more) => historyQuery({ ...fields, ...more }, NOW).error;
  assert.match(error({ unit: "u 3" }), /^unit "u 3": letters, digits/);
  assert.equal(error({ kind: "energy" }), '"energy" is neither jobs nor charges');
  assert.match(error({ until: "2026-11-27T08:00:00Z" }), /is not before until/);
});

test("a charge entry is shown only as §6.10 has it", () => {
  assert.ok(isChargeEntry(charge()));
  assert.ok(isChargeEntry(charge({ reason: null, event: "ended", battery_pct: 100 })));
  assert.ok(isChargeEntry(charge({ reason: undefined, battery_pct: 0 })));
  for (const bad of [
    null, "u03", [charge()], charge({ at: "soon" }), charge({ at: 5 }), charge({ unit: null }), charge({ unit: "u 3" }),
    charge({ charger: undefined }), charge({ event: "paused" }), charge({ battery_pct: "35" }),
    charge({ battery_pct: -1 }), charge({ battery_pct: 100.5 }), charge({ battery_pct: NaN }), charge({ reason: 7 }),
  ]) assert.equal(isChargeEntry(bad), false, JSON.stringify(bad));
  // The jobs' entries are checked too, each by its own kind's rule.
  assert.ok(isJobEntry(job()));
  for (const bad of [null, job({ job: 7 }), job({ state: "lost" }), job({ at: null }), job({ unit: "a b" }),
    job({ reason: {} }), job({ since_submitted_s: "5" })]) assert.equal(isJobEntry(bad), false, JSON.stringify(bad));
  assert.ok(isHistoryEntry(charge(), { kind: "charges" }));
  assert.equal(isHistoryEntry(charge(), { kind: "jobs" }), false);
  assert.ok(isHistoryEntry(job(), {}));
});

test("a charges' page is read from its charges, bad entries left out and counted", () => {
  const q = new PagedQuery({ entriesOf: historyEntriesOf, valid: isHistoryEntry });
  q.begin(historyQuery({ kind: "charges", since: "" }, NOW).body);
  q.sent("r-1");
  const page = {
    request_id: "r-1", accepted: true, entries: [job()],
    charges: [charge(), null, charge({ battery_pct: 250 }), charge({ event: "ended", battery_pct: 82 })], next_cursor: "4",
  };
  assert.ok(q.take(page));
  assert.deepEqual(q.entries.map((e) => e.event), ["started", "ended"]);
  assert.equal(q.dropped, 2);
  q.sent("r-2");
  assert.ok(q.take({ request_id: "r-2", accepted: true, charges: "not a list", next_cursor: null }));
  assert.equal(q.entries.length, 2);
  assert.ok(q.complete);
  // The jobs' query reads `entries`; a new query counts afresh.
  q.begin(historyQuery({ since: "" }, NOW).body);
  assert.equal(q.dropped, 0);
  q.sent("r-3");
  assert.ok(q.take({ ...page, request_id: "r-3", entries: [job(), { job: "j2" }] }));
  assert.deepEqual(q.entries, [job()]);
  assert.equal(q.dropped, 1);
});

test("a charge's cells, the summary and the CSV are the command's", () => {
  const clock = (iso) => iso.slice(11, 19);
  assert.deepEqual(chargeCells(charge(), clock), [
    ["09:00:00", "at"], ["u03", "unit"], ["C1", "charger"], ["started", "event"], ["35.0 %", "battery"],
    ["battery at 35 % (below 40 %)", "reason"],
  ]);
  assert.deepEqual(chargeCells(charge({ reason: null, battery_pct: 82.25 }), clock).slice(4), [["82.3 %", "battery"], ["", "reason"]]);
  assert.deepEqual(CHARGE_COLUMNS, ["at", "unit", "charger", "event", "battery_pct", "reason"]);
  assert.deepEqual(chargeRow(charge({ reason: null })), ["2026-11-27T09:00:00.123Z", "u03", "C1", "started", "35", ""]);
  const ended = charge({ event: "ended", battery_pct: 82.5, reason: 'full, "95 %"', at: "2026-11-27T09:00:24Z" });
  assert.equal(historyCsv([charge(), ended], "charges"), "at,unit,charger,event,battery_pct,reason\n"
    + "2026-11-27T09:00:00.123Z,u03,C1,started,35,battery at 35 % (below 40 %)\n"
    + '2026-11-27T09:00:24.000Z,u03,C1,ended,82.5,"full, ""95 %"""\n');
  assert.equal(csvName({ kind: "charges", since: "2026-11-26T10:30:00.000Z", until: null }, NOW),
    "gridfleet-charges-2026-11-26T103000Z-2026-11-27T103000Z.csv");
  assert.equal(chargeSummary([charge(), ended, charge({ unit: "u04" })], true),
    "3 charge entries (more to load) — started 2 · ended 1 — 2 units");
  assert.equal(chargeSummary([charge()], false), "1 charge entry — started 1 · ended 0 — 1 unit");
  assert.equal(chargeSummary([], false), "no charge started or ended in this range");
});
